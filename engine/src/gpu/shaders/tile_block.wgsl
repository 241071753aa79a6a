// The tiled body for large batches (after common.wgsl, before the kernel's file, which defines
// entry / column / row as for row_block.wgsl). Compiled with CHUNK = 64.
//
// row_block.wgsl decodes a matrix entry once per CHUNK (at most 8) light sets, and its 4 rows
// share each gathered light value: a batch of 64 sets reads and decodes the matrix 8 times, and
// every workgroup gathers the whole light vector for 4 rows. That is the right shape for a
// matrix-vector product, bound by reading the matrix. A batch of many sets is a matrix-matrix
// product, (rows × n) · (n × sets) per channel, bound by arithmetic once each entry is decoded
// once: so here a workgroup computes a TM × CHUNK tile of the output like a GEMM. Each step
// decodes a TM × TK tile of the matrix and gathers a TK × CHUNK tile of light into workgroup
// memory, once, and every thread multiplies RM rows by RS sets of them from there
// (48 multiply-adds for each 6 vec4 loads). Each entry is decoded once a pass, each light value
// gathered once per TM rows (row_block: per 4).
//
// Loads stay inline in the loop: a version that loaded the next step ahead through a helper
// taking pointers to the thread's arrays ran 3–4× slower a pass on an H200 (those arrays, we
// suspect, went to local memory), with or without the look-ahead (docs/h200).
//
// Sums run over the columns in order, k = 0, 1, ..., n − 1, one sum per (row, set, channel): the
// result does not depend on which sets share the batch, but it is not row_block's order (which
// sums a row across 64 threads, then reduces), so a set's result here may differ from the same
// set's in a small batch by f32 rounding.

const TM: u32 = 64u;
const TK: u32 = 8u;
const TWG: u32 = 256u;
// A thread's share of the tile: RM rows × RS light sets, four of each so one vec4 carries them.
const RM: u32 = 4u;
const RS: u32 = 4u;
const ROW_GROUPS: u32 = TM / RM;
const SET_GROUPS: u32 = CHUNK / RS;

// Channel-planar tiles, four rows (or four sets) to a vec4, so a thread reads its four with one
// load: a_tile[(c * TK + k) * ROW_GROUPS + g][r] is channel c of the entry at row g * RM + r of
// the tile and column k of the step; b_tile likewise for set g * RS + r. 6 KiB each.
var<workgroup> a_tile: array<vec4<f32>, 384>; // 3 * TK * ROW_GROUPS
var<workgroup> b_tile: array<vec4<f32>, 384>; // 3 * TK * SET_GROUPS

fn tile_block(wid: vec3<u32>, tid: u32) {
    let n = params.n;
    let rows = params.rows;
    let w = work(wid);
    let row0 = w.group * TM;
    // The whole workgroup leaves together, so the barriers below stay in uniform control flow.
    if row0 >= rows {
        return;
    }
    let base = w.base;
    let sets = min(CHUNK, params.sets - base);
    let rg = tid / SET_GROUPS;
    let sg = tid % SET_GROUPS;
    // acc[c * RM + r]: channel c of row rg * RM + r, over the thread's RS sets.
    var acc: array<vec4<f32>, 12>;
    for (var k0 = 0u; k0 < n; k0 += TK) {
        // Neighbouring threads take neighbouring columns of one row: a warp's texels fall in
        // two 4 × 4 blocks, its dense entries in whole 32-byte sectors.
        for (var i = 0u; i < TM * TK / TWG; i++) {
            let e = tid + i * TWG;
            let r = e / TK;
            let k = e % TK;
            var v = vec3<f32>(0.0);
            if k0 + k < n {
                // Rows past the end repeat the last row; their sums are never stored.
                v = entry(min(row0 + r, rows - 1u), k0 + k);
            }
            let g = r / RM;
            let q = r % RM;
            a_tile[k * ROW_GROUPS + g][q] = v.x;
            a_tile[(TK + k) * ROW_GROUPS + g][q] = v.y;
            a_tile[(2u * TK + k) * ROW_GROUPS + g][q] = v.z;
        }
        for (var i = 0u; i < CHUNK * TK / TWG; i++) {
            let e = tid + i * TWG;
            let s = e / TK;
            let k = e % TK;
            var v = vec3<f32>(0.0);
            if k0 + k < n && s < sets {
                v = light(base + s, column(k0 + k));
            }
            let g = s / RS;
            let q = s % RS;
            b_tile[k * SET_GROUPS + g][q] = v.x;
            b_tile[(TK + k) * SET_GROUPS + g][q] = v.y;
            b_tile[(2u * TK + k) * SET_GROUPS + g][q] = v.z;
        }
        workgroupBarrier();
        for (var k = 0u; k < TK; k++) {
            for (var c = 0u; c < 3u; c++) {
                let a = a_tile[(c * TK + k) * ROW_GROUPS + rg];
                let b = b_tile[(c * TK + k) * SET_GROUPS + sg];
                acc[c * RM] += a.x * b;
                acc[c * RM + 1u] += a.y * b;
                acc[c * RM + 2u] += a.z * b;
                acc[c * RM + 3u] += a.w * b;
            }
        }
        workgroupBarrier();
    }
    // Constant indices only (see `pick` in row_block.wgsl): the loops unroll.
    for (var r = 0u; r < RM; r++) {
        let k = row0 + rg * RM + r;
        for (var q = 0u; q < RS; q++) {
            let s = sg * RS + q;
            if k < rows && s < sets {
                store(base + s, row(k), vec3<f32>(acc[r][q], acc[RM + r][q], acc[2u * RM + r][q]));
            }
        }
    }
}

@compute @workgroup_size(256)
fn matvec_tiled(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) tid: u32,
) {
    tile_block(wid, tid);
}
