// What the direct-light kernels share (`direct.wgsl`, `direct_surface.wgsl`): the prepared light
// and `bounce_core::direct::light_sample`, what one light delivers to one surface point before
// visibility. Prepended to each kernel's own file.

// `bounce_core::direct::PreparedLight`.
struct GpuLight {
    position: vec3<f32>,
    // 0 directional, 1 point, 2 spot.
    kind: u32,
    axis: vec3<f32>,
    inv_range: f32,
    radiant: vec3<f32>,
    angle_scale: f32,
    angle_offset: f32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
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
    if l.kind == 0u {
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
        if l.kind == 2u {
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
