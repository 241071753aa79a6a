// The renderer's one shading module: direct light with shadow maps, indirect light from the
// six-direction irradiance volume (client/src/volume.rs's convention; `sample_volume` is the twin
// of `Volume::sample`), and the tonemap (or linear radiance, for a float target). The light model
// (`GpuLight`, `KIND_*`, `light_sample`) is the engine's `light.wgsl`
// (engine/src/gpu/shaders/light.wgsl), prepended to this file (`renderer::shade_source`), so a
// pixel is lit with the same code as the engine's patches. The Rust mirrors of `Globals` and
// `Object` live in render/src/gpu_types.rs; a naga test checks that the layouts agree.
//
// The probe-lit test object (render/src/object.rs) is drawn by the same entry points: a unit
// sphere's vertices as instance 1, placed by `object`, lit by its ambient cube instead of the
// volume.

const MIN_COVERAGE: f32 = 0.00390625; // 1/256, client::volume::MIN_COVERAGE
const PI: f32 = 3.14159265358979;
const WRAP_REPEAT_U: u32 = 1u;
const WRAP_REPEAT_V: u32 = 2u;
const FLAG_LINEAR: u32 = 1u;
const FLAG_NO_EMISSION: u32 = 2u;

struct Globals {
    view_proj: mat4x4<f32>,
    eye: vec3<f32>,
    exposure: f32,
    volume_origin: vec3<f32>,
    voxel_size: f32,
    volume_dims: vec3<f32>,
    light_count: u32,
    indirect: u32,
    normal_offset: f32,
    // FLAG_LINEAR | FLAG_NO_EMISSION (render/src/gpu_types.rs).
    flags: u32,
    pad1: u32,
}

// The probe-lit sphere: centre, radius, albedo, and the ambient cube blended from the probes
// (+X, −X, +Y, −Y, +Z, −Z).
struct Object {
    centre: vec3<f32>,
    radius: f32,
    albedo: vec3<f32>,
    pad: u32,
    cube: array<vec4<f32>, 6>,
}

@group(0) @binding(0) var<uniform> g: Globals;
@group(0) @binding(5) var<uniform> object: Object;
@group(0) @binding(1) var<storage, read> lights: array<GpuLight>;
@group(0) @binding(2) var<storage, read> views: array<mat4x4<f32>>;
@group(0) @binding(3) var shadow_maps: texture_depth_2d_array;
@group(0) @binding(4) var shadow_sampler: sampler_comparison;
@group(0) @binding(6) var vol_px: texture_3d<f32>;
@group(0) @binding(7) var vol_nx: texture_3d<f32>;
@group(0) @binding(8) var vol_py: texture_3d<f32>;
@group(0) @binding(9) var vol_ny: texture_3d<f32>;
@group(0) @binding(10) var vol_pz: texture_3d<f32>;
@group(0) @binding(11) var vol_nz: texture_3d<f32>;
// Base-colour maps, one layer a texture, layer 0 white (render/src/mesh.rs).
@group(0) @binding(12) var albedo_maps: texture_2d_array<f32>;
@group(0) @binding(13) var albedo_sampler: sampler;
// Per voxel, bit f set when a thin wall separates it from its neighbour in direction f.
@group(0) @binding(14) var vol_separators: texture_3d<u32>;

// One texel of a grid: rgb and coverage.
fn volume_texel(face: u32, t: vec3<i32>) -> vec4<f32> {
    switch face {
        case 0u: { return textureLoad(vol_px, t, 0); }
        case 1u: { return textureLoad(vol_nx, t, 0); }
        case 2u: { return textureLoad(vol_py, t, 0); }
        case 3u: { return textureLoad(vol_ny, t, 0); }
        case 4u: { return textureLoad(vol_pz, t, 0); }
        default: { return textureLoad(vol_nz, t, 0); }
    }
}

// The face a normal faces most: bounce_core::voxel::dominant_face (ties to X, then Y).
fn dominant_face(n: vec3<f32>) -> u32 {
    let a = abs(n);
    if a.x >= a.y && a.x >= a.z {
        return select(1u, 0u, n.x >= 0.0);
    }
    if a.y >= a.z {
        return select(3u, 2u, n.y >= 0.0);
    }
    return select(5u, 4u, n.z >= 0.0);
}

// Indirect irradiance at `p` on a surface whose seen side has normal `n` (Volume::sample): the
// grid of n's dominant face, filtered trilinearly by hand (texel centres at voxel centres, clamp
// to edge) over the texels that are not across a separator from p's own voxel, divided by
// their coverage.
fn sample_volume(p: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    if !(dot(n, n) > 0.0) {
        return vec3<f32>(0.0);
    }
    let face = dominant_face(n);
    let u = (p - g.volume_origin) / g.voxel_size - 0.5;
    let max_t = vec3<i32>(g.volume_dims) - 1;
    let fl = floor(u);
    let lo = vec3<i32>(clamp(fl, vec3<f32>(-1.0), vec3<f32>(max_t) + 1.0));
    let frac = clamp(u - fl, vec3<f32>(0.0), vec3<f32>(1.0));
    // The own voxel: the corner nearest p.
    let own = vec3<i32>(frac >= vec3<f32>(0.5));
    let separated = textureLoad(vol_separators, clamp(lo + own, vec3<i32>(0), max_t), 0).r;
    var acc = vec4<f32>(0.0);
    for (var corner = 0u; corner < 8u; corner++) {
        let step = vec3<i32>(vec3<u32>(corner & 1u, (corner >> 1u) & 1u, (corner >> 2u) & 1u));
        var blocked = false;
        for (var a = 0u; a < 3u; a++) {
            if step[a] != own[a] {
                // Towards +axis (face code 2a) or −axis (2a + 1).
                let towards = 2u * a + select(1u, 0u, step[a] > own[a]);
                if (separated & (1u << towards)) != 0u {
                    blocked = true;
                }
            }
        }
        if blocked {
            continue;
        }
        let w3 = select(vec3<f32>(1.0) - frac, frac, step == vec3<i32>(1));
        let w = w3.x * w3.y * w3.z;
        if w == 0.0 {
            continue;
        }
        acc += w * volume_texel(face, clamp(lo + step, vec3<i32>(0), max_t));
    }
    if acc.w >= MIN_COVERAGE {
        return acc.rgb / acc.w;
    }
    return vec3<f32>(0.0);
}

// The ambient cube's irradiance for unit normal `n` (object::cube_irradiance): each axis's
// side by the sign of n's component, weighted by the component squared.
fn cube_irradiance(n: vec3<f32>) -> vec3<f32> {
    let n2 = n * n;
    return n2.x * object.cube[select(0u, 1u, n.x < 0.0)].rgb
        + n2.y * object.cube[select(2u, 3u, n.y < 0.0)].rgb
        + n2.z * object.cube[select(4u, 5u, n.z < 0.0)].rgb;
}

// 1 where the light reaches `p` according to its shadow map, 0 where something is in front;
// outside every map's frustum, lit.
fn shadow(light: GpuLight, p: vec3<f32>, n: vec3<f32>) -> f32 {
    var view = light.first_view;
    if light.kind == KIND_POINT {
        // The six faces are +X, −X, +Y, −Y, +Z, −Z; each covers where its axis dominates.
        let d = p - light.position;
        let a = abs(d);
        if a.x >= a.y && a.x >= a.z {
            view += select(1u, 0u, d.x >= 0.0);
        } else if a.y >= a.z {
            view += select(3u, 2u, d.y >= 0.0);
        } else {
            view += select(5u, 4u, d.z >= 0.0);
        }
    }
    // Offsetting along the normal keeps a surface from shadowing itself (acne).
    let clip = views[view] * vec4<f32>(p + n * g.normal_offset, 1.0);
    if clip.w <= 0.0 {
        return 1.0;
    }
    let ndc = clip.xyz / clip.w;
    let uv = vec2<f32>(ndc.x * 0.5 + 0.5, 0.5 - ndc.y * 0.5);
    if any(uv < vec2<f32>(0.0)) || any(uv > vec2<f32>(1.0)) || ndc.z > 1.0 || ndc.z < 0.0 {
        return 1.0;
    }
    return textureSampleCompareLevel(shadow_maps, shadow_sampler, uv, view, ndc.z);
}

struct VertexIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) albedo: vec3<f32>,
    @location(3) emission: vec3<f32>,
    @location(4) uv: vec2<f32>,
    @location(5) layer: u32,
    @location(6) wrap: u32,
}

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) albedo: vec3<f32>,
    @location(3) emission: vec3<f32>,
    @location(4) uv: vec2<f32>,
    @location(5) @interpolate(flat) layer: u32,
    @location(6) @interpolate(flat) wrap: u32,
    // 1 for the probe-lit sphere.
    @location(7) @interpolate(flat) object: u32,
}

@vertex
fn vs_main(v: VertexIn, @builtin(instance_index) instance: u32) -> VertexOut {
    var out: VertexOut;
    out.world = v.position;
    out.normal = v.normal;
    out.albedo = v.albedo;
    out.emission = v.emission;
    out.uv = v.uv;
    out.layer = v.layer;
    out.wrap = v.wrap;
    out.object = 0u;
    if instance == 1u {
        // The unit sphere's position is its normal; the uv and layer stay 0 (white).
        out.world = object.centre + object.radius * v.position;
        out.normal = v.position;
        out.albedo = object.albedo;
        out.emission = vec3<f32>(0.0);
        out.object = 1u;
    }
    out.clip = g.view_proj * vec4<f32>(out.world, 1.0);
    return out;
}

@fragment
fn fs_main(frag: VertexOut, @builtin(front_facing) front: bool) -> @location(0) vec4<f32> {
    // The side the camera sees is the side that is lit and sampled: walls whose winding faces
    // away from the viewer still shade as seen.
    var n = normalize(frag.normal);
    if !front && frag.object == 0u {
        n = -n;
    }
    // The volume is read with the triangle's own normal on the seen side: the side whose patch
    // (by the direction it faces most) holds this surface's light; an interpolated shading
    // normal can face another direction most near 45°.
    var ng = cross(dpdx(frag.world), dpdy(frag.world));
    if !(dot(ng, ng) > 0.0) {
        ng = n;
    }
    if dot(ng, g.eye - frag.world) < 0.0 {
        ng = -ng;
    }
    var e = vec3<f32>(0.0);
    for (var i = 0u; i < g.light_count; i++) {
        let light = lights[i];
        let s = light_sample(light, frag.world, n);
        if s.lit {
            e += s.irradiance * shadow(light, frag.world, n);
        }
    }
    if g.indirect != 0u {
        if frag.object != 0u {
            e += cube_irradiance(n);
        } else {
            e += sample_volume(frag.world, ng);
        }
    }
    // The map is sRGB-encoded, so the sample is linear; the white layer leaves the tint.
    // The array's sampler repeats; a layer that clamps to its edge keeps its coordinates half a
    // texel inside, so bilinear filtering does not blend in the opposite edge.
    let half_texel = 0.5 / vec2<f32>(textureDimensions(albedo_maps));
    let repeat = vec2<bool>((frag.wrap & WRAP_REPEAT_U) != 0u, (frag.wrap & WRAP_REPEAT_V) != 0u);
    let uv = select(clamp(frag.uv, half_texel, vec2<f32>(1.0) - half_texel), frag.uv, repeat);
    let albedo = frag.albedo * textureSample(albedo_maps, albedo_sampler, uv, frag.layer).rgb;
    // Radiance of a diffuse surface: albedo / π · E, plus emitted exitance / π.
    var emission = frag.emission;
    if (g.flags & FLAG_NO_EMISSION) != 0u {
        emission = vec3<f32>(0.0);
    }
    let radiance = (albedo * e + emission) / PI;
    // A float target takes the radiance itself.
    if (g.flags & FLAG_LINEAR) != 0u {
        return vec4<f32>(radiance, 1.0);
    }
    // Tonemap: exposure, then Reinhard per channel; the sRGB target encodes the result.
    let x = radiance * g.exposure;
    return vec4<f32>(x / (vec3<f32>(1.0) + x), 1.0);
}

@vertex
fn vs_shadow(@location(0) position: vec3<f32>, @builtin(instance_index) view: u32) -> @builtin(position) vec4<f32> {
    // The view (shadow-map layer) rides in the draw's first instance.
    return views[view] * vec4<f32>(position, 1.0);
}

// The test probe: `Volume::sample`'s inputs in, the shader's answer out.
@group(1) @binding(0) var<storage, read> probe_points: array<vec4<f32>>;
@group(1) @binding(1) var<storage, read> probe_normals: array<vec4<f32>>;
@group(1) @binding(2) var<storage, read_write> probe_out: array<vec4<f32>>;

@compute @workgroup_size(64)
fn cs_probe(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if i >= arrayLength(&probe_points) {
        return;
    }
    probe_out[i] = vec4<f32>(sample_volume(probe_points[i].xyz, probe_normals[i].xyz), 0.0);
}
