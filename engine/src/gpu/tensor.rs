//! The block codecs' large-batch product on tensor cores (`tensor_block.wgsl`): where the device
//! has 16 × 16 × 16 cooperative matrices of f16 into f32 (see
//! [`super::context::tensor_support`]), a batch of more than [`CHUNK`](super::CHUNK) light sets
//! runs three dispatches in place of the FP32 tiled kernel: each set's largest value, the batch
//! packed as scaled f16 in the image's column order, then the product. The FP32 kernel stays
//! the twin that tests and `bench engines --kernels tensor,tiled` compare it with.

use super::GpuError;
use super::kernel::{Loops, TILE_ROWS, TILE_SETS, grid, pipeline_with, tensor_source};

/// Threads a workgroup of the two packing kernels (`TWG` in the shader).
const PACK_WG: u32 = 256;
/// Columns the product decodes a step (`TK`): the packed light is padded to a multiple of it.
const STEP: u32 = 32;

/// The three pipelines, compiled for BC1 or BC4 / raw codes like the block pass, and the block
/// pass's own resources they read.
pub(super) struct TensorKernel {
    top: wgpu::ComputePipeline,
    pack: wgpu::ComputePipeline,
    product: wgpu::ComputePipeline,
    blocks: wgpu::TextureView,
    row_perm: wgpu::Buffer,
    col_perm: wgpu::Buffer,
}

/// A batch's packed light, the sets' largest values, and the bind groups over them.
pub(super) struct TensorIo {
    tops: wgpu::Buffer,
    top_group: wgpu::BindGroup,
    pack_group: wgpu::BindGroup,
    product_group: wgpu::BindGroup,
}

impl TensorKernel {
    pub fn new(
        device: &wgpu::Device,
        bc4: f64,
        blocks: wgpu::TextureView,
        row_perm: wgpu::Buffer,
        col_perm: wgpu::Buffer,
    ) -> Result<TensorKernel, GpuError> {
        let source = tensor_source();
        let constants = [("BC4", bc4)];
        let compile =
            |label, entry| pipeline_with(device, label, &source, entry, &constants, Loops::Counted);
        Ok(TensorKernel {
            top: compile("tensor_light_top", "light_top_of")?,
            pack: compile("tensor_light_pack", "light_pack")?,
            product: compile("tensor_matvec", "matvec_tensor")?,
            blocks,
            row_perm,
            col_perm,
        })
    }

    /// Buffers for up to `sets` light sets of an `n`-column matrix.
    pub fn io(
        &self,
        device: &wgpu::Device,
        sets: u32,
        n: u32,
        params: &wgpu::Buffer,
        x: &wgpu::Buffer,
        out: &wgpu::Buffer,
    ) -> TensorIo {
        use wgpu::BufferUsages as U;
        let chunks = u64::from(sets.div_ceil(TILE_SETS).max(1));
        let npad = u64::from(n.div_ceil(STEP) * STEP);
        let xh = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("packed lights (f16)"),
            size: chunks * 3 * npad * u64::from(TILE_SETS) * 2,
            usage: U::STORAGE,
            mapped_at_creation: false,
        });
        let tops = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("light set maxima"),
            size: chunks * u64::from(TILE_SETS) * 4,
            usage: U::STORAGE | U::COPY_DST,
            mapped_at_creation: false,
        });
        let resource = |binding: u32| -> wgpu::BindingResource<'_> {
            match binding {
                0 => params.as_entire_binding(),
                1 => x.as_entire_binding(),
                2 => out.as_entire_binding(),
                3 => wgpu::BindingResource::TextureView(&self.blocks),
                4 => self.row_perm.as_entire_binding(),
                5 => self.col_perm.as_entire_binding(),
                6 => xh.as_entire_binding(),
                _ => tops.as_entire_binding(),
            }
        };
        // Each entry point's derived layout holds only the bindings it uses.
        let group = |pipeline: &wgpu::ComputePipeline, bindings: &[u32]| {
            let entries: Vec<wgpu::BindGroupEntry<'_>> = bindings
                .iter()
                .map(|&binding| wgpu::BindGroupEntry {
                    binding,
                    resource: resource(binding),
                })
                .collect();
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: None,
                layout: &pipeline.get_bind_group_layout(0),
                entries: &entries,
            })
        };
        let top_group = group(&self.top, &[0, 1, 7]);
        let pack_group = group(&self.pack, &[0, 1, 5, 6, 7]);
        let product_group = group(&self.product, &[0, 2, 3, 4, 6, 7]);
        TensorIo {
            tops,
            top_group,
            pack_group,
            product_group,
        }
    }

    /// The sets' maxima are folded in with atomicMax: zero them before the compute pass.
    pub fn clear(&self, encoder: &mut wgpu::CommandEncoder, io: &TensorIo) {
        encoder.clear_buffer(&io.tops, 0, None);
    }

    /// The product's grid for `sets` light sets over `rows` image rows, and its x extent, which
    /// the pass's `Params.groups_x` must carry (the packing kernels do not read it).
    pub fn dispatch_size(device: &wgpu::Device, rows: u32, sets: u32) -> ([u32; 3], u32) {
        grid(device, rows.div_ceil(TILE_ROWS), sets, TILE_SETS)
    }

    /// The three dispatches for `sets` light sets of an `n`-column matrix, the product on
    /// `product_grid` (from [`TensorKernel::dispatch_size`]).
    pub fn dispatch(
        &self,
        cpass: &mut wgpu::ComputePass<'_>,
        io: &TensorIo,
        n: u32,
        sets: u32,
        product_grid: [u32; 3],
    ) {
        let npad = n.div_ceil(STEP) * STEP;
        cpass.set_pipeline(&self.top);
        cpass.set_bind_group(0, &io.top_group, &[]);
        cpass.dispatch_workgroups((n * 3).div_ceil(PACK_WG), sets, 1);
        cpass.set_pipeline(&self.pack);
        cpass.set_bind_group(0, &io.pack_group, &[]);
        cpass.dispatch_workgroups(
            (npad * TILE_SETS).div_ceil(PACK_WG),
            sets.div_ceil(TILE_SETS),
            1,
        );
        cpass.set_pipeline(&self.product);
        cpass.set_bind_group(0, &io.product_group, &[]);
        let [gx, gy, gz] = product_grid;
        cpass.dispatch_workgroups(gx, gy, gz);
    }

    /// Whether a batch of `sets` fits the packing kernels' grids (sets along y).
    pub fn takes(device: &wgpu::Device, sets: u32) -> bool {
        sets <= device.limits().max_compute_workgroups_per_dimension
    }
}
