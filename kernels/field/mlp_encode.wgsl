// Encoding of the MLP field (owner: engine/src/field/mlp/mod.rs): one thread per sample
// of a chunk. Writes the position encoding (and, with 4 streams, its derivative along
// each axis as rows 1..3 of the sample) into the trunk's input slot, and the direction
// encoding into the colour layer's input slot. `encode_samples` reads SampleBatch
// samples (frustum variance for IPE); `encode_points` reads density-query points
// (isotropic variance `point_var`; no direction).

//#include "field/mlp_lib.wgsl"

// Samples (2 vec4 each: pos, t | dir, dt) or points (xyz, w unused).
@group(0) @binding(1) var<storage, read> data: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> enc: array<f32>;
@group(0) @binding(3) var<storage, read_write> dir_enc: array<f32>;

// Diagonal covariance of the sample's conical frustum in the field's normalized space
// (mip-NeRF's conical_frustum_to_gaussian with the half-width dt/2, radius r0 + r1 t).
fn frustum_var(t: f32, dt: f32, dir: vec3<f32>) -> vec3<f32> {
    let mu = t;
    let hw = 0.5 * dt;
    let mu2 = mu * mu;
    let hw2 = hw * hw;
    let den = 3.0 * mu2 + hw2;
    let t_var = hw2 / 3.0 - (4.0 / 15.0) * (hw2 * hw2 * (12.0 * mu2 - hw2)) / (den * den);
    let r_var = P.radius1 * P.radius1 * (mu2 / 4.0 + (5.0 / 12.0) * hw2 - (4.0 / 15.0) * hw2 * hw2 / den)
        + 0.25 * P.radius0 * P.radius0;
    let d2 = dir * dir;
    let dn = max(dot(dir, dir), 1e-10);
    let cov = t_var * d2 + r_var * (vec3<f32>(1.0) - d2 / dn);
    return max(cov, vec3<f32>(0.0)) * (P.scale * P.scale);
}

fn write_position(s: u32, p: vec3<f32>, var3: vec3<f32>) {
    let S = P.streams;
    let ipe = (P.flags & FLAG_IPE) != 0u;
    var col = 0u;
    let row0 = (s * S) * P.enc_stride + P.enc_off;
    if (!ipe) {
        // Identity (plain PE only).
        for (var d = 0u; d < 3u; d++) {
            enc[row0 + d] = p[d];
            if (S == 4u) {
                for (var e = 0u; e < 3u; e++) {
                    enc[row0 + (e + 1u) * P.enc_stride + d] = select(0.0, 1.0, d == e);
                }
            }
        }
        col = 3u;
    }
    let half = 3u * P.pos_bands;
    for (var k = 0u; k < P.pos_bands; k++) {
        let f = exp2(f32(P.pos_min_deg + k));
        let on = k < P.active_bands;
        for (var d = 0u; d < 3u; d++) {
            let y = f * p[d];
            var att = 1.0;
            if (ipe) {
                att = exp(-0.5 * f * f * var3[d]);
            }
            if (!on) {
                att = 0.0;
            }
            let cs = col + 3u * k + d;
            enc[row0 + cs] = sin(y) * att;
            enc[row0 + cs + half] = cos(y) * att;
            if (S == 4u) {
                for (var e = 0u; e < 3u; e++) {
                    let r = row0 + (e + 1u) * P.enc_stride;
                    var ds = 0.0;
                    var dc = 0.0;
                    if (d == e) {
                        ds = f * cos(y) * att;
                        dc = -f * sin(y) * att;
                    }
                    enc[r + cs] = ds;
                    enc[r + cs + half] = dc;
                }
            }
        }
    }
}

fn write_direction(s: u32, dir: vec3<f32>) {
    let v = normalize(dir);
    let row = s * P.dir_stride + P.dir_off;
    for (var d = 0u; d < 3u; d++) {
        dir_enc[row + d] = v[d];
    }
    let half = 3u * P.dir_deg;
    for (var k = 0u; k < P.dir_deg; k++) {
        let f = exp2(f32(k));
        for (var d = 0u; d < 3u; d++) {
            dir_enc[row + 3u + 3u * k + d] = sin(f * v[d]);
            dir_enc[row + 3u + half + 3u * k + d] = cos(f * v[d]);
        }
    }
}

@compute @workgroup_size(WG_SIZE)
fn encode_samples(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    P = P_buffer;
    let s = thread_index(gid, nwg);
    if (s >= P.n) {
        return;
    }
    let a = data[2u * (P.chunk_start + s)];
    let b = data[2u * (P.chunk_start + s) + 1u];
    let p = (a.xyz - P.center) * P.scale;
    write_position(s, p, frustum_var(a.w, b.w, b.xyz));
    if ((P.flags & FLAG_COLOR) != 0u) {
        write_direction(s, b.xyz);
    }
}

@compute @workgroup_size(WG_SIZE)
fn encode_points(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    P = P_buffer;
    let s = thread_index(gid, nwg);
    if (s >= P.n) {
        return;
    }
    let p = (data[P.chunk_start + s].xyz - P.center) * P.scale;
    write_position(s, p, vec3<f32>(P.point_var) * (P.scale * P.scale));
}
