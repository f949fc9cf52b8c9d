// Hash-grid field density at every sample of a SampleBatch (owner:
// engine/src/field/grid/mod.rs), for the sampler's visibility pass: one thread per
// sample, dispatched indirectly over count[0] (gpu/indirect.rs), writing the
// post-activation density (zero outside the AABB) into the w of a vec4 (x, y, z
// zero), the layout of a forward's rgb_density. Only the first output of the density
// MLP is evaluated, as in grid_density.wgsl; no colour, no normals.

//#include "field/grid_lib.wgsl"
// encode and the density MLP: generated per configuration (codegen's SampleDensity).
//#generated

@group(0) @binding(3) var<storage, read> samples: array<Sample>;
@group(0) @binding(4) var<storage, read> count: array<u32>;
@group(0) @binding(5) var<storage, read_write> out_rgb_density: array<vec4<f32>>;

@compute @workgroup_size(WG_SIZE)
fn sample_density(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    P = P_buffer;
    load_shared_weights(li);
    // No early return (see grid_forward.wgsl): threads past the count evaluate the last
    // sample again and write nothing.
    let n_valid = min(count[0], P.n);
    let t = thread_index(gid, nwg);
    let i = min(t, max(n_valid, 1u) - 1u);
    let up = to_unit(samples[i].pos);
    var e: Vec64;
    var jac: Jac64;
    encode(up.p, false, &e, &jac);
    var a1: Vec64;
    density_hidden(&e, &a1);
    let sigma = select(0.0, density_act(density_h0(&a1)), up.inside);
    if (t < n_valid) {
        out_rgb_density[i] = vec4<f32>(0.0, 0.0, 0.0, sigma);
    }
}
