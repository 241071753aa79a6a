// Sparse part of the `bc1` / `bc4` codecs, added onto the block product: CSR in matrix order,
// values channel-major (`values[c * nnz + e]`). A part larger than one binding goes in row bands,
// one pass each: rows params.row0 .. + params.rows, with the band's own row pointers (from 0) and
// entry count (params.nnz). A workgroup owns one row and one chunk of light
// sets; its threads stride over the row's entries, each loaded once per chunk.

@group(0) @binding(3) var<storage, read> row_ptr: array<u32>;
@group(0) @binding(4) var<storage, read> col_idx: array<u32>;
@group(0) @binding(5) var<storage, read> values: array<f32>;

const PADDED: u32 = max(CHUNK, LANES);

// acc[k] read at constant indices only (see `pick` in row_block.wgsl: a run-time index moves the
// array to local memory).
fn pick_padded(acc: array<vec3<f32>, PADDED>, k: u32) -> vec3<f32> {
    var v = vec3<f32>(0.0);
    for (var s = 0u; s < PADDED; s++) {
        v = select(v, acc[s], s == k);
    }
    return v;
}

@compute @workgroup_size(64)
fn sparse_add(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) tid: u32,
) {
    let w = work(wid);
    let i = w.group;
    if i >= params.rows {
        return;
    }
    let base = w.base;
    let sets = min(CHUNK, params.sets - base);
    let nnz = params.nnz;
    // At least LANES slots, so a round of the reduction never reads past them (CHUNK may be 1);
    // slots past `sets` stay zero and are never stored.
    var acc: array<vec3<f32>, PADDED>;
    for (var e = row_ptr[i] + tid; e < row_ptr[i + 1u]; e += WG) {
        let j = col_idx[e];
        var v = vec3<f32>(values[e]);
        if params.channels == 3u {
            v = vec3<f32>(values[e], values[nnz + e], values[2u * nnz + e]);
        }
        for (var s = 0u; s < CHUNK; s++) {
            if s < sets {
                acc[s] += v * light(base + s, j);
            }
        }
    }
    for (var round = 0u; round < CHUNK; round += LANES) {
        if round >= sets {
            continue;
        }
        for (var q = 0u; q < LANES; q++) {
            red[q * WG + tid] = pick_padded(acc, round + q);
        }
        reduce_lanes(tid);
        if tid < LANES && round + tid < sets {
            add(base + round + tid, params.row0 + i, red[tid * WG]);
        }
        workgroupBarrier();
    }
}
