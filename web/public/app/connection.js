// A session's WebSocket, kept open through dropped connections and server restarts: the browser
// twin of client/src/watcher.rs. The newest frame is what the picture is drawn from, and it stays
// when the connection goes: the page keeps its last indirect light while disconnected.
//
// Retries wait 250 ms doubling to 5 s, each wait drawn between half and all of that (jitter, so a
// restarted server is not hit by every viewer at once), back to the start once frames flow. A
// refusal that retrying cannot fix (an unknown session) waits the longest each time rather than
// giving up: the session's server may come back with it.
//
// Order: a frame is kept only if it is newer than the one held. On one connection that is a
// greater (lights version, sequence); after a reconnect sequences restart, so a frame is newer
// when its lights version is at least the held one's.
//
// Probes: with `probes` set the socket asks for probe frames (`?probes=1`). A probe frame is kept
// only when it carries the sequence and lights version of the patch frame just kept on the same
// connection, so the probes' light is never older or newer than the walls'.

import { ApiError, getSession, socketUrl } from './api.js';
import { parseFrame } from './frame.js';

const INITIAL_BACKOFF_MS = 250;
const MAX_BACKOFF_MS = 5000;

// Close codes the server uses (server/src/ws.rs, http.rs ErrorCode::close_code).
const CLOSE_REASONS = {
  1001: 'the server is shutting down',
  1009: 'a message was over the 1 MiB limit',
  1011: 'the server failed',
  4400: 'the server refused a message as invalid',
  4401: 'the server refused the write token',
  4404: 'the session no longer exists',
  4503: 'the server is unavailable',
};

export class Connection {
  constructor(sessionId, token, handlers, { probes = false } = {}) {
    this.sessionId = sessionId;
    this.token = token;
    // onFrame(frame, receivedAt), onProbes(frame, receivedAt), onState({state, detail}),
    // onHello(hello)
    this.handlers = handlers;
    this.probes = probes;
    this.attempt = 0;
    this.held = null; // {lightsVersion, sequence} of the newest frame kept
    this.connectionFrames = 0;
    this.closed = false;
    this.lastError = '';
    this.open();
  }

  open() {
    if (this.closed) return;
    this.attempt += 1;
    this.handlers.onState({ state: 'connecting', detail: `attempt ${this.attempt}` });
    const ws = new WebSocket(socketUrl(this.sessionId, this.token, { probes: this.probes }));
    ws.binaryType = 'arraybuffer';
    this.ws = ws;
    this.connectionFrames = 0;
    let hello = false;
    let sameConnection = false;
    let kept = null; // the patch frame last kept on this connection, for its probe frame
    ws.onmessage = (event) => {
      if (typeof event.data === 'string') {
        let message;
        try {
          message = JSON.parse(event.data);
        } catch {
          this.lastError = 'the server sent a text message that is not JSON';
          return;
        }
        if (message.type === 'hello') {
          hello = true;
          this.attempt = 0;
          this.handlers.onHello?.(message);
          this.handlers.onState({ state: 'live', detail: '' });
        } else if (message.type === 'error') {
          this.lastError = `${message.code}: ${message.message}`;
        }
        return;
      }
      const receivedAt = performance.now();
      let frame;
      try {
        frame = parseFrame(event.data);
      } catch (e) {
        this.lastError = e.message;
        this.handlers.onState({ state: 'live', detail: `bad frame: ${e.message}` });
        return;
      }
      if (frame.kind === 'probes') {
        if (kept && frame.sequence === kept.sequence && frame.lightsVersion === kept.lightsVersion) {
          kept = null;
          this.handlers.onProbes?.(frame, receivedAt);
        }
        return;
      }
      if (!this.isNewer(frame, sameConnection)) {
        kept = null;
        return;
      }
      kept = frame;
      sameConnection = true;
      this.connectionFrames += 1;
      this.held = { lightsVersion: frame.lightsVersion, sequence: frame.sequence };
      this.handlers.onFrame(frame, receivedAt);
    };
    ws.onclose = async (event) => {
      if (this.closed) return;
      let reason = CLOSE_REASONS[event.code] ?? (event.reason || `connection closed (${event.code})`);
      if (this.lastError) reason = `${reason}: ${this.lastError}`;
      this.lastError = '';
      let delay = Math.min(MAX_BACKOFF_MS, INITIAL_BACKOFF_MS * 2 ** Math.min(this.attempt - 1, 10));
      if (!hello) {
        // The upgrade itself failed: the browser does not say why, so ask.
        try {
          await getSession(this.sessionId);
        } catch (e) {
          if (e instanceof ApiError && e.status === 404) {
            reason = `session ${this.sessionId} does not exist (it expired, or was never created)`;
            delay = MAX_BACKOFF_MS;
          } else {
            reason = e.message;
          }
        }
      }
      if (this.closed) return;
      const wait = delay * (0.5 + 0.5 * Math.random());
      this.handlers.onState({ state: 'disconnected', detail: reason, retryInMs: wait });
      this.timer = setTimeout(() => this.open(), wait);
    };
  }

  isNewer(frame, sameConnection) {
    const h = this.held;
    if (!h) return true;
    if (sameConnection) {
      return frame.lightsVersion > h.lightsVersion || (frame.lightsVersion === h.lightsVersion && frame.sequence > h.sequence);
    }
    return frame.lightsVersion >= h.lightsVersion;
  }

  close() {
    this.closed = true;
    clearTimeout(this.timer);
    this.ws?.close(1000);
  }
}
