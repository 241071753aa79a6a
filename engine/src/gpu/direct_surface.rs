//! [`GpuSurfaceDirect`]: direct irradiance with shadows against the scene's triangles on the GPU,
//! the twin of `bounce_core::direct::direct_irradiance` on a surface-geometry scene
//! (`ShadowScene::surface`, `surface_irradiance`).
//!
//! Uploaded once per scene: the triangles' BVH as `bounce_core::trimesh::TriMesh` builds it (its
//! nodes, and the triangles in primitive order, so a leaf indexes them directly) and every
//! patch's stored sample points. Per call: the prepared lights of a whole batch of light sets,
//! flattened with per-set offsets, then two passes (`shaders/direct_surface.wgsl`):
//!
//! 1. `shadow`, one thread per (light, patch, sample): one shadow ray from the sample point,
//!    traced through the BVH (iterative, a fixed stack in private memory, near child first, any
//!    hit ends it), recorded as one bit, whether the light reaches the sample. Where the rows
//!    are denser than the default's (`bounce_core::direct::pilots_apply`), `shadow_pilots`
//!    runs first, one thread per (light, patch, pilot), packed so that no thread idles on a
//!    sample that is not a pilot; `shadow` then takes the pilots' bits from it and sets no bit
//!    and traces no ray for the other samples of a patch some pilot of which faces the light
//!    and none of which is reached, as the CPU does;
//! 2. `gather`, one thread per (patch, light set): the patch's samples in order and, per sample,
//!    the set's lights in order, adding the irradiance of every ray whose bit is set into the
//!    sample's value (kept finite), the samples' values into the patch's sum, then dividing by
//!    the sample count.
//!
//! So the rays, which are the work, get `patches × samples × lights` threads even for a single
//! light set (a 2,000-patch scene at 16 samples and one light is 32,000 rays), while each patch
//! still sums **in the CPU's order**: the GPU result differs from the CPU's only by f32 rounding,
//! not by a reordered sum. What remains: f32 division and `sqrt` may round differently on a GPU
//! and drivers may fuse multiply-adds, so values agree to a few ulps, and a shadow ray that grazes
//! a triangle's edge (or a BVH box's face) may flip, moving its patch by that sample's share, at
//! most `1/count` of the patch's unshadowed value (`engine/tests/it/gpu_direct_surface.rs` bounds
//! both: relative `1e-4` per patch, at most 1% of the patches off by up to `1.5/count` of their
//! unshadowed value). Under the pilot rule a flipped pilot can change which of the patch's other
//! rays are traced, and so move it by more: on lavapipe the bits are the CPU's, and the dense
//! tests there hold the same bounds.
//!
//! Measured on lavapipe (software Vulkan, 2 cores) on a 2,624-patch room with a pillar, 16
//! samples (`surface_direct_timing` in `engine/tests/it/gpu_direct_surface.rs`): 1 set of 1 light
//! 6.0 ms (CPU twin 2.4 ms), 8 sets of 14 lights in all 61 ms (22 ms). At one set lavapipe's fixed
//! cost of two passes, a submission and a readback (about 5 ms) dominates; at eight about half is
//! the traversal and half lavapipe's cost per invocation of 590,000 threads (with a traversal
//! that returns at once: 34 ms). `auto` never takes lavapipe. On lavapipe the results are
//! bit-identical to the CPU's on every scene of the tests. On an NVIDIA H200 (`docs/h200`), with
//! the near field: `pandora` at 11,857 rows and 16 samples, 0.82 ms for one set, 2.60 ms for 8
//! and 34.5 ms for 64, against 6.06 / 47.3 / 339 ms on the 16 CPU cores beside it.
//!
//! Large batches go in slices (each light set's output within a storage binding, thread indices
//! within u32), and within a slice the patches go in pieces of at most [`RAYS_PER_PIECE`] rays,
//! so the visibility bits stay small whatever the batch.
//!
//! With a near-field matrix attached ([`GpuSurfaceDirect::with_near_field`],
//! `bounce_core::nearfield`), [`GpuSurfaceDirect::irradiance_near`] runs `gather_samples`
//! instead of `gather`: the same sums, which also keep every sample's value in a device buffer
//! (a slice's `sets × patches × count` values, within a binding: the slices are cut smaller for
//! it). After the slice's last piece, the pass of `shaders/near_field.wgsl` (`super::near_field`)
//! turns those values and the means into `ΔE` per (light set, row), read back with the means;
//! the per-sample values never leave the device. When the matrix keeps its samples' sky view
//! and a set of the slice has a sky, `sky_samples` first adds each sample's sky irradiance to
//! its value and the row's mean of them to the row's mean (after the means were copied out for
//! the host), so the same pass corrects the sky too.

use bounce_core::direct::{PILOT_STRIDE, PreparedLight, SHADOW_END, pilots_apply};
use bounce_core::light::LightSet;
use bounce_core::nearfield::{NearField, Reflect};
use bounce_core::surface::SurfaceData;
use bounce_core::trimesh::MeshNode;
use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

use super::kernel::{check_binding, pipeline, read_rgb, storage};
use super::light::{self, GpuLight};
use super::near_field::{NEAR_WG, NearBuffers, NearParams};
use super::{GpuContext, GpuError};

/// Threads per workgroup (mirrors `WG` in `direct_surface.wgsl`).
pub const SURFACE_WG: u32 = 64;
/// Entries of the traversal stack (mirrors `STACK` in `direct_surface.wgsl`): a BVH deeper than
/// this is refused ([`GpuError::TooLarge`]) and lit on the CPU.
pub const SURFACE_STACK: u32 = 64;
/// The most shadow rays (visibility bits) one pass of the `shadow` kernel covers: 4 MiB of bits.
pub const RAYS_PER_PIECE: u64 = 1 << 25;

/// The uniform of the surface direct kernels (`SurfaceParams` in `direct_surface.wgsl`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct SurfaceParams {
    /// Patches in the scene.
    pub n: u32,
    /// Sample points stored per patch.
    pub per_patch: u32,
    /// Samples per patch used (the first of each patch's points).
    pub count: u32,
    /// Lights in this dispatch, every light set together.
    pub lights: u32,
    /// The piece of patches this pass covers: `first..first + patches`.
    pub first: u32,
    pub patches: u32,
    /// Light sets in this dispatch.
    pub sets: u32,
    /// BVH nodes, 0 when there is no triangle.
    pub nodes: u32,
    /// Samples a patch's mean is taken over: the first of the `count` used (those spread by
    /// area, `SurfaceData::mean_count`).
    pub averaged: u32,
    /// 1 when the pilot rule holds (`bounce_core::direct::pilots_apply(averaged)`).
    pub pilots: u32,
    pub pad: [u32; 2],
}

/// One sample point as the kernel reads it (`GpuSample` in `direct_surface.wgsl`):
/// `bounce_core::surface::SamplePoint` padded to vec4 alignment.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct GpuSample {
    pub position: [f32; 3],
    pub pad0: u32,
    pub normal: [f32; 3],
    pub pad1: u32,
}

/// The overrides every pipeline of `direct_surface.wgsl` is compiled with: the host sets
/// `SHADOW_END` so the two sides cannot round it apart.
const CONSTANTS: [(&str, f64); 1] = [("SHADOW_END", SHADOW_END as f64)];

pub fn direct_surface_source() -> String {
    [light::WGSL, include_str!("shaders/direct_surface.wgsl")].concat()
}

/// The depth of the tree (nodes on its longest root-to-leaf path), which bounds the traversal
/// stack (it holds at most one entry per inner node on the current path). `None` for a tree
/// whose indices leave the node or triangle arrays or that revisits nodes: not what obvhs
/// builds, and not for the kernel to walk.
fn tree_depth(nodes: &[MeshNode], triangles: usize) -> Option<usize> {
    let mut deepest = 0;
    let mut todo = vec![(0usize, 1usize)];
    let mut visited = 0usize;
    while let Some((i, depth)) = todo.pop() {
        visited += 1;
        if visited > nodes.len() {
            return None;
        }
        let node = nodes.get(i)?;
        deepest = deepest.max(depth);
        let first = node.first_index as usize;
        if node.prim_count > 0 {
            if first + node.prim_count as usize > triangles {
                return None;
            }
        } else {
            if first == 0 || first + 1 >= nodes.len() {
                return None;
            }
            todo.push((first, depth + 1));
            todo.push((first + 1, depth + 1));
        }
    }
    Some(deepest)
}

/// A storage buffer of `items`, with one zeroed element when there is none (a binding of an
/// array holds at least one element).
fn storage_of<T: Pod>(
    device: &wgpu::Device,
    label: &'static str,
    items: &[T],
) -> Result<wgpu::Buffer, GpuError> {
    if items.is_empty() {
        storage(device, label, bytemuck::bytes_of(&T::zeroed()))
    } else {
        storage(device, label, bytemuck::cast_slice(items))
    }
}

/// One compute pass of `pipeline` over `grid` (`(x, y)` workgroups) with `group` bound.
fn dispatch(
    encoder: &mut wgpu::CommandEncoder,
    pipeline: &wgpu::ComputePipeline,
    group: &wgpu::BindGroup,
    (gx, gy): (u32, u32),
) {
    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, group, &[]);
    pass.dispatch_workgroups(gx, gy, 1);
}

/// A dispatch grid of `groups` workgroups along x, folded into y past the per-dimension limit.
fn grid(device: &wgpu::Device, groups: u64) -> Result<(u32, u32), GpuError> {
    let max = device.limits().max_compute_workgroups_per_dimension.max(1);
    let gx = groups.clamp(1, u64::from(max));
    let gy = groups.div_ceil(gx).max(1);
    let gy = u32::try_from(gy)
        .ok()
        .filter(|&y| y <= max)
        .ok_or(GpuError::TooLarge {
            what: "workgroups of one surface direct-light pass",
            needed: groups,
            limit: u64::from(max) * u64::from(max),
        })?;
    // At most `max`, a u32.
    Ok((gx as u32, gy))
}

/// A surface scene's triangles (as a BVH) and sample points resident on the GPU, ready for
/// batches of light sets.
pub struct GpuSurfaceDirect {
    device: wgpu::Device,
    queue: wgpu::Queue,
    shadow: wgpu::ComputePipeline,
    shadow_pilots: wgpu::ComputePipeline,
    gather: wgpu::ComputePipeline,
    nodes: wgpu::Buffer,
    tris: wgpu::Buffer,
    points: wgpu::Buffer,
    n: u32,
    per_patch: u32,
    /// Samples of a patch spread by area, its first: its mean is theirs.
    area_samples: u32,
    /// BVH nodes, 0 when there is no triangle to trace.
    node_count: u32,
    /// The most rays one `shadow` pass covers.
    rays_per_piece: u64,
    /// The most bytes a slice's output or per-sample values may take, below the device's
    /// binding limit only in tests.
    binding_cap: u64,
    /// The near-field matrix, when one is attached, with `gather_samples`.
    near: Option<(NearBuffers, wgpu::ComputePipeline)>,
}

impl GpuSurfaceDirect {
    /// Build `surface`'s BVH ([`SurfaceData::mesh`], as the CPU does) and upload it with the
    /// sample points. A scene whose arrays exceed a storage binding, or whose BVH is deeper than
    /// the kernel's stack ([`SURFACE_STACK`]), is refused with [`GpuError::TooLarge`].
    pub fn upload(ctx: &GpuContext, surface: &SurfaceData) -> Result<GpuSurfaceDirect, GpuError> {
        let per_patch = surface.per_patch;
        let n = surface.points.len() / (per_patch.max(1) as usize);
        let n = u32::try_from(n).map_err(|_| GpuError::TooLarge {
            what: "patch count",
            needed: n as u64,
            limit: u64::from(u32::MAX),
        })?;
        let device = &ctx.device;
        let stored = u64::from(n) * u64::from(per_patch);
        check_binding(
            device,
            "sample points",
            stored * std::mem::size_of::<GpuSample>() as u64,
        )?;
        let mesh = surface.mesh();
        let mut node_count = 0;
        let nodes = if mesh.is_empty() {
            Vec::new()
        } else {
            let nodes = mesh.nodes();
            let depth = tree_depth(&nodes, mesh.len()).unwrap_or(usize::MAX);
            if depth > SURFACE_STACK as usize {
                return Err(GpuError::TooLarge {
                    what: "triangle BVH depth (traversal stack entries)",
                    needed: depth as u64,
                    limit: u64::from(SURFACE_STACK),
                });
            }
            node_count = u32::try_from(nodes.len()).map_err(|_| GpuError::TooLarge {
                what: "triangle BVH nodes",
                needed: nodes.len() as u64,
                limit: u64::from(u32::MAX),
            })?;
            nodes
        };
        // Within a binding, so it fits in memory.
        let points: Vec<GpuSample> = surface.points[..stored as usize]
            .iter()
            .map(|p| GpuSample {
                position: p.position,
                pad0: 0,
                normal: p.normal,
                pad1: 0,
            })
            .collect();
        let constants = CONSTANTS;
        let source = direct_surface_source();
        Ok(GpuSurfaceDirect {
            shadow: pipeline(
                device,
                "direct_surface shadow",
                &source,
                "shadow",
                &constants,
            )?,
            shadow_pilots: pipeline(
                device,
                "direct_surface shadow_pilots",
                &source,
                "shadow_pilots",
                &constants,
            )?,
            gather: pipeline(
                device,
                "direct_surface gather",
                &source,
                "gather",
                &constants,
            )?,
            nodes: storage_of(device, "triangle BVH nodes", &nodes)?,
            tris: storage_of(device, "triangles", mesh.triangles())?,
            points: storage_of(device, "sample points", &points)?,
            device: device.clone(),
            queue: ctx.queue.clone(),
            n,
            per_patch,
            area_samples: surface.area_samples,
            node_count,
            rays_per_piece: RAYS_PER_PIECE,
            binding_cap: u64::MAX,
            near: None,
        })
    }

    /// Attach the near-field matrix `near` (rows: these patches; columns: their sample points)
    /// and the rows' (and samples') `albedo`, so [`GpuSurfaceDirect::irradiance_near`] also returns the
    /// correction `ΔE`. A matrix whose `per_row` is not this scene's samples per patch, whose
    /// rows are not its patches or that fails [`NearField::check`], or an albedo not one a row,
    /// is refused with [`GpuError::NearField`]; an array over a storage binding with
    /// [`GpuError::TooLarge`].
    pub fn with_near_field(
        mut self,
        near: &NearField,
        albedo: Reflect<'_>,
    ) -> Result<GpuSurfaceDirect, GpuError> {
        let buffers =
            NearBuffers::upload(&self.device, near, albedo, self.n as usize, self.per_patch)?;
        let gather = pipeline(
            &self.device,
            "direct_surface gather_samples",
            &direct_surface_source(),
            "gather_samples",
            &CONSTANTS,
        )?;
        self.near = Some((buffers, gather));
        Ok(self)
    }

    /// At most `rays` shadow rays per `shadow` pass instead of [`RAYS_PER_PIECE`] (at least one
    /// patch's worth for a light set): the same result from more slices and passes. For tests
    /// of that splitting.
    #[doc(hidden)]
    pub fn with_rays_per_piece(mut self, rays: u64) -> GpuSurfaceDirect {
        self.rays_per_piece = rays.max(1);
        self
    }

    /// At most `bytes` for one slice's output and for its per-sample values, instead of the
    /// device's binding limit: the same result from more slices. For tests of that slicing.
    #[doc(hidden)]
    pub fn with_binding_limit(mut self, bytes: u64) -> GpuSurfaceDirect {
        self.binding_cap = bytes.max(1);
        self
    }

    pub fn patch_count(&self) -> usize {
        self.n as usize
    }

    /// `E_direct` per patch for every light set of the batch from the first
    /// `samples.clamp(1, per_patch)` sample points of each patch, as
    /// `bounce_core::direct::direct_irradiance` takes them; lights that fail validation or are
    /// dark are skipped, as on the CPU. Blocks until the result is back on the host.
    pub fn irradiance(
        &self,
        sets: &[LightSet],
        samples: u32,
    ) -> Result<Vec<Vec<[f32; 3]>>, GpuError> {
        Ok(self.batch(sets, samples, false)?.0)
    }

    /// [`GpuSurfaceDirect::irradiance`], and with it the near-field correction `ΔE` per light set
    /// and row (`NearField::correction` of that set's per-sample values and means, which stay on
    /// the device) when a matrix is attached ([`GpuSurfaceDirect::with_near_field`]) and the
    /// samples used, `samples.clamp(1, per_patch)`, are all its columns per row; else `None`.
    #[allow(clippy::type_complexity)]
    pub fn irradiance_near(
        &self,
        sets: &[LightSet],
        samples: u32,
    ) -> Result<(Vec<Vec<[f32; 3]>>, Option<Vec<Vec<[f32; 3]>>>), GpuError> {
        self.batch(sets, samples, true)
    }

    #[allow(clippy::type_complexity)]
    fn batch(
        &self,
        sets: &[LightSet],
        samples: u32,
        want_near: bool,
    ) -> Result<(Vec<Vec<[f32; 3]>>, Option<Vec<Vec<[f32; 3]>>>), GpuError> {
        let n = self.n as usize;
        let used = samples.max(1).min(self.per_patch);
        let near = self
            .near
            .as_ref()
            .filter(|(b, _)| want_near && b.per_row == used);
        // Without the near field only the samples of the mean (spread by area) are lit.
        let count = if near.is_some() {
            used
        } else {
            used.min(self.area_samples)
        };
        if n == 0 || sets.is_empty() {
            let zeros = vec![vec![[0.0; 3]; n]; sets.len()];
            return Ok((zeros.clone(), near.map(|_| zeros)));
        }
        let prepared: Vec<Vec<GpuLight>> = sets
            .iter()
            .map(|set| {
                set.lights
                    .iter()
                    .filter_map(PreparedLight::new)
                    .map(|l| GpuLight::from(&l))
                    .collect()
            })
            .collect();
        // Slices of the batch: each one's output (and per-sample values) within a binding, its
        // gather thread indices within u32, and one patch's rays within a piece.
        let limits = self.device.limits();
        let binding = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size)
            .min(self.binding_cap);
        let set_bytes = n as u64 * 12;
        let (what, per_set) = match near {
            Some(_) => (
                "one light set's direct irradiance per sample point",
                set_bytes * u64::from(count).max(1),
            ),
            None => ("one light set's direct irradiance", set_bytes),
        };
        let by_binding = binding / per_set;
        let by_index = u64::from(u32::MAX / 2) / n as u64;
        let max_sets = by_binding.min(by_index);
        if max_sets == 0 {
            return Err(GpuError::TooLarge {
                what,
                needed: per_set,
                limit: binding,
            });
        }
        let ray_cap = self.rays_per_piece.min(binding.saturating_mul(8));
        let mut out = Vec::with_capacity(sets.len());
        let mut deltas = near.map(|_| Vec::with_capacity(sets.len()));
        let mut start = 0;
        while start < sets.len() {
            let (mut end, mut lights) = (start, 0u64);
            while end < sets.len() && ((end - start) as u64) < max_sets {
                let more = lights + prepared[end].len() as u64;
                if more * u64::from(count) > ray_cap {
                    break;
                }
                lights = more;
                end += 1;
            }
            if end == start {
                return Err(GpuError::TooLarge {
                    what: "one light set's shadow rays per patch",
                    needed: prepared[start].len() as u64 * u64::from(count),
                    limit: ray_cap,
                });
            }
            let skies = near.and_then(|(b, _)| slice_skies(b, &sets[start..end]));
            let (flat, delta) = self.run(
                &prepared[start..end],
                count,
                ray_cap,
                near,
                skies.as_deref(),
            )?;
            out.extend(flat.chunks(n).map(<[[f32; 3]]>::to_vec));
            if let (Some(all), Some(delta)) = (deltas.as_mut(), delta) {
                all.extend(delta.chunks(n).map(<[[f32; 3]]>::to_vec));
            }
            start = end;
        }
        Ok((out, deltas))
    }

    /// One slice of the batch: `count × lights` rays per patch fit in `ray_cap`, and the sets'
    /// output (and per-sample values, with `near`) in a binding. With `near`, the slice's `ΔE`
    /// too, with the sky of each set in `skies` (27 values a set, [`slice_skies`]) when given.
    #[allow(clippy::type_complexity)]
    fn run(
        &self,
        sets: &[Vec<GpuLight>],
        count: u32,
        ray_cap: u64,
        near: Option<&(NearBuffers, wgpu::ComputePipeline)>,
        skies: Option<&[f32]>,
    ) -> Result<(Vec<[f32; 3]>, Option<Vec<[f32; 3]>>), GpuError> {
        let mut lights: Vec<GpuLight> = Vec::new();
        let mut offsets: Vec<u32> = vec![0];
        for set in sets {
            lights.extend_from_slice(set);
            // Below `ray_cap`, so within u32.
            offsets.push(lights.len() as u32);
        }
        let light_count = lights.len() as u32;
        let sets_n = sets.len() as u32;
        let rays_per_patch = u64::from(count) * u64::from(light_count);
        let n = u64::from(self.n);
        // Patches a piece holds: every patch when there is no ray to trace.
        let piece = ray_cap
            .checked_div(rays_per_patch)
            .map_or(n, |p| p.clamp(1, n));
        let device = &self.device;
        use wgpu::BufferUsages as U;
        // Two words per `shadow` workgroup; every word a gather reads was written by the shadow
        // pass of its piece.
        let words = (piece * rays_per_patch).div_ceil(u64::from(SURFACE_WG)) * 2;
        let bits_bytes = words.max(1) * 4;
        check_binding(device, "visibility bits", bits_bytes)?;
        let bits = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("visibility bits"),
            size: bits_bytes,
            usage: U::STORAGE,
            mapped_at_creation: false,
        });
        let averaged = self.area_samples.min(count);
        let pilots = pilots_apply(averaged);
        let pilots_per_row = u64::from(averaged.div_ceil(PILOT_STRIDE as u32));
        // Four words per `shadow_pilots` workgroup of 64 pilots; one word, never read, where the
        // rule does not hold (`shadow` binds it either way).
        let pilot_bytes = if pilots {
            (piece * pilots_per_row * u64::from(light_count)).div_ceil(u64::from(SURFACE_WG)) * 16
        } else {
            4
        };
        check_binding(device, "pilot bits", pilot_bytes.max(4))?;
        let pilot_bits = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("pilot bits"),
            size: pilot_bytes.max(4),
            usage: U::STORAGE,
            mapped_at_creation: false,
        });
        let lights_buf = storage_of(device, "prepared lights", &lights)?;
        let offsets_buf = storage(device, "light offsets", bytemuck::cast_slice(&offsets))?;
        let bytes = n * u64::from(sets_n) * 12;
        // A result per (light set, row) the passes write, and the buffer it is read back from.
        let rgb_out = |what: &str| {
            let buffer = |suffix: &str, usage| {
                device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(&format!("{what}{suffix}")),
                    size: bytes,
                    usage,
                    mapped_at_creation: false,
                })
            };
            (
                buffer("", U::STORAGE | U::COPY_SRC),
                buffer(" readback", U::MAP_READ | U::COPY_DST),
            )
        };
        let (out, readback) = rgb_out("surface direct irradiance");
        let per_sample = match near {
            Some(_) => {
                // Within the binding the slice was cut to.
                let size = (bytes * u64::from(count)).max(4);
                check_binding(device, "direct irradiance per sample point", size)?;
                Some(device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("surface direct per sample point"),
                    size,
                    usage: U::STORAGE,
                    mapped_at_creation: false,
                }))
            }
            None => None,
        };
        let gather = near.map_or(&self.gather, |(_, g)| g);
        let bind = |pipeline: &wgpu::ComputePipeline, entries: &[(u32, &wgpu::Buffer)]| {
            let entries: Vec<wgpu::BindGroupEntry> = entries
                .iter()
                .map(|&(binding, buffer)| wgpu::BindGroupEntry {
                    binding,
                    resource: buffer.as_entire_binding(),
                })
                .collect();
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("direct_surface"),
                layout: &pipeline.get_bind_group_layout(0),
                entries: &entries,
            })
        };
        let mut encoder =
            device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        let mut first = 0u64;
        while first < n {
            let patches = piece.min(n - first);
            let params = SurfaceParams {
                n: self.n,
                per_patch: self.per_patch,
                count,
                lights: light_count,
                // Both below `n`, a u32.
                first: first as u32,
                patches: patches as u32,
                sets: sets_n,
                nodes: self.node_count,
                averaged,
                pilots: u32::from(pilots),
                pad: [0; 2],
            };
            let params_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("direct_surface params"),
                contents: bytemuck::bytes_of(&params),
                usage: U::UNIFORM,
            });
            if rays_per_patch > 0 && pilots {
                let group = bind(
                    &self.shadow_pilots,
                    &[
                        (0, &params_buf),
                        (1, &self.nodes),
                        (2, &self.tris),
                        (3, &self.points),
                        (4, &lights_buf),
                        (9, &pilot_bits),
                    ],
                );
                let (gx, gy) = grid(
                    device,
                    (patches * pilots_per_row * u64::from(light_count))
                        .div_ceil(u64::from(SURFACE_WG)),
                )?;
                dispatch(&mut encoder, &self.shadow_pilots, &group, (gx, gy));
            }
            if rays_per_patch > 0 {
                let group = bind(
                    &self.shadow,
                    &[
                        (0, &params_buf),
                        (1, &self.nodes),
                        (2, &self.tris),
                        (3, &self.points),
                        (4, &lights_buf),
                        (6, &bits),
                        (9, &pilot_bits),
                    ],
                );
                let (gx, gy) = grid(
                    device,
                    (patches * rays_per_patch).div_ceil(u64::from(SURFACE_WG)),
                )?;
                dispatch(&mut encoder, &self.shadow, &group, (gx, gy));
            }
            let mut entries = vec![
                (0, &params_buf),
                (3, &self.points),
                (4, &lights_buf),
                (5, &offsets_buf),
                (6, &bits),
                (7, &out),
            ];
            if let Some(per_sample) = &per_sample {
                entries.push((8, per_sample));
            }
            let group = bind(gather, &entries);
            let (gx, gy) = grid(
                device,
                (patches * u64::from(sets_n)).div_ceil(u64::from(SURFACE_WG)),
            )?;
            dispatch(&mut encoder, gather, &group, (gx, gy));
            first += patches;
        }
        encoder.copy_buffer_to_buffer(&out, 0, &readback, 0, bytes);
        // After the last piece: a row's correction reads samples of any row.
        let mut delta_readback = None;
        if let (Some((near, _)), Some(per_sample)) = (near, &per_sample) {
            let (delta, readback) = rgb_out("near-field correction");
            let params = NearParams {
                n: self.n,
                sets: sets_n,
                per_row: count,
                averaged: self.area_samples.min(count),
            };
            let params_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("near_field params"),
                contents: bytemuck::bytes_of(&params),
                usage: U::UNIFORM,
            });
            if let (Some(sky), Some(skies)) = (&near.sky, skies) {
                let skies_buf = storage(device, "light sets' skies", bytemuck::cast_slice(skies))?;
                // After the means were copied out: the sky's row means join them for the
                // correction only (the host adds the rows' own sky view to what it reads).
                let group = bind(
                    &sky.pass,
                    &[
                        (0, &params_buf),
                        (8, &sky.view),
                        (9, &skies_buf),
                        (10, per_sample),
                        (12, &out),
                    ],
                );
                let (gx, gy) = grid(device, (n * u64::from(sets_n)).div_ceil(u64::from(NEAR_WG)))?;
                dispatch(&mut encoder, &sky.pass, &group, (gx, gy));
            }
            let group = bind(
                &near.pass,
                &[
                    (0, &params_buf),
                    (1, &near.row_ptr),
                    (2, &near.cols),
                    (3, &near.values),
                    (4, &near.albedo),
                    (5, &out),
                    (6, per_sample),
                    (7, &delta),
                    (11, &near.landed_albedo),
                ],
            );
            let (gx, gy) = grid(device, (n * u64::from(sets_n)).div_ceil(u64::from(NEAR_WG)))?;
            dispatch(&mut encoder, &near.pass, &group, (gx, gy));
            encoder.copy_buffer_to_buffer(&delta, 0, &readback, 0, bytes);
            delta_readback = Some(readback);
        }
        self.queue.submit([encoder.finish()]);
        let rows = (n * u64::from(sets_n)) as usize;
        let means = read_rgb(device, &readback, rows)?;
        let delta = match delta_readback {
            Some(b) => Some(read_rgb(device, &b, rows)?),
            None => None,
        };
        Ok((means, delta))
    }
}

/// The radiance coefficients of each set's sky, 27 a set (`skies` in `near_field.wgsl`; zero for
/// a set without one), when `near` keeps its samples' sky view and some set of the slice has a
/// sky; else `None`, and the slice's correction is the punctual lights' alone.
fn slice_skies(near: &NearBuffers, sets: &[LightSet]) -> Option<Vec<f32>> {
    near.sky.as_ref()?;
    let skies: Vec<Option<_>> = sets.iter().map(LightSet::sky_sh).collect();
    if skies.iter().all(Option::is_none) {
        return None;
    }
    Some(
        skies
            .iter()
            .flat_map(|sky| sky.unwrap_or_default())
            .flatten()
            .collect(),
    )
}
