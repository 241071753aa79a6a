//! `bounce demo`: bake the embedded Cornell box with no configuration, then inspect it.
//!
//! The scene ships inside the binary so the first command of the README works on a fresh
//! machine; it is written next to the baked file because a viewer needs the original meshes.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use bounce_core::bake::{BakeOptions, CodecRequest};
use bounce_core::meta::Bounces;
use bounce_core::voxel::Resolution;
use clap::Args;

const SCENE_GLTF: &[u8] = include_bytes!("../../assets/cornell-box/scene.gltf");
const SCENE_BIN: &[u8] = include_bytes!("../../assets/cornell-box/scene.bin");
const LICENSE: &[u8] = include_bytes!("../../assets/cornell-box/license.txt");

/// Writes the embedded Cornell box (glTF, buffer, licence) into `dir/cornell-box/` and returns
/// the glTF's path.
pub fn write_scene(dir: &Path) -> Result<PathBuf> {
    let scene_dir = dir.join("cornell-box");
    std::fs::create_dir_all(&scene_dir)
        .with_context(|| format!("creating {}", scene_dir.display()))?;
    for (name, bytes) in [
        ("scene.gltf", SCENE_GLTF),
        ("scene.bin", SCENE_BIN),
        ("license.txt", LICENSE),
    ] {
        let path = scene_dir.join(name);
        std::fs::write(&path, bytes).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(scene_dir.join("scene.gltf"))
}

/// What the demo bakes with; `bounce demo`'s flags and the first-run `serve` (which takes the
/// defaults) fill it.
#[derive(Debug, Clone, PartialEq)]
pub struct DemoBake {
    pub patches: u32,
    pub bounces: Bounces,
    pub codec: CodecRequest,
}

impl Default for DemoBake {
    fn default() -> Self {
        DemoBake {
            patches: DEMO_PATCHES,
            bounces: Bounces::All,
            codec: crate::bake::codec_request(
                crate::bake::DEFAULT_CODEC,
                crate::bake::DEFAULT_MAX_ERROR,
            ),
        }
    }
}

/// Patches of the demo bake (`bounce demo` and the first-run `serve`).
pub const DEMO_PATCHES: u32 = 2000;

/// Writes the embedded scene into `dir` and bakes it to `out`.
pub fn bake_demo(dir: &Path, out: &Path, bake: &DemoBake, quiet: bool) -> Result<()> {
    let gltf = write_scene(dir)?;
    let options = BakeOptions {
        resolution: Resolution::TargetPatches(bake.patches),
        bounces: bake.bounces,
        codec: bake.codec.clone(),
        ..BakeOptions::default()
    };
    // The model is kept: the browser page `bounce serve` hands out draws it.
    crate::bake::bake(&gltf, out, &options, true, quiet)?;
    Ok(())
}

#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Directory for the demo scene and its baked file.
    #[arg(long, default_value = "bounce-demo")]
    pub dir: PathBuf,
    /// Target patch count.
    #[arg(long, default_value_t = DEMO_PATCHES)]
    pub patches: u32,
    /// Light bounces: a number or "all" (every bounce, as a camera sees them).
    #[arg(long, default_value = "all")]
    pub bounces: Bounces,
    /// How the transport is stored: auto (the smallest within --max-error), or a codec by name
    /// (dense-f32, dense-f16, bc1, bc4, log8, bc1-resid), as for `bounce bake`.
    #[arg(long, value_name = "NAME|auto", default_value = crate::bake::DEFAULT_CODEC)]
    pub codec: String,
    /// For --codec auto: the largest relative L2 error of the indirect irradiance allowed.
    #[arg(long, value_name = "E", default_value_t = crate::bake::DEFAULT_MAX_ERROR)]
    pub max_error: f64,
    #[arg(short, long)]
    pub quiet: bool,
}

pub fn run(args: &DemoArgs) -> Result<()> {
    let out = args.dir.join("cornell-box.bounce");
    let bake = DemoBake {
        patches: args.patches,
        bounces: args.bounces,
        codec: crate::bake::codec_request(&args.codec, args.max_error),
    };
    bake_demo(&args.dir, &out, &bake, args.quiet)?;
    println!();
    crate::inspect::run(&crate::inspect::InspectArgs {
        file: out,
        json: false,
    })
}
