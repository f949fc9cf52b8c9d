// Global gradient norm, non-finite detection and clipping (owner:
// engine/src/optim/grad.rs, which documents the formulas).
//
// `partial_sums` runs once per gradient buffer: workgroup b reduces elements
// [b * BLOCK, (b + 1) * BLOCK) of that buffer into partials[offset + b] as
// (sum g^2, sum clamp(g)^2, non-finite count, max |g|), finite elements only.
// `finalize` (one workgroup) reduces all partials into the stats buffer: the first
// `count` are the gradients', the `guards` after them the guard buffers', of which only
// the non-finite count is kept (STAT_GUARD).
// `clip_in_place` scales one gradient buffer by the stats; `mark_applied` records that
// it was done. Every reduction order is fixed by the sizes alone: deterministic.

//#include "common/dispatch.wgsl"
//#include "optim/grad_stats.wgsl"

const RED_WG: u32 = 256u;
const ITEMS: u32 = 64u;
const BLOCK: u32 = 16384u; // RED_WG * ITEMS

struct PartialParams {
    n: u32,
    offset: u32,
    blocks: u32,
    clip_value: f32,
}

struct FinalParams {
    count: u32,
    max_norm: f32,
    clip_value: f32,
    norm_eps: f32,
    guards: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

struct ClipParams {
    n: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

var<workgroup> shared_acc: array<vec4<f32>, RED_WG>;

fn combine(a: vec4<f32>, b: vec4<f32>) -> vec4<f32> {
    return vec4<f32>(a.x + b.x, a.y + b.y, a.z + b.z, max(a.w, b.w));
}

// Tree reduction of shared_acc; every invocation of the workgroup must call it.
fn reduce_workgroup(lid: u32) {
    for (var s = RED_WG / 2u; s > 0u; s = s / 2u) {
        if (lid < s) {
            shared_acc[lid] = combine(shared_acc[lid], shared_acc[lid + s]);
        }
        workgroupBarrier();
    }
}

@group(0) @binding(0) var<storage, read> pp: PartialParams;
@group(0) @binding(1) var<storage, read> grads_in: array<f32>;
@group(0) @binding(2) var<storage, read_write> partials_out: array<vec4<f32>>;

@compute @workgroup_size(RED_WG)
fn partial_sums(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    // Branch-free on purpose: the parameters are read once before the loop, and every
    // element is loaded (an index past the end reads the last element) and masked
    // with `select`. A load under a divergent branch is a per-lane gather on lavapipe,
    // which made this pass several times slower.
    let p = pp;
    let block = wid.x + wid.y * nwg.x;
    let in_block = block < p.blocks;
    let last = max(p.n, 1u) - 1u;
    var acc = vec4<f32>(0.0);
    let base = block * BLOCK;
    for (var k = 0u; k < ITEMS; k = k + 1u) {
        let i = base + k * RED_WG + lid;
        let present = in_block && i < p.n;
        let g = grads_in[min(i, last)];
        let finite = grad_is_finite(g);
        let x = select(0.0, g, present && finite);
        let c = select(x, clamp(x, -p.clip_value, p.clip_value), p.clip_value > 0.0);
        acc = combine(acc, vec4<f32>(x * x, c * c, select(0.0, 1.0, present && !finite), abs(x)));
    }
    shared_acc[lid] = acc;
    workgroupBarrier();
    reduce_workgroup(lid);
    if (lid == 0u && block < pp.blocks) {
        partials_out[pp.offset + block] = shared_acc[0];
    }
}

@group(0) @binding(0) var<storage, read> fp: FinalParams;
@group(0) @binding(1) var<storage, read> partials_in: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> stats_out: array<f32>;

@compute @workgroup_size(RED_WG)
fn finalize(@builtin(local_invocation_index) lid: u32) {
    let count = fp.count;
    var acc = vec4<f32>(0.0);
    for (var j = lid; j < count; j = j + RED_WG) {
        acc = combine(acc, partials_in[j]);
    }
    // The guards' non-finite counts, summed in a fixed order (one strided loop per
    // invocation, then the tree) like the gradients'.
    var guard = 0.0;
    for (var j = count + lid; j < count + fp.guards; j = j + RED_WG) {
        guard = guard + partials_in[j].z;
    }
    shared_acc[lid] = acc;
    workgroupBarrier();
    reduce_workgroup(lid);
    let total = shared_acc[0];
    workgroupBarrier();
    shared_acc[lid] = vec4<f32>(0.0, 0.0, guard, 0.0);
    workgroupBarrier();
    reduce_workgroup(lid);
    if (lid == 0u) {
        let guard_total = shared_acc[0].z;
        let raw_norm = sqrt(total.x);
        var norm = raw_norm;
        if (fp.clip_value > 0.0) {
            norm = sqrt(total.y);
        }
        var scale = 1.0;
        if (total.z > 0.0) {
            scale = 0.0;
        } else if (fp.max_norm > 0.0) {
            scale = min(1.0, fp.max_norm / (fp.norm_eps + norm));
        }
        stats_out[STAT_RAW_NORM] = raw_norm;
        stats_out[STAT_NORM] = norm;
        stats_out[STAT_SCALE] = scale;
        stats_out[STAT_NONFINITE] = total.z;
        stats_out[STAT_ABS_MAX] = total.w;
        stats_out[STAT_CLIP_VALUE] = max(fp.clip_value, 0.0);
        stats_out[STAT_APPLIED] = 0.0;
        stats_out[STAT_GUARD] = guard_total;
    }
}

@group(0) @binding(0) var<storage, read> cp: ClipParams;
@group(0) @binding(1) var<storage, read> stats_in: array<f32>;
@group(0) @binding(2) var<storage, read_write> grads_inout: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn clip_in_place(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = thread_index(gid, nwg);
    // Non-finite gradients are left untouched (the step is to be skipped), and a clip
    // already applied is not applied twice.
    if (i >= cp.n || stats_in[STAT_NONFINITE] > 0.0 || stats_in[STAT_GUARD] > 0.0 || stats_in[STAT_APPLIED] != 0.0) {
        return;
    }
    var g = grads_inout[i];
    let clip_value = stats_in[STAT_CLIP_VALUE];
    if (clip_value > 0.0) {
        g = clamp(g, -clip_value, clip_value);
    }
    grads_inout[i] = g * stats_in[STAT_SCALE];
}

@group(0) @binding(0) var<storage, read_write> stats_mark: array<f32>;

@compute @workgroup_size(1)
fn mark_applied() {
    stats_mark[STAT_APPLIED] = 1.0;
}
