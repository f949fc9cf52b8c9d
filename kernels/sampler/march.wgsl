// Sample placement (owner: engine/src/sampler/march.rs). Every ray is cut into
// segments of constant length dt = step / |dir| in t on a grid anchored at
// t0 = t_min - jitter * dt, clipped to [t_min, t_max]; a segment becomes a sample
// (at its midpoint) when
//   * uniform mode: always;
//   * occupancy mode: its midpoint lies in one of the ray's occupied intervals and
//     in a cell whose occupancy bit is set (an empty cell is skipped in one jump to
//     its exit).
// Two passes run the same walk: `count_samples` stores the per-ray count (capped at
// max_per_ray) and, after an exclusive scan of the counts, `write_samples` writes
// the samples contiguously, truncating at the batch capacity.

//#include "common/dispatch.wgsl"
//#include "common/layout.wgsl"
//#include "sampler/common.wgsl"

struct Params {
    geom: OccupancyGeom,
    n_rays: u32,
    capacity: u32,
    max_per_ray: u32,
    // 0: uniform; 1: occupancy (intervals + bits).
    occupancy: u32,
    step: f32,
    max_intervals: u32,
    // 1: offset the segment grid per ray by a random fraction of dt.
    jitter: u32,
    seed: u32,
}

@group(0) @binding(0) var<storage, read> params_buffer: Params;
// Copied to private memory as the first statement of each entry point, before any
// branch (see gpu/kernel.rs, "Uniform buffers": storage reads inside branches are
// lane by lane on lavapipe).
var<private> params: Params;
@group(0) @binding(1) var<storage, read> rays: array<Ray>;
@group(0) @binding(2) var<storage, read> intervals: array<vec2<f32>>;
@group(0) @binding(3) var<storage, read> interval_count: array<u32>;
@group(0) @binding(4) var<storage, read> occupancy_bits: array<u32>;
@group(0) @binding(5) var<storage, read_write> counts: array<u32>;
@group(0) @binding(6) var<storage, read> offsets: array<u32>;
@group(0) @binding(7) var<storage, read_write> samples: array<Sample>;
@group(0) @binding(8) var<storage, read_write> ranges: array<SampleRange>;
@group(0) @binding(9) var<storage, read_write> sample_count: array<u32>;

// Walks ray r; returns the number of samples (at most max_per_ray). With `write`,
// stores the first `allowed` of them at samples[start ..].
fn march(r: u32, write: bool, start: u32, allowed: u32) -> u32 {
    let ray = rays[r];
    let len = length(ray.dir);
    let dt = params.step / len;
    // Also rejects NaN and infinite steps and empty ranges.
    if (!(dt > 0.0 && dt < 3.0e38 && ray.t_max > ray.t_min)) {
        return 0u;
    }
    var t0 = ray.t_min;
    if (params.jitter != 0u) {
        t0 -= unit_f32(rand_u32(params.seed, r, 0u)) * dt;
    }
    let inv_d = safe_inverse_dir(ray.dir);
    let g = params.geom;
    let cell_size = (g.aabb_max - g.aabb_min) / f32(g.res);
    var n = 0u;
    var n_iv = 1u;
    if (params.occupancy != 0u) {
        n_iv = interval_count[r];
    }
    for (var i = 0u; i < n_iv; i++) {
        var iv = vec2<f32>(ray.t_min, ray.t_max);
        if (params.occupancy != 0u) {
            iv = intervals[r * params.max_intervals + i];
        }
        // First candidate: a segment or two before the interval's entry.
        var k = u32(max(floor((iv.x - t0) / dt) - 1.0, 0.0));
        loop {
            let lo = max(t0 + f32(k) * dt, ray.t_min);
            let hi = min(t0 + f32(k + 1u) * dt, ray.t_max);
            if (lo >= ray.t_max) {
                return n;
            }
            let m = 0.5 * (lo + hi);
            if (m >= iv.y) {
                break;
            }
            if (hi > lo && m >= iv.x) {
                if (params.occupancy != 0u) {
                    let p = ray.origin + m * ray.dir;
                    let c = grid_cell_coord(g, p);
                    var occupied = false;
                    if (grid_cell_inside(g, c)) {
                        let idx = grid_cell_index(g, c);
                        occupied = ((occupancy_bits[idx >> 5u] >> (idx & 31u)) & 1u) != 0u;
                    }
                    if (!occupied) {
                        // Jump to (one segment before) the first midpoint past the cell.
                        let cmin = g.aabb_min + vec3<f32>(c) * cell_size;
                        let t_exit = ray_box(ray.origin, inv_d, cmin, cmin + cell_size).y;
                        let k_exit = ceil((t_exit - t0) / dt - 0.5) - 1.0;
                        k = max(k + 1u, u32(clamp(k_exit, 0.0, 4.0e9)));
                        continue;
                    }
                }
                if (write && n < allowed) {
                    samples[start + n] = Sample(ray.origin + m * ray.dir, m, ray.dir, hi - lo);
                }
                n += 1u;
                if (n >= params.max_per_ray || (write && n >= allowed)) {
                    return n;
                }
            }
            k += 1u;
        }
    }
    return n;
}

// counts[r] = number of samples of ray r; counts[n_rays] = 0 (so that the scan of
// n_rays + 1 counts ends with the total).
@compute @workgroup_size(WG_SIZE)
fn count_samples(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    params = params_buffer;
    let r = thread_index(gid, nwg);
    if (r == 0u) {
        counts[params.n_rays] = 0u;
    }
    if (r >= params.n_rays) {
        return;
    }
    counts[r] = march(r, false, 0u, 0u);
}

// Writes ranges and samples from the scanned counts; samples past the capacity are
// dropped (a ray straddling it keeps its first samples, later rays get none).
@compute @workgroup_size(WG_SIZE)
fn write_samples(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    params = params_buffer;
    let r = thread_index(gid, nwg);
    if (r == 0u) {
        let total = offsets[params.n_rays];
        sample_count[0] = min(total, params.capacity);
        sample_count[1] = total;
    }
    if (r >= params.n_rays) {
        return;
    }
    let start = offsets[r];
    var allowed = 0u;
    if (start < params.capacity) {
        allowed = min(counts[r], params.capacity - start);
    }
    ranges[r] = SampleRange(min(start, params.capacity), allowed);
    if (allowed > 0u) {
        march(r, true, start, allowed);
    }
}
