// Hash-grid field forward (owner: engine/src/field/grid/mod.rs): one thread per sample
// of a SampleBatch, dispatched over its capacity, returning past count[0]. Writes the
// sigmoid colour and the post-activation density packed as (r, g, b, sigma) and, with FLAG_NORMALS, the unit normal
// n = -grad_x sigma / |grad_x sigma| from the analytic gradient (zero when
// |grad_x sigma| <= normal_eps or outside the AABB).

//#include "field/grid_lib.wgsl"

@group(0) @binding(3) var<storage, read> samples: array<Sample>;
@group(0) @binding(4) var<storage, read> count: array<u32>;
@group(0) @binding(5) var<storage, read_write> out_rgb_density: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> out_normal: array<vec4<f32>>;

@compute @workgroup_size(WG_SIZE)
fn forward(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    P = P_buffer;
    let i = thread_index(gid, nwg);
    if (i >= min(count[0], P.n)) {
        return;
    }
    let smp = samples[i];
    let up = to_unit(smp.pos);
    let normals = (P.flags & FLAG_NORMALS) != 0u;
    let want_jac = normals && up.inside;
    var e: Vec64;
    var jac: Jac64;
    encode(up.p, want_jac, &e, &jac);
    var a1: Vec64;
    var xc: Vec64;
    density_mlp(&e, &a1, &xc);
    let h0 = xc[0].x;
    var sigma = 0.0;
    if (up.inside) {
        sigma = density_act(h0);
    }

    sh_encode(smp.dir, &xc);
    var ac1: Vec64;
    var ac2: Vec64;
    let o = color_mlp(&xc, &ac1, &ac2);
    out_rgb_density[i] = vec4<f32>(sigmoid3(o), sigma);

    if (normals) {
        var n = vec3<f32>(0.0);
        if (want_jac) {
            var g: Vec64;
            density_dir(&a1, &g);
            let u = density_act_d1(h0) * jac_t_vec(&g, &jac);
            let len = length(u);
            if (len > P.normal_eps) {
                n = -u / len;
            }
        }
        out_normal[i] = vec4<f32>(n, 0.0);
    }
}
