//! What a stage's GPU objects are made with: the device, the renderer's bind group layouts and
//! samplers, and the shadow maps' size and format. A [`crate::Renderer`] owns one and derefs to
//! it, so a stage is built from the renderer without depending on the code that draws it.

use bounce_engine::gpu::GpuContext;

pub(crate) const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
pub(crate) const SHADOW_SIZE: u32 = 1024;
/// Most shadow-map layers one image may use (a directional or spot light takes one, a point
/// light six): 4 MiB each.
pub const MAX_SHADOW_VIEWS: usize = 64;

/// The device and the layouts and samplers every stage's bind groups are made with.
pub struct Resources<'a> {
    pub(crate) ctx: &'a GpuContext,
    pub(crate) main_layout: wgpu::BindGroupLayout,
    /// The shadow pipeline's bind group layout.
    pub(crate) shadow_layout: wgpu::BindGroupLayout,
    pub(crate) shadow_sampler: wgpu::Sampler,
    pub(crate) albedo_sampler: wgpu::Sampler,
}

/// A bind group of `layout` from `(binding, resource)` pairs.
pub(crate) fn bind_group(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    entries: Vec<(u32, wgpu::BindingResource<'_>)>,
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = entries
        .into_iter()
        .map(|(binding, resource)| wgpu::BindGroupEntry { binding, resource })
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout,
        entries: &entries,
    })
}
