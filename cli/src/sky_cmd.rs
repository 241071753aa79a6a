//! `bounce sky`: an equirectangular HDR image (Radiance `.hdr` or OpenEXR) to the sky light it
//! stands for, order-2 spherical harmonics (`bounce_core::environment`), or a sun and its clear
//! sky from the sun's direction (`bounce_core::sunsky`), as a light file any command or session
//! takes. The server does the same at `POST /v1/sky/sh` and `POST /v1/sky/sun`.

use std::path::PathBuf;

use anyhow::{Context, Result};
use bounce_core::light::{Light, LightSet};
use clap::Args;

#[derive(Args, Debug)]
pub struct SkyArgs {
    /// The environment map: equirectangular, +Y up (three.js's and Blender's mapping: the
    /// image's middle looks along +X, its top row is the zenith), linear radiance.
    #[arg(required_unless_present = "sun", conflicts_with = "sun")]
    pub image: Option<PathBuf>,
    /// Instead of a map: a sun towards X,Y,Z (+Y up, any length) and its clear sky (Preetham's
    /// model): a directional light and an SH sky, in klux and kcd/m² times --scale.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, allow_hyphen_values = true)]
    pub sun: Option<[f32; 3]>,
    /// The air's turbidity for --sun: 2 very clear, 3 typical, 6 and over hazy (1.7 to 10).
    #[arg(long, default_value_t = 3.0, requires = "sun")]
    pub turbidity: f64,
    /// Multiply the light by this: the map's radiance (its exposure), or the sun's and sky's
    /// (their thousands of lux into the scene's own light units).
    #[arg(long, default_value_t = 1.0)]
    pub scale: f32,
    /// Write the light file here rather than to standard output.
    #[arg(long, short)]
    pub out: Option<PathBuf>,
}

pub fn run(args: &SkyArgs) -> Result<()> {
    if !(args.scale.is_finite() && args.scale >= 0.0) {
        anyhow::bail!(
            "--scale must be finite and not negative (got {})",
            args.scale
        );
    }
    let (set, what) = match (&args.image, &args.sun) {
        (Some(image), _) => from_image(image, args.scale)?,
        (None, Some(towards)) => {
            let set =
                bounce_core::sunsky::sun_and_sky(*towards, args.turbidity, f64::from(args.scale))?;
            (
                set,
                format!("a sun towards {towards:?}, turbidity {}", args.turbidity),
            )
        }
        (None, None) => anyhow::bail!("give an environment map, or --sun X,Y,Z"),
    };
    set.validate().context("the sky is not a valid light")?;
    let json = serde_json::to_string_pretty(&set)?;
    match &args.out {
        Some(path) => {
            std::fs::write(path, json + "\n")
                .with_context(|| format!("writing {}", path.display()))?;
            eprintln!("{what} → {}", path.display());
        }
        None => println!("{json}"),
    }
    Ok(())
}

fn from_image(image: &std::path::Path, scale: f32) -> Result<(LightSet, String)> {
    let bytes = std::fs::read(image).with_context(|| format!("reading {}", image.display()))?;
    let env = bounce_core::environment::sh_from_image(&bytes)
        .with_context(|| format!("{}", image.display()))?;
    let set = LightSet {
        lights: vec![Light::Sky {
            color: None,
            sh: Some(env.sh.iter().map(|c| c.map(|v| v * scale)).collect()),
            // Named after the file, where its name is short enough to be a light's.
            name: image
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .filter(|s| s.len() <= 64),
        }],
    };
    let what = format!("{}: {} × {} pixels", image.display(), env.width, env.height);
    Ok((set, what))
}

/// `X,Y,Z`: three finite numbers.
fn parse_vec3(s: &str) -> Result<[f32; 3], String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("{s:?}: {e}"))?;
    match <[f32; 3]>::try_from(v) {
        Ok(v) if v.iter().all(|x| x.is_finite()) => Ok(v),
        _ => Err(format!("{s:?}: three finite numbers, X,Y,Z")),
    }
}
