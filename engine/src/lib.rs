//! bounce's run-time relight engines: what turns a baked scene and a batch of light
//! configurations into direct and indirect irradiance per patch (docs/design.md §1, §2 "Serve").
//!
//! [`Engine`] is the interface: `auto` opens the GPU when an adapter exists and the CPU otherwise,
//! and says which it took; [`Engine::load`] makes a baked scene ready on it; [`Engine::relight`]
//! computes, for every light set of a batch, direct light with shadows, `B0`, and
//! `E_ind = T · B0` in one batched product. [`gpu`] holds the wgpu side: an encoded matrix uploaded
//! once and multiplied with compute kernels, one per codec, each with a CPU twin in
//! `bounce_core::codec` (the codec's `MatrixOp`) that the tests compare it with. [`baseline`] keeps
//! the thesis' starting point, classic radiosity by Jacobi steps, for the benchmark.
//!
//! Not here: encoding matrices and their error measurement (`bounce_core::codec`), the baked file
//! format (`bounce_core::format`), and the direct-light model itself (`bounce_core::direct`).

pub mod baseline;
mod error;
pub mod gpu;
mod relight;

pub use error::EngineError;
pub use relight::{
    Engine, EngineChoice, EngineKind, Irradiance, Scene, Timing, carried_source, carries_near_field,
};
