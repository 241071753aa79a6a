// Direct irradiance with voxel-grid shadows: the twin of `bounce_core::direct::direct_irradiance`
// on the grid tracer (`bounce_core::rays::VoxelGrid::occluded`). Read that module's doc for the
// model; the comments here only say where the two differ.
//
// One thread per (patch, light set): the thread walks the patch's samples in order and, per
// sample, the set's lights in order, so a patch sums in the same order as on the CPU. The rest
// of the difference is f32 rounding (division, sqrt, fused multiply-adds the driver may form),
// which can flip a shadow ray that grazes a voxel edge.
//
// `light.wgsl` (the prepared light, `light_sample`, `BIG`) is prepended.

struct DirectParams {
    // Patches.
    n: u32,
    // Light sets in this dispatch.
    sets: u32,
    // Samples per patch are side * side.
    side: u32,
    // Workgroups along x of the dispatch (a 2-D grid, linearised).
    groups_x: u32,
    dims: vec3<u32>,
    voxel_size: f32,
    origin: vec3<f32>,
    pad: u32,
}

// A patch's quad (as `bounce_core::patch::Quad`) and the voxel its shadow walks start in,
// computed on the host exactly as the CPU walk does.
struct GpuPatch {
    face: u32,
    plane: f32,
    lo0: f32,
    lo1: f32,
    hi0: f32,
    hi1: f32,
    cell_x: i32,
    cell_y: i32,
    cell_z: i32,
}

const WG: u32 = 64u;

@group(0) @binding(0) var<uniform> params: DirectParams;
@group(0) @binding(1) var<storage, read> patches: array<GpuPatch>;
// One bit per voxel, x fastest, 32 to a word.
@group(0) @binding(2) var<storage, read> occupancy: array<u32>;
@group(0) @binding(3) var<storage, read> lights: array<GpuLight>;
// Set s owns lights[offsets[s]..offsets[s + 1]].
@group(0) @binding(4) var<storage, read> offsets: array<u32>;
// Packed RGB, light set s, patch i at (s * n + i) * 3.
@group(0) @binding(5) var<storage, read_write> out: array<f32>;

fn hash_u32(x0: u32) -> u32 {
    var x = x0;
    x ^= x >> 16u;
    x *= 0x7feb352du;
    x ^= x >> 15u;
    x *= 0x846ca68bu;
    x ^= x >> 16u;
    return x;
}

fn jitter(pid: u32, k: u32, dim: u32) -> f32 {
    let h = hash_u32(hash_u32(pid) ^ (k * 2u + dim));
    return (f32(h >> 9u) + 0.5) * (1.0 / 8388608.0);
}

fn axis_of(face: u32) -> u32 {
    return face / 2u;
}

fn face_normal(face: u32) -> vec3<f32> {
    var n = vec3<f32>(0.0);
    let s = select(-1.0, 1.0, face % 2u == 0u);
    n[axis_of(face)] = s;
    return n;
}

fn quad_point(q: GpuPatch, s: f32, t: f32) -> vec3<f32> {
    let a = axis_of(q.face);
    var p = vec3<f32>(0.0);
    p[a] = q.plane;
    p[(a + 1u) % 3u] = q.lo0 + s * (q.hi0 - q.lo0);
    p[(a + 2u) % 3u] = q.lo1 + t * (q.hi1 - q.lo1);
    return p;
}

// `bounce_core::direct::shadow_length`: a shadow ray towards a point or spot light stops where it
// comes within one voxel of the light (the light's own voxel never shadows it).
fn shadow_length(p: vec3<f32>, dir: vec3<f32>, distance: f32, light: vec3<f32>, size: f32) -> f32 {
    if !(distance < BIG) {
        return distance;
    }
    let lo = light - vec3<f32>(size);
    let hi = light + vec3<f32>(size);
    var enter = 0.0;
    for (var a = 0u; a < 3u; a++) {
        if dir[a] != 0.0 {
            let t0 = (lo[a] - p[a]) / dir[a];
            let t1 = (hi[a] - p[a]) / dir[a];
            enter = max(enter, min(t0, t1));
        }
    }
    return min(distance, max(enter - size * 1e-3, 0.0));
}

fn occupied(c: vec3<i32>) -> bool {
    let k = u32(c.x) + params.dims.x * (u32(c.y) + params.dims.y * u32(c.z));
    return ((occupancy[k >> 5u] >> (k & 31u)) & 1u) == 1u;
}

fn outside(c: vec3<i32>) -> bool {
    return any(c < vec3<i32>(0)) || any(vec3<u32>(c) >= params.dims);
}

// `VoxelGrid::walk` reduced to its yes/no answer: whether an occupied voxel is entered before
// `max_t` (BIG: before leaving the grid).
fn occluded(q: GpuPatch, origin: vec3<f32>, dir: vec3<f32>, max_t: f32) -> bool {
    var cell = vec3<i32>(q.cell_x, q.cell_y, q.cell_z);
    var step = vec3<i32>(0);
    var t_max = vec3<f32>(BIG);
    var t_delta = vec3<f32>(BIG);
    let size = params.voxel_size;
    for (var ax = 0u; ax < 3u; ax++) {
        let d = dir[ax];
        if d > 0.0 {
            step[ax] = 1;
            let boundary = params.origin[ax] + f32(cell[ax] + 1) * size;
            t_max[ax] = (boundary - origin[ax]) / d;
            t_delta[ax] = size / d;
        } else if d < 0.0 {
            step[ax] = -1;
            let boundary = params.origin[ax] + f32(cell[ax]) * size;
            t_max[ax] = (boundary - origin[ax]) / d;
            t_delta[ax] = -size / d;
        }
    }
    if outside(cell) {
        return false;
    }
    if occupied(cell) {
        return true;
    }
    // Every step moves one cell along one axis, so a walk leaves the grid within the sum of
    // the dims; the bound only guards the loop against a driver's rounding surprises.
    let steps = params.dims.x + params.dims.y + params.dims.z + 3u;
    for (var i = 0u; i < steps; i++) {
        var ax = 2u;
        if t_max.x < t_max.y {
            if t_max.x < t_max.z {
                ax = 0u;
            }
        } else if t_max.y < t_max.z {
            ax = 1u;
        }
        let t = t_max[ax];
        if t >= max_t || !(t < BIG) {
            return false;
        }
        cell[ax] += step[ax];
        t_max[ax] += t_delta[ax];
        if cell[ax] < 0 || u32(cell[ax]) >= params.dims[ax] {
            return false;
        }
        if occupied(cell) {
            return true;
        }
    }
    return false;
}

@compute @workgroup_size(WG)
fn direct(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let id = (wg.y * params.groups_x + wg.x) * WG + lid;
    if id >= params.n * params.sets {
        return;
    }
    let sid = id / params.n;
    let pid = id % params.n;
    let first = offsets[sid];
    let last = offsets[sid + 1u];
    var sum = vec3<f32>(0.0);
    let o = id * 3u;
    if first == last {
        out[o] = 0.0;
        out[o + 1u] = 0.0;
        out[o + 2u] = 0.0;
        return;
    }
    let q = patches[pid];
    let n = face_normal(q.face);
    let side = params.side;
    let count = side * side;
    let fs = f32(side);
    for (var k = 0u; k < count; k++) {
        let u = (f32(k % side) + jitter(pid, k, 0u)) / fs;
        let v = (f32(k / side) + jitter(pid, k, 1u)) / fs;
        let p = quad_point(q, u, v);
        for (var l = first; l < last; l++) {
            let s = light_sample(lights[l], p, n);
            if s.lit
                && !occluded(
                    q,
                    p,
                    s.dir,
                    shadow_length(p, s.dir, s.distance, lights[l].position, params.voxel_size),
                ) {
                sum += s.irradiance;
            }
        }
    }
    let e = min(sum / f32(count), vec3<f32>(BIG));
    out[o] = e.x;
    out[o + 1u] = e.y;
    out[o + 2u] = e.z;
}
