//! [`GpuDirect`]: direct irradiance with voxel-grid shadows on the GPU, the twin of
//! `bounce_core::direct::direct_irradiance` on the grid tracer.
//!
//! Uploaded once per scene: every patch's quad with the voxel its shadow walks start in (both
//! computed here by the CPU's own code, so the GPU never re-derives them with other rounding),
//! and the occupancy as a bitset. Per call: the prepared lights of a whole batch of light sets,
//! flattened with per-set offsets, and one thread per (patch, light set), which sums its samples
//! in the CPU's order (`shaders/direct.wgsl`).
//!
//! Why one thread per (patch, light set) rather than per (patch, sample): it keeps the CPU's
//! summation order (sample, then light) without a reduction, so lavapipe reproduces the CPU bit
//! for bit, and a batch of light sets already multiplies the thread count. Measured on lavapipe
//! (software Vulkan, 2 cores) on a 2,140-patch room with a pillar, 16 samples, 1–3 lights a set:
//! 1 set 5.3 ms (CPU engine 4.2 ms), 8 sets 25.5 ms (34.6 ms), 32 sets 113 ms (147 ms). On a
//! hardware GPU a single light set is only `n` threads; splitting samples over threads is the
//! next step if one-set relights turn out latency-bound there (not measured: no GPU here).
//!
//! It is a twin, not a copy: f32 division and `sqrt` may round differently on a GPU and drivers
//! may fuse multiply-adds, so values agree to a few ulps and a shadow ray that grazes a voxel edge
//! may flip (`engine/tests/it/gpu_direct.rs` bounds both).

use bounce_core::direct::{PreparedLight, samples_side};
use bounce_core::light::LightSet;
use bounce_core::patch::PatchLayout;
use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

use super::kernel::{check_binding, pipeline, read_rgb, storage};
use super::light::{self, GpuLight};
use super::{GpuContext, GpuError};

/// Threads per workgroup (mirrors `WG` in `direct.wgsl`).
pub const DIRECT_WG: u32 = 64;

/// The uniform of the direct kernel (`DirectParams` in `direct.wgsl`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct DirectParams {
    pub n: u32,
    pub sets: u32,
    pub side: u32,
    pub groups_x: u32,
    pub dims: [u32; 3],
    pub voxel_size: f32,
    pub origin: [f32; 3],
    pub pad: u32,
}

/// One patch as the kernel reads it (`GpuPatch` in `direct.wgsl`): its quad (`Quad`'s fields)
/// and the start voxel of its shadow walks.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct GpuPatch {
    pub face: u32,
    pub plane: f32,
    pub lo: [f32; 2],
    pub hi: [f32; 2],
    pub cell: [i32; 3],
}

pub fn direct_source() -> String {
    [light::WGSL, include_str!("shaders/direct.wgsl")].concat()
}

/// The start voxel of a shadow walk from `patch`, from the CPU walk's own function.
fn start_cell(layout: &PatchLayout, patch: usize) -> [i32; 3] {
    bounce_core::rays::start_cell(&layout.quad(patch), layout.origin, layout.voxel_size)
}

/// A scene's patches and occupancy resident on the GPU, ready for batches of light sets.
pub struct GpuDirect {
    device: wgpu::Device,
    queue: wgpu::Queue,
    pipeline: wgpu::ComputePipeline,
    patches: wgpu::Buffer,
    occupancy: wgpu::Buffer,
    n: u32,
    dims: [u32; 3],
    origin: [f32; 3],
    voxel_size: f32,
}

impl GpuDirect {
    /// Upload `layout`'s patches and the occupied voxels (ascending linear indices, as
    /// `Voxelization::occupied` and `Baked::occupancy` hold them; indices outside the grid are
    /// ignored, as on the CPU). A grid whose bitset exceeds a storage binding, or whose cells
    /// overflow the kernel's u32 indices, is refused.
    pub fn upload(
        ctx: &GpuContext,
        layout: &PatchLayout,
        occupied: &[u64],
    ) -> Result<GpuDirect, GpuError> {
        let cells = layout.dims.iter().map(|&d| u64::from(d)).product::<u64>();
        if cells > u64::from(u32::MAX) {
            return Err(GpuError::TooLarge {
                what: "voxel grid (cells)",
                needed: cells,
                limit: u64::from(u32::MAX),
            });
        }
        let n = u32::try_from(layout.len()).map_err(|_| GpuError::TooLarge {
            what: "patch count",
            needed: layout.len() as u64,
            limit: u64::from(u32::MAX),
        })?;
        let words = cells.div_ceil(32);
        check_binding(&ctx.device, "occupancy bitset", words * 4)?;
        check_binding(
            &ctx.device,
            "patch quads",
            u64::from(n) * std::mem::size_of::<GpuPatch>() as u64,
        )?;
        // Below the binding limit, so it fits in memory.
        let mut bits = vec![0u32; words as usize];
        for &k in occupied.iter().filter(|&&k| k < cells) {
            bits[(k / 32) as usize] |= 1 << (k % 32);
        }
        let quads: Vec<GpuPatch> = (0..layout.len())
            .map(|i| {
                let q = layout.quad(i);
                GpuPatch {
                    face: u32::from(q.face.code()),
                    plane: q.plane,
                    lo: q.lo,
                    hi: q.hi,
                    cell: start_cell(layout, i),
                }
            })
            .collect();
        let device = &ctx.device;
        Ok(GpuDirect {
            pipeline: pipeline(device, "direct", &direct_source(), "direct", &[])?,
            patches: storage(device, "patch quads", bytemuck::cast_slice(&quads))?,
            occupancy: storage(device, "occupancy bitset", bytemuck::cast_slice(&bits))?,
            device: device.clone(),
            queue: ctx.queue.clone(),
            n,
            dims: layout.dims,
            origin: layout.origin,
            voxel_size: layout.voxel_size,
        })
    }

    pub fn patch_count(&self) -> usize {
        self.n as usize
    }

    /// `E_direct` per patch for every light set of the batch, with about `samples` samples per
    /// patch (`bounce_core::direct::samples_side`); lights that fail validation or are dark are
    /// skipped, as on the CPU. Blocks until the result is back on the host.
    pub fn irradiance(
        &self,
        sets: &[LightSet],
        samples: u32,
    ) -> Result<Vec<Vec<[f32; 3]>>, GpuError> {
        let n = self.n as usize;
        if n == 0 || sets.is_empty() {
            return Ok(vec![vec![[0.0; 3]; n]; sets.len()]);
        }
        // Batches whose output exceeds a binding, or whose thread index (padded to whole
        // workgroups) could overflow u32, go in slices.
        let limits = self.device.limits();
        let set_bytes = n as u64 * 12;
        let by_binding = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size)
            / set_bytes;
        let by_index = u64::from(u32::MAX / 2) / n as u64;
        let slice = by_binding.min(by_index).min(sets.len() as u64) as usize;
        if slice == 0 {
            return Err(GpuError::TooLarge {
                what: "one light set's direct irradiance",
                needed: set_bytes,
                limit: limits.max_storage_buffer_binding_size,
            });
        }
        let side = samples_side(samples);
        let mut out = Vec::with_capacity(sets.len());
        for chunk in sets.chunks(slice) {
            let flat = self.run(chunk, side)?;
            out.extend(flat.chunks(n).map(<[[f32; 3]]>::to_vec));
        }
        Ok(out)
    }

    fn run(&self, sets: &[LightSet], side: u32) -> Result<Vec<[f32; 3]>, GpuError> {
        let mut lights: Vec<GpuLight> = Vec::new();
        let mut offsets: Vec<u32> = vec![0];
        for set in sets {
            lights.extend(
                set.lights
                    .iter()
                    .filter_map(PreparedLight::new)
                    .map(|l| GpuLight::from(&l)),
            );
            let end = u32::try_from(lights.len()).map_err(|_| GpuError::TooLarge {
                what: "lights in one batch",
                needed: lights.len() as u64,
                limit: u64::from(u32::MAX),
            })?;
            offsets.push(end);
        }
        if lights.is_empty() {
            // A binding holds at least one element; the offsets keep the kernel off it.
            lights.push(GpuLight::default());
        }
        let sets_n = sets.len() as u32;
        let threads = self.n * sets_n;
        let groups = threads.div_ceil(DIRECT_WG);
        let max = self
            .device
            .limits()
            .max_compute_workgroups_per_dimension
            .max(1);
        let gx = groups.clamp(1, max);
        let gy = groups.div_ceil(gx).max(1);
        let params = DirectParams {
            n: self.n,
            sets: sets_n,
            side,
            groups_x: gx,
            dims: self.dims,
            voxel_size: self.voxel_size,
            origin: self.origin,
            pad: 0,
        };
        let bytes = u64::from(threads) * 12;
        let device = &self.device;
        let params_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("direct params"),
            contents: bytemuck::bytes_of(&params),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let lights_buf = storage(device, "prepared lights", bytemuck::cast_slice(&lights))?;
        let offsets_buf = storage(device, "light offsets", bytemuck::cast_slice(&offsets))?;
        use wgpu::BufferUsages as U;
        let out = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("direct irradiance"),
            size: bytes,
            usage: U::STORAGE | U::COPY_SRC,
            mapped_at_creation: false,
        });
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("direct readback"),
            size: bytes,
            usage: U::MAP_READ | U::COPY_DST,
            mapped_at_creation: false,
        });
        let entries = [
            params_buf.as_entire_binding(),
            self.patches.as_entire_binding(),
            self.occupancy.as_entire_binding(),
            lights_buf.as_entire_binding(),
            offsets_buf.as_entire_binding(),
            out.as_entire_binding(),
        ];
        let entries: Vec<wgpu::BindGroupEntry> = entries
            .into_iter()
            .enumerate()
            .map(|(binding, resource)| wgpu::BindGroupEntry {
                binding: binding as u32,
                resource,
            })
            .collect();
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("direct"),
            layout: &self.pipeline.get_bind_group_layout(0),
            entries: &entries,
        });
        let mut encoder =
            device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        {
            let mut cpass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
            cpass.set_pipeline(&self.pipeline);
            cpass.set_bind_group(0, &group, &[]);
            cpass.dispatch_workgroups(gx, gy, 1);
        }
        encoder.copy_buffer_to_buffer(&out, 0, &readback, 0, bytes);
        self.queue.submit([encoder.finish()]);
        read_rgb(device, &readback, threads as usize)
    }
}
