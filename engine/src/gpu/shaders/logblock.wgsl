// Block part of the `bc1` / `bc4` codecs: the log-quantised image sampled with textureLoad, so
// the texture unit decodes the blocks. BC1: one layer, RGB = the three channels (a one-channel
// matrix repeats channel 0). BC4: one layer per channel, red only. `log8`: one R8 layer per
// channel, read as BC4 is (and decoded exactly, so it matches the CPU bit for bit in codes).
//
// Decoded unorm u maps to max * exp(25 * u - 25), the continuous inverse of the quantisation
// (u = q / 255 gives exactly the CPU table's value). Hardware interpolates BC palettes with its
// own rounding (Mesa truncates the expanded 8-bit endpoints, NVIDIA keeps extra bits), so u need
// not be the integer code the CPU decoder (bcdec's rounding) gives; the continuous map keeps such
// a texel within the distance of the two decodes, where rounding to a code would jump a whole
// code step (10%) whenever the two round differently. Measured on lavapipe (Mesa 22.3): it returns
// whole codes, one code off bcdec's in about 27% (BC1) and 38% (BC4) of the non-zero texels of a
// random transport matrix, so GPU and CPU products of the same blocks differ by about 1% (rel. L2). u = 0, and BC1's transparent black
// (alpha 0, the 3-colour-mode zero), is exactly 0: no light path.

override BC4: bool = false;

@group(0) @binding(3) var blocks: texture_2d_array<f32>;
@group(0) @binding(4) var<storage, read> row_perm: array<u32>;
@group(0) @binding(5) var<storage, read> col_perm: array<u32>;

fn dequantize(u: f32, top: f32) -> f32 {
    return select(top * exp(25.0 * u - 25.0), 0.0, u == 0.0);
}

// The decoded unorm u of storage row k, column l, per channel (0 where there is no light path).
// The image is cut into square tiles of side params.tile (one tile when it fits the device's
// texture side), row-major; tile t holds layers t * L .. t * L + L, L = 1 for BC1 and the channel
// count for BC4 and raw codes.
fn unit(k: u32, l: u32) -> vec3<f32> {
    var at = vec2<u32>(l, k);
    var tile = 0u;
    // Integer division by a run-time value is slow on every GPU: only a tiled image pays it
    // (the branch is uniform, the same for every thread of a dispatch).
    let side = params.tile;
    if side < params.n {
        let across = ((params.n + 3u) / 4u * 4u + side - 1u) / side;
        let ty = k / side;
        let tx = l / side;
        at = vec2<u32>(l - tx * side, k - ty * side);
        tile = ty * across + tx;
    }
    var u: vec3<f32>;
    if BC4 {
        let layer = tile * params.channels;
        let r = textureLoad(blocks, at, layer, 0).r;
        if params.channels == 1u {
            u = vec3<f32>(r);
        } else {
            u = vec3<f32>(
                r,
                textureLoad(blocks, at, layer + 1u, 0).r,
                textureLoad(blocks, at, layer + 2u, 0).r,
            );
        }
    } else {
        let t = textureLoad(blocks, at, tile, 0);
        if t.a == 0.0 {
            return vec3<f32>(0.0);
        }
        u = select(t.rgb, vec3<f32>(t.r), params.channels == 1u);
    }
    return u;
}

// The channel maxima the codes scale (a one-channel matrix repeats channel 0).
fn tops() -> vec3<f32> {
    return select(params.max.xyz, vec3<f32>(params.max.x), params.channels == 1u);
}

fn entry(k: u32, l: u32) -> vec3<f32> {
    let u = unit(k, l);
    let mx = tops();
    return vec3<f32>(dequantize(u.x, mx.x), dequantize(u.y, mx.y), dequantize(u.z, mx.z));
}

fn column(l: u32) -> u32 {
    return col_perm[l];
}

fn row(k: u32) -> u32 {
    return row_perm[k];
}
