//! bounce's run-time relight engines: what turns a stored transport matrix and a batch of light
//! configurations into indirect irradiance `E_ind = T · B0` (DESIGN.md §1, §2 "Serve").
//!
//! For now this is the GPU side: [`gpu`] uploads an encoded matrix once and multiplies batches of
//! `B0` vectors with wgpu compute kernels, one kernel per codec, each with a CPU twin in
//! `bounce_core::codec` (the codec's `MatrixOp`) that the tests compare it with.
//!
//! Not here: encoding matrices and their error measurement (`bounce_core::codec`), the baked file
//! format (`bounce_core::format`), and computing `B0` from lights (`bounce_core::light`).

pub mod gpu;
