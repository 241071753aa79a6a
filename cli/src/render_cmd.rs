//! `bounce render`: one image of a glTF scene lit by a baked transport, offscreen, to a PNG
//! (tonemapped) or to a PFM or OpenEXR file (linear radiance).
//!
//! The indirect light comes from the viewer's own sources ([`crate::indirect`]): `--baked`
//! relights in this process (engine → indirect per patch → irradiance volume → renderer);
//! `--server` watches a session of a running `bounce serve` (layout, a session, its first frame →
//! irradiance volume → renderer), as a viewer does.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use bounce_client::Volume;
use bounce_core::import::{ImportOptions, import_path_with};
use bounce_core::scene::Scene;
use bounce_engine::EngineChoice;
use bounce_engine::gpu::GpuContext;
use bounce_render::{Camera, LinearImage, RenderOptions, Renderer};
use clap::Args;
use glam::Vec3;

use crate::indirect::{Local, Remote, Source};

#[derive(Args, Debug)]
pub struct RenderArgs {
    /// The glTF/GLB scene to draw (the one the baked file was baked from).
    pub scene: PathBuf,
    /// A file from `bounce bake` of this scene: indirect light is computed in this process.
    #[arg(long, value_name = "FILE")]
    pub baked: Option<PathBuf>,
    /// A running `bounce serve` to take indirect light from: `http://HOST:PORT` (gRPC) or
    /// `ws://HOST:PORT` (WebSocket). Needs --scene-name.
    #[arg(
        long,
        value_name = "URL",
        conflicts_with = "baked",
        requires = "scene_name"
    )]
    pub server: Option<String>,
    /// The scene's name on the server (its baked file's stem: `cornell-box`).
    #[arg(long, value_name = "NAME")]
    pub scene_name: Option<String>,
    /// Watch this session instead of creating one with --lights (its lights should match
    /// --lights, which direct light is drawn with).
    #[arg(long, value_name = "ID", requires = "server")]
    pub session: Option<String>,
    /// The server's write token, needed to create a session when it has one.
    #[arg(long, value_name = "T", env = "BOUNCE_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// Light configuration, `{"lights": [...]}`; without it, the scene's own glTF lights.
    #[arg(long, value_name = "L.json")]
    pub lights: Option<PathBuf>,
    /// `eye_x,eye_y,eye_z,target_x,target_y,target_z[,fov_deg]`; without it, the scene's bounds
    /// framed from +Z with a 45° vertical field of view.
    #[arg(long, value_name = "EYE,TARGET[,FOV]", allow_hyphen_values = true)]
    pub camera: Option<String>,
    /// The image to write, by its extension: `.png` is tonemapped and sRGB-encoded (see
    /// --exposure); `.pfm` and `.exr` hold linear RGB radiance in 32-bit float, before exposure
    /// and tonemap (the lights' units per m² and steradian: cd/m² for glTF's lights), for
    /// comparing with other renderers.
    #[arg(long, value_name = "IMG.png|IMG.pfm|IMG.exr")]
    pub out: PathBuf,
    #[arg(long, default_value_t = 640)]
    pub width: u32,
    #[arg(long, default_value_t = 480)]
    pub height: u32,
    /// Radiance is multiplied by this before the Reinhard tonemap (PNG only: PFM and EXR
    /// images are linear radiance).
    #[arg(long, default_value_t = 1.0)]
    pub exposure: f32,
    /// `on`: direct light, emission and indirect light. `off` leaves the indirect (volume) term
    /// out: direct light and emission only. `only`: the indirect term alone, radiance =
    /// albedo / π · E_indirect as the irradiance volume interpolates it, with no direct light
    /// and no emission.
    #[arg(long, value_name = "on|off|only", default_value = "on")]
    pub indirect: String,
    /// The relight engine; the renderer itself always takes a GPU adapter (software included).
    #[arg(long, value_name = "auto|gpu|cpu", default_value = "auto")]
    pub engine: String,
}

pub fn run(args: &RenderArgs) -> Result<()> {
    let (direct, indirect) = match args.indirect.as_str() {
        "on" => (true, true),
        "off" => (true, false),
        "only" => (false, true),
        other => {
            bail!("--indirect must be on or off (or only: the indirect term alone), not {other:?}")
        }
    };
    let format = ImageFile::of(&args.out)?;
    let choice: EngineChoice = args.engine.parse()?;
    if args.baked.is_none() && args.server.is_none() {
        bail!("give the indirect light's source: --baked FILE or --server URL");
    }
    // Argument errors before any file is read.
    let camera = args.camera.as_deref().map(parse_camera).transpose()?;
    let scene = import_for_drawing(&args.scene)?;
    let bounds = scene
        .bounds()
        .with_context(|| format!("{} has no triangles", args.scene.display()))?;
    let lights = crate::lights_file::or_scene(args.lights.as_deref(), &scene)?;
    let camera = camera.unwrap_or_else(|| Camera::framing(bounds));

    // The viewer's own sources: the same engine thread or session watcher `bounce view` uses.
    let (mut source, send) = match (&args.baked, &args.server) {
        (Some(baked), _) => (Source::Local(Local::open(baked, choice)?), true),
        (None, Some(url)) => {
            let name = args
                .scene_name
                .as_deref()
                .context("--server needs --scene-name NAME")?;
            // A new session is created with these lights; a given one keeps its own.
            let (remote, _) = Remote::connect(
                url,
                args.token.as_deref(),
                name,
                args.session.as_deref(),
                &lights,
            )?;
            (Source::Remote(Box::new(remote)), false)
        }
        (None, None) => bail!("give the indirect light's source: --baked FILE or --server URL"),
    };
    let mut volume = Volume::new(source.layout()).context("building the irradiance volume")?;
    if send {
        source.send(1, &lights);
    }
    let answer = source.first_answer(&mut volume, FIRST_ANSWER)?;
    eprintln!(
        "indirect light: {}, frame {} answering lights version {}",
        source.status(),
        answer.sequence,
        answer.lights_version
    );
    drop(source);

    let ctx = GpuContext::new().context("the renderer needs a GPU adapter (lavapipe will do)")?;
    eprintln!("renderer: {}", ctx.adapter());
    let renderer = Renderer::new(&ctx)?;
    let options = RenderOptions {
        width: args.width,
        height: args.height,
        exposure: args.exposure,
        indirect,
        direct,
    };
    let (width, height) = (args.width, args.height);
    match format {
        ImageFile::Png => {
            let image = renderer.render(&scene, &camera, &lights, &volume, &options)?;
            image::save_buffer(
                &args.out,
                &image.pixels,
                image.width,
                image.height,
                image::ColorType::Rgba8,
            )
            .with_context(|| format!("writing {}", args.out.display()))?;
        }
        ImageFile::Pfm | ImageFile::Exr => {
            let image = renderer.render_linear(&scene, &camera, &lights, &volume, &options)?;
            if format == ImageFile::Pfm {
                write_pfm(&args.out, &image)
            } else {
                write_exr(&args.out, &image)
            }
            .with_context(|| format!("writing {}", args.out.display()))?;
        }
    }
    eprintln!("wrote {} ({width}×{height})", args.out.display());
    Ok(())
}

/// What `--out` writes, by its extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ImageFile {
    /// Tonemapped, sRGB-encoded 8-bit.
    Png,
    /// Linear radiance, 32-bit float.
    Pfm,
    Exr,
}

impl ImageFile {
    fn of(path: &Path) -> Result<ImageFile> {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        Ok(match ext.as_deref() {
            Some("png") => ImageFile::Png,
            Some("pfm") => ImageFile::Pfm,
            Some("exr") => ImageFile::Exr,
            _ => bail!(
                "--out {}: the image's extension must be .png (tonemapped), .pfm or .exr \
                 (linear radiance)",
                path.display()
            ),
        })
    }
}

/// A colour PFM: the header `PF`, the size, `-1.0` (little-endian), then RGB f32 rows from the
/// bottom one up.
fn write_pfm(path: &Path, image: &LinearImage) -> Result<()> {
    let mut bytes = Vec::with_capacity(32 + image.pixels.len() * 12);
    write!(bytes, "PF\n{} {}\n-1.0\n", image.width, image.height)?;
    if image.width > 0 {
        for row in image.pixels.chunks_exact(image.width as usize).rev() {
            for channel in row.iter().flatten() {
                bytes.extend_from_slice(&channel.to_le_bytes());
            }
        }
    }
    std::fs::write(path, bytes)?;
    Ok(())
}

/// An OpenEXR file of RGB f32, rows top to bottom.
fn write_exr(path: &Path, image: &LinearImage) -> Result<()> {
    let floats: Vec<f32> = image.pixels.iter().flatten().copied().collect();
    let buffer: image::ImageBuffer<image::Rgb<f32>, Vec<f32>> =
        image::ImageBuffer::from_raw(image.width, image.height, floats)
            .context("the image's pixels do not fill its size")?;
    buffer.save_with_format(path, image::ImageFormat::OpenExr)?;
    Ok(())
}

/// How long to wait for the first answer: a session's first frame, or the engine's first solve
/// (which includes loading the matrix).
const FIRST_ANSWER: Duration = Duration::from_secs(60);

/// The scene as the renderers draw it: with the file's normals, texture coordinates and
/// base-colour images, which a bake does not import.
pub(crate) fn import_for_drawing(path: &Path) -> Result<Scene> {
    import_path_with(path, &ImportOptions { shading: true })
        .with_context(|| format!("importing {}", path.display()))
}

pub(crate) fn parse_camera(text: &str) -> Result<Camera> {
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

    #[test]
    fn image_files_by_extension() {
        assert_eq!(ImageFile::of(Path::new("a.png")).unwrap(), ImageFile::Png);
        assert_eq!(ImageFile::of(Path::new("d/a.PFM")).unwrap(), ImageFile::Pfm);
        assert_eq!(ImageFile::of(Path::new("a.exr")).unwrap(), ImageFile::Exr);
        for bad in ["a.jpg", "a", "a.png.tmp"] {
            let err = ImageFile::of(Path::new(bad)).unwrap_err().to_string();
            assert!(err.contains(".pfm or .exr"), "{bad}: {err}");
        }
    }

    #[test]
    fn pfm_rows_run_bottom_to_top() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.pfm");
        let image = LinearImage {
            width: 2,
            height: 2,
            pixels: vec![
                [1.0, 2.0, 3.0],
                [4.0, 5.0, 6.0],
                [7.0, 8.0, 9.0],
                [0.5, 0.25, 0.0],
            ],
        };
        write_pfm(&path, &image).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let header = b"PF\n2 2\n-1.0\n";
        assert_eq!(&bytes[..header.len()], header);
        let floats: Vec<f32> = bytes[header.len()..]
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
            .collect();
        assert_eq!(
            floats,
            [7.0, 8.0, 9.0, 0.5, 0.25, 0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
        );
    }
}
