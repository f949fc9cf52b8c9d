// Hash-grid field density queries (owner: engine/src/field/grid/mod.rs), for the
// occupancy grid: one thread per point (xyz of a vec4, w ignored), P.n points; writes
// the post-activation density (zero outside the AABB). Only the first output of the
// density MLP is evaluated.

//#include "field/grid_lib.wgsl"

@group(0) @binding(3) var<storage, read> points: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> out_density: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn density(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    P = P_buffer;
    let i = thread_index(gid, nwg);
    if (i >= P.n) {
        return;
    }
    let up = to_unit(points[i].xyz);
    var sigma = 0.0;
    if (up.inside) {
        var e: Vec64;
        var jac: Jac64;
        encode(up.p, false, &e, &jac);
        var a1: Vec64;
        mat_vec(P.w1, P.width4, P.in4, &e, &a1);
        relu_in_place(&a1, P.width4);
        sigma = density_act(density_h0(&a1));
    }
    out_density[i] = sigma;
}
