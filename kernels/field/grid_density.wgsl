// Hash-grid field density queries (owner: engine/src/field/grid/mod.rs), for the
// occupancy grid: one thread per point (xyz of a vec4, w ignored), P.n points; writes
// the post-activation density (zero outside the AABB). Only the first output of the
// density MLP is evaluated.

//#include "field/grid_lib.wgsl"
// encode, the MLP products and the other vector code: generated per configuration.
//#generated

@group(0) @binding(3) var<storage, read> points: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> out_density: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn density(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    P = P_buffer;
    load_shared_weights(li);
    // No early return (see grid_forward.wgsl): threads past P.n evaluate the last point
    // again and write nothing.
    let t = thread_index(gid, nwg);
    let i = min(t, max(P.n, 1u) - 1u);
    let up = to_unit(points[i].xyz);
    var e: Vec64;
    var jac: Jac64;
    encode(up.p, false, &e, &jac);
    var a1: Vec64;
    density_hidden(&e, &a1);
    let sigma = select(0.0, density_act(density_h0(&a1)), up.inside);
    if (t < P.n) {
        out_density[i] = sigma;
    }
}
