// Direct irradiance with shadows against the scene's triangles: the twin of
// `bounce_core::direct::surface_irradiance` (read it and `bounce_core::trimesh` for the model;
// the comments here only say where the two differ). `light.wgsl` (the prepared light,
// `light_sample`, `BIG`) is prepended.
//
// Two passes over a piece of the patches (`params.first` onward, `params.patches` of them):
//
// - `shadow_pilots` (only where the pilot rule holds, `bounce_core::direct::pilots_apply`):
//   one thread per (light, patch, pilot) traces the pilots' rays first and records whether each
//   is reached and whether it faces the light. `shadow` then takes a pilot's answer from it,
//   and leaves dark without a ray the other samples of a patch some pilot of which faces the
//   light and none is reached.
// - `shadow`: one thread per (light of the dispatch, patch, sample) traces that shadow ray
//   through the BVH and records one bit, whether the light reaches the sample (lit and not
//   occluded). The rays are the work, so they get the threads, even for a single light set.
//   Light-major: neighbouring threads trace neighbouring samples towards one light, rays that
//   walk the same nodes. A workgroup's 64 bits meet in workgroup memory and leave as two words,
//   with no atomics.
// - `gather`: one thread per (light set, patch) walks the patch's samples in order and, per
//   sample, the set's lights in order, adding the irradiance of every ray whose bit is set into
//   the sample's value (kept finite), and the samples' values into the patch's sum. So a patch
//   sums in the CPU's order, and its value differs from the CPU's only by f32 rounding
//   (division, sqrt, fused multiply-adds the driver may form), which can also flip a shadow ray
//   that grazes a triangle's edge. `gather_samples` is `gather` that also keeps every sample's
//   value (`per_sample`) for the near-field pass (`near_field.wgsl`).

struct SurfaceParams {
    // Patches in the scene (the stride of one light set's output).
    n: u32,
    // Sample points stored per patch (the stride of `points`).
    per_patch: u32,
    // Samples per patch used: the first `count` of each patch's points.
    count: u32,
    // Lights in this dispatch, all its light sets together.
    lights: u32,
    // The piece: patches `first..first + patches`.
    first: u32,
    patches: u32,
    // Light sets in this dispatch.
    sets: u32,
    // BVH nodes; 0 when there is no triangle (nothing blocks light).
    nodes: u32,
    // Samples a patch's mean is taken over: the first `averaged` of the `count` used (those
    // spread by area; landing samples after them serve the near field only).
    averaged: u32,
    // 1 when the pilot rule holds (`bounce_core::direct::pilots_apply(averaged)`): `shadow`
    // then reads `shadow_pilots`' answers.
    pilots: u32,
    pad1: u32,
    pad2: u32,
}

// `bounce_core::trimesh::MeshTri`: a corner and two edges.
struct Tri {
    p0: vec3<f32>,
    source: u32,
    e1: vec3<f32>,
    double_sided: u32,
    e2: vec3<f32>,
    pad: u32,
}

// `bounce_core::trimesh::MeshNode` (obvhs' `Bvh2Node`): an inner node when `prim_count` is 0,
// with children at `first_index` and `first_index + 1`, else a leaf over
// `tris[first_index..first_index + prim_count]`.
struct Node {
    min: vec3<f32>,
    prim_count: u32,
    max: vec3<f32>,
    first_index: u32,
}

// `bounce_core::surface::SamplePoint`, padded to vec4 alignment.
struct GpuSample {
    position: vec3<f32>,
    pad0: u32,
    normal: vec3<f32>,
    pad1: u32,
}

const WG: u32 = 64u;
// Words of visibility bits one `shadow` workgroup writes.
const WORDS: u32 = 2u;
// Traversal stack entries: the host refuses a BVH deeper than this.
const STACK: u32 = 64u;
// `bounce_core::direct::SHADOW_END`, set by the host (so the two cannot round it apart).
override SHADOW_END: f32;
// obvhs' `safe_inverse` clamps |x| <= f32::EPSILON (2^-23) to ±1/EPSILON.
const EPSILON: f32 = 1.1920929e-7;
const INV_EPSILON: f32 = 8388608.0;

@group(0) @binding(0) var<uniform> params: SurfaceParams;
@group(0) @binding(1) var<storage, read> nodes: array<Node>;
@group(0) @binding(2) var<storage, read> tris: array<Tri>;
@group(0) @binding(3) var<storage, read> points: array<GpuSample>;
@group(0) @binding(4) var<storage, read> lights: array<GpuLight>;
// Set s owns lights[offsets[s]..offsets[s + 1]].
@group(0) @binding(5) var<storage, read> offsets: array<u32>;
// Bit `(l * patches + i) * count + k` (32 to a word): light l reaches sample k of the piece's
// patch i. Light-major, so a workgroup's rays share a light and neighbouring samples.
@group(0) @binding(6) var<storage, read_write> bits: array<u32>;
// Packed RGB, light set s, patch i at (s * n + i) * 3.
@group(0) @binding(7) var<storage, read_write> out: array<f32>;

// The pilots' answers (`shadow_pilots`), two words per 32 pilots: whether the light reaches
// each, then whether each faces it (is lit). Pilot `(l * patches + i) * pilots_per_row() + p` is
// sample `PILOT_STRIDE · p` of the piece's patch i towards light l. Bound to every `shadow`
// pass; read only when `params.pilots` is 1.
@group(0) @binding(9) var<storage, read_write> pilot_bits: array<u32>;

// `bounce_core::direct::PILOT_STRIDE`.
const PILOT_STRIDE: u32 = 4u;

// Each thread's visibility bit, in place in its word.
var<workgroup> visible: array<u32, WG>;
// Each pilot thread's facing bit, in place in its word.
var<workgroup> facing: array<u32, WG>;

// glam's `Vec3::dot` and `Vec3::cross`, term by term in its order.
fn dot3(a: vec3<f32>, b: vec3<f32>) -> f32 {
    return a.x * b.x + a.y * b.y + a.z * b.z;
}

fn cross3(a: vec3<f32>, b: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(a.y * b.z - b.y * a.z, a.z * b.x - b.z * a.x, a.x * b.y - b.x * a.y);
}

// obvhs' `safe_inverse`, with Rust's `signum` (-1 for -0.0, where WGSL's `sign` gives 0).
fn safe_inverse(x: f32) -> f32 {
    if abs(x) <= EPSILON {
        return select(INV_EPSILON, -INV_EPSILON, (bitcast<u32>(x) & 0x80000000u) != 0u);
    }
    return 1.0 / x;
}

// obvhs' `Aabb::intersect_ray`: the entry distance, BIG for a miss (the CPU's infinity: it
// fails every `t < t_max` test either way).
fn node_t(nd: Node, origin: vec3<f32>, inv: vec3<f32>) -> f32 {
    let t1 = (nd.min - origin) * inv;
    let t2 = (nd.max - origin) * inv;
    let lo = min(t1, t2);
    let hi = max(t1, t2);
    let enter = max(max(lo.x, lo.y), lo.z);
    let leave = min(min(hi.x, hi.y), hi.z);
    if leave >= enter && leave >= 0.0 {
        return enter;
    }
    return BIG;
}

// `bounce_core::trimesh::intersect` (Möller–Trumbore), the same arithmetic in the same order,
// reduced to whether the crossing lies in (0, t_max).
fn tri_hit(tri: Tri, origin: vec3<f32>, dir: vec3<f32>, t_max: f32) -> bool {
    let p = cross3(dir, tri.e2);
    let det = dot3(tri.e1, p);
    if det == 0.0 || !(abs(det) <= BIG) {
        return false;
    }
    let inv = 1.0 / det;
    let s = origin - tri.p0;
    let u = dot3(s, p) * inv;
    if !(u >= 0.0 && u <= 1.0) {
        return false;
    }
    let q = cross3(s, tri.e1);
    let v = dot3(dir, q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return false;
    }
    let t = dot3(tri.e2, q) * inv;
    return t > 0.0 && t < t_max;
}

fn leaf_hit(nd: Node, origin: vec3<f32>, dir: vec3<f32>, t_max: f32) -> bool {
    let end = nd.first_index + nd.prim_count;
    for (var i = nd.first_index; i < end; i++) {
        if tri_hit(tris[i], origin, dir, t_max) {
            return true;
        }
    }
    return false;
}

// `TriMesh::occluded`: obvhs' `ray_traverse_miss` (near child first, any hit ends the walk),
// with a fixed stack the host sized against the tree's depth.
fn occluded(origin: vec3<f32>, dir: vec3<f32>, t_max: f32) -> bool {
    if params.nodes == 0u || !(t_max > 0.0) {
        return false;
    }
    let inv = vec3<f32>(safe_inverse(dir.x), safe_inverse(dir.y), safe_inverse(dir.z));
    let root = nodes[0];
    if !(node_t(root, origin, inv) < t_max) {
        return false;
    }
    if root.prim_count > 0u {
        return leaf_hit(root, origin, dir, t_max);
    }
    var stack: array<u32, STACK>;
    var sp = 0u;
    var current = root.first_index;
    // Each round visits one inner node's children, and no inner node twice: the bound only
    // guards the loop against a malformed tree.
    for (var round = 0u; round < params.nodes; round++) {
        var near = nodes[current];
        var far = nodes[current + 1u];
        var t_near = node_t(near, origin, inv);
        var t_far = node_t(far, origin, inv);
        if t_near > t_far {
            let n = near;
            near = far;
            far = n;
            let t = t_near;
            t_near = t_far;
            t_far = t;
        }
        var go_near = t_near < t_max;
        if go_near && near.prim_count > 0u {
            if leaf_hit(near, origin, dir, t_max) {
                return true;
            }
            go_near = false;
        }
        var go_far = t_far < t_max;
        if go_far && far.prim_count > 0u {
            if leaf_hit(far, origin, dir, t_max) {
                return true;
            }
            go_far = false;
        }
        if go_near {
            current = near.first_index;
            if go_far && sp < STACK {
                stack[sp] = far.first_index;
                sp++;
            }
        } else if go_far {
            current = far.first_index;
        } else {
            if sp == 0u {
                return false;
            }
            sp--;
            current = stack[sp];
        }
    }
    return false;
}

// Pilots a patch has towards one light: samples 0, 4, 8, … of the `averaged`.
fn pilots_per_row() -> u32 {
    return (params.averaged + PILOT_STRIDE - 1u) / PILOT_STRIDE;
}

// Whether any of pilots `start..start + len` has bit `which` (0: reached, 1: faces the light).
fn any_pilot(start: u32, len: u32, which: u32) -> bool {
    let end = start + len;
    var b = start;
    while b < end {
        let lo = b & 31u;
        let take = min(32u - lo, end - b);
        let mask = (0xffffffffu >> (32u - take)) << lo;
        if (pilot_bits[(b >> 5u) * 2u + which] & mask) != 0u {
            return true;
        }
        b += take;
    }
    return false;
}

// Light l's shadow ray from sample k of the piece's patch i: 0 when the sample does not face
// the light (or lies outside its range or cone), 1 when it does and the ray is blocked, 3 when
// the light reaches it (bit 0: faces it, bit 1: reached).
fn sample_ray(l: u32, i: u32, k: u32) -> u32 {
    let pt = points[(params.first + i) * params.per_patch + k];
    let s = light_sample(lights[l], pt.position, pt.normal);
    if !s.lit {
        return 0u;
    }
    if occluded(pt.position, s.dir, s.distance * SHADOW_END) {
        return 1u;
    }
    return 3u;
}

// One thread per (light of the dispatch, patch, pilot): the pilot's shadow ray, as `shadow`
// traces any, and whether the pilot faces the light. A workgroup's 64 pilots leave as four
// words, with no atomics.
@compute @workgroup_size(WG)
fn shadow_pilots(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let group = wg.y * groups.x + wg.x;
    let per_row = pilots_per_row();
    let per_light = params.patches * per_row;
    let total = per_light * params.lights;
    if group * WG >= total {
        return;
    }
    let t = group * WG + lid;
    var bit = 0u;
    var faces = 0u;
    if t < total {
        let l = t / per_light;
        let r = t - l * per_light;
        let i = r / per_row;
        let ray = sample_ray(l, i, (r - i * per_row) * PILOT_STRIDE);
        faces = (ray & 1u) << (lid % 32u);
        bit = (ray >> 1u) << (lid % 32u);
    }
    visible[lid] = bit;
    facing[lid] = faces;
    workgroupBarrier();
    if lid < 4u {
        // Words: reached then facing, for pilots 0..32 then 32..64 of the workgroup.
        let half = lid / 2u;
        var word = 0u;
        for (var j = 0u; j < 32u; j++) {
            if lid % 2u == 0u {
                word |= visible[half * 32u + j];
            } else {
                word |= facing[half * 32u + j];
            }
        }
        pilot_bits[group * 4u + lid] = word;
    }
}

@compute @workgroup_size(WG)
fn shadow(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let group = wg.y * groups.x + wg.x;
    let per_light = params.patches * params.count;
    let total = per_light * params.lights;
    // Whole workgroups past the end (the grid is padded to a rectangle) leave together.
    if group * WG >= total {
        return;
    }
    let t = group * WG + lid;
    var bit = 0u;
    if t < total {
        // Two divisions, not four: integer division is slow on every target.
        let l = t / per_light;
        let r = t - l * per_light;
        let i = r / params.count;
        let k = r - i * params.count;
        var trace = true;
        if params.pilots == 1u {
            let per_row = pilots_per_row();
            let first = (l * params.patches + i) * per_row;
            if k < params.averaged && k % PILOT_STRIDE == 0u {
                // A pilot: `shadow_pilots` traced it.
                trace = false;
                let p = first + k / PILOT_STRIDE;
                if ((pilot_bits[(p >> 5u) * 2u] >> (p & 31u)) & 1u) == 1u {
                    bit = 1u << (lid % 32u);
                }
            } else if !any_pilot(first, per_row, 0u) && any_pilot(first, per_row, 1u) {
                // Some pilot faces the light and none is reached: taken as blocked.
                trace = false;
            }
        }
        if trace {
            bit = (sample_ray(l, i, k) >> 1u) << (lid % 32u);
        }
    }
    visible[lid] = bit;
    workgroupBarrier();
    if lid < WORDS {
        var word = 0u;
        for (var j = 0u; j < 32u; j++) {
            word |= visible[lid * 32u + j];
        }
        bits[group * WORDS + lid] = word;
    }
}

// Light set `sid`'s irradiance at sample `k` of the piece's patch `i` (the scene's patch `pid`):
// its lights in order, kept finite as the CPU keeps each sample's value.
fn sample_value(sid: u32, i: u32, pid: u32, k: u32) -> vec3<f32> {
    let pt = points[pid * params.per_patch + k];
    let column = i * params.count + k;
    let stride = params.patches * params.count;
    let last = offsets[sid + 1u];
    var e = vec3<f32>(0.0);
    for (var l = offsets[sid]; l < last; l++) {
        let b = l * stride + column;
        if ((bits[b >> 5u] >> (b & 31u)) & 1u) == 1u {
            let s = light_sample(lights[l], pt.position, pt.normal);
            if s.lit {
                e += s.irradiance;
            }
        }
    }
    return min(e, vec3<f32>(BIG));
}

// The (light set, patch) of a `gather` thread, or none past the end: `vec2(sid, i)`.
fn gather_id(wg: vec3<u32>, groups: vec3<u32>, lid: u32) -> vec2<u32> {
    let id = (wg.y * groups.x + wg.x) * WG + lid;
    if id >= params.patches * params.sets {
        return vec2<u32>(0xffffffffu);
    }
    return vec2<u32>(id / params.patches, id % params.patches);
}

// A set with no light leaves its patches dark without reading a bit (its pieces may have had no
// rays to trace).
fn lit_set(sid: u32) -> bool {
    return offsets[sid] != offsets[sid + 1u] && params.count > 0u;
}

fn write_mean(sid: u32, pid: u32, sum: vec3<f32>) {
    var e = vec3<f32>(0.0);
    if params.averaged > 0u {
        e = min(sum / f32(params.averaged), vec3<f32>(BIG));
    }
    let o = (sid * params.n + pid) * 3u;
    out[o] = e.x;
    out[o + 1u] = e.y;
    out[o + 2u] = e.z;
}

@compute @workgroup_size(WG)
fn gather(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let at = gather_id(wg, groups, lid);
    if at.x == 0xffffffffu {
        return;
    }
    let sid = at.x;
    let i = at.y;
    let pid = params.first + i;
    var sum = vec3<f32>(0.0);
    if lit_set(sid) {
        // Samples beyond `averaged` are not in the mean: `gather` need not light them.
        for (var k = 0u; k < params.averaged; k++) {
            sum += sample_value(sid, i, pid, k);
        }
    }
    write_mean(sid, pid, sum);
}

// Packed RGB per sample for the near-field pass: light set s, patch i, sample k at
// ((s * n + i) * count + k) * 3. Only `gather_samples` binds it.
@group(0) @binding(8) var<storage, read_write> per_sample: array<f32>;

// `gather`, also keeping each sample's value for `near_field.wgsl`: the same function sums the
// same terms, so the means are `gather`'s.
@compute @workgroup_size(WG)
fn gather_samples(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let at = gather_id(wg, groups, lid);
    if at.x == 0xffffffffu {
        return;
    }
    let sid = at.x;
    let i = at.y;
    let pid = params.first + i;
    let lit = lit_set(sid);
    var sum = vec3<f32>(0.0);
    for (var k = 0u; k < params.count; k++) {
        var e = vec3<f32>(0.0);
        if lit {
            e = sample_value(sid, i, pid, k);
        }
        if k < params.averaged {
            sum += e;
        }
        let o = ((sid * params.n + pid) * params.count + k) * 3u;
        per_sample[o] = e.x;
        per_sample[o + 1u] = e.y;
        per_sample[o + 2u] = e.z;
    }
    write_mean(sid, pid, sum);
}
