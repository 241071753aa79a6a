//! What the engine's GPU tests share: one adapter for the whole test binary, and the rule that a
//! missing adapter fails the tests unless `BOUNCE_ALLOW_NO_GPU=1` says skipping is intended.

use std::sync::OnceLock;

use bounce_engine::gpu::GpuContext;

pub fn context() -> Option<&'static GpuContext> {
    static CTX: OnceLock<Result<GpuContext, String>> = OnceLock::new();
    match CTX.get_or_init(|| GpuContext::new().map_err(|e| e.to_string())) {
        Ok(ctx) => {
            eprintln!("GPU tests on {}", ctx.adapter());
            Some(ctx)
        }
        Err(e) if std::env::var("BOUNCE_ALLOW_NO_GPU").as_deref() == Ok("1") => {
            eprintln!("SKIPPED (BOUNCE_ALLOW_NO_GPU=1): {e}");
            None
        }
        Err(e) => panic!("GPU tests need an adapter: {e}; set BOUNCE_ALLOW_NO_GPU=1 to skip them"),
    }
}
