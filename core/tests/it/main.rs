//! bounce-core's integration tests, in one binary: each file used to link its own ~300 MB test
//! executable, which cost CI minutes of linking and, once, the disk it ran on.
//! `format.rs` stays a binary of its own because it installs a tracking global allocator.

mod bake;
mod codec;
mod codec_bc;
mod codec_transform;
mod direct;
mod emitter;
mod formfactor;
mod furnace;
mod import;
mod nearfield;
mod pack;
mod shard;
mod sky;
mod stress;
mod surface;
mod tracers;
mod trimesh;
