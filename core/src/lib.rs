//! bounce-core: the CPU side of bounce's precomputed radiosity.
//!
//! It owns scene import (glTF), voxel simplification into patches, form factors with visibility,
//! the multi-bounce transport matrix, the baked file format ([`format`], which reads and writes
//! files and shard files without knowing the pipeline) and the bake pipeline that ties them
//! together, whole or sharded ([`bake`]), and the CPU side of relighting: shadowed direct
//! irradiance. It does not own any GPU
//! code, networking or command-line handling: those live in the crates that depend on this one.
//! Lights and patch faces are `bounce-types`' (re-exported as [`light`], [`patch::Face`] and
//! [`voxel::dominant_face`]), so a thin client can name them without building the bake.
//!
//! Conventions (see docs/design.md §1): `F[i][j]` is the fraction of energy leaving patch `i` that
//! arrives at patch `j`; the transport `T` maps initial exitance `B0` to indirect irradiance
//! `E_ind = T B0`.

pub mod bake;
pub mod codec;
pub mod coherence;
pub mod direct;
pub mod element;
pub mod emitter;
pub mod environment;
pub mod extent;
pub mod format;
pub mod formfactor;
pub mod import;
pub mod landings;
pub use bounce_types::light;
pub use bounce_types::sh;
pub mod matrix;
pub mod meta;
pub mod nearfield;
pub mod openness;
pub mod patch;
pub mod pointwise;
pub mod probe;
pub mod rays;
pub mod sample;
pub mod scene;
pub mod sky;
pub mod space;
pub mod sunsky;
pub mod surface;
pub mod tail;
pub mod transport;
pub mod trimesh;
pub mod visibility;
pub mod voxel;
