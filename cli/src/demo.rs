//! `bounce demo`: bake the embedded Cornell box with no configuration, then inspect it.
//!
//! The scene ships inside the binary so the first command of the README works on a fresh
//! machine; it is written next to the baked file because a viewer needs the original meshes.

use std::path::PathBuf;

use anyhow::{Context, Result};
use bounce_core::bake::BakeOptions;
use bounce_core::meta::Bounces;
use bounce_core::voxel::Resolution;
use clap::Args;

const SCENE_GLTF: &[u8] = include_bytes!("../../assets/cornell-box/scene.gltf");
const SCENE_BIN: &[u8] = include_bytes!("../../assets/cornell-box/scene.bin");
const LICENSE: &[u8] = include_bytes!("../../assets/cornell-box/license.txt");

#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Directory for the demo scene and its baked file.
    #[arg(long, default_value = "bounce-demo")]
    pub dir: PathBuf,
    /// Target patch count.
    #[arg(long, default_value_t = 2000)]
    pub patches: u32,
    /// Light bounces: a number or "all".
    #[arg(long, default_value = "3")]
    pub bounces: Bounces,
    #[arg(short, long)]
    pub quiet: bool,
}

pub fn run(args: &DemoArgs) -> Result<()> {
    let scene_dir = args.dir.join("cornell-box");
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
    let out = args.dir.join("cornell-box.bounce");
    let options = BakeOptions {
        resolution: Resolution::TargetPatches(args.patches),
        bounces: args.bounces,
        ..BakeOptions::default()
    };
    crate::bake_cmd::bake(&scene_dir.join("scene.gltf"), &out, &options, args.quiet)?;
    println!();
    crate::inspect::run(&crate::inspect::InspectArgs {
        file: out,
        json: false,
    })
}
