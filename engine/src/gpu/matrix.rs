//! [`GpuMatrix`]: one uploaded matrix, the passes that multiply by it, and the batch buffers
//! reused from call to call.

use std::sync::Mutex;

use bounce_core::codec::CodecError;
use bounce_core::matrix::EncodedMatrix;

use super::kernel::{
    ALL_COLUMNS, CHUNK, CHUNKS, LIT_GROUP, Params, Split, TILE_SETS, Variant, check_binding, grid,
    scoped, sets_per_dispatch, u32_bytes, variant_for, variant_within,
};
use super::lit::lit_groups;
use super::tensor::{TensorIo, TensorKernel};
use super::{GpuContext, GpuError, dense, logblock};

/// The passes, channel maxima, sparse band count and column order of an upload.
type Loaded = (Vec<Pass>, [f32; 4], usize, Option<Vec<u32>>);

/// A resource a pass binds besides the shared params, light and output buffers (bindings 0–2).
pub(super) enum Bound {
    Buffer(wgpu::Buffer),
    Texture(wgpu::TextureView),
}

/// One dispatch per batch chunk: a kernel variant per entry of [`CHUNKS`], its own resources,
/// and the part of the matrix it covers.
pub(super) struct Pass {
    pub variants: Vec<Variant>,
    pub bound: Vec<(u32, Bound)>,
    /// First matrix row and row count (a dense band); the whole matrix for the other passes.
    pub row0: u32,
    pub rows: u32,
    /// Side of a block-image tile (block pass), else 0.
    pub tile: u32,
    /// Entries of a sparse band (sparse passes), else 0.
    pub nnz: u32,
    /// The block pass's tensor-core kernel where the device has tensor cores (or why the driver
    /// refused it); `None` elsewhere.
    pub tensor: Option<Result<TensorKernel, String>>,
}

/// Which kernel multiplies a batch of more than [`CHUNK`] light sets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BatchKernel {
    /// The block codecs' tensor-core kernel (`tensor_block.wgsl`): f16 inputs, f32 sums. The
    /// default where the device has it.
    Tensor,
    /// The FP32 tiled kernel (`tile_block.wgsl`), one pass per 64 sets: the default elsewhere.
    Tiled,
    /// The matrix-vector kernel, one pass per [`CHUNK`] sets.
    Matvec,
}

impl Pass {
    /// Workgroups a chunk of light sets needs under `variant`.
    fn groups(&self, variant: usize) -> u32 {
        self.rows.div_ceil(self.variants[variant].rows_per_group)
    }
}

/// Light, output and readback buffers for up to `sets` light sets, with the bind groups that
/// reference them.
struct Io {
    sets: u32,
    /// Timestamps around the compute pass, where the device has timestamp queries.
    timer: Option<Timer>,
    x: wgpu::Buffer,
    out: wgpu::Buffer,
    /// The lit column groups of the batch (`lit_groups` in `row_block.wgsl`).
    lit: wgpu::Buffer,
    readback: wgpu::Buffer,
    params: Vec<wgpu::Buffer>,
    /// `groups[variant][pass]`: pipelines with derived layouts take only their own bind groups.
    groups: Vec<Vec<wgpu::BindGroup>>,
    /// Per pass, the tensor kernel's buffers where the pass has one.
    tensor: Vec<Option<TensorIo>>,
}

/// Two timestamps (start and end of the product's compute pass), resolved and read back.
struct Timer {
    queries: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    readback: wgpu::Buffer,
}

/// A transport matrix resident on the GPU, ready for batched products `E_ind = T · B0`.
pub struct GpuMatrix {
    device: wgpu::Device,
    queue: wgpu::Queue,
    codec: String,
    n: u32,
    channels: u32,
    max: [f32; 4],
    /// The dense passes (one per row band) or the block pass, then (bc1/bc4) the sparse pass
    /// that adds onto the block pass's output.
    passes: Vec<Pass>,
    /// Device time of the last `matvec_batch`'s compute passes, where it can be measured.
    kernel_seconds: Mutex<Option<f64>>,
    /// How the matrix was cut to fit the device: row bands (dense) or tiles (block codecs).
    pieces: usize,
    /// Row bands of the sparse part (block codecs; 0 when nothing was kept exactly).
    sparse_bands: usize,
    /// The kernel for batches over `CHUNK` sets (the bench measures each on one upload).
    kernel: BatchKernel,
    /// Storage column `l` multiplies patch `col_order[l]` (block codecs); the identity when
    /// `None` (dense).
    col_order: Option<Vec<u32>>,
    /// Whether the matrix-vector kernels skip the column groups every light set of a batch
    /// leaves dark (the default; the bench turns it off to measure what it saves).
    gather: bool,
    /// The share of column groups the last product's matrix-vector passes walked.
    lit_share: Mutex<Option<f64>>,
    io: Mutex<Option<Io>>,
}

impl GpuMatrix {
    /// Upload an encoded matrix. Which kernel runs follows the codec; a codec without one is an
    /// error. A matrix larger than one storage binding or one texture is cut into row bands or
    /// tiles by the device's own limits; one the device cannot hold at all (too many tiles, out
    /// of memory) is an error the caller can fall back from.
    pub fn upload(ctx: &GpuContext, m: &EncodedMatrix) -> Result<GpuMatrix, GpuError> {
        GpuMatrix::upload_split(ctx, m, Split::of(&ctx.device))
    }

    /// [`GpuMatrix::upload`] under limits smaller than the device's (clamped to them): how tests
    /// exercise the bands and tiles on an adapter whose real limits a small matrix never meets.
    pub fn upload_split(
        ctx: &GpuContext,
        m: &EncodedMatrix,
        split: Split,
    ) -> Result<GpuMatrix, GpuError> {
        m.validate_shape().map_err(CodecError::from)?;
        let split = split.within(&ctx.device);
        // Allocation failures are reported through an error scope, not wgpu's default panic, so
        // a scene the device cannot hold falls back instead of ending the process.
        let (uploaded, error) = scoped(&ctx.device, wgpu::ErrorFilter::OutOfMemory, || {
            match m.codec.as_str() {
                "dense-f32" | "dense-f16" => {
                    dense::upload(&ctx.device, m, split).map(|passes| (passes, [0.0; 4], 0, None))
                }
                "bc1" | "bc1-resid" | "bc4" | "log8" => logblock::upload(ctx, m, split).map(|u| {
                    let bands = u.sparse.len();
                    let passes = std::iter::once(u.block).chain(u.sparse).collect();
                    (passes, u.max, bands, Some(u.col_order))
                }),
                other => Err(GpuError::UnsupportedCodec(other.to_string())),
            }
        });
        if let Some(e) = error {
            return Err(GpuError::OutOfMemory {
                what: "transport matrix",
                message: e.to_string(),
            });
        }
        let (passes, max, sparse_bands, col_order): Loaded = uploaded?;
        let pieces = match passes.first() {
            Some(p) if p.tile > 0 => {
                let width = m.rows.div_ceil(4) * 4;
                (width.div_ceil(p.tile) as usize).pow(2)
            }
            _ => passes.len() - sparse_bands,
        };
        let mut matrix = GpuMatrix {
            device: ctx.device.clone(),
            queue: ctx.queue.clone(),
            codec: m.codec.clone(),
            n: m.rows,
            channels: m.channels,
            max,
            passes,
            sparse_bands,
            pieces,
            kernel: BatchKernel::Tensor,
            col_order,
            gather: true,
            lit_share: Mutex::new(None),
            kernel_seconds: Mutex::new(None),
            io: Mutex::new(None),
        };
        matrix.set_kernel(BatchKernel::Tensor);
        Ok(matrix)
    }

    /// Into how many row bands the block codecs' exactly kept entries were cut (0 when none
    /// were kept, 1 when they fit one binding).
    pub fn sparse_bands(&self) -> usize {
        self.sparse_bands
    }

    /// Seconds the device spent in the last product's kernels (timestamp queries around its
    /// compute passes, all slices of the batch summed): the product without the upload of the
    /// light, the readback and the submission. `None` where the device has no timestamp queries.
    pub fn last_kernel_seconds(&self) -> Option<f64> {
        self.kernel_seconds.lock().ok().and_then(|k| *k)
    }

    /// Into how many pieces the matrix was cut to fit the device: dense row bands, or block
    /// image tiles; 1 when it fits whole.
    pub fn pieces(&self) -> usize {
        self.pieces
    }

    pub fn n(&self) -> usize {
        self.n as usize
    }

    pub fn channels(&self) -> usize {
        self.channels as usize
    }

    pub fn codec(&self) -> &str {
        &self.codec
    }

    /// How many times a batch of `sets` light sets reads the matrix.
    pub fn passes_for(sets: usize) -> usize {
        let sets = u32::try_from(sets).unwrap_or(u32::MAX);
        sets.div_ceil(CHUNKS[variant_for(sets)]) as usize
    }

    /// [`GpuMatrix::passes_for`] for this matrix's kernel choice.
    pub fn passes(&self, sets: usize) -> usize {
        let sets = u32::try_from(sets).unwrap_or(u32::MAX);
        sets.div_ceil(CHUNKS[self.variant(sets)]) as usize
    }

    /// Run batches over `CHUNK` light sets on `kernel` (to measure the kernels against each
    /// other). The tensor kernel falls back to the tiled one where the matrix has none (dense
    /// codecs, a device without tensor cores, a driver that refused it): returns the kernel
    /// that will run.
    pub fn set_kernel(&mut self, kernel: BatchKernel) -> BatchKernel {
        self.kernel = match kernel {
            BatchKernel::Tensor if self.tensor_refused().is_some() || !self.has_tensor() => {
                BatchKernel::Tiled
            }
            k => k,
        };
        self.kernel
    }

    /// The kernel batches over `CHUNK` light sets run on.
    pub fn batch_kernel(&self) -> BatchKernel {
        self.kernel
    }

    /// Whether the matrix-vector kernels (batches of up to [`CHUNK`] sets) skip the column
    /// groups every light set of the batch leaves dark. On by default: a skipped group adds
    /// exactly zero, so the result has the same bits either way (a test checks it); off, the
    /// kernels read the whole matrix, which the bench measures against.
    pub fn set_gather(&mut self, gather: bool) {
        self.gather = gather;
    }

    /// The share of column groups (of [`super::LIT_GROUP`] columns) the last product's
    /// matrix-vector passes walked: 1 when they walked every column, `None` when the last
    /// product ran the tiled or tensor kernel, or none ran yet. Such a pass reads about this
    /// share of the matrix.
    pub fn last_lit_share(&self) -> Option<f64> {
        self.lit_share.lock().ok().and_then(|s| *s)
    }

    /// Why the driver refused the tensor kernel on a device that has tensor cores, if it did.
    pub fn tensor_refused(&self) -> Option<&str> {
        self.passes.iter().find_map(|p| match &p.tensor {
            Some(Err(why)) => Some(why.as_str()),
            _ => None,
        })
    }

    fn has_tensor(&self) -> bool {
        self.passes.iter().any(|p| matches!(p.tensor, Some(Ok(_))))
    }

    fn variant(&self, sets: u32) -> usize {
        match self.kernel {
            BatchKernel::Tensor | BatchKernel::Tiled => variant_for(sets),
            BatchKernel::Matvec => variant_within(sets, CHUNK),
        }
    }

    /// Whether `pass` runs its tensor kernel for a batch of `sets` under `variant`.
    fn tensor_for<'a>(
        &self,
        pass: &'a Pass,
        variant: usize,
        sets: u32,
    ) -> Option<&'a TensorKernel> {
        match &pass.tensor {
            Some(Ok(t))
                if self.kernel == BatchKernel::Tensor
                    && CHUNKS[variant] == TILE_SETS
                    && TensorKernel::takes(&self.device, sets) =>
            {
                Some(t)
            }
            _ => None,
        }
    }

    /// `out[k·n + i][c] = Σ_j T_c(i, j) · x[k·n + j][c]` for every light set `k`, as
    /// `MatrixOp::matvec_batch`; blocks until the result is back on the host.
    pub fn matvec_batch(&self, x: &[[f32; 3]], out: &mut [[f32; 3]]) -> Result<(), GpuError> {
        let n = self.n as usize;
        if n == 0 || !x.len().is_multiple_of(n) || out.len() != x.len() {
            return Err(CodecError::Batch { got: x.len(), n }.into());
        }
        let sets = x.len() / n;
        // Batches larger than one binding (or the dispatch grid) go in slices.
        let set_bytes = n as u64 * 12;
        let limits = self.device.limits();
        let by_binding = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size)
            / set_bytes;
        let widest = self
            .passes
            .iter()
            .flat_map(|p| (0..CHUNKS.len()).map(|v| p.groups(v)))
            .max()
            .unwrap_or(1);
        let by_grid = sets_per_dispatch(&self.device, widest);
        let slice = by_binding.min(by_grid).min(sets as u64) as usize;
        if slice == 0 {
            return Err(GpuError::TooLarge {
                what: "one light set",
                needed: set_bytes,
                limit: limits.max_storage_buffer_binding_size,
            });
        }
        let mut io = self
            .io
            .lock()
            .map_err(|_| GpuError::Readback("a previous product panicked".into()))?;
        let mut kernel = Some(0.0);
        let (mut walked, mut slices) = (0.0, 0);
        for (xs, outs) in x.chunks(slice * n).zip(out.chunks_mut(slice * n)) {
            let (spent, share) = self.run(&mut io, xs, outs)?;
            kernel = kernel.zip(spent).map(|(a, b)| a + b);
            if let Some(share) = share {
                walked += share;
                slices += 1;
            }
        }
        if let Ok(mut k) = self.kernel_seconds.lock() {
            *k = kernel;
        }
        if let Ok(mut s) = self.lit_share.lock() {
            *s = (slices > 0).then(|| walked / f64::from(slices));
        }
        Ok(())
    }

    /// One slice of a batch: the kernel time where it was measured, and the share of column
    /// groups the matrix-vector passes walked where one ran.
    fn run(
        &self,
        io: &mut Option<Io>,
        x: &[[f32; 3]],
        out: &mut [[f32; 3]],
    ) -> Result<(Option<f64>, Option<f64>), GpuError> {
        let sets = (x.len() / self.n as usize) as u32;
        if io.as_ref().is_none_or(|io| io.sets < sets) {
            *io = Some(self.io_for(sets)?);
        }
        let Some(io) = io.as_ref() else {
            return Err(GpuError::Readback("batch buffers missing".into()));
        };
        let bytes: &[u8] = bytemuck::cast_slice(x);
        self.queue.write_buffer(&io.x, 0, bytes);
        let variant = self.variant(sets);
        let gathers = self.passes.iter().any(|p| p.variants[variant].gathers);
        let lit = (self.gather && gathers)
            .then(|| lit_groups(x, self.n as usize, self.col_order.as_deref()))
            .flatten();
        if let Some(groups) = lit.as_ref().filter(|g| !g.is_empty()) {
            self.queue.write_buffer(&io.lit, 0, u32_bytes(groups));
        }
        let share = gathers.then(|| {
            let all = (self.n as usize).div_ceil(LIT_GROUP).max(1);
            lit.as_ref().map_or(1.0, |g| g.len() as f64 / all as f64)
        });
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        for (pass, tio) in self.passes.iter().zip(&io.tensor) {
            if let (Some(t), Some(tio)) = (self.tensor_for(pass, variant, sets), tio) {
                t.clear(&mut encoder, tio);
            }
        }
        {
            let mut cpass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: None,
                timestamp_writes: io.timer.as_ref().map(|t| wgpu::ComputePassTimestampWrites {
                    query_set: &t.queries,
                    beginning_of_pass_write_index: Some(0),
                    end_of_pass_write_index: Some(1),
                }),
            });
            let groups = &io.groups[variant];
            for (((pass, params), group), tio) in self
                .passes
                .iter()
                .zip(&io.params)
                .zip(groups)
                .zip(&io.tensor)
            {
                let kernel = &pass.variants[variant];
                let tensor = self.tensor_for(pass, variant, sets).zip(tio.as_ref());
                let ([gx, gy, gz], groups_x) = match tensor {
                    Some(_) => TensorKernel::dispatch_size(&self.device, pass.rows, sets),
                    None => grid(&self.device, pass.groups(variant), sets, kernel.chunk),
                };
                let p = Params {
                    n: self.n,
                    channels: self.channels,
                    sets,
                    groups_x,
                    nnz: pass.nnz,
                    row0: pass.row0,
                    rows: pass.rows,
                    tile: pass.tile,
                    lit: match &lit {
                        Some(groups) if kernel.gathers => groups.len() as u32,
                        _ => ALL_COLUMNS,
                    },
                    pad: [0; 3],
                    max: self.max,
                };
                self.queue.write_buffer(params, 0, bytemuck::bytes_of(&p));
                if let Some((t, tio)) = tensor {
                    t.dispatch(&mut cpass, tio, self.n, sets, [gx, gy, gz]);
                    continue;
                }
                cpass.set_pipeline(&kernel.pipeline);
                cpass.set_bind_group(0, group, &[]);
                // Dispatches in one pass are ordered: wgpu puts a barrier between the block
                // pass's writes to `out` and the sparse pass's read-modify-write.
                cpass.dispatch_workgroups(gx, gy, gz);
            }
        }
        let len = bytes.len() as u64;
        encoder.copy_buffer_to_buffer(&io.out, 0, &io.readback, 0, len);
        if let Some(t) = &io.timer {
            encoder.resolve_query_set(&t.queries, 0..2, &t.resolve, 0);
            encoder.copy_buffer_to_buffer(&t.resolve, 0, &t.readback, 0, 16);
        }
        self.queue.submit([encoder.finish()]);
        let slice = io.readback.slice(..len);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            // The receiver outlives the poll below; a send can only fail after it gave up.
            let _ = tx.send(r);
        });
        let timed = io.timer.as_ref().map(|t| {
            let (tx, rx) = std::sync::mpsc::channel();
            t.readback
                .slice(..)
                .map_async(wgpu::MapMode::Read, move |r| {
                    let _ = tx.send(r);
                });
            rx
        });
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        rx.recv()
            .map_err(|e| GpuError::Readback(e.to_string()))?
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        {
            let view = slice
                .get_mapped_range()
                .map_err(|e| GpuError::Readback(e.to_string()))?;
            bytemuck::cast_slice_mut::<[f32; 3], u8>(out).copy_from_slice(&view);
        }
        io.readback.unmap();
        let (Some(t), Some(rx)) = (&io.timer, timed) else {
            return Ok((None, share));
        };
        // A timing that did not come back costs the figure, not the product.
        if !matches!(rx.recv(), Ok(Ok(()))) {
            return Ok((None, share));
        }
        let ticks = {
            let Ok(view) = t.readback.slice(..).get_mapped_range() else {
                return Ok((None, share));
            };
            let stamps: &[u64] = bytemuck::cast_slice(&view);
            stamps[1].saturating_sub(stamps[0])
        };
        t.readback.unmap();
        let seconds = ticks as f64 * f64::from(self.queue.get_timestamp_period()) * 1e-9;
        Ok((Some(seconds), share))
    }

    fn io_for(&self, sets: u32) -> Result<Io, GpuError> {
        let bytes = u64::from(sets) * u64::from(self.n) * 12;
        check_binding(&self.device, "light batch", bytes)?;
        let buffer = |label, usage| {
            self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes,
                usage,
                mapped_at_creation: false,
            })
        };
        use wgpu::BufferUsages as U;
        let x = buffer("lights", U::STORAGE | U::COPY_DST);
        let out = buffer("irradiance", U::STORAGE | U::COPY_SRC);
        let readback = buffer("readback", U::MAP_READ | U::COPY_DST);
        let lit = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("lit column groups"),
            size: ((self.n as usize).div_ceil(LIT_GROUP).max(1) * 4) as u64,
            usage: U::STORAGE | U::COPY_DST,
            mapped_at_creation: false,
        });
        let params: Vec<wgpu::Buffer> = self
            .passes
            .iter()
            .map(|_| {
                self.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("params"),
                    size: std::mem::size_of::<Params>() as u64,
                    usage: U::UNIFORM | U::COPY_DST,
                    mapped_at_creation: false,
                })
            })
            .collect();
        let groups = (0..CHUNKS.len())
            .map(|variant| self.bind_groups(variant, &params, &x, &out, &lit))
            .collect();
        let tensor = self
            .passes
            .iter()
            .zip(&params)
            .map(|(pass, params)| match &pass.tensor {
                Some(Ok(t)) => Some(t.io(&self.device, sets, self.n, params, &x, &out)),
                _ => None,
            })
            .collect();
        let timer = self
            .device
            .features()
            .contains(wgpu::Features::TIMESTAMP_QUERY)
            .then(|| Timer {
                queries: self.device.create_query_set(&wgpu::QuerySetDescriptor {
                    label: Some("product time"),
                    ty: wgpu::QueryType::Timestamp,
                    count: 2,
                }),
                resolve: self.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("product time"),
                    size: 16,
                    usage: U::QUERY_RESOLVE | U::COPY_SRC,
                    mapped_at_creation: false,
                }),
                readback: self.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("product time readback"),
                    size: 16,
                    usage: U::MAP_READ | U::COPY_DST,
                    mapped_at_creation: false,
                }),
            });
        Ok(Io {
            sets,
            timer,
            x,
            out,
            lit,
            readback,
            params,
            groups,
            tensor,
        })
    }

    /// One bind group per pass for the pipelines of `variant`.
    fn bind_groups(
        &self,
        variant: usize,
        params: &[wgpu::Buffer],
        x: &wgpu::Buffer,
        out: &wgpu::Buffer,
        lit: &wgpu::Buffer,
    ) -> Vec<wgpu::BindGroup> {
        self.passes
            .iter()
            .zip(params)
            .map(|(pass, params)| {
                let mut entries = vec![
                    entry(0, params.as_entire_binding()),
                    entry(1, x.as_entire_binding()),
                    entry(2, out.as_entire_binding()),
                ];
                if pass.variants[variant].gathers {
                    entries.push(entry(6, lit.as_entire_binding()));
                }
                for (binding, bound) in &pass.bound {
                    entries.push(entry(
                        *binding,
                        match bound {
                            Bound::Buffer(b) => b.as_entire_binding(),
                            Bound::Texture(t) => wgpu::BindingResource::TextureView(t),
                        },
                    ));
                }
                self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: None,
                    layout: &pass.variants[variant].pipeline.get_bind_group_layout(0),
                    entries: &entries,
                })
            })
            .collect()
    }
}

fn entry(binding: u32, resource: wgpu::BindingResource<'_>) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry { binding, resource }
}
