// Self-test of the runtime (owner: engine/src/gpu/selftest.rs): a scatter-add with
// many colliding float atomic adds, plus a plain element-wise write. Checks uploads,
// dispatch folding, the float-atomic path in use, and readback.

//#include "common/dispatch.wgsl"

struct Params {
    n: u32,
    bins: u32,
    scale: f32,
    _pad: u32,
}

@group(0) @binding(0) var<storage, read> params: Params;
@group(0) @binding(1) var<storage, read> values: array<f32>;
@group(0) @binding(2) var<storage, read_write> scaled: array<f32>;
@group(0) @binding(3) var<storage, read_write> sums: array<AtomicF32>;

@compute @workgroup_size(WG_SIZE)
fn scatter_add(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = thread_index(gid, nwg);
    if (i >= params.n) {
        return;
    }
    let v = values[i];
    scaled[i] = v * params.scale;
    let bin = i % params.bins;
    atomicAddF32(sums, bin, v);
}
