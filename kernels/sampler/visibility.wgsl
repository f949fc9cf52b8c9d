// The visibility pass (owner: engine/src/sampler/visibility.rs): from the marched
// samples of each ray and their densities, keep the samples that can still be seen,
// packed into a second batch. Per ray, front to back, with the compositing of
// render/composite.wgsl:
//   tau_i = sigma_i dt_i,  trans_i = exp(-tau_i),  alpha_i = 1 - trans_i,
//   T_0 = 1,  T_{i+1} = T_i trans_i;
// the walk stops at the first i with T_i < min_transmittance (tested before the
// sample, as the renderer's early termination), and sample i is kept iff
// alpha_i >= min_alpha (nerfacc's `early_stop_eps` and `alpha_thre`) or dropping it
// would take the ray's dropped optical thickness sum tau past max_dropped_tau (the
// bound on the opacity a ray loses to the floor). T runs over every
// marched sample, dropped ones included. A NaN density keeps its sample and every
// later one (NaN compares false both ways), so it reaches the field's outputs and the
// optimizer's check instead of vanishing here.
// Two passes run the same walk: `count_visible` stores the per-ray count and, after an
// exclusive scan of the counts, `write_visible` copies the kept samples contiguously.
// The output never holds more samples than the input, so it has no capacity cut.

//#include "common/dispatch.wgsl"
//#include "common/layout.wgsl"
//#include "common/opacity.wgsl"

struct Params {
    n_rays: u32,
    min_transmittance: f32,
    min_alpha: f32,
    // -ln(1 - max_dropped_opacity); f32 max for no bound.
    max_dropped_tau: f32,
}

@group(0) @binding(0) var<storage, read> params_buffer: Params;
// Copied to private memory first (see gpu/kernel.rs, "Uniform buffers").
var<private> params: Params;
@group(0) @binding(1) var<storage, read> in_ranges: array<SampleRange>;
@group(0) @binding(2) var<storage, read> in_samples: array<Sample>;
@group(0) @binding(3) var<storage, read> in_count: array<u32>;
// The marched samples' densities in .w (a field's `record_sample_density`).
@group(0) @binding(4) var<storage, read> density: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> counts: array<u32>;
@group(0) @binding(6) var<storage, read> offsets: array<u32>;
@group(0) @binding(7) var<storage, read_write> samples: array<Sample>;
@group(0) @binding(8) var<storage, read_write> ranges: array<SampleRange>;
@group(0) @binding(9) var<storage, read_write> sample_count: array<u32>;

// Walks ray r's marched samples; returns how many are kept and, with `write`, copies
// them to samples[start ..].
fn walk(r: u32, write: bool, start: u32) -> u32 {
    let range = in_ranges[r];
    var T = 1.0;
    var dropped = 0.0;
    var n = 0u;
    for (var k = 0u; k < range.count; k++) {
        if (T < params.min_transmittance) {
            break;
        }
        let s = range.start + k;
        let smp = in_samples[s];
        let tau = density[s].w * smp.dt;
        let trans = exp(-tau);
        if (alpha_of(tau, trans) < params.min_alpha && dropped + tau <= params.max_dropped_tau) {
            dropped += tau;
        } else {
            if (write) {
                samples[start + n] = smp;
            }
            n += 1u;
        }
        T *= trans;
    }
    return n;
}

// counts[r] = kept samples of ray r; counts[n_rays] = 0 (the scan then ends with the total).
@compute @workgroup_size(WG_SIZE)
fn count_visible(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    params = params_buffer;
    let r = thread_index(gid, nwg);
    if (r == 0u) {
        counts[params.n_rays] = 0u;
    }
    if (r >= params.n_rays) {
        return;
    }
    counts[r] = walk(r, false, 0u);
}

// Writes ranges and kept samples from the scanned counts. sample_count: [kept, the
// marched batch's wanted count] (the capacity grows from what the march wanted).
@compute @workgroup_size(WG_SIZE)
fn write_visible(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    params = params_buffer;
    let r = thread_index(gid, nwg);
    if (r == 0u) {
        sample_count[0] = offsets[params.n_rays];
        sample_count[1] = in_count[1];
    }
    if (r >= params.n_rays) {
        return;
    }
    let start = offsets[r];
    ranges[r] = SampleRange(start, counts[r]);
    if (counts[r] > 0u) {
        walk(r, true, start);
    }
}
