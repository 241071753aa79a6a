// The device's memory read bandwidth: every 16-byte word of `data` read once per dispatch, summed
// (u32, wrapping) into one partial sum per workgroup. The sums keep the reads from being optimised
// away and let the host check that every word was read (`bandwidth::checksum` is the CPU twin).

struct Probe {
    // vec4 words in `data`.
    len: u32,
    // Workgroups in the dispatch: threads stride over the buffer by groups * 256.
    groups: u32,
}

@group(0) @binding(0) var<uniform> probe: Probe;
@group(0) @binding(1) var<storage, read> data: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read_write> sums: array<u32>;

var<workgroup> part: array<u32, 256>;

@compute @workgroup_size(256)
fn read_all(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) tid: u32,
) {
    var acc = vec4<u32>(0u);
    for (var i = wid.x * 256u + tid; i < probe.len; i += probe.groups * 256u) {
        acc += data[i];
    }
    part[tid] = acc.x + acc.y + acc.z + acc.w;
    workgroupBarrier();
    for (var s = 128u; s > 0u; s = s / 2u) {
        if tid < s {
            part[tid] += part[tid + s];
        }
        workgroupBarrier();
    }
    if tid == 0u {
        sums[wid.x] = part[0];
    }
}
