// Hash-grid field forward (owner: engine/src/field/grid/mod.rs): one thread per sample
// of a SampleBatch, dispatched over its capacity, returning past count[0]. Writes the
// sigmoid colour and the post-activation density packed as (r, g, b, sigma) and, with FLAG_NORMALS, the unit normal
// n = -grad_x sigma / |grad_x sigma| from the analytic gradient (zero when
// |grad_x sigma| <= normal_eps or outside the AABB). The variant of a training step
// (codegen's ForwardKeep) also writes each sample's encoding and normal Jacobian to the
// backward's scratch buffer (binding 7, declared by the generated code), which the
// backward then reads instead of gathering them from the table again.

//#include "field/grid_lib.wgsl"
// encode, the MLP products and the other vector code: generated per configuration.
//#generated

@group(0) @binding(3) var<storage, read> samples: array<Sample>;
@group(0) @binding(4) var<storage, read> count: array<u32>;
@group(0) @binding(5) var<storage, read_write> out_rgb_density: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> out_normal: array<vec4<f32>>;

@compute @workgroup_size(WG_SIZE)
fn forward(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    P = P_buffer;
    load_shared_weights(li);
    // No early return: threads past the count compute the last sample again and write
    // nothing. Code after a divergent return runs under an execution mask on lavapipe,
    // where every weight read then becomes a per-lane gather instead of one broadcast
    // load (the MLPs ran 2x slower).
    let n_valid = min(count[0], P.n);
    let t = thread_index(gid, nwg);
    let valid = t < n_valid;
    let i = min(t, max(n_valid, 1u) - 1u);
    let smp = samples[i];
    let up = to_unit(smp.pos);
    let normals = (P.flags & FLAG_NORMALS) != 0u;
    let want_jac = normals && up.inside;
    var e: Vec64;
    var jac: Jac64;
    encode(up.p, want_jac, &e, &jac);
    // The training step's variant keeps e and the Jacobian for the backward (a no-op
    // otherwise; generated).
    keep_encoding(i, valid, &e, &jac);
    var a1: Vec64;
    var xc: Vec64;
    density_mlp(&e, &a1, &xc);
    let h0 = xc[0].x;
    let sigma = select(0.0, density_act(h0), up.inside);

    sh_encode(smp.dir, &xc);
    var ac1: Vec64;
    var ac2: Vec64;
    let o = color_mlp(&xc, &ac1, &ac2);
    if (valid) {
        out_rgb_density[i] = vec4<f32>(sigmoid3(o), sigma);
    }

    // g = dh0/de at the top level, outside the branches: the generated product reads
    // its weights from workgroup memory only there (codegen.rs, "Weights in workgroup
    // memory"); without normals it is unused.
    var g: Vec64;
    density_dir(&a1, &g);
    if (normals) {
        var n = vec3<f32>(0.0);
        if (want_jac) {
            let u = density_act_d1(h0) * jac_t_vec(&g, &jac);
            let len = length(u);
            if (len > P.normal_eps) {
                n = -u / len;
            }
        }
        if (valid) {
            out_normal[i] = vec4<f32>(n, 0.0);
        }
    }
}
