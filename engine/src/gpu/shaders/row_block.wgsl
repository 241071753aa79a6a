// The body the dense and block kernels share (after common.wgsl, before the kernel's file).

// The shared body of the row-block kernels. The kernel file defines
//   entry(k, l) -> vec3<f32>  matrix value at storage row k, storage column l (per colour),
//   column(l) -> u32          the patch whose light storage column l multiplies,
//   row(k) -> u32             the patch storage row k lights.
// Storage rows and columns are matrix rows and columns for dense kernels (rows counted from
// the pass's band, params.row0), image rows and columns for block kernels. A pass computes
// params.rows storage rows over all params.n columns.
// acc[k] for a run-time k, reading acc only at constant indices. Indexing a thread's array with a
// run-time value makes the driver keep the whole array in local memory, the hot loop's sums too
// (an H100 ran the 8-set kernel 7 times slower a pass than the 1-set one); this loop unrolls, so
// the array stays in registers, for SLOTS selects once a round.
fn pick(acc: array<vec3<f32>, SLOTS>, k: u32) -> vec3<f32> {
    var v = vec3<f32>(0.0);
    for (var s = 0u; s < SLOTS; s++) {
        v = select(v, acc[s], s == k);
    }
    return v;
}

// The groups of WG consecutive storage columns where some light set of the batch is lit, in
// ascending order (the host's `lit_groups`). A dark column adds exactly +0 to every sum, and a
// thread keeps the columns l ≡ tid (mod WG) in the same order whether dark groups are walked or
// skipped, so skipping them changes no bit of the result, whatever else is in the batch.
@group(0) @binding(6) var<storage, read> lit_groups: array<u32>;

fn row_block(wid: vec3<u32>, tid: u32) {
    let n = params.n;
    let rows = params.rows;
    let w = work(wid);
    let row0 = w.group * ROWS;
    // Whole workgroup leaves together, so the barriers below stay in uniform control flow.
    if row0 >= rows {
        return;
    }
    let base = w.base;
    let sets = min(CHUNK, params.sets - base);
    var acc: array<vec3<f32>, SLOTS>;
    let gather = params.lit != ALL_COLUMNS;
    let steps = select((n + WG - 1u) / WG, params.lit, gather);
    for (var q = 0u; q < steps; q++) {
        var g = q;
        if gather {
            g = lit_groups[q];
        }
        let l = g * WG + tid;
        if l >= n {
            continue;
        }
        let j = column(l);
        var xs: array<vec3<f32>, CHUNK>;
        for (var s = 0u; s < CHUNK; s++) {
            if s < sets {
                xs[s] = light(base + s, j);
            }
        }
        for (var r = 0u; r < ROWS; r++) {
            // Rows past the end repeat the last row; their sums are never stored.
            let m = entry(min(row0 + r, rows - 1u), l);
            for (var s = 0u; s < CHUNK; s++) {
                acc[r * CHUNK + s] += m * xs[s];
            }
        }
    }
    for (var round = 0u; round < SLOTS; round += LANES) {
        // Lanes of a round share a row and cover sets round % CHUNK ..; skip rounds of absent
        // sets (batch 1 reduces 4 slots, not 32).
        if round % CHUNK >= sets {
            continue;
        }
        for (var q = 0u; q < LANES; q++) {
            red[q * WG + tid] = pick(acc, round + q);
        }
        reduce_lanes(tid);
        if tid < LANES {
            let slot = round + tid;
            let k = row0 + slot / CHUNK;
            let s = slot % CHUNK;
            // Fewer slots than lanes (one row, one set) leave lanes past SLOTS unused.
            if slot < SLOTS && k < rows && s < sets {
                store(base + s, row(k), red[tid * WG]);
            }
        }
        workgroupBarrier();
    }
}

@compute @workgroup_size(64)
fn matvec(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) tid: u32,
) {
    row_block(wid, tid);
}
