//! bounce-engine's integration tests, in one binary (one link, one shared GPU adapter).

mod common;
mod emissive;
mod gpu;
mod gpu_direct;
mod gpu_direct_surface;
mod gpu_near_field;
mod layout;
mod probes;
mod relight;
mod sky;
mod stress;
