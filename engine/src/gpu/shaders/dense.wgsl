// Dense batched matvec over `dense-f32` or `dense-f16`: one row band of the matrix per pass,
// `m[c * rows * n + (i - row0) * n + j]`, one or three channels (the stored payload is the whole
// matrix channel-major; the host cuts it into bands that each fit one binding). Both come in as u32 words so one kernel serves both: f32 bit-cast, f16 unpacked with
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
    let at = i * n + j;
    if params.channels == 1u {
        return vec3<f32>(value(at));
    }
    let plane = params.rows * n;
    return vec3<f32>(value(at), value(plane + at), value(2u * plane + at));
}

fn column(l: u32) -> u32 {
    return l;
}

fn row(k: u32) -> u32 {
    return params.row0 + k;
}
