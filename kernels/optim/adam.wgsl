// Adam step over one parameter group (owner: engine/src/optim/adam.rs, which
// documents the formulas). One invocation per parameter, element-wise, no atomics.
//
//   g  = grad                                  (skip the element when sparse and g == 0)
//   g  = clamp(g, -c, c) * scale               (from the stats buffer, unless applied)
//   g += wd * w                                (L2 weight decay)
//   m  = b1 m + (1 - b1) g ;  v = b2 v + (1 - b2) g^2
//   w -= lr wd w                               (decoupled weight decay, old w)
//   w -= lr (m / bias1) / (sqrt(v / bias2) + eps)

//#include "common/dispatch.wgsl"
//#include "optim/grad_stats.wgsl"

struct AdamParams {
    n: u32,
    flags: u32,
    lr: f32,
    beta1: f32,
    beta2: f32,
    eps: f32,
    // 1 - beta1^t and 1 - beta2^t, computed on the host in f64.
    bias1: f32,
    bias2: f32,
    weight_decay: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

const FLAG_SKIP_ZERO_GRAD: u32 = 1u;
const FLAG_L2: u32 = 2u;
const FLAG_DECOUPLED: u32 = 4u;
const FLAG_SKIP_NONFINITE: u32 = 8u;

@group(0) @binding(0) var<storage, read> cfg: AdamParams;
@group(0) @binding(1) var<storage, read_write> weights: array<f32>;
@group(0) @binding(2) var<storage, read> grads: array<f32>;
@group(0) @binding(3) var<storage, read_write> moment1: array<f32>;
@group(0) @binding(4) var<storage, read_write> moment2: array<f32>;
@group(0) @binding(5) var<storage, read> stats: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn adam_step(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    // Every uniform read first, outside any branch: on lavapipe a storage read at a
    // uniform address is one broadcast load there, and a per-lane load under the
    // execution mask a divergent branch leaves behind (grid_forward.wgsl).
    let c = cfg;
    let nonfinite = stats[STAT_NONFINITE];
    let applied = stats[STAT_APPLIED];
    let clip_value = stats[STAT_CLIP_VALUE];
    let scale = stats[STAT_SCALE];
    let guard = stats[STAT_GUARD];
    let i = thread_index(gid, nwg);
    // A non-finite loss skips the step whatever the flags (grad_stats.wgsl).
    if (i >= c.n || guard > 0.0) {
        return;
    }
    if ((c.flags & FLAG_SKIP_NONFINITE) != 0u && nonfinite > 0.0) {
        return;
    }
    var g = grads[i];
    if ((c.flags & FLAG_SKIP_ZERO_GRAD) != 0u && g == 0.0) {
        return;
    }
    if (applied == 0.0) {
        if (clip_value > 0.0) {
            g = clamp(g, -clip_value, clip_value);
        }
        g = g * scale;
    }
    var w = weights[i];
    if ((c.flags & FLAG_L2) != 0u) {
        g = g + c.weight_decay * w;
    }
    let m = c.beta1 * moment1[i] + (1.0 - c.beta1) * g;
    let v = c.beta2 * moment2[i] + (1.0 - c.beta2) * (g * g);
    moment1[i] = m;
    moment2[i] = v;
    let m_hat = m / c.bias1;
    let v_hat = v / c.bias2;
    var w_new = w - c.lr * (m_hat / (sqrt(v_hat) + c.eps));
    if ((c.flags & FLAG_DECOUPLED) != 0u) {
        w_new = w_new - c.lr * c.weight_decay * w;
    }
    weights[i] = w_new;
}
