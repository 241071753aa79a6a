// Prelude of every matvec kernel (prepended to the kernel's own file before compiling).
//
// A batch of light sets is `x[(s * n + j) * 3 + c]`: packed RGB, light set `s`, patch `j`, the
// same layout as the host's `[[f32; 3]]`, so uploads are a plain byte copy.
//
// Work split: a workgroup owns ROWS consecutive rows and one chunk of CHUNK light sets (see
// `work`); its threads stride over the columns, so every matrix value is loaded once per
// chunk and multiplied into all the chunk's light sets. A batch of b sets thus costs
// ceil(b / CHUNK) passes over the matrix. ROWS rows share each gathered light value; CHUNK is
// bounded by the ROWS * CHUNK RGB accumulators each thread keeps in registers.

struct Params {
    n: u32,
    channels: u32,
    // Light sets in the whole batch.
    sets: u32,
    // Workgroups along x of the dispatch: grids over many rows are 2-D (a dimension is capped at
    // 65535 workgroups), and this linearises them.
    groups_x: u32,
    // Sparse entries (sparse kernel only).
    nnz: u32,
    // First matrix row of this pass and how many it computes: a dense matrix larger than one
    // storage binding goes in row bands, one pass (and one buffer) each.
    row0: u32,
    rows: u32,
    // Side of one block-image tile (block kernels): an image wider than the device's texture
    // side goes in square tiles, each its own array layer (per channel for BC4 / raw codes).
    tile: u32,
    // Lit column groups the matrix-vector kernels walk (`lit_groups` in row_block.wgsl), or
    // ALL_COLUMNS: every column.
    lit: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
    // Per-channel maxima of the log quantisation (block kernels only).
    max: vec4<f32>,
}

const WG: u32 = 64u;
// `Params.lit` when the kernel walks every column (mirrors `kernel::ALL_COLUMNS`).
const ALL_COLUMNS: u32 = 0xffffffffu;
const ROWS: u32 = 4u;
// The host compiles one variant per entry of `kernel::CHUNKS`, replacing this line: a batch of one
// light set then keeps 4 accumulators a thread, not 32.
const CHUNK: u32 = 8u;
const SLOTS: u32 = ROWS * CHUNK;
// Accumulator slots reduced per round: bounded by workgroup memory (WG * LANES vec3s).
const LANES: u32 = 4u;

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read_write> out: array<f32>;

var<workgroup> red: array<vec3<f32>, 256>; // WG * LANES

fn group_index(wid: vec3<u32>) -> u32 {
    return wid.x + wid.y * params.groups_x;
}

// A workgroup's share of a pass: which group of rows (`ROWS` rows for the matvec kernels, one row
// for the sparse kernel) and the first light set of its chunk.
struct Work {
    group: u32,
    base: u32,
}

// The chunks of light sets over the same rows are neighbours in the dispatch (chunk fastest), so
// they run at about the same time and all but the first find the rows' matrix bytes in the L2
// cache: a batch of 64 sets reads the matrix from memory about once, not once per chunk.
fn work(wid: vec3<u32>) -> Work {
    let g = group_index(wid);
    let chunks = (params.sets + CHUNK - 1u) / CHUNK;
    return Work(g / chunks, (g % chunks) * CHUNK);
}

fn light(li: u32, j: u32) -> vec3<f32> {
    let at = (li * params.n + j) * 3u;
    return vec3<f32>(x[at], x[at + 1u], x[at + 2u]);
}

fn store(li: u32, i: u32, v: vec3<f32>) {
    let at = (li * params.n + i) * 3u;
    out[at] = v.x;
    out[at + 1u] = v.y;
    out[at + 2u] = v.z;
}

fn add(li: u32, i: u32, v: vec3<f32>) {
    let at = (li * params.n + i) * 3u;
    out[at] += v.x;
    out[at + 1u] += v.y;
    out[at + 2u] += v.z;
}

// Sums slot `slot` of every thread's accumulators into lane `lane` of `red`; call in uniform
// control flow. Results end in red[lane * WG] for lanes 0..LANES.
fn reduce_lanes(tid: u32) {
    workgroupBarrier();
    for (var stride = WG / 2u; stride > 0u; stride = stride / 2u) {
        if tid < stride {
            for (var q = 0u; q < LANES; q++) {
                red[q * WG + tid] += red[q * WG + tid + stride];
            }
        }
        workgroupBarrier();
    }
}
