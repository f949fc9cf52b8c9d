// The samples that carry gradient (owner: engine/src/sampler/live.rs), listed in order
// for the field's backward. `mark_live`: one thread per sample slot i < capacity,
// flags[i] = 1 iff i < count[0] and the sample's output gradient (dL/drgb, dL/dsigma
// and, with `normals`, dL/dn) has a component != 0 (NaN counts: it must reach the
// optimizer's non-finite check). The host scans flags into offsets (sampler/scan.wgsl);
// `write_live`: list[LIVE_HEADER + offsets[i]] = i for every flagged i, and the last slot's thread
// writes the total to list[0] (the LiveSamples layout, engine/src/layout.rs).

//#include "common/dispatch.wgsl"
//#include "common/layout.wgsl"

struct Params {
    capacity: u32,
    normals: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<storage, read> params: Params;
@group(0) @binding(1) var<storage, read> count: array<u32>;
@group(0) @binding(2) var<storage, read> d_rgb_density: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> d_normal: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> flags: array<u32>;

@compute @workgroup_size(WG_SIZE)
fn mark_live(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = thread_index(gid, nwg);
    if (i >= params.capacity) {
        return;
    }
    // Tested on the bits (magnitude != 0): a float compare may treat NaN as equal to 0
    // under fast-math (lavapipe does), and NaN must be listed.
    let magnitude = vec4<u32>(0x7fffffffu);
    var live = false;
    if (i < count[0]) {
        live = any((bitcast<vec4<u32>>(d_rgb_density[i]) & magnitude) != vec4<u32>(0u));
        if (params.normals != 0u) {
            live = live || any((bitcast<vec4<u32>>(d_normal[i]).xyz & magnitude.xyz) != vec3<u32>(0u));
        }
    }
    flags[i] = select(0u, 1u, live);
}

@group(0) @binding(0) var<storage, read> wparams: Params;
@group(0) @binding(1) var<storage, read> live_flags: array<u32>;
@group(0) @binding(2) var<storage, read> offsets: array<u32>;
@group(0) @binding(3) var<storage, read_write> list: array<u32>;

@compute @workgroup_size(WG_SIZE)
fn write_live(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = thread_index(gid, nwg);
    if (i >= wparams.capacity) {
        return;
    }
    let flag = live_flags[i];
    if (flag != 0u) {
        list[LIVE_HEADER + offsets[i]] = i;
    }
    if (i + 1u == wparams.capacity) {
        list[0] = offsets[i] + flag;
    }
}
