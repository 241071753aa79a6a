//! `bounce sky`: an equirectangular HDR image (Radiance `.hdr` or OpenEXR) to the sky light it
//! stands for, order-2 spherical harmonics (`bounce_core::environment`), as a light file any
//! command or session takes. The server does the same at `POST /v1/sky/sh`.

use std::path::PathBuf;

use anyhow::{Context, Result};
use bounce_core::light::{Light, LightSet};
use clap::Args;

#[derive(Args, Debug)]
pub struct SkyArgs {
    /// The environment map: equirectangular, +Y up (three.js's and Blender's mapping: the
    /// image's middle looks along +X, its top row is the zenith), linear radiance.
    pub image: PathBuf,
    /// Multiply the map's radiance by this (its exposure in the scene's light units).
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
    let bytes =
        std::fs::read(&args.image).with_context(|| format!("reading {}", args.image.display()))?;
    let env = bounce_core::environment::sh_from_image(&bytes)
        .with_context(|| format!("{}", args.image.display()))?;
    let set = LightSet {
        lights: vec![Light::Sky {
            color: None,
            sh: Some(env.sh.iter().map(|c| c.map(|v| v * args.scale)).collect()),
            // Named after the file, where its name is short enough to be a light's.
            name: args
                .image
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .filter(|s| s.len() <= 64),
        }],
    };
    set.validate()
        .context("the projected sky is not a valid light")?;
    let json = serde_json::to_string_pretty(&set)?;
    match &args.out {
        Some(path) => {
            std::fs::write(path, json + "\n")
                .with_context(|| format!("writing {}", path.display()))?;
            eprintln!(
                "{}: {} × {} pixels → {}",
                args.image.display(),
                env.width,
                env.height,
                path.display()
            );
        }
        None => println!("{json}"),
    }
    Ok(())
}
