//! `bounce view`: the native viewer. A window (winit + wgpu) draws the scene's own glTF with
//! direct light from its own shadow maps and indirect light from a session's frames (or a baked
//! file relit in this process), through the same `bounce-render` stage as `bounce render`.
//!
//! `app` owns the window and its loop, `source` where indirect light comes from, `fly` the
//! camera, `edit` the light edits, `stats` the figures it reports.

mod app;
mod edit;
mod fly;
mod stats;

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use bounce_core::light::LightSet;
use bounce_engine::EngineChoice;
use bounce_render::Camera;
use clap::Args;

use crate::indirect::{Local, Remote, Source};
use crate::render_cmd::{import_for_drawing, parse_camera};
use app::{App, Options};

#[derive(Args, Debug)]
pub struct ViewArgs {
    /// The glTF/GLB scene to draw (the one the baked file was baked from).
    pub scene: PathBuf,
    /// A file from `bounce bake` of this scene: indirect light is computed in this process.
    #[arg(long, value_name = "FILE")]
    pub baked: Option<PathBuf>,
    /// A running `bounce serve`: `http://HOST:PORT` (gRPC) or `ws://HOST:PORT` (WebSocket).
    #[arg(long, value_name = "URL", conflicts_with = "baked")]
    pub server: Option<String>,
    /// The scene's name on the server (its baked file's stem); default: the glTF file's stem.
    #[arg(long, value_name = "NAME", requires = "server")]
    pub scene_name: Option<String>,
    /// Join this session (its lights are drawn and edited) instead of creating one.
    #[arg(long, value_name = "ID", requires = "server")]
    pub session: Option<String>,
    /// The server's write token, needed to create a session or move its lights when it has one.
    #[arg(long, value_name = "T", env = "BOUNCE_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// Light configuration, `{"lights": [...]}`; without it, the scene's own glTF lights (or
    /// the joined session's).
    #[arg(long, value_name = "L.json")]
    pub lights: Option<PathBuf>,
    /// `eye_x,eye_y,eye_z,target_x,target_y,target_z[,fov_deg]`; without it, the scene's
    /// bounds framed from +Z.
    #[arg(long, value_name = "EYE,TARGET[,FOV]", allow_hyphen_values = true)]
    pub camera: Option<String>,
    #[arg(long, default_value_t = 1280)]
    pub width: u32,
    #[arg(long, default_value_t = 720)]
    pub height: u32,
    /// Radiance is multiplied by this before the Reinhard tonemap.
    #[arg(long, default_value_t = 1.0)]
    pub exposure: f32,
    /// The in-process relight engine (with --baked).
    #[arg(long, value_name = "auto|gpu|cpu", default_value = "auto")]
    pub engine: String,
    /// `off` draws as fast as the GPU can (frame-time measurements); `on` waits for the display.
    #[arg(long, value_name = "on|off", default_value = "on")]
    pub vsync: String,
    /// Exit by itself after this many frames drawn with indirect light (and after the
    /// --auto-move moves); for tests and measurements.
    #[arg(long, value_name = "N")]
    pub frames: Option<u64>,
    /// Move the selected light this many times, each move once the last one's indirect light
    /// is on screen (the GI latency figures come from these).
    #[arg(long, value_name = "K", requires = "frames")]
    pub auto_move: Option<u32>,
    /// With --frames: write the last frame, as the window showed it, to this PNG.
    #[arg(long, value_name = "OUT.png", requires = "frames")]
    pub screenshot: Option<PathBuf>,
    /// Write frame times and GI latencies as JSON when the window closes.
    #[arg(long, value_name = "OUT.json")]
    pub stats: Option<PathBuf>,
    /// The text overlay (frame rate, GI latency, frame sequence, keys); `H` toggles it.
    #[arg(long, value_name = "on|off", default_value = "on")]
    pub overlay: String,
    /// With --frames: give up (an error) if the frames are not done in this many seconds.
    #[arg(long, value_name = "SECONDS", default_value_t = 300.0)]
    pub timeout: f64,
}

pub fn run(args: &ViewArgs) -> Result<()> {
    let vsync = match args.vsync.as_str() {
        "on" => true,
        "off" => false,
        other => bail!("--vsync must be on or off, not {other:?}"),
    };
    let overlay = match args.overlay.as_str() {
        "on" => true,
        "off" => false,
        other => bail!("--overlay must be on or off, not {other:?}"),
    };
    let choice: EngineChoice = args.engine.parse()?;
    if args.baked.is_none() && args.server.is_none() {
        bail!("give the indirect light's source: --baked FILE or --server URL");
    }
    if !(args.timeout > 0.0 && args.timeout.is_finite()) {
        bail!("--timeout must be a positive number of seconds");
    }
    if args.frames == Some(0) {
        bail!("--frames must be at least 1");
    }
    let camera = args.camera.as_deref().map(parse_camera).transpose()?;
    let scene = import_for_drawing(&args.scene)?;
    let bounds = scene
        .bounds()
        .with_context(|| format!("{} has no triangles", args.scene.display()))?;
    let given = args
        .lights
        .as_deref()
        .map(crate::lights_file::read)
        .transpose()?;
    let own = || LightSet {
        lights: scene.lights.clone(),
    };

    let (source, lights, send_first) = match (&args.baked, &args.server) {
        (Some(baked), _) => {
            let lights = given.unwrap_or_else(own);
            (Source::Local(Local::open(baked, choice)?), lights, true)
        }
        (None, Some(url)) => {
            let name = match &args.scene_name {
                Some(n) => n.clone(),
                None => args
                    .scene
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .context("give --scene-name NAME")?,
            };
            let wanted = given.clone().unwrap_or_else(own);
            let (remote, session_lights) = Remote::connect(
                url,
                args.token.as_deref(),
                &name,
                args.session.as_deref(),
                &wanted,
            )?;
            // A joined session keeps its lights unless --lights replaces them.
            let (lights, send) = match (given, session_lights) {
                (Some(g), Some(_)) => (g, true),
                (None, Some(s)) => (s, false),
                (_, None) => (wanted, false),
            };
            eprintln!("session {}", remote.session);
            (Source::Remote(Box::new(remote)), lights, send)
        }
        (None, None) => bail!("give the indirect light's source: --baked FILE or --server URL"),
    };
    if lights.lights.is_empty() {
        eprintln!(
            "no lights: direct light is off until one is added (the scene has none of its own; give --lights)"
        );
    }
    let camera = camera.unwrap_or_else(|| Camera::framing(bounds));
    let options = Options {
        width: args.width,
        height: args.height,
        exposure: args.exposure,
        vsync,
        frames: args.frames,
        auto_move: args.auto_move.unwrap_or(0),
        screenshot: args.screenshot.clone(),
        timeout: Duration::from_secs_f64(args.timeout),
        title: args
            .scene
            .file_name()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
        overlay,
    };
    let stats = App::run(options, scene, lights, send_first, source, camera)?;
    eprintln!("{}", stats.summary());
    if let Some(path) = &args.stats {
        std::fs::write(path, serde_json::to_string_pretty(&stats.json())?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}
