// The numbers a person watching the stream wants, as the native viewer's overlay shows them:
// frame rate, GI latency (a light edit to the indirect light answering it on screen), the frame
// sequence and lights version, bytes per frame, the connection.

const KEEP = 120;

function median(xs) {
  if (!xs.length) return null;
  const s = [...xs].sort((a, b) => a - b);
  return s[Math.floor(s.length / 2)];
}

function push(list, x) {
  list.push(x);
  if (list.length > KEEP) list.shift();
}

export class Overlay {
  constructor(element, visible) {
    this.el = element;
    this.visible = visible;
    this.el.hidden = !visible;
    this.intervals = [];
    this.drawTimes = [];
    this.latencies = [];
    this.lastNow = null;
    this.received_ = 0;
    this.lastFrame = null;
    this.firstDrawnAt = null;
    this.applyMs = null;
    this.shownAt = 0;
  }

  toggle() {
    this.visible = !this.visible;
    this.el.hidden = !this.visible;
  }

  frameTime(now, drawMs) {
    if (this.lastNow !== null) push(this.intervals, now - this.lastNow);
    this.lastNow = now;
    push(this.drawTimes, drawMs);
  }

  latency(ms) {
    push(this.latencies, ms);
  }

  received(frame) {
    this.received_ += 1;
    this.lastBytes = frame.bytes;
  }

  // A probe frame's bytes, counted into the frame's size: what a frame costs a viewer.
  receivedProbes(frame) {
    this.lastProbeBytes = frame.bytes;
  }

  frame(frame, applyMs, firstDrawnAt) {
    this.lastFrame = frame;
    this.applyMs = applyMs;
    this.firstDrawnAt = firstDrawnAt;
  }

  snapshot() {
    const interval = median(this.intervals);
    const f = this.lastFrame;
    return {
      fps: interval ? 1000 / interval : null,
      frame_interval_ms: interval,
      draw_ms: median(this.drawTimes),
      gi_latency_ms: median(this.latencies),
      gi_latencies_ms: [...this.latencies],
      frames_received: this.received_,
      sequence: f ? f.sequence : null,
      lights_version: f ? f.lightsVersion : null,
      frame_bytes: this.lastBytes ?? null,
      probe_frame_bytes: this.lastProbeBytes ?? null,
      flags: f ? f.flags : null,
      first_drawn_at_ms: this.firstDrawnAt,
    };
  }

  render(state) {
    if (!this.visible) return;
    const now = performance.now();
    // A few times a second is enough for text, and keeps layout work out of most frames.
    if (now - this.shownAt < 250) return;
    this.shownAt = now;
    const s = this.snapshot();
    const n = (x, digits = 1) => (x === null || x === undefined ? '–' : x.toFixed(digits));
    const c = state.connection;
    const link =
      c.state === 'disconnected'
        ? `disconnected: ${c.detail} (retrying in ${n((c.retryInMs ?? 0) / 1000)} s)`
        : `${c.state}${c.detail ? `: ${c.detail}` : ''}`;
    const terms = state.terms.direct && state.terms.indirect ? 'direct + indirect' : state.terms.direct ? 'direct only' : 'indirect only';
    const sel = state.lights.lights[state.selected];
    const lines = [
      `${n(s.fps)} fps · draw ${n(s.draw_ms, 2)} ms`,
      `GI latency ${n(s.gi_latency_ms, 0)} ms (median of ${this.latencies.length})`,
      `frame #${s.sequence ?? '–'} · lights v${s.lights_version ?? '–'} (session v${state.lightsVersion}) · ${s.frame_bytes ?? '–'} B${s.probe_frame_bytes ? ` + ${s.probe_frame_bytes} B probes` : ''}`,
      `${terms} [1/2/3] · ${state.fly ? 'fly [WASD QE, F: orbit]' : 'orbit [F: fly]'}${state.object ? ` · probe-lit sphere [P]: ${state.object}` : ''}`,
      `${state.writable ? 'drag a light, wheel over it to dim' : 'read-only'}${sel ? ` · light ${state.selected + 1}: ${sel.type}, ${n(sel.intensity, 2)}` : ''}`,
      link,
    ];
    if (s.flags) lines.push('frame flagged: some values were clamped or not finite');
    this.el.textContent = lines.join('\n');
  }
}
