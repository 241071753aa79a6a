//! What can go wrong relighting.

use bounce_core::codec::CodecError;
use bounce_core::light::LightError;
use thiserror::Error;

use crate::gpu::GpuError;

#[derive(Debug, Error)]
pub enum EngineError {
    /// `--engine gpu` was asked for and no usable GPU is here.
    #[error("GPU engine unavailable: {0}")]
    NoGpu(GpuError),
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error(transparent)]
    Codec(#[from] CodecError),
    /// A light set failed validation; `index` is its place in the batch.
    #[error("light set {index}: {error}")]
    Lights { index: usize, error: LightError },
    #[error("unknown engine '{0}' (known: auto, gpu, cpu)")]
    UnknownEngine(String),
    #[error("the classic-radiosity baseline needs the form factors: bake with --keep-form-factors")]
    NoFormFactors,
}
