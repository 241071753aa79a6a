//! What the engine's GPU tests share: one adapter for the whole test binary, and the rule that a
//! missing adapter fails the tests (naming `scripts/test`, which installs lavapipe) unless
//! `BOUNCE_ALLOW_NO_GPU=1` says skipping is intended.

use std::sync::OnceLock;

use bounce_engine::gpu::GpuContext;

pub fn context() -> Option<&'static GpuContext> {
    static CTX: OnceLock<Result<GpuContext, String>> = OnceLock::new();
    match CTX.get_or_init(|| GpuContext::new().map_err(|e| e.to_string())) {
        Ok(ctx) => {
            eprintln!("GPU tests on {}", ctx.adapter());
            Some(ctx)
        }
        Err(e) => bounce_testkit::missing(bounce_testkit::Tool::GpuAdapter, e),
    }
}
