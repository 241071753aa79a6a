// The block codecs' product for large batches on tensor cores (after common.wgsl, compiled with
// CHUNK = 64, before logblock.wgsl; the host prepends the `enable` lines). Three entry points run
// in order in one compute pass:
//   light_top      the largest light value of each set (one atomicMax a workgroup);
//   light_pack     the batch as f16, scaled per set, in the image's column order, K-major:
//                  xh[((chunk * 3 + c) * npad + l) * 64 + s] = x[set, col_perm[l], c] · scale(set);
//   matvec_tensor  a workgroup computes 64 rows × 64 sets like tile_block.wgsl, but the
//                  multiply-adds run as 16 × 16 × 16 cooperative-matrix products (f16 inputs, f32
//                  sums): tile_block's FP32 loop is bound by arithmetic (2·10¹¹ multiply-adds for
//                  32,768 rows × 64 sets × 3 channels), which tensor cores do an order faster.
//
// Why the scales: f16 holds 6·10⁻⁵ .. 65504 at full precision. A matrix entry is decoded as
// 2¹⁴ · exp(25u − 25) (≤ 16384; the smallest non-zero code, 2¹⁴ · e⁻²⁵ ≈ 2·10⁻⁷, is a subnormal,
// and such entries carry ~10⁻¹¹ of a row's weight), and the channel's top is applied to the f32
// sum instead. A light set is scaled by a power of two that puts its largest value in
// [2¹³, 2¹⁴), so a bright set cannot overflow and a dim one keeps its 11 bits; the power of two
// is undone exactly on the sum. A set's scale depends on that set alone, so its result does not
// depend on the sets beside it. The f16 rounding of both factors (2⁻¹¹ relative each) is the
// price: about 10⁻³ relative on a product, under the BC1 code step (10%) by two orders.

const TT: u32 = 64u;
// Matrix columns decoded a step (two 16-deep products).
const TK: u32 = 32u;
const TWG: u32 = 256u;

@group(0) @binding(6) var<storage, read_write> xh: array<f16>;
@group(0) @binding(7) var<storage, read_write> light_top: array<atomic<u32>>;

// Decoded entries of the step, per channel 64 rows × TK columns, row-major (f16, 12 KiB).
var<workgroup> a_tile: array<f16, 6144>; // 3 * TT * TK
// One channel of the workgroup's result, 64 rows × 64 sets, row-major (16 KiB).
var<workgroup> c_tile: array<f32, 4096>; // TT * TT
var<workgroup> top_red: array<u32, 256>; // TWG

fn padded_n() -> u32 {
    return (params.n + TK - 1u) / TK * TK;
}

// 2^(13 − e) for a set whose largest value is in [2^e, 2^(e+1)); 1 for a dark set.
fn set_scale(s: u32) -> f32 {
    let bits = atomicLoad(&light_top[s]);
    if bits == 0u {
        return 1.0;
    }
    let e = i32((bits >> 23u) & 0xffu) - 127;
    return ldexp(1.0, clamp(13 - e, -126, 126));
}

// Grid: x over the set's n · 3 values, 256 a workgroup; y over the sets of the batch. Light
// values are non-negative, so their bit patterns order as the values do.
@compute @workgroup_size(256)
fn light_top_of(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) tid: u32,
) {
    let s = wid.y;
    let i = wid.x * TWG + tid;
    var v = 0u;
    if i < params.n * 3u {
        v = bitcast<u32>(abs(x[s * params.n * 3u + i]));
    }
    top_red[tid] = v;
    workgroupBarrier();
    for (var stride = TWG / 2u; stride > 0u; stride = stride / 2u) {
        if tid < stride {
            top_red[tid] = max(top_red[tid], top_red[tid + stride]);
        }
        workgroupBarrier();
    }
    if tid == 0u {
        atomicMax(&light_top[s], top_red[0]);
    }
}

// Grid: x over padded columns × 64 sets of a chunk, 256 a workgroup (sets fastest, so the
// writes are whole lines); y over the chunks. Sets past the batch and columns past n are zeros.
@compute @workgroup_size(256)
fn light_pack(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) tid: u32,
) {
    let npad = padded_n();
    let chunk = wid.y;
    let e = wid.x * TWG + tid;
    let l = e / TT;
    let q = e % TT;
    if l >= npad {
        return;
    }
    let s = chunk * TT + q;
    var v = vec3<f32>(0.0);
    if s < params.sets && l < params.n {
        v = light(s, column(l)) * set_scale(s);
    }
    let at = (chunk * 3u * npad + l) * TT + q;
    xh[at] = f16(v.x);
    xh[at + npad * TT] = f16(v.y);
    xh[at + 2u * npad * TT] = f16(v.z);
}

@compute @workgroup_size(256)
fn matvec_tensor(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) tid: u32,
    @builtin(subgroup_id) sg: u32,
) {
    let n = params.n;
    let rows = params.rows;
    let w = work(wid);
    // A grid folded into 2-D has workgroups past the last tile. They compute tile 0 and store
    // nothing, rather than return: naga cannot prove a return on the workgroup id uniform, and
    // cooperative operations after a possibly non-uniform return do not validate.
    let live = w.group * TT < rows && w.base < params.sets;
    let row0 = select(0u, w.group * TT, live);
    let base = select(0u, w.base, live);
    let chunk = base / TT;
    let sets = select(0u, min(TT, params.sets - base), live);
    let npad = padded_n();
    // Eight subgroups of 32 (the host runs this kernel only where subgroups are 32 wide): each
    // owns 16 rows (rb) and two 16-set blocks (sb, sb + 1) of all three channels, six
    // accumulators.
    let rb = sg / 2u;
    let sb = (sg % 2u) * 2u;
    var c00 = coop_mat16x16<f32, C>();
    var c01 = coop_mat16x16<f32, C>();
    var c10 = coop_mat16x16<f32, C>();
    var c11 = coop_mat16x16<f32, C>();
    var c20 = coop_mat16x16<f32, C>();
    var c21 = coop_mat16x16<f32, C>();
    // Strides and offsets as named values: naga's SPIR-V writer wants each operand of a
    // cooperative load as an expression of its own.
    let a_stride = TK;
    let x_stride = TT;
    let plane = TT * TK;
    let x_plane = npad * TT;
    for (var k0 = 0u; k0 < npad; k0 += TK) {
        // Neighbouring threads decode neighbouring columns of one row (as tile_block does).
        for (var i = 0u; i < TT * TK / TWG; i++) {
            let e = tid + i * TWG;
            let r = e / TK;
            let k = e % TK;
            var v = vec3<f32>(0.0);
            if k0 + k < n {
                // Rows past the end repeat the last row; their sums are never stored.
                let u = unit(min(row0 + r, rows - 1u), k0 + k);
                // 2^14 · exp(25u − 25) = exp2(14 + (25u − 25) · log2 e).
                v = select(exp2(14.0 + (25.0 * u - 25.0) * 1.442695), vec3<f32>(0.0), u == vec3<f32>(0.0));
            }
            a_tile[e] = f16(v.x);
            a_tile[plane + e] = f16(v.y);
            a_tile[2u * plane + e] = f16(v.z);
        }
        workgroupBarrier();
        for (var kk = 0u; kk < TK; kk += 16u) {
            let ao = rb * 16u * TK + kk;
            let xo = (chunk * 3u * npad + k0 + kk) * TT + sb * 16u;
            let xo1 = xo + 16u;
            let a0 = coopLoadT<coop_mat16x16<f16, A>>(&a_tile[ao], a_stride);
            let b00 = coopLoadT<coop_mat16x16<f16, B>>(&xh[xo], x_stride);
            let b01 = coopLoadT<coop_mat16x16<f16, B>>(&xh[xo1], x_stride);
            c00 = coopMultiplyAdd(a0, b00, c00);
            c01 = coopMultiplyAdd(a0, b01, c01);
            let ao1 = ao + plane;
            let xo10 = xo + x_plane;
            let xo11 = xo1 + x_plane;
            let a1 = coopLoadT<coop_mat16x16<f16, A>>(&a_tile[ao1], a_stride);
            let b10 = coopLoadT<coop_mat16x16<f16, B>>(&xh[xo10], x_stride);
            let b11 = coopLoadT<coop_mat16x16<f16, B>>(&xh[xo11], x_stride);
            c10 = coopMultiplyAdd(a1, b10, c10);
            c11 = coopMultiplyAdd(a1, b11, c11);
            let ao2 = ao1 + plane;
            let xo20 = xo10 + x_plane;
            let xo21 = xo11 + x_plane;
            let a2 = coopLoadT<coop_mat16x16<f16, A>>(&a_tile[ao2], a_stride);
            let b20 = coopLoadT<coop_mat16x16<f16, B>>(&xh[xo20], x_stride);
            let b21 = coopLoadT<coop_mat16x16<f16, B>>(&xh[xo21], x_stride);
            c20 = coopMultiplyAdd(a2, b20, c20);
            c21 = coopMultiplyAdd(a2, b21, c21);
        }
        workgroupBarrier();
    }
    // Each channel through workgroup memory: the output is set-major RGB, scattered by the row
    // order, which no cooperative store can write directly.
    let top = tops() * (1.0 / 16384.0);
    let co = rb * 16u * TT + sb * 16u;
    let co1 = co + 16u;
    let c_stride = TT;
    for (var c = 0u; c < 3u; c++) {
        if c == 0u {
            coopStoreT(c00, &c_tile[co], c_stride);
            coopStoreT(c01, &c_tile[co1], c_stride);
        } else if c == 1u {
            coopStoreT(c10, &c_tile[co], c_stride);
            coopStoreT(c11, &c_tile[co1], c_stride);
        } else {
            coopStoreT(c20, &c_tile[co], c_stride);
            coopStoreT(c21, &c_tile[co1], c_stride);
        }
        workgroupBarrier();
        for (var i = 0u; i < TT * TT / TWG; i++) {
            let e = tid + i * TWG;
            let r = e / TT;
            let q = e % TT;
            let k = row0 + r;
            if k < rows && q < sets {
                let s = base + q;
                out[(s * n + row(k)) * 3u + c] = c_tile[e] * top[c] / set_scale(s);
            }
        }
        workgroupBarrier();
    }
}
