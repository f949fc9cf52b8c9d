// Occupied intervals of each ray (owner: engine/src/sampler/intervals.rs): one thread
// per ray walks the BVH over occupied bricks with a stack, collects the ray's
// [t_enter, t_exit] through every brick it hits (clipped to [t_min, t_max]), sorts
// them, merges overlapping or touching ones and, above `max_intervals`, merges the
// closest gaps. The CPU reference in intervals.rs follows the same steps.

//#include "common/dispatch.wgsl"
//#include "common/layout.wgsl"
//#include "sampler/common.wgsl"

// Bricks one ray can cross: at most 3 * 32 - 2 with <= 32 bricks per axis (checked
// by SamplerConfig::validate).
const RAW_CAP: u32 = 96u;
// Traversal stack; the brick BVH's depth is checked against it when it is built.
const STACK_CAP: u32 = 64u;

struct Params {
    n_rays: u32,
    n_nodes: u32,
    max_intervals: u32,
    _pad: u32,
}

// A BVH2 node (flattened from obvhs): leaf iff prim_count > 0; then its primitives
// are prims[first_index .. first_index + prim_count]; else its children are
// nodes[first_index] and nodes[first_index + 1]. Primitives use the same layout.
struct BvhNode {
    min: vec3<f32>,
    prim_count: u32,
    max: vec3<f32>,
    first_index: u32,
}

@group(0) @binding(0) var<storage, read> params: Params;
@group(0) @binding(1) var<storage, read> rays: array<Ray>;
@group(0) @binding(2) var<storage, read> nodes: array<BvhNode>;
@group(0) @binding(3) var<storage, read> prims: array<BvhNode>;
@group(0) @binding(4) var<storage, read_write> intervals: array<vec2<f32>>;
@group(0) @binding(5) var<storage, read_write> interval_count: array<u32>;

// Gap below which two consecutive intervals count as touching (float noise where a
// ray crosses from one brick into its neighbour).
fn merge_tolerance(t: f32) -> f32 {
    return 1e-5 * max(1.0, abs(t));
}

@compute @workgroup_size(WG_SIZE)
fn ray_intervals(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let r = thread_index(gid, nwg);
    if (r >= params.n_rays) {
        return;
    }
    let ray = rays[r];
    let inv_d = safe_inverse_dir(ray.dir);
    var raw: array<vec2<f32>, RAW_CAP>;
    var n_raw = 0u;
    var stack: array<u32, STACK_CAP>;
    var sp = 0u;
    if (params.n_nodes > 0u && ray.t_max > ray.t_min) {
        stack[0] = 0u;
        sp = 1u;
    }
    while (sp > 0u) {
        sp -= 1u;
        let node = nodes[stack[sp]];
        let h = ray_box(ray.origin, inv_d, node.min, node.max);
        if (h.x > h.y || h.y < ray.t_min || h.x > ray.t_max) {
            continue;
        }
        if (node.prim_count == 0u) {
            if (sp + 2u <= STACK_CAP) {
                stack[sp] = node.first_index;
                stack[sp + 1u] = node.first_index + 1u;
                sp += 2u;
            }
            continue;
        }
        for (var p = node.first_index; p < node.first_index + node.prim_count; p++) {
            let b = prims[p];
            let hb = ray_box(ray.origin, inv_d, b.min, b.max);
            let iv = vec2<f32>(max(hb.x, ray.t_min), min(hb.y, ray.t_max));
            // Slivers (a ray grazing a brick's edge or corner) are dropped: shorter than
            // the touching tolerance, they hold no sample, and whether rounding makes
            // them empty differs between implementations (NVIDIA kept one that the CPU's
            // slab test found empty).
            if (iv.y - iv.x > merge_tolerance(iv.y) && n_raw < RAW_CAP) {
                // Insertion into raw, sorted by (enter, exit).
                var j = n_raw;
                while (j > 0u && (raw[j - 1u].x > iv.x || (raw[j - 1u].x == iv.x && raw[j - 1u].y > iv.y))) {
                    raw[j] = raw[j - 1u];
                    j -= 1u;
                }
                raw[j] = iv;
                n_raw += 1u;
            }
        }
    }
    // Merge overlapping / touching intervals in place.
    var n = 0u;
    for (var i = 0u; i < n_raw; i++) {
        let iv = raw[i];
        if (n > 0u && iv.x <= raw[n - 1u].y + merge_tolerance(raw[n - 1u].y)) {
            raw[n - 1u].y = max(raw[n - 1u].y, iv.y);
        } else {
            raw[n] = iv;
            n += 1u;
        }
    }
    // Over the cap: repeatedly close the smallest gap (first one on ties).
    let cap = max(params.max_intervals, 1u);
    while (n > cap) {
        var best = 0u;
        var best_gap = raw[1].x - raw[0].y;
        for (var i = 1u; i + 1u < n; i++) {
            let g = raw[i + 1u].x - raw[i].y;
            if (g < best_gap) {
                best_gap = g;
                best = i;
            }
        }
        raw[best].y = raw[best + 1u].y;
        for (var i = best + 1u; i + 1u < n; i++) {
            raw[i] = raw[i + 1u];
        }
        n -= 1u;
    }
    let base = r * params.max_intervals;
    for (var i = 0u; i < n; i++) {
        intervals[base + i] = raw[i];
    }
    interval_count[r] = n;
}
