// The viewer's text overlay: one premultiplied RGBA image (text rasterised on the CPU, see
// render/src/overlay.rs) drawn at a pixel position over the scene. `OverlayParams` is mirrored by
// render/src/overlay.rs's `OverlayParams`; a naga test checks the layouts agree.

struct OverlayParams {
    origin: vec2<f32>,
    size: vec2<f32>,
    target_size: vec2<f32>,
    pad: vec2<f32>,
}

@group(0) @binding(0) var<uniform> p: OverlayParams;
@group(0) @binding(1) var text: texture_2d<f32>;

@vertex
fn vs_overlay(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    // A triangle strip over the image's rectangle, in pixels, then to clip space (y down).
    let corner = vec2<f32>(f32(i & 1u), f32(i >> 1u));
    let px = p.origin + corner * p.size;
    return vec4<f32>(px.x / p.target_size.x * 2.0 - 1.0, 1.0 - px.y / p.target_size.y * 2.0, 0.0, 1.0);
}

@fragment
fn fs_overlay(@builtin(position) pos: vec4<f32>) -> @location(0) vec4<f32> {
    let texel = vec2<i32>(floor(pos.xy - p.origin));
    return textureLoad(text, texel, 0);
}
