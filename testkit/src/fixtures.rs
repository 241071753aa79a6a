//! Fixtures that need the bake or the engine, each behind its feature so that a crate whose
//! tests do not use them builds none of it.

#[cfg(feature = "gpu")]
use bounce_engine::gpu::GpuContext;

/// The Cornell box baked as the server and client tests serve it: about `patches` patches, 512
/// rays a patch, everything else the bake's defaults.
#[cfg(feature = "bake")]
pub fn baked_cornell_box(patches: u32) -> bounce_core::format::Baked {
    use bounce_core::bake::{BakeOptions, NoProgress, bake_file};
    use bounce_core::voxel::Resolution;
    let options = BakeOptions {
        resolution: Resolution::TargetPatches(patches),
        rays: 512,
        ..BakeOptions::default()
    };
    bake_file(&crate::cornell_gltf(), &options, &NoProgress).expect("baking the Cornell box")
}

/// One adapter for the whole test binary. A missing adapter fails the test that asked (naming
/// `scripts/test`, which installs lavapipe) unless `BOUNCE_ALLOW_NO_GPU=1` says skipping is
/// intended, as [`crate::missing`] does for every tool.
#[cfg(feature = "gpu")]
pub fn gpu_context() -> Option<&'static GpuContext> {
    use std::sync::OnceLock;
    static CTX: OnceLock<Result<GpuContext, String>> = OnceLock::new();
    match CTX.get_or_init(|| GpuContext::new().map_err(|e| e.to_string())) {
        Ok(ctx) => {
            eprintln!("GPU tests on {}", ctx.adapter());
            Some(ctx)
        }
        Err(e) => crate::missing(crate::Tool::GpuAdapter, e),
    }
}
