//! `bounce render`: one image of a glTF scene lit by a baked transport, offscreen, to a PNG.
//!
//! `--baked` relights in this process (engine → indirect per patch → irradiance volume →
//! renderer); `--server` (a running `bounce serve`) is not built yet.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use bounce_core::format::Baked;
use bounce_core::import::import_path;
use bounce_core::light::LightSet;
use bounce_engine::gpu::GpuContext;
use bounce_engine::{Engine, EngineChoice};
use bounce_render::{Camera, RenderOptions, Renderer, volume_from_baked};
use clap::Args;
use glam::Vec3;

#[derive(Args, Debug)]
pub struct RenderArgs {
    /// The glTF/GLB scene to draw (the one the baked file was baked from).
    pub scene: PathBuf,
    /// A file from `bounce bake` of this scene: indirect light is computed in this process.
    #[arg(long, value_name = "FILE")]
    pub baked: Option<PathBuf>,
    /// A running `bounce serve` to take indirect light from (not yet supported).
    #[arg(long, value_name = "URL", conflicts_with = "baked")]
    pub server: Option<String>,
    /// Light configuration, `{"lights": [...]}`; without it, the scene's own glTF lights.
    #[arg(long, value_name = "L.json")]
    pub lights: Option<PathBuf>,
    /// `eye_x,eye_y,eye_z,target_x,target_y,target_z[,fov_deg]`; without it, the scene's bounds
    /// framed from +Z with a 45° vertical field of view.
    #[arg(long, value_name = "EYE,TARGET[,FOV]", allow_hyphen_values = true)]
    pub camera: Option<String>,
    /// The PNG to write.
    #[arg(long, value_name = "IMG.png")]
    pub out: PathBuf,
    #[arg(long, default_value_t = 640)]
    pub width: u32,
    #[arg(long, default_value_t = 480)]
    pub height: u32,
    /// Radiance is multiplied by this before the Reinhard tonemap.
    #[arg(long, default_value_t = 1.0)]
    pub exposure: f32,
    /// `off` leaves the indirect (volume) term out: direct light and emission only.
    #[arg(long, value_name = "on|off", default_value = "on")]
    pub indirect: String,
    /// The relight engine; the renderer itself always takes a GPU adapter (software included).
    #[arg(long, value_name = "auto|gpu|cpu", default_value = "auto")]
    pub engine: String,
}

pub fn run(args: &RenderArgs) -> Result<()> {
    let indirect = match args.indirect.as_str() {
        "on" => true,
        "off" => false,
        other => bail!("--indirect must be on or off, not {other:?}"),
    };
    let choice: EngineChoice = args.engine.parse()?;
    if args.server.is_some() {
        bail!("--server is not yet supported: render with --baked FILE");
    }
    let Some(baked_path) = &args.baked else {
        bail!("give the baked scene with --baked FILE");
    };
    // Argument errors before any file is read.
    let camera = args.camera.as_deref().map(parse_camera).transpose()?;
    let scene =
        import_path(&args.scene).with_context(|| format!("importing {}", args.scene.display()))?;
    let bounds = scene
        .bounds()
        .with_context(|| format!("{} has no triangles", args.scene.display()))?;
    let lights = match &args.lights {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("reading {}", path.display()))?;
            LightSet::from_json(&text).with_context(|| format!("{}", path.display()))?
        }
        None if scene.lights.is_empty() => {
            bail!("the scene has no lights of its own: give a configuration with --lights L.json")
        }
        None => LightSet {
            lights: scene.lights.clone(),
        },
    };
    let camera = camera.unwrap_or_else(|| Camera::framing(bounds));

    let baked =
        Baked::read(baked_path).with_context(|| format!("reading {}", baked_path.display()))?;
    let engine = Engine::new(choice)?;
    eprintln!("engine: {}", engine.describe());
    let loaded = engine.load(&baked)?;
    let lit = engine.relight(&loaded, std::slice::from_ref(&lights))?;
    let Some(lit) = lit.first() else {
        bail!("the engine answered no light set");
    };
    let name = baked_path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let volume = volume_from_baked(&name, &baked.layout, &lit.indirect)?;

    let ctx = GpuContext::new().context("the renderer needs a GPU adapter (lavapipe will do)")?;
    eprintln!("renderer: {}", ctx.adapter());
    let renderer = Renderer::new(&ctx)?;
    let options = RenderOptions {
        width: args.width,
        height: args.height,
        exposure: args.exposure,
        indirect,
    };
    let image = renderer.render(&scene, &camera, &lights, &volume, &options)?;
    image::save_buffer(
        &args.out,
        &image.pixels,
        image.width,
        image.height,
        image::ColorType::Rgba8,
    )
    .with_context(|| format!("writing {}", args.out.display()))?;
    eprintln!(
        "wrote {} ({}×{})",
        args.out.display(),
        image.width,
        image.height
    );
    Ok(())
}

fn parse_camera(text: &str) -> Result<Camera> {
    let values = text
        .split(',')
        .map(|v| v.trim().parse::<f32>())
        .collect::<Result<Vec<f32>, _>>()
        .with_context(|| format!("--camera {text:?}: not a list of numbers"))?;
    let fov_deg = match values.len() {
        6 => 45.0,
        7 => values[6],
        n => bail!("--camera takes 6 or 7 numbers (eye, target[, fov]), not {n}"),
    };
    if values.iter().any(|v| !v.is_finite()) {
        bail!("--camera {text:?}: every number must be finite");
    }
    Ok(Camera {
        eye: Vec3::new(values[0], values[1], values[2]),
        target: Vec3::new(values[3], values[4], values[5]),
        fov_y: fov_deg.to_radians(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_arguments() {
        let c = parse_camera("0,1,4,0,1,0").unwrap();
        assert_eq!(c.eye, Vec3::new(0.0, 1.0, 4.0));
        assert!((c.fov_y - 45f32.to_radians()).abs() < 1e-6);
        let c = parse_camera("0,1,4, 0,1,0, 60").unwrap();
        assert!((c.fov_y - 60f32.to_radians()).abs() < 1e-6);
        assert!(parse_camera("0,1,4").is_err());
        assert!(parse_camera("0,1,4,0,1,x").is_err());
        assert!(parse_camera("0,1,4,0,1,inf").is_err());
    }
}
