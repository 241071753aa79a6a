//! What every kernel shares: the uniform [`Params`], the work split constants, the WGSL prelude
//! and the plumbing that turns a source into a pipeline and a row count into a dispatch grid.

use std::sync::Mutex;

use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

use super::GpuError;

/// Rows a workgroup owns in the matrix-vector kernels (mirrors `ROWS` in `common.wgsl`).
pub const ROWS: u32 = 4;
/// Light sets a workgroup of the matrix-vector kernels serves per pass over its rows, at most
/// (mirrors `CHUNK` in `common.wgsl`).
pub const CHUNK: u32 = 8;
/// Light sets and rows a workgroup of the tiled kernel serves (`CHUNK` and `TM` in
/// `tile_block.wgsl`): batches over [`CHUNK`] sets are matrix-matrix products, and that kernel
/// decodes each entry once for up to 64 of them.
pub const TILE_SETS: u32 = 64;
pub const TILE_ROWS: u32 = 64;

/// The chunk sizes the product kernels are compiled for: the matrix-vector kernel for 1, 4 and
/// [`CHUNK`], the tiled kernel for [`TILE_SETS`]. A thread keeps `ROWS · chunk` RGB sums in
/// registers whatever the batch holds, so one kernel for every batch would make a batch of one
/// light set pay 32 accumulators (and the occupancy they cost) to use 4. A batch of `b` sets
/// reads the matrix `ceil(b / chunk)` times.
pub const CHUNKS: [u32; 4] = [1, 4, CHUNK, TILE_SETS];

/// Which of [`CHUNKS`] serves a batch of `sets` light sets: the smallest that takes the batch in
/// one pass over the matrix, else the largest allowed. `BOUNCE_GPU_MAX_CHUNK` (1, 4, 8 or 64)
/// caps it, to measure the variants against each other on a device (8: no tiled kernel).
pub fn variant_for(sets: u32) -> usize {
    variant_within(sets, max_chunk())
}

/// [`variant_for`] with the chunks capped at `cap` (`CHUNK`: the matrix-vector kernel alone).
pub fn variant_within(sets: u32, cap: u32) -> usize {
    let allowed = CHUNKS.iter().filter(|&&c| c <= cap).count().max(1);
    CHUNKS[..allowed]
        .iter()
        .position(|&c| c >= sets)
        .unwrap_or(allowed - 1)
}

fn max_chunk() -> u32 {
    static MAX: std::sync::OnceLock<u32> = std::sync::OnceLock::new();
    *MAX.get_or_init(|| {
        std::env::var("BOUNCE_GPU_MAX_CHUNK")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(TILE_SETS)
    })
}

/// The uniform every kernel reads (`Params` in `common.wgsl`; a test checks the layouts agree).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct Params {
    pub n: u32,
    pub channels: u32,
    pub sets: u32,
    pub groups_x: u32,
    pub nnz: u32,
    /// First matrix row of this pass, and how many rows it computes (a dense matrix larger than
    /// one binding goes in row bands, one pass each).
    pub row0: u32,
    pub rows: u32,
    /// Side of one block-image tile (block kernels; an image wider than a texture goes in
    /// tiles, one array layer each).
    pub tile: u32,
    /// How many lit column groups the matrix-vector kernels walk (`lit_groups`, binding 6 of
    /// `row_block.wgsl`), or [`ALL_COLUMNS`].
    pub lit: u32,
    pub pad: [u32; 3],
    pub max: [f32; 4],
}

/// `Params::lit` for a pass that walks every column (mirrors `ALL_COLUMNS` in `common.wgsl`).
pub const ALL_COLUMNS: u32 = u32::MAX;

/// Columns in one lit group: the matrix-vector kernels skip the groups where every light set of
/// the batch is dark (mirrors `WG` in `common.wgsl`; a thread takes one column of each group).
pub const LIT_GROUP: usize = 64;

/// How large one piece of an uploaded matrix may be: bytes in one storage binding, texels on a
/// texture's side, layers in a texture array. [`Split::of`] reads them from the device; tests
/// force smaller ones to exercise the bands and tiles on a software adapter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Split {
    pub binding_bytes: u64,
    pub texture_side: u32,
    pub texture_layers: u32,
}

impl Split {
    /// The device's own limits (the context asks for the adapter's, not wgpu's defaults).
    pub fn of(device: &wgpu::Device) -> Split {
        let limits = device.limits();
        Split {
            binding_bytes: binding_limit(&limits),
            texture_side: limits.max_texture_dimension_2d,
            texture_layers: limits.max_texture_array_layers,
        }
    }

    /// These limits, each no larger than the device's.
    pub fn within(self, device: &wgpu::Device) -> Split {
        let own = Split::of(device);
        Split {
            binding_bytes: self.binding_bytes.min(own.binding_bytes),
            texture_side: self.texture_side.min(own.texture_side),
            texture_layers: self.texture_layers.min(own.texture_layers),
        }
    }
}

/// One binding's byte limit. A binding's range is also addressed in u32 words by the kernels
/// (byte offsets reach 4 GiB − 4 at most), so it never passes `u32::MAX`.
fn binding_limit(limits: &wgpu::Limits) -> u64 {
    limits
        .max_storage_buffer_binding_size
        .min(limits.max_buffer_size)
        .min(u64::from(u32::MAX) & !3)
}

const COMMON: &str = include_str!("shaders/common.wgsl");
const ROW_BLOCK: &str = include_str!("shaders/row_block.wgsl");
const TILE_BLOCK: &str = include_str!("shaders/tile_block.wgsl");
const DENSE: &str = include_str!("shaders/dense.wgsl");
const LOGBLOCK: &str = include_str!("shaders/logblock.wgsl");

/// The dense kernels' matrix-vector source (entry point `matvec`).
pub fn dense_source() -> String {
    [COMMON, ROW_BLOCK, DENSE].concat()
}

/// The block codecs' matrix-vector source (entry point `matvec`).
pub fn logblock_source() -> String {
    [COMMON, ROW_BLOCK, LOGBLOCK].concat()
}

/// The dense kernels' tiled source (entry point `matvec_tiled`, compiled with
/// `CHUNK` = [`TILE_SETS`]).
pub fn dense_tiled_source() -> String {
    with_chunk(&[COMMON, TILE_BLOCK, DENSE].concat(), TILE_SETS)
}

/// The block codecs' tiled source (entry point `matvec_tiled`).
pub fn logblock_tiled_source() -> String {
    with_chunk(&[COMMON, TILE_BLOCK, LOGBLOCK].concat(), TILE_SETS)
}

/// The block codecs' tensor-core source (entry points `light_top_of`, `light_pack` and
/// `matvec_tensor`, compiled with `CHUNK` = [`TILE_SETS`]); `enable` lines come first in WGSL.
pub fn tensor_source() -> String {
    with_chunk(
        &[
            "enable f16;\nenable wgpu_cooperative_matrix;\n",
            COMMON,
            include_str!("shaders/tensor_block.wgsl"),
            LOGBLOCK,
        ]
        .concat(),
        TILE_SETS,
    )
}

pub fn sparse_source() -> String {
    [COMMON, include_str!("shaders/sparse.wgsl")].concat()
}

const CHUNK_LINE: &str = "const CHUNK: u32 = 8u;";
const ROWS_LINE: &str = "const ROWS: u32 = 4u;";

/// A matvec source compiled for `rows` rows a workgroup.
fn with_rows(source: &str, rows: u32) -> String {
    debug_assert!(source.contains(ROWS_LINE), "the prelude declares ROWS");
    source.replace(ROWS_LINE, &format!("const ROWS: u32 = {rows}u;"))
}

/// Rows a workgroup of the matrix-vector kernel owns for `chunk` light sets: [`ROWS`], except
/// that `BOUNCE_GPU_ROWS1` (1, 2, 4 or 8) sets it for the one-set kernel, to measure how many
/// rows a matrix-vector product should keep in flight on a device (fewer rows a workgroup means
/// fewer distinct rows streaming at once).
fn rows_for(chunk: u32) -> u32 {
    static ROWS1: std::sync::OnceLock<u32> = std::sync::OnceLock::new();
    if chunk != 1 {
        return ROWS;
    }
    *ROWS1.get_or_init(|| {
        std::env::var("BOUNCE_GPU_ROWS1")
            .ok()
            .and_then(|v| v.parse().ok())
            .filter(|r| [1, 2, 4, 8].contains(r))
            .unwrap_or(ROWS)
    })
}

/// A matvec source compiled for `chunk` light sets a pass.
pub fn with_chunk(source: &str, chunk: u32) -> String {
    debug_assert!(source.contains(CHUNK_LINE), "the prelude declares CHUNK");
    source.replace(CHUNK_LINE, &format!("const CHUNK: u32 = {chunk}u;"))
}

/// One compiled product kernel: the light sets it serves a pass and the matrix rows a
/// workgroup of it owns.
#[derive(Clone)]
pub struct Variant {
    pub pipeline: wgpu::ComputePipeline,
    pub chunk: u32,
    pub rows_per_group: u32,
    /// Whether the kernel walks only the batch's lit column groups (binds `lit_groups`).
    pub gathers: bool,
}

/// Which product a pass runs: the dense or the block codecs' kernels (`dense.wgsl`,
/// `logblock.wgsl`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Body {
    Dense,
    Blocks,
}

/// One variant per entry of [`CHUNKS`] for a product kernel (the matrix-vector kernel, then the
/// tiled one), with the loops compiled as counted loops (see [`Loops::Counted`]).
pub fn matvec_variants(
    device: &wgpu::Device,
    label: &'static str,
    body: Body,
    constants: &[(&str, f64)],
) -> Result<Vec<Variant>, GpuError> {
    let (row, tiled) = match body {
        Body::Dense => (dense_source(), dense_tiled_source()),
        Body::Blocks => (logblock_source(), logblock_tiled_source()),
    };
    CHUNKS
        .iter()
        .map(|&chunk| {
            let (source, entry, rows_per_group) = if chunk == TILE_SETS {
                (tiled.clone(), "matvec_tiled", TILE_ROWS)
            } else {
                let rows = rows_for(chunk);
                (with_rows(&with_chunk(&row, chunk), rows), "matvec", rows)
            };
            Ok(Variant {
                pipeline: pipeline_with(device, label, &source, entry, constants, Loops::Counted)?,
                chunk,
                rows_per_group,
                gathers: chunk != TILE_SETS,
            })
        })
        .collect()
}

/// The sparse pass's variants, one per entry of [`CHUNKS`] so a batch picks the same index in
/// every pass: one row a workgroup, at most [`CHUNK`] sets a pass (the exactly kept entries are
/// a few per cent of the matrix, so a batch of 64 reads them 8 times).
pub fn sparse_variants(device: &wgpu::Device) -> Result<Vec<Variant>, GpuError> {
    let source = sparse_source();
    let mut compiled: Vec<Variant> = Vec::with_capacity(CHUNKS.len());
    for &c in &CHUNKS {
        let chunk = c.min(CHUNK);
        // The tiled kernel's index runs the sparse pass at CHUNK sets too: one pipeline serves
        // both.
        if let Some(same) = compiled.iter().find(|v| v.chunk == chunk) {
            compiled.push(same.clone());
            continue;
        }
        compiled.push(Variant {
            pipeline: pipeline_with(
                device,
                "sparse_add",
                &with_chunk(&source, chunk),
                "sparse_add",
                &[],
                Loops::Counted,
            )?,
            chunk,
            rows_per_group: 1,
            gathers: false,
        });
    }
    Ok(compiled)
}

/// Whether naga guards a kernel's loops against running forever.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Loops {
    /// wgpu's default: every loop carries a 64-bit iteration counter that breaks out at 2^64.
    /// Kept for kernels whose loops walk data (BVH stacks, voxel walks): a NaN ray must not hang
    /// the device.
    Bounded,
    /// No added counter, for kernels whose every loop steps a counter by a positive constant up
    /// to a bound read from `Params` or from the sparse part's row pointers (which decoding checks
    /// are non-decreasing and at most the entry count, so a counter cannot wrap): the matvec
    /// kernels and the bandwidth probe. The counter hides the trip count of the constant inner
    /// loops from the driver (on an H100 it cost 1.2–2× in kernel time, docs/h100).
    /// `BOUNCE_GPU_SHADER_CHECKS=full` puts the counter back (to rule it out when a kernel
    /// misbehaves, and to measure what it costs).
    Counted,
}

/// A pipeline with its layout derived from the shader, overrides set by name. A shader the
/// driver or naga rejects is an error here, not wgpu's default panic.
pub fn pipeline(
    device: &wgpu::Device,
    label: &'static str,
    source: &str,
    entry: &str,
    constants: &[(&str, f64)],
) -> Result<wgpu::ComputePipeline, GpuError> {
    pipeline_with(device, label, source, entry, constants, Loops::Bounded)
}

/// [`pipeline`] with the loop guard chosen (see [`Loops`]).
pub fn pipeline_with(
    device: &wgpu::Device,
    label: &'static str,
    source: &str,
    entry: &str,
    constants: &[(&str, f64)],
    loops: Loops,
) -> Result<wgpu::ComputePipeline, GpuError> {
    let full = std::env::var("BOUNCE_GPU_SHADER_CHECKS").is_ok_and(|v| v == "full");
    let checks = wgpu::ShaderRuntimeChecks {
        force_loop_bounding: loops == Loops::Bounded || full,
        // Bounds checks, division checks and the rest stay as wgpu has them.
        ..wgpu::ShaderRuntimeChecks::checked()
    };
    let (pipeline, error) = scoped(device, wgpu::ErrorFilter::Validation, || {
        let desc = wgpu::ShaderModuleDescriptor {
            label: Some(label),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        };
        // SAFETY: the one check this may leave out is the loop counter, and only for kernels
        // declared `Loops::Counted`, whose loops all end (see `Loops`); memory accesses stay
        // bounds-checked.
        let module = unsafe { device.create_shader_module_trusted(desc, checks) };
        device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(label),
            layout: None,
            module: &module,
            entry_point: Some(entry),
            compilation_options: wgpu::PipelineCompilationOptions {
                constants,
                ..Default::default()
            },
            cache: None,
        })
    });
    match error {
        None => Ok(pipeline),
        Some(e) => Err(GpuError::Shader {
            kernel: label,
            message: e.to_string(),
        }),
    }
}

/// Run `f` inside an error scope of `filter` and return what the scope caught. wgpu requires
/// scopes to pop in the order they were pushed, and uploads running on several threads at once
/// broke that here ("Mismatched pop_error_scope call" in the engine's tests): scopes are taken
/// one thread at a time, and a scope opened inside another (a pipeline compiled during an upload)
/// nests on the same thread without waiting on itself.
pub fn scoped<T>(
    device: &wgpu::Device,
    filter: wgpu::ErrorFilter,
    f: impl FnOnce() -> T,
) -> (T, Option<wgpu::Error>) {
    static SCOPES: Mutex<()> = Mutex::new(());
    thread_local! {
        static HELD: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
    }
    let outer = !HELD.get();
    let _one = outer.then(|| {
        SCOPES
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    });
    HELD.set(true);
    let scope = device.push_error_scope(filter);
    let out = f();
    let error = pollster::block_on(scope.pop());
    if outer {
        HELD.set(false);
    }
    (out, error)
}

/// A read-only storage buffer holding `bytes`, refused when over the binding limit. Padded to a
/// whole word (and to one word when empty: wgpu does not bind empty buffers).
pub fn storage(
    device: &wgpu::Device,
    label: &'static str,
    bytes: &[u8],
) -> Result<wgpu::Buffer, GpuError> {
    check_binding(device, label, bytes.len() as u64)?;
    let mut padded;
    let contents = if bytes.is_empty() || !bytes.len().is_multiple_of(4) {
        padded = bytes.to_vec();
        padded.resize(bytes.len().next_multiple_of(4).max(4), 0);
        &padded[..]
    } else {
        bytes
    };
    Ok(
        device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents,
            usage: wgpu::BufferUsages::STORAGE,
        }),
    )
}

pub fn check_binding(
    device: &wgpu::Device,
    what: &'static str,
    bytes: u64,
) -> Result<(), GpuError> {
    let limit = binding_limit(&device.limits());
    if bytes > limit {
        return Err(GpuError::TooLarge {
            what,
            needed: bytes,
            limit,
        });
    }
    Ok(())
}

/// A grid of `groups · ceil(sets / chunk)` workgroups (row groups times chunks of light sets,
/// the chunk varying fastest: `work` in `common.wgsl`) along x, folded into y past the
/// per-dimension limit. Returns the grid and the x extent the shader linearises with.
pub fn grid(device: &wgpu::Device, groups: u32, sets: u32, chunk: u32) -> ([u32; 3], u32) {
    let max = device.limits().max_compute_workgroups_per_dimension.max(1);
    let total = groups.saturating_mul(sets.div_ceil(chunk));
    let gx = total.clamp(1, max);
    let gy = total.div_ceil(gx).max(1);
    ([gx, gy, 1], gx)
}

/// The most light sets one dispatch of `groups` row groups can take: the grid holds at most
/// `max²` workgroups (and their linear index must fit u32), counted as if every chunk held one
/// set, whichever variant runs.
pub fn sets_per_dispatch(device: &wgpu::Device, groups: u32) -> u64 {
    let max = u64::from(device.limits().max_compute_workgroups_per_dimension.max(1));
    let workgroups = (max * max).min(u64::from(u32::MAX));
    workgroups / u64::from(groups.max(1))
}

pub fn u32_bytes(values: &[u32]) -> &[u8] {
    bytemuck::cast_slice(values)
}

/// Wait for the queue, then copy `count` u32 words out of `readback` (a `MAP_READ` buffer the
/// submitted work filled) and unmap it.
pub fn read_words(
    device: &wgpu::Device,
    readback: &wgpu::Buffer,
    count: usize,
) -> Result<Vec<u32>, GpuError> {
    let slice = readback.slice(..);
    let (tx, rx) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        // The receiver outlives the poll below; a send can only fail after it gave up.
        let _ = tx.send(r);
    });
    device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| GpuError::Readback(e.to_string()))?;
    rx.recv()
        .map_err(|e| GpuError::Readback(e.to_string()))?
        .map_err(|e| GpuError::Readback(e.to_string()))?;
    let words = {
        let view = slice
            .get_mapped_range()
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        bytemuck::cast_slice::<u8, u32>(&view)[..count].to_vec()
    };
    readback.unmap();
    Ok(words)
}

/// Wait for the queue, then copy `count` RGB f32 triples out of `readback` (a `MAP_READ` buffer
/// that the submitted work filled) and unmap it: the end of the direct-light kernels.
pub fn read_rgb(
    device: &wgpu::Device,
    readback: &wgpu::Buffer,
    count: usize,
) -> Result<Vec<[f32; 3]>, GpuError> {
    let words = read_words(device, readback, count * 3)?;
    Ok(words
        .chunks_exact(3)
        .map(|w| {
            [
                f32::from_bits(w[0]),
                f32::from_bits(w[1]),
                f32::from_bits(w[2]),
            ]
        })
        .collect())
}
