//! The window and its loop: input, light edits sent to the source, new indirect light into the
//! stage, one draw a frame with the overlay, screenshots and the measurements.

use std::collections::HashSet;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use bounce_client::{LightSet, Volume};
use bounce_core::scene::Scene;
use bounce_engine::gpu::GpuContext;
use bounce_render::{
    Camera, IMAGE_FORMAT, Overlay, ProbeSphere, Renderer, Stage, Target, Terms, ambient_cube,
    read_buffer,
};
use glam::Vec3;
use winit::application::ApplicationHandler;
use winit::dpi::{PhysicalPosition, PhysicalSize};
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{KeyCode, PhysicalKey};
use winit::window::{Window, WindowId};

use super::edit;
use super::fly::{Fly, Motion};
use super::stats::{Stats, quantile};
use crate::indirect::{Answer, Source};

pub struct Options {
    pub width: u32,
    pub height: u32,
    pub exposure: f32,
    pub vsync: bool,
    pub frames: Option<u64>,
    pub auto_move: u32,
    pub screenshot: Option<PathBuf>,
    pub timeout: Duration,
    pub title: String,
    pub overlay: bool,
}

/// A light change on its way: sent at `sent`, answered by the server with `version`.
struct Pending {
    tag: u64,
    sent: Instant,
    version: Option<u64>,
    /// The first light configuration: its answer is the start-up time, not a GI latency.
    initial: bool,
}

/// The GPU side, made once the window exists.
struct Gfx {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    /// The surface can be copied from: screenshots are what the window shows.
    copy_src: bool,
    renderer: Renderer<'static>,
    stage: Stage,
    overlay: Overlay,
    depth: wgpu::TextureView,
}

pub struct App {
    options: Options,
    scene: Scene,
    radius: f32,
    centre: Vec3,
    lights: LightSet,
    selected: usize,
    source: Source,
    volume: Volume,
    fly: Fly,
    terms: Terms,
    /// Draw the probe-lit sphere ahead of the camera (`P`).
    sphere: bool,
    /// The newest probe irradiance (six values a probe of `source.layout().probes()`, in the
    /// face order), from the source's answers.
    probe_light: Vec<[f32; 3]>,
    held: HashSet<KeyCode>,
    drag: Option<PhysicalPosition<f64>>,
    gfx: Option<Gfx>,
    next_tag: u64,
    lights_changed: bool,
    send_lights: bool,
    pending: Vec<Pending>,
    shown: Option<Answer>,
    last_tick: Option<Instant>,
    last_present: Option<Instant>,
    started: Instant,
    moves_done: u32,
    frames_since_move: u64,
    with_indirect: u64,
    write_error: Option<String>,
    error: Option<anyhow::Error>,
    stats: Stats,
}

impl App {
    /// Opens the window and runs until it is closed, Esc, or the --frames are done.
    pub fn run(
        options: Options,
        scene: Scene,
        lights: LightSet,
        send_first: bool,
        source: Source,
        camera: Camera,
    ) -> Result<Stats> {
        let volume = Volume::new(source.layout()).context("building the irradiance volume")?;
        let (lo, hi) = scene.bounds().context("the scene has no triangles")?;
        let radius = ((hi - lo).length() / 2.0).max(1e-3);
        let stats = Stats {
            patches: source.layout().patch_count(),
            triangles: scene.triangles.len(),
            width: options.width,
            height: options.height,
            ..Stats::default()
        };
        let mut app = App {
            fly: Fly::from_camera(&camera, radius),
            options,
            scene,
            radius,
            centre: (lo + hi) / 2.0,
            lights,
            selected: 0,
            source,
            volume,
            terms: Terms {
                direct: true,
                indirect: true,
            },
            sphere: true,
            probe_light: Vec::new(),
            held: HashSet::new(),
            drag: None,
            gfx: None,
            next_tag: 1,
            lights_changed: true,
            send_lights: send_first,
            pending: Vec::new(),
            shown: None,
            last_tick: None,
            last_present: None,
            started: Instant::now(),
            moves_done: 0,
            frames_since_move: 0,
            with_indirect: 0,
            write_error: None,
            error: None,
            stats,
        };
        let event_loop = EventLoop::new().map_err(|e| {
            anyhow!("cannot open a window: {e} (is DISPLAY set? headless machines can run under Xvfb: xvfb-run bounce view ...)")
        })?;
        event_loop.set_control_flow(ControlFlow::Poll);
        event_loop
            .run_app(&mut app)
            .context("the window's event loop failed")?;
        if let Some(e) = app.error.take() {
            return Err(e);
        }
        app.stats.source = app.source.status();
        Ok(app.stats)
    }

    fn fail(&mut self, event_loop: &ActiveEventLoop, e: anyhow::Error) {
        self.error.get_or_insert(e);
        event_loop.exit();
    }

    fn open(&mut self, event_loop: &ActiveEventLoop) -> Result<Gfx> {
        let attributes = Window::default_attributes()
            .with_title(format!("bounce view: {}", self.options.title))
            .with_inner_size(PhysicalSize::new(self.options.width, self.options.height));
        let window = Arc::new(
            event_loop
                .create_window(attributes)
                .context("creating the window")?,
        );
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let surface = instance
            .create_surface(window.clone())
            .context("creating the window's surface")?;
        let request = |fallback: bool| {
            pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
                power_preference: wgpu::PowerPreference::HighPerformance,
                force_fallback_adapter: fallback,
                compatible_surface: Some(&surface),
                apply_limit_buckets: false,
            }))
        };
        let adapter = request(false)
            .or_else(|_| request(true))
            .map_err(|e| anyhow!("no GPU adapter can draw to this window: {e}"))?;
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("bounce-view"),
            required_features: adapter.features() & wgpu::Features::TEXTURE_COMPRESSION_BC,
            required_limits: adapter.limits(),
            ..Default::default()
        }))
        .context("opening the GPU device")?;
        // The window, its renderer and the context live until the process ends: leaking the
        // context lets the renderer borrow it for 'static.
        let ctx: &'static GpuContext = Box::leak(Box::new(GpuContext::from_device(
            device,
            queue,
            &adapter.get_info(),
        )));
        self.stats.adapter = ctx.adapter().to_string();
        eprintln!("window renderer: {}", ctx.adapter());

        let caps = surface.get_capabilities(&adapter);
        // The shader writes linear values for an sRGB target to encode.
        let format = caps
            .formats
            .iter()
            .copied()
            .find(|f| f.is_srgb())
            .or_else(|| caps.formats.first().copied())
            .context("the surface offers no format")?;
        let copy_src = caps.usages.contains(wgpu::TextureUsages::COPY_SRC);
        let size = window.inner_size();
        let config = wgpu::SurfaceConfiguration {
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                | if copy_src {
                    wgpu::TextureUsages::COPY_SRC
                } else {
                    wgpu::TextureUsages::empty()
                },
            format,
            color_space: wgpu::SurfaceColorSpace::Auto,
            width: size.width.max(1),
            height: size.height.max(1),
            present_mode: if self.options.vsync {
                wgpu::PresentMode::AutoVsync
            } else {
                wgpu::PresentMode::AutoNoVsync
            },
            desired_maximum_frame_latency: 2,
            alpha_mode: caps
                .alpha_modes
                .first()
                .copied()
                .unwrap_or(wgpu::CompositeAlphaMode::Auto),
            view_formats: vec![],
        };
        surface.configure(ctx.device(), &config);
        self.stats.surface = format!("{format:?}, {:?}", config.present_mode);
        let renderer = Renderer::with_formats(ctx, &[format, IMAGE_FORMAT])?;
        let mut stage = Stage::new(&renderer, &self.scene, &self.volume)?;
        stage.set_lights(&renderer, &self.lights)?;
        // Text twice the font's size from a 1000-pixel window up.
        let scale = if config.width >= 1000 { 2 } else { 1 };
        let overlay = Overlay::new(ctx.device(), &[format, IMAGE_FORMAT], scale)?;
        let depth = renderer.depth_view(config.width, config.height);
        Ok(Gfx {
            window,
            surface,
            config,
            copy_src,
            renderer,
            stage,
            overlay,
            depth,
        })
    }

    /// Held keys this frame: camera motion, and light motion (which marks the lights changed).
    fn apply_held_keys(&mut self, dt: f32) {
        let axis = |pos: KeyCode, neg: KeyCode| {
            f32::from(u8::from(self.held.contains(&pos)))
                - f32::from(u8::from(self.held.contains(&neg)))
        };
        let motion = Motion {
            right: axis(KeyCode::KeyD, KeyCode::KeyA),
            up: axis(KeyCode::KeyE, KeyCode::KeyQ),
            forward: axis(KeyCode::KeyW, KeyCode::KeyS),
        };
        let fast =
            self.held.contains(&KeyCode::ShiftLeft) || self.held.contains(&KeyCode::ShiftRight);
        self.fly.step(motion, dt, fast);

        // Light motion on the ground plane relative to the camera's heading.
        let right = self.fly.right();
        let ahead = Vec3::Y.cross(right).normalize_or(Vec3::NEG_Z);
        let dir = right * axis(KeyCode::ArrowRight, KeyCode::ArrowLeft)
            + ahead * axis(KeyCode::ArrowUp, KeyCode::ArrowDown)
            + Vec3::Y * axis(KeyCode::PageUp, KeyCode::PageDown);
        if dir != Vec3::ZERO {
            let step = dir * self.radius * 0.5 * dt;
            self.edit_selected(|light, radius| edit::nudge(light, step, radius));
        }
    }

    fn edit_selected(&mut self, f: impl FnOnce(&mut bounce_core::light::Light, f32)) {
        let radius = self.radius;
        if let Some(light) = self.lights.lights.get_mut(self.selected) {
            f(light, radius);
            self.lights_changed = true;
            self.send_lights = true;
        }
    }

    /// --auto-move: the selected light turns 20° about the scene's vertical axis through its
    /// centre, once the previous move is on screen and a few frames have shown it.
    fn auto_move(&mut self) {
        const SETTLE: u64 = 5;
        if self.moves_done >= self.options.auto_move
            || self.shown.is_none()
            || !self.pending.is_empty()
            || self.frames_since_move < SETTLE
        {
            return;
        }
        let centre = self.centre;
        let turn = glam::Quat::from_rotation_y(20f32.to_radians());
        self.edit_selected(|light, _| match light {
            bounce_core::light::Light::Point { position, .. }
            | bounce_core::light::Light::Spot { position, .. } => {
                let p = Vec3::from_array(*position) - centre;
                *position = (centre + turn * p).to_array();
            }
            bounce_core::light::Light::Directional { direction, .. } => {
                *direction = (turn * Vec3::from_array(*direction)).to_array();
            }
            bounce_core::light::Light::Sky { .. } | bounce_core::light::Light::Emissive { .. } => {}
        });
        self.moves_done += 1;
        self.frames_since_move = 0;
    }

    fn redraw(&mut self, event_loop: &ActiveEventLoop) -> Result<()> {
        let now = Instant::now();
        let dt = self
            .last_tick
            .map_or(0.0, |t| now.duration_since(t).as_secs_f32().min(0.1));
        self.last_tick = Some(now);
        self.apply_held_keys(dt);
        self.auto_move();

        for ack in self.source.acks() {
            if let Some(p) = self.pending.iter_mut().find(|p| p.tag == ack.tag) {
                p.version = ack.lights_version;
            }
            if let Some(e) = ack.error {
                self.write_error = Some(e);
                self.pending.retain(|p| p.tag != ack.tag);
            } else {
                self.write_error = None;
            }
        }
        if let Some((version, lights)) = self.source.others_lights()
            && self.pending.is_empty()
            && !self.send_lights
            && self
                .shown
                .as_ref()
                .is_none_or(|s| s.lights_version <= version)
        {
            self.lights = lights;
            self.selected = self
                .selected
                .min(self.lights.lights.len().saturating_sub(1));
            self.lights_changed = true;
        }
        let Some(gfx) = self.gfx.as_mut() else {
            return Ok(());
        };
        if self.lights_changed {
            gfx.stage.set_lights(&gfx.renderer, &self.lights)?;
            self.lights_changed = false;
        }
        if self.send_lights {
            let tag = self.next_tag;
            self.next_tag += 1;
            self.source.send(tag, &self.lights);
            let local = matches!(self.source, Source::Local(_));
            self.pending.push(Pending {
                tag,
                sent: now,
                // In process the tag is the version.
                version: local.then_some(tag),
                initial: tag == 1 && self.shown.is_none(),
            });
            self.send_lights = false;
        }
        if let Some(mut answer) = self.source.poll(&mut self.volume)? {
            gfx.stage.set_volume(&gfx.renderer, &self.volume);
            if let Some(probes) = answer.probes.take() {
                self.probe_light = probes;
            }
            self.shown = Some(answer);
        }

        let frame = match gfx.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t)
            | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => {
                return Ok(());
            }
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                gfx.surface
                    .configure(gfx.renderer.context().device(), &gfx.config);
                return Ok(());
            }
            other => bail!("the window's surface failed: {other:?}"),
        };
        let view = frame.texture.create_view(&Default::default());
        let ctx = gfx.renderer.context();
        let mut encoder = ctx.device().create_command_encoder(&Default::default());
        let target = Target {
            color: &view,
            format: gfx.config.format,
            depth: &gfx.depth,
            width: gfx.config.width,
            height: gfx.config.height,
        };
        let camera = self.fly.camera();
        let sphere = probe_sphere(
            self.sphere,
            self.source.layout().probes(),
            &self.probe_light,
            &camera,
            gfx.stage.bounds(),
        );
        gfx.stage.set_probe_sphere(&gfx.renderer, sphere);
        gfx.renderer.draw(
            &mut gfx.stage,
            &mut encoder,
            &target,
            &camera,
            self.options.exposure,
            self.terms,
        )?;
        let lines = if !self.options.overlay {
            Vec::new()
        } else {
            overlay_lines(
                &self.stats,
                &self.options.title,
                &self.source,
                self.shown.as_ref(),
                self.terms,
                sphere_status(
                    self.sphere,
                    self.source.layout().probes().len(),
                    gfx.stage.probe_sphere().is_some(),
                ),
                &self.lights,
                self.selected,
                self.write_error.as_deref(),
            )
        };
        let device = ctx.device();
        gfx.overlay
            .draw(device, ctx.queue(), &mut encoder, &target, &lines)?;

        let last = is_last(
            &self.options,
            self.shown.is_some(),
            self.with_indirect,
            self.moves_done,
            self.pending.is_empty(),
        );
        let shot = match (&self.options.screenshot, last) {
            (Some(path), true) if gfx.copy_src => {
                Some((path.clone(), copy_out(device, &mut encoder, &frame.texture)))
            }
            _ => None,
        };
        ctx.queue().submit([encoder.finish()]);
        if let Some((path, (buffer, padded))) = shot {
            save_copy(device, &buffer, padded, &gfx.config, &path)?;
            self.stats.screenshot = Some(format!("{} (the window's surface)", path.display()));
        } else if let (Some(path), true) = (&self.options.screenshot, last) {
            // This surface cannot be copied from: the same stage drawn offscreen instead.
            let image = gfx.renderer.render_stage(
                &mut gfx.stage,
                &camera,
                gfx.config.width,
                gfx.config.height,
                self.options.exposure,
                self.terms,
            )?;
            image::save_buffer(
                path,
                &image.pixels,
                image.width,
                image.height,
                image::ColorType::Rgba8,
            )
            .with_context(|| format!("writing {}", path.display()))?;
            self.stats.screenshot = Some(format!(
                "{} (offscreen: the surface cannot be copied)",
                path.display()
            ));
        }
        gfx.window.pre_present_notify();
        ctx.queue().present(frame);

        let presented = Instant::now();
        if let Some(prev) = self.last_present {
            self.stats
                .frame_ms
                .push(presented.duration_since(prev).as_secs_f64() * 1e3);
        }
        self.last_present = Some(presented);
        self.stats.frames += 1;
        self.frames_since_move += 1;
        if let Some(shown) = &self.shown {
            self.with_indirect += 1;
            if self.stats.first_indirect_ms.is_none() {
                self.stats.first_indirect_ms =
                    Some(presented.duration_since(self.started).as_secs_f64() * 1e3);
            }
            let answered = shown.lights_version;
            let stats = &mut self.stats;
            self.pending.retain(|p| match p.version {
                Some(v) if v <= answered => {
                    if !p.initial {
                        stats
                            .gi_latency_ms
                            .push(presented.duration_since(p.sent).as_secs_f64() * 1e3);
                    }
                    false
                }
                _ => true,
            });
        }
        if last {
            event_loop.exit();
        } else if self.options.frames.is_some() && self.started.elapsed() > self.options.timeout {
            bail!(
                "--frames: not done after {:.0} s ({} frames with indirect light, {} of {} moves, \
                 {} changes unanswered; source: {})",
                self.options.timeout.as_secs_f64(),
                self.with_indirect,
                self.moves_done,
                self.options.auto_move,
                self.pending.len(),
                self.source.status()
            );
        }
        Ok(())
    }

    fn key(
        &mut self,
        event_loop: &ActiveEventLoop,
        code: KeyCode,
        state: ElementState,
        repeat: bool,
    ) {
        if state == ElementState::Released {
            self.held.remove(&code);
            return;
        }
        self.held.insert(code);
        if repeat {
            return;
        }
        match code {
            KeyCode::Escape => event_loop.exit(),
            KeyCode::KeyH => self.options.overlay = !self.options.overlay,
            KeyCode::Digit1 => {
                self.terms = Terms {
                    direct: true,
                    indirect: true,
                }
            }
            KeyCode::Digit2 => {
                self.terms = Terms {
                    direct: true,
                    indirect: false,
                }
            }
            KeyCode::Digit3 => {
                self.terms = Terms {
                    direct: false,
                    indirect: true,
                }
            }
            KeyCode::KeyP => self.sphere = !self.sphere,
            KeyCode::Tab if !self.lights.lights.is_empty() => {
                self.selected = (self.selected + 1) % self.lights.lights.len();
            }
            KeyCode::Equal | KeyCode::NumpadAdd => {
                self.edit_selected(|l, _| edit::scale(l, 1.25));
            }
            KeyCode::Minus | KeyCode::NumpadSubtract => {
                self.edit_selected(|l, _| edit::scale(l, 0.8));
            }
            _ => {}
        }
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.gfx.is_some() {
            return;
        }
        match self.open(event_loop) {
            Ok(gfx) => {
                gfx.window.request_redraw();
                self.gfx = Some(gfx);
            }
            Err(e) => self.fail(event_loop, e),
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(size) => {
                if let Some(gfx) = self.gfx.as_mut()
                    && size.width > 0
                    && size.height > 0
                {
                    gfx.config.width = size.width;
                    gfx.config.height = size.height;
                    gfx.surface
                        .configure(gfx.renderer.context().device(), &gfx.config);
                    gfx.depth = gfx.renderer.depth_view(size.width, size.height);
                    self.stats.width = size.width;
                    self.stats.height = size.height;
                }
            }
            WindowEvent::KeyboardInput { event, .. } => {
                if let PhysicalKey::Code(code) = event.physical_key {
                    self.key(event_loop, code, event.state, event.repeat);
                }
            }
            WindowEvent::MouseInput {
                state,
                button: MouseButton::Left,
                ..
            } => {
                if state == ElementState::Released {
                    self.drag = None;
                }
                // A press starts the drag at the next cursor position.
                else {
                    self.drag = Some(PhysicalPosition::new(f64::NAN, f64::NAN));
                }
            }
            WindowEvent::CursorMoved { position, .. } => {
                if let Some(last) = self.drag {
                    if last.x.is_finite() {
                        self.fly
                            .turn((position.x - last.x) as f32, (position.y - last.y) as f32);
                    }
                    self.drag = Some(position);
                }
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let lines = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y,
                    MouseScrollDelta::PixelDelta(p) => p.y as f32 / 40.0,
                };
                self.fly.speed *= 1.2f32.powf(lines);
            }
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.redraw(event_loop) {
                    self.fail(event_loop, e);
                }
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, _event_loop: &ActiveEventLoop) {
        if let Some(gfx) = &self.gfx {
            gfx.window.request_redraw();
        }
    }
}

/// Whether the frame being drawn is the last one --frames asks for: the indirect light has
/// been on screen for the other frames, every move is done and answered.
fn is_last(
    options: &Options,
    shown: bool,
    with_indirect: u64,
    moves_done: u32,
    nothing_pending: bool,
) -> bool {
    let Some(frames) = options.frames else {
        return false;
    };
    shown && with_indirect + 1 >= frames && moves_done >= options.auto_move && nothing_pending
}

#[allow(clippy::too_many_arguments)]
fn overlay_lines(
    stats: &Stats,
    title: &str,
    source: &Source,
    shown: Option<&Answer>,
    terms: Terms,
    sphere: &str,
    lights: &LightSet,
    selected: usize,
    write_error: Option<&str>,
) -> Vec<String> {
    let recent = &stats.frame_ms[stats.frame_ms.len().saturating_sub(60)..];
    let frame = quantile(recent, 0.5);
    let latency = stats.gi_latency_ms.last();
    let mut lines = vec![
        format!(
            "{title}  {} patches  {} triangles",
            stats.patches, stats.triangles
        ),
        match frame {
            Some(ms) => format!("{:.0} fps  {ms:.1} ms a frame", 1e3 / ms.max(1e-3)),
            None => "- fps".into(),
        },
        match (latency, quantile(&stats.gi_latency_ms, 0.5)) {
            (Some(last), Some(median)) => {
                format!("GI latency {last:.0} ms (median {median:.0} ms)")
            }
            _ => "GI latency: move a light (arrows, PgUp/PgDn)".into(),
        },
        match shown {
            Some(a) => format!(
                "indirect frame #{}  lights v{}",
                a.sequence, a.lights_version
            ),
            None => "waiting for the first indirect frame".into(),
        },
        source.status(),
        format!(
            "[1] both [2] direct [3] indirect: {}",
            match (terms.direct, terms.indirect) {
                (true, true) => "both",
                (true, false) => "direct only",
                _ => "indirect only",
            }
        ),
        format!("[P] probe-lit sphere: {sphere}"),
    ];
    match lights.lights.get(selected) {
        Some(l) => lines.push(format!(
            "light {}/{}: {}  [Tab] next [+/-] intensity",
            selected + 1,
            lights.lights.len(),
            edit::describe(l)
        )),
        None => lines.push("no lights".into()),
    }
    if let Some(e) = write_error {
        lines.push(format!(
            "light change refused: {}",
            e.chars().take(70).collect::<String>()
        ));
    }
    lines.push("WASD QE fly, Shift fast, drag to look, wheel speed, H hide, Esc quit".into());
    lines
}

/// The probe-lit sphere ahead of `camera`, lit by the ambient cube the probes nearest its
/// centre give: none while it is off, or without probes or their light.
fn probe_sphere(
    on: bool,
    positions: &[Vec3],
    light: &[[f32; 3]],
    camera: &Camera,
    bounds: (Vec3, Vec3),
) -> Option<ProbeSphere> {
    if !on {
        return None;
    }
    let placed = ProbeSphere::ahead_of(camera, bounds, [[0.0; 3]; 6]);
    let cube = ambient_cube(positions, light, placed.centre)?;
    Some(ProbeSphere { cube, ..placed })
}

/// The overlay's word on the sphere.
fn sphere_status(on: bool, probes: usize, drawn: bool) -> &'static str {
    match (on, probes, drawn) {
        (false, _, _) => "off",
        (true, 0, _) => "the scene has no probes (bake --probes)",
        (true, _, false) => "waiting for probe light",
        (true, _, true) => "on",
    }
}

/// Records a copy of the presented texture into a buffer (rows padded to wgpu's alignment).
fn copy_out(
    device: &wgpu::Device,
    encoder: &mut wgpu::CommandEncoder,
    texture: &wgpu::Texture,
) -> (wgpu::Buffer, u32) {
    let size = texture.size();
    let padded = (size.width * 4).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("screenshot"),
        size: u64::from(padded) * u64::from(size.height),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    encoder.copy_texture_to_buffer(
        texture.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &buffer,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(padded),
                rows_per_image: Some(size.height),
            },
        },
        size,
    );
    (buffer, padded)
}

/// Maps the copy and writes it as RGBA; BGRA surfaces are swizzled.
fn save_copy(
    device: &wgpu::Device,
    buffer: &wgpu::Buffer,
    padded: u32,
    config: &wgpu::SurfaceConfiguration,
    path: &std::path::Path,
) -> Result<()> {
    let data = read_buffer(device, buffer).context("reading the screenshot back")?;
    let (w, h) = (config.width, config.height);
    let bgra = matches!(
        config.format,
        wgpu::TextureFormat::Bgra8Unorm | wgpu::TextureFormat::Bgra8UnormSrgb
    );
    let mut pixels = Vec::with_capacity((w * h * 4) as usize);
    for row in data.chunks(padded as usize).take(h as usize) {
        for px in row[..(w * 4) as usize].chunks(4) {
            if bgra {
                pixels.extend_from_slice(&[px[2], px[1], px[0], 255]);
            } else {
                pixels.extend_from_slice(&[px[0], px[1], px[2], 255]);
            }
        }
    }
    image::save_buffer(path, &pixels, w, h, image::ColorType::Rgba8)
        .with_context(|| format!("writing {}", path.display()))
}
