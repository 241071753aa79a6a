// The near-field correction `ΔE = C · (ρ_e ⊙ E_q − ρ_j ⊙ Ē_j)`: the twin of
// `bounce_core::nearfield::NearField::correction_with` (read it and `bounce_core::nearfield` for
// the model). One thread per (light set, row) walks the row's CSR entries in order and sums as
// the CPU does, in f32: `sum += c * (ρ_e * E_q − ρ_j * Ē_j)`, with `ρ_e` the albedo where entry
// `e`'s rays landed. It reads what `gather_samples`
// (`direct_surface.wgsl`) wrote for the same slice of light sets: every row's mean and every
// sample's value, so it runs after the slice's last piece.

struct NearParams {
    // Rows (patches) in the scene: the stride of one light set's means and corrections.
    n: u32,
    // Light sets in this dispatch.
    sets: u32,
    // Sample points per row, both the matrix's columns per row and the values `gather_samples`
    // kept per row (the host runs this pass only when the two agree).
    per_row: u32,
    // Samples a row's mean is taken over: its first (those spread by area), as `gather`'s.
    averaged: u32,
}

const NEAR_WG: u32 = 64u;

// Eight storage buffers: the most a stage may bind on WebGPU's default limits, so the pass runs
// wherever the direct light does.
@group(0) @binding(0) var<uniform> params: NearParams;
// `NearField::row_ptr`, `cols`, `values`: row i's entries are row_ptr[i]..row_ptr[i + 1].
@group(0) @binding(1) var<storage, read> row_ptr: array<u32>;
@group(0) @binding(2) var<storage, read> cols: array<u32>;
@group(0) @binding(3) var<storage, read> values: array<f32>;
// Packed RGB albedo per row.
@group(0) @binding(4) var<storage, read> albedo: array<f32>;
// Packed RGB, light set s, row j at (s * n + j) * 3: `gather_samples`' means.
@group(0) @binding(5) var<storage, read> mean: array<f32>;
// Packed RGB, light set s, sample q (= j * per_row + k) at (s * n * per_row + q) * 3.
@group(0) @binding(6) var<storage, read> per_sample: array<f32>;
// Packed RGB, light set s, row i at (s * n + i) * 3.
@group(0) @binding(7) var<storage, read_write> delta: array<f32>;
// Packed RGB albedo per entry: where its rays landed (the host fills in the sample's, or its
// row's, for files that keep none).
@group(0) @binding(11) var<storage, read> landed_albedo: array<f32>;

fn albedo_of(j: u32) -> vec3<f32> {
    let o = j * 3u;
    return vec3<f32>(albedo[o], albedo[o + 1u], albedo[o + 2u]);
}

@compute @workgroup_size(NEAR_WG)
fn near_field(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let id = (wg.y * groups.x + wg.x) * NEAR_WG + lid;
    if id >= params.n * params.sets {
        return;
    }
    let sid = id / params.n;
    let i = id % params.n;
    let samples = sid * params.n * params.per_row;
    let means = sid * params.n;
    var sum = vec3<f32>(0.0);
    let end = row_ptr[i + 1u];
    for (var e = row_ptr[i]; e < end; e++) {
        let q = cols[e];
        let j = q / params.per_row;
        let so = (samples + q) * 3u;
        let mo = (means + j) * 3u;
        let eq = vec3<f32>(per_sample[so], per_sample[so + 1u], per_sample[so + 2u]);
        let ej = vec3<f32>(mean[mo], mean[mo + 1u], mean[mo + 2u]);
        let ae = vec3<f32>(landed_albedo[e * 3u], landed_albedo[e * 3u + 1u], landed_albedo[e * 3u + 2u]);
        let d = ae * eq - albedo_of(j) * ej;
        sum += values[e] * d;
    }
    let o = id * 3u;
    delta[o] = sum.x;
    delta[o + 1u] = sum.y;
    delta[o + 2u] = sum.z;
}

// The sky's part of the correction, run before `near_field` on the same slice: per (light set,
// row), each of the row's samples gets its sky irradiance added to its punctual value,
// `E_q += s_q`, and the row's mean gets the samples' mean, `Ē_j += s̄_j`, so `near_field`'s one
// pass corrects both. The twin of `NearField::sky_samples` and `NearField::correction_with`:
// `s_q = max(Σ_k c_qk L_k, 0)` per channel (in f32 here, f64 on the CPU), the mean summed in
// sample order and divided by the count. A set without a sky has zero coefficients and adds
// exactly zero.

// Per sample point q, its 9 coefficients at q * 9: `NearField::sky`.
@group(0) @binding(8) var<storage, read> sample_sky: array<f32>;
// Per light set of the dispatch, its 9 RGB radiance coefficients at set * 27 + k * 3 + channel.
@group(0) @binding(9) var<storage, read> skies: array<f32>;
// `per_sample` above, written: what `gather_samples` kept, laid out the same.
@group(0) @binding(10) var<storage, read_write> per_sample_sky: array<f32>;
// `mean` above, written (after the host's copy of the means was taken).
@group(0) @binding(12) var<storage, read_write> mean_sky: array<f32>;

fn sky_at(sid: u32, q: u32) -> vec3<f32> {
    var e = vec3<f32>(0.0);
    for (var k = 0u; k < 9u; k++) {
        let c = sample_sky[q * 9u + k];
        let o = sid * 27u + k * 3u;
        e += c * vec3<f32>(skies[o], skies[o + 1u], skies[o + 2u]);
    }
    // An SH sky may ring below zero; the largest f32 keeps a sum finite, as on the CPU.
    return min(max(e, vec3<f32>(0.0)), vec3<f32>(3.4028235e38));
}

@compute @workgroup_size(NEAR_WG)
fn sky_samples(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let id = (wg.y * groups.x + wg.x) * NEAR_WG + lid;
    if id >= params.n * params.sets {
        return;
    }
    let sid = id / params.n;
    let j = id % params.n;
    let first = j * params.per_row;
    var sum = vec3<f32>(0.0);
    for (var k = 0u; k < params.averaged; k++) {
        sum += sky_at(sid, first + k);
    }
    let mean = sum / f32(max(params.averaged, 1u));
    let samples = sid * params.n * params.per_row;
    for (var k = 0u; k < params.per_row; k++) {
        let q = first + k;
        let s = sky_at(sid, q);
        let o = (samples + q) * 3u;
        per_sample_sky[o] += s.x;
        per_sample_sky[o + 1u] += s.y;
        per_sample_sky[o + 2u] += s.z;
    }
    let mo = id * 3u;
    mean_sky[mo] += mean.x;
    mean_sky[mo + 1u] += mean.y;
    mean_sky[mo + 2u] += mean.z;
}
