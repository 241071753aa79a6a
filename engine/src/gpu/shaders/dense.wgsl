// Dense batched matvec over `dense-f32` or `dense-f16`: one row band of the matrix per pass, rows
// interleaved by channel, `m[((i - row0) * channels + c) * n + j]` (the stored payload is the whole
// matrix channel-major; the host cuts it into bands that each fit one binding and interleaves
// them). Interleaved, the 4 rows × 3 channels a workgroup reads lie within 12 · n values of each
// other; channel-major, they were a third of the band apart (gigabytes at 32,768 rows). Both
// come in as u32 words so one kernel serves both: f32 bit-cast, f16 unpacked with
// unpack2x16float (no `shader-f16` feature needed, which lavapipe and some drivers lack).

override HALF: bool = false;

@group(0) @binding(3) var<storage, read> m: array<u32>;

fn value(at: u32) -> f32 {
    if HALF {
        let pair = unpack2x16float(m[at / 2u]);
        return select(pair.x, pair.y, (at & 1u) == 1u);
    }
    return bitcast<f32>(m[at]);
}

fn entry(i: u32, j: u32) -> vec3<f32> {
    let n = params.n;
    if params.channels == 1u {
        return vec3<f32>(value(i * n + j));
    }
    let at = i * 3u * n + j;
    return vec3<f32>(value(at), value(at + n), value(at + 2u * n));
}

fn column(l: u32) -> u32 {
    return l;
}

fn row(k: u32) -> u32 {
    return params.row0 + k;
}

@compute @workgroup_size(64)
fn dense_matvec(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) tid: u32,
) {
    row_block(wid, tid);
}
