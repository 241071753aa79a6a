//! The light model on the GPU, one definition for every shader that lights a point: the engine's
//! direct-light kernels ([`GpuDirect`](super::GpuDirect),
//! [`GpuSurfaceDirect`](super::GpuSurfaceDirect)) and bounce-render's shading.
//!
//! [`WGSL`] holds [`GpuLight`]'s WGSL twin, the glTF range window, the spot cone falloff and
//! `light_sample` (the twin of `bounce_core::direct::light_sample`); each of those shaders is
//! this text with its own file appended, so the physics exists once in WGSL and the struct once
//! in Rust, and a change to either reaches the relight kernels and the renderer together.
//! `engine/tests/it/layout.rs` checks the two layouts against each other with naga.

use bounce_core::direct::{LightKind, PreparedLight};
use bytemuck::{Pod, Zeroable};

/// The WGSL module: `GpuLight`, `KIND_*`, `BIG`, `range_window`, `spot_attenuation`, `Sample`
/// and `light_sample`. Prepend it; it declares no bindings, so each shader binds its own
/// `array<GpuLight>` where it likes.
pub const WGSL: &str = include_str!("shaders/light.wgsl");

/// [`GpuLight::kind`] of a directional light (`KIND_DIRECTIONAL` in [`WGSL`]).
pub const KIND_DIRECTIONAL: u32 = 0;
/// [`GpuLight::kind`] of a point light (`KIND_POINT` in [`WGSL`]).
pub const KIND_POINT: u32 = 1;
/// [`GpuLight::kind`] of a spot light (`KIND_SPOT` in [`WGSL`]).
pub const KIND_SPOT: u32 = 2;

/// A `bounce_core::direct::PreparedLight` as the shaders read it (`GpuLight` in [`WGSL`]).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct GpuLight {
    pub position: [f32; 3],
    /// [`KIND_DIRECTIONAL`], [`KIND_POINT`] or [`KIND_SPOT`].
    pub kind: u32,
    pub axis: [f32; 3],
    pub inv_range: f32,
    pub radiant: [f32; 3],
    pub angle_scale: f32,
    pub angle_offset: f32,
    /// The renderer's first shadow view: the index of the light's first shadow-map view (a point
    /// light has six from there). The engine's kernels ignore it. A field of its own rather than
    /// padding, so the engine and the renderer upload one layout; 0 from [`From`].
    pub first_view: u32,
    pub pad: [u32; 2],
}

impl From<&PreparedLight> for GpuLight {
    fn from(l: &PreparedLight) -> GpuLight {
        GpuLight {
            position: l.position.to_array(),
            kind: match l.kind {
                LightKind::Directional => KIND_DIRECTIONAL,
                LightKind::Point => KIND_POINT,
                LightKind::Spot => KIND_SPOT,
            },
            axis: l.axis.to_array(),
            inv_range: l.inv_range,
            radiant: l.radiant.to_array(),
            angle_scale: l.angle_scale,
            angle_offset: l.angle_offset,
            first_view: 0,
            pad: [0; 2],
        }
    }
}
