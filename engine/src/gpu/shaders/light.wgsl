// The light model on the GPU, written once: prepended to the engine's direct-light kernels
// (`direct.wgsl`, `direct_surface.wgsl`) and to bounce-render's `shade.wgsl`, so the kernels that
// light patches and the renderer that lights pixels cannot drift apart. `light_sample` is the twin
// of `bounce_core::direct::light_sample`. The Rust side is `bounce_engine::gpu::GpuLight`
// (engine/src/gpu/light.rs); a naga test checks that the layouts agree.

// `GpuLight::kind`, from `bounce_core::direct::LightKind`.
const KIND_DIRECTIONAL: u32 = 0u;
const KIND_POINT: u32 = 1u;
const KIND_SPOT: u32 = 2u;

// `bounce_core::direct::PreparedLight`.
struct GpuLight {
    position: vec3<f32>,
    kind: u32,
    axis: vec3<f32>,
    inv_range: f32,
    radiant: vec3<f32>,
    angle_scale: f32,
    angle_offset: f32,
    // The renderer's first shadow view (an index into its `views`); the engine's kernels ignore
    // it. A field of its own rather than padding, so both read the same layout.
    first_view: u32,
    pad0: u32,
    pad1: u32,
}

// Stands for the CPU's infinity: WGSL has no infinite literal, and drivers may assume none occur.
const BIG: f32 = 3.4028235e38;

fn range_window(d: f32, inv_range: f32) -> f32 {
    let x = d * inv_range;
    let w = clamp(1.0 - x * x * x * x, 0.0, 1.0);
    return w * w;
}

fn spot_attenuation(cd: f32, scale: f32, offset: f32) -> f32 {
    let a = clamp(cd * scale + offset, 0.0, 1.0);
    return a * a;
}

struct Sample {
    lit: bool,
    dir: vec3<f32>,
    distance: f32,
    irradiance: vec3<f32>,
}

fn light_sample(l: GpuLight, p: vec3<f32>, n: vec3<f32>) -> Sample {
    var s: Sample;
    s.lit = false;
    var scale = 1.0;
    if l.kind == KIND_DIRECTIONAL {
        s.dir = -l.axis;
        s.distance = BIG;
    } else {
        let to = l.position - p;
        let d2 = dot(to, to);
        let d = sqrt(d2);
        if !(d > 0.0 && d < BIG) {
            return s;
        }
        s.dir = to / d;
        s.distance = d;
        scale = range_window(d, l.inv_range) / d2;
        if l.kind == KIND_SPOT {
            scale *= spot_attenuation(dot(l.axis, -s.dir), l.angle_scale, l.angle_offset);
        }
    }
    let c = dot(n, s.dir);
    if !(c > 0.0 && scale > 0.0) {
        return s;
    }
    s.lit = true;
    s.irradiance = l.radiant * (c * scale);
    return s;
}
