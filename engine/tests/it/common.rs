//! What the engine's GPU tests share: one adapter for the whole test binary (the workspace's one
//! fixture, in `bounce-testkit`), which fails the tests when missing (naming `scripts/test`,
//! which installs lavapipe) unless `BOUNCE_ALLOW_NO_GPU=1` says skipping is intended.

pub use bounce_testkit::fixtures::gpu_context as context;
