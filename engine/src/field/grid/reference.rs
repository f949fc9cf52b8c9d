//! CPU reference of the hash-grid field in `f64`: the same indexing, encoding, MLPs,
//! analytic normals and backward pass as the kernels (see the parent module doc for
//! the math), written plainly. Used only by tests: the GPU is compared with
//! [`GridModel::forward`] / [`GridModel::backward`], and those with central finite
//! differences of [`GridModel::forward`].
//!
//! Invariant: parameters are held in the GPU layout ([`GridLayout`]), so gradients
//! compare element by element with the GPU's gradient buffers.

use super::{DensityActivation, GridLayout, DENSITY_OUT};

/// The field on the CPU: layout, settings and a copy of the parameters.
#[derive(Clone, Debug)]
pub struct GridModel {
    pub layout: GridLayout,
    pub activation: DensityActivation,
    /// `[min, max]` of the box.
    pub aabb: [[f64; 3]; 2],
    pub active_levels: u32,
    pub normal_eps: f64,
    /// `beta_l` of every level in the analytic normal (one per level).
    pub normal_weights: Vec<f64>,
    /// Added to the density MLP's output before the activation.
    pub density_bias: f64,
    /// Highest spherical-harmonics band of the view direction (terms above it are 0).
    pub sh_degree: u32,
    /// 2 features per entry, entry-major.
    pub table: Vec<f64>,
    /// GPU layout, padding included.
    pub mlp: Vec<f64>,
}

/// One corner of one level: table entry, trilinear weight, weight gradient w.r.t. `f`.
#[derive(Clone, Copy, Debug)]
pub struct Corner {
    pub entry: usize,
    pub w: f64,
    pub dw: [f64; 3],
}

/// The encoding of one point.
#[derive(Clone, Debug)]
pub struct Encoding {
    /// Unit-cube position (clamped) and whether the point was inside the box.
    pub p: [f64; 3],
    pub inside: bool,
    /// `in_pad` features (zero for inactive levels and padding).
    pub e: Vec<f64>,
    /// `beta_l de_k/dx` (world units, `l = k / 2`), `in_dim` rows: the Jacobian of the
    /// normal path (the exact `de/dx` when every `beta_l` is 1).
    pub jac: Vec<[f64; 3]>,
    /// Per active level: its 8 corners (empty for inactive levels).
    pub corners: Vec<Vec<Corner>>,
}

/// Everything the forward pass computes for one sample.
#[derive(Clone, Debug)]
pub struct Trace {
    pub enc: Encoding,
    pub a1: Vec<f64>,
    /// Density MLP outputs (16); `h[0]` is the pre-activation density.
    pub h: Vec<f64>,
    pub sigma: f64,
    /// `[h, SH_4(dir)]`.
    pub xc: Vec<f64>,
    pub ac1: Vec<f64>,
    pub ac2: Vec<f64>,
    pub rgb: [f64; 3],
    /// `g = dh0/de` (`in_pad`).
    pub g: Vec<f64>,
    /// `v = J^T g` and `u = act'(h0) v` (zero outside the box), with the normal path's
    /// level-weighted `J`: `u = grad_x sigma` when every `beta_l` is 1.
    pub v: [f64; 3],
    pub u: [f64; 3],
    pub normal: [f64; 3],
}

/// Gradients in the GPU layout.
#[derive(Clone, Debug)]
pub struct Grads {
    pub table: Vec<f64>,
    pub mlp: Vec<f64>,
}

fn dot3(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Terms of the real spherical harmonics up to band `degree` (`(degree + 1)^2`; 16 at 3).
pub fn sh_terms(degree: u32) -> u32 {
    (degree + 1) * (degree + 1)
}

/// Real spherical harmonics of degree 4 (16 terms) of a direction (normalised here).
/// Constants as printed by tiny-cuda-nn.
#[allow(clippy::excessive_precision)]
pub fn sh4(dir: [f64; 3]) -> [f64; 16] {
    let len = dot3(dir, dir).sqrt();
    let [x, y, z] = if len > 0.0 { dir.map(|c| c / len) } else { [0.0, 0.0, 1.0] };
    let (xx, yy, zz) = (x * x, y * y, z * z);
    [
        0.28209479177387814,
        -0.48860251190291987 * y,
        0.48860251190291987 * z,
        -0.48860251190291987 * x,
        1.0925484305920792 * x * y,
        -1.0925484305920792 * y * z,
        0.94617469575755997 * zz - 0.31539156525251999,
        -1.0925484305920792 * x * z,
        0.54627421529603959 * (xx - yy),
        0.59004358992664352 * y * (yy - 3.0 * xx),
        2.8906114426405538 * x * y * z,
        0.45704579946446572 * y * (1.0 - 5.0 * zz),
        0.3731763325901154 * z * (5.0 * zz - 3.0),
        0.45704579946446572 * x * (1.0 - 5.0 * zz),
        1.4453057213202769 * z * (xx - yy),
        0.59004358992664352 * x * (3.0 * yy - xx),
    ]
}

impl GridModel {
    fn relu(x: &mut [f64]) {
        x.iter_mut().for_each(|v| *v = v.max(0.0));
    }

    /// `W x` for the matrix at float offset `off` with `rows` rows and row `stride`;
    /// `x.len()` columns are used.
    pub fn mat_vec(&self, off: usize, rows: usize, stride: usize, x: &[f64]) -> Vec<f64> {
        (0..rows).map(|r| x.iter().enumerate().map(|(c, xv)| self.mlp[off + r * stride + c] * xv).sum()).collect()
    }

    /// `W^T d` (`cols` outputs).
    pub fn mat_t_vec(&self, off: usize, cols: usize, stride: usize, d: &[f64]) -> Vec<f64> {
        (0..cols).map(|c| d.iter().enumerate().map(|(r, dv)| self.mlp[off + r * stride + c] * dv).sum()).collect()
    }

    pub fn act(&self, h0: f64) -> f64 {
        let h0 = h0 + self.density_bias;
        match self.activation {
            DensityActivation::TruncExp => h0.min(80.0).exp(),
            DensityActivation::Softplus => h0.max(0.0) + (-h0.abs()).exp().ln_1p(),
        }
    }
    pub fn act_d1(&self, h0: f64) -> f64 {
        let h0 = h0 + self.density_bias;
        match self.activation {
            DensityActivation::TruncExp => h0.clamp(-15.0, 15.0).exp(),
            DensityActivation::Softplus => 1.0 / (1.0 + (-h0).exp()),
        }
    }
    pub fn act_d2(&self, h0: f64) -> f64 {
        let h0 = h0 + self.density_bias;
        match self.activation {
            DensityActivation::TruncExp => h0.clamp(-15.0, 15.0).exp(),
            DensityActivation::Softplus => {
                let s = 1.0 / (1.0 + (-h0).exp());
                s * (1.0 - s)
            }
        }
    }

    /// Table entry of integer vertex `c` of level `l`.
    pub fn corner_entry(&self, l: usize, c: [u32; 3]) -> usize {
        let lv = &self.layout.levels[l];
        let idx = if lv.dense_res != 0 {
            let r = lv.dense_res;
            let c = c.map(|v| v.min(r - 1));
            c[0] + r * (c[1] + r * c[2])
        } else {
            (c[0] ^ c[1].wrapping_mul(2654435761) ^ c[2].wrapping_mul(805459861)) & (lv.size - 1)
        };
        (lv.offset + idx) as usize
    }

    /// Unit-cube position (clamped) and the inside flag.
    pub fn to_unit(&self, x: [f64; 3]) -> ([f64; 3], bool) {
        let mut p = [0.0; 3];
        let mut inside = true;
        for d in 0..3 {
            let q = (x[d] - self.aabb[0][d]) / (self.aabb[1][d] - self.aabb[0][d]);
            inside &= (0.0..=1.0).contains(&q);
            p[d] = q.clamp(0.0, 1.0);
        }
        (p, inside)
    }

    pub fn encode(&self, x: [f64; 3]) -> Encoding {
        self.encode_per_level(x, |_| x)
    }

    /// [`GridModel::encode`] with level `l` read at `at(l)` instead of `x` (`p`, the
    /// inside flag and the Jacobian's meaning stay those of `x`).
    fn encode_per_level(&self, x: [f64; 3], at: impl Fn(usize) -> [f64; 3]) -> Encoding {
        let (p, inside) = self.to_unit(x);
        let lay = &self.layout;
        let mut e = vec![0.0; lay.in_pad];
        let mut jac = vec![[0.0; 3]; lay.in_dim];
        let mut corners = Vec::new();
        for (l, lv) in lay.levels.iter().enumerate() {
            if l as u32 >= self.active_levels {
                corners.push(Vec::new());
                continue;
            }
            let s = lv.scale as f64;
            let pos = self.to_unit(at(l)).0.map(|v| v * s + 0.5);
            let fl = pos.map(f64::floor);
            let f = [pos[0] - fl[0], pos[1] - fl[1], pos[2] - fl[2]];
            let c0 = fl.map(|v| v as u32);
            let mut cs = Vec::with_capacity(8);
            for c in 0..8u32 {
                let bits = [c & 1, (c >> 1) & 1, (c >> 2) & 1];
                let wv: [f64; 3] = std::array::from_fn(|d| if bits[d] == 1 { f[d] } else { 1.0 - f[d] });
                let sg: [f64; 3] = bits.map(|b| if b == 1 { 1.0 } else { -1.0 });
                let w = wv[0] * wv[1] * wv[2];
                let dw = [sg[0] * wv[1] * wv[2], wv[0] * sg[1] * wv[2], wv[0] * wv[1] * sg[2]];
                let entry = self.corner_entry(l, [c0[0] + bits[0], c0[1] + bits[1], c0[2] + bits[2]]);
                for k in 0..2 {
                    let feat = self.table[2 * entry + k];
                    e[2 * l + k] += w * feat;
                    for d in 0..3 {
                        jac[2 * l + k][d] +=
                            dw[d] * feat * self.normal_weights[l] * s / (self.aabb[1][d] - self.aabb[0][d]);
                    }
                }
                cs.push(Corner { entry, w, dw });
            }
            corners.push(cs);
        }
        Encoding { p, inside, e, jac, corners }
    }

    /// Density MLP: `(a1, h)`.
    pub fn density_mlp(&self, e: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let lay = &self.layout;
        let mut a1 = self.mat_vec(lay.w1, lay.width, lay.in_pad, e);
        Self::relu(&mut a1);
        let h = self.mat_vec(lay.w2, DENSITY_OUT as usize, lay.width, &a1);
        (a1, h)
    }

    /// Colour MLP on `xc`: `(ac1, ac2, o)`.
    pub fn color_mlp(&self, xc: &[f64]) -> (Vec<f64>, Vec<f64>, [f64; 3]) {
        let lay = &self.layout;
        let mut ac1 = self.mat_vec(lay.c1, lay.width, 32, xc);
        Self::relu(&mut ac1);
        let mut ac2 = self.mat_vec(lay.c2, lay.width, lay.width, &ac1);
        Self::relu(&mut ac2);
        let o = self.mat_vec(lay.c3, 3, lay.width, &ac2);
        (ac1, ac2, [o[0], o[1], o[2]])
    }

    /// `g = W1^T (relu'(z1) * W2[0,:])`.
    pub fn density_dir(&self, a1: &[f64]) -> Vec<f64> {
        let lay = &self.layout;
        let q: Vec<f64> = (0..lay.width).map(|j| if a1[j] > 0.0 { self.mlp[lay.w2 + j] } else { 0.0 }).collect();
        self.mat_t_vec(lay.w1, lay.in_pad, lay.in_pad, &q)
    }

    /// Post-activation density at `x`.
    pub fn density(&self, x: [f64; 3]) -> f64 {
        let enc = self.encode(x);
        if !enc.inside {
            return 0.0;
        }
        let (_, h) = self.density_mlp(&enc.e);
        self.act(h[0])
    }

    /// Density at `x` with level `l` of the encoding read at `x + beta_l dx`: its
    /// gradient in `dx` at `dx = 0` is the normal path's `u = act'(h0) sum_l beta_l
    /// J_l^T g_l` (the density gradient when every `beta_l` is 1), which the tests
    /// check with central differences.
    pub fn density_level_shifted(&self, x: [f64; 3], dx: [f64; 3]) -> f64 {
        let enc = self.encode_per_level(x, |l| std::array::from_fn(|d| x[d] + self.normal_weights[l] * dx[d]));
        if !enc.inside {
            return 0.0;
        }
        let (_, h) = self.density_mlp(&enc.e);
        self.act(h[0])
    }

    /// The full forward pass of one sample (normal always computed).
    pub fn forward(&self, x: [f64; 3], dir: [f64; 3]) -> Trace {
        let enc = self.encode(x);
        let (a1, h) = self.density_mlp(&enc.e);
        let sigma = if enc.inside { self.act(h[0]) } else { 0.0 };
        let mut xc = h.clone();
        let terms = sh_terms(self.sh_degree) as usize;
        xc.extend(sh4(dir).iter().enumerate().map(|(i, v)| if i < terms { *v } else { 0.0 }));
        let (ac1, ac2, o) = self.color_mlp(&xc);
        let rgb = o.map(|v| 1.0 / (1.0 + (-v).exp()));
        let g = self.density_dir(&a1);
        let mut v = [0.0; 3];
        let mut u = [0.0; 3];
        let mut normal = [0.0; 3];
        if enc.inside {
            for (k, j) in enc.jac.iter().enumerate() {
                for d in 0..3 {
                    v[d] += g[k] * j[d];
                }
            }
            let s1 = self.act_d1(h[0]);
            u = v.map(|c| c * s1);
            let len = dot3(u, u).sqrt();
            if len > self.normal_eps {
                normal = u.map(|c| -c / len);
            }
        }
        Trace { enc, a1, h, sigma, xc, ac1, ac2, rgb, g, v, u, normal }
    }

    /// Zero gradients in this model's layout.
    pub fn zero_grads(&self) -> Grads {
        Grads { table: vec![0.0; self.table.len()], mlp: vec![0.0; self.mlp.len()] }
    }

    /// Adds the gradients of `L` for one sample with output gradients `dsigma`, `drgb`,
    /// `dn` (the normal path only when `normal_grads`).
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        x: [f64; 3],
        dir: [f64; 3],
        dsigma: f64,
        drgb: [f64; 3],
        dn: [f64; 3],
        normal_grads: bool,
        grads: &mut Grads,
    ) {
        let lay = &self.layout;
        let w = lay.width;
        let t = self.forward(x, dir);
        let h0 = t.h[0];
        // Colour MLP.
        let d_o: Vec<f64> = (0..3).map(|c| drgb[c] * t.rgb[c] * (1.0 - t.rgb[c])).collect();
        let mut dc2 = self.mat_t_vec(lay.c3, w, w, &d_o);
        dc2.iter_mut().zip(&t.ac2).for_each(|(d, a)| *d = if *a > 0.0 { *d } else { 0.0 });
        let mut dc1 = self.mat_t_vec(lay.c2, w, w, &dc2);
        dc1.iter_mut().zip(&t.ac1).for_each(|(d, a)| *d = if *a > 0.0 { *d } else { 0.0 });
        let dxc = self.mat_t_vec(lay.c1, 32, 32, &dc1);
        outer_add(&mut grads.mlp, lay.c3, w, &d_o, &t.ac2);
        outer_add(&mut grads.mlp, lay.c2, w, &dc2, &t.ac1);
        outer_add(&mut grads.mlp, lay.c1, 32, &dc1, &t.xc);
        let mut dh: Vec<f64> = dxc[..DENSITY_OUT as usize].to_vec();
        // Density.
        let mut dh0 = if t.enc.inside { dsigma * self.act_d1(h0) } else { 0.0 };
        let mut dv = [0.0; 3];
        let mut dg = vec![0.0; lay.in_pad];
        let ulen = dot3(t.u, t.u).sqrt();
        if normal_grads && t.enc.inside && ulen > self.normal_eps {
            let n = t.normal;
            let nc = dot3(n, dn);
            let du: [f64; 3] = std::array::from_fn(|d| -(dn[d] - n[d] * nc) / ulen);
            let s1 = self.act_d1(h0);
            dv = du.map(|c| c * s1);
            dh0 += self.act_d2(h0) * dot3(t.v, du);
            for (g, j) in dg.iter_mut().zip(&t.enc.jac) {
                *g = dot3(*j, dv);
            }
            // dW1 += (m * W2[0,:]) (x) dg;  dW2[0,j] += m_j (W1 dg)_j
            let w1dg = self.mat_vec(lay.w1, w, lay.in_pad, &dg);
            for (j, (a, w1dg_j)) in t.a1.iter().zip(&w1dg).enumerate() {
                if *a > 0.0 {
                    let w20 = self.mlp[lay.w2 + j];
                    let row = lay.w1 + j * lay.in_pad;
                    grads.mlp[row..row + lay.in_pad].iter_mut().zip(&dg).for_each(|(gw, d)| *gw += w20 * d);
                    grads.mlp[lay.w2 + j] += w1dg_j;
                }
            }
        }
        dh[0] += dh0;
        let mut d1 = self.mat_t_vec(lay.w2, w, w, &dh);
        d1.iter_mut().zip(&t.a1).for_each(|(d, a)| *d = if *a > 0.0 { *d } else { 0.0 });
        outer_add(&mut grads.mlp, lay.w2, w, &dh, &t.a1);
        outer_add(&mut grads.mlp, lay.w1, lay.in_pad, &d1, &t.enc.e);
        let de = self.mat_t_vec(lay.w1, lay.in_pad, lay.in_pad, &d1);
        // Hash features.
        for (l, cs) in t.enc.corners.iter().enumerate() {
            let s = lay.levels[l].scale as f64;
            let sdv: [f64; 3] =
                std::array::from_fn(|d| dv[d] * self.normal_weights[l] * s / (self.aabb[1][d] - self.aabb[0][d]));
            for c in cs {
                for k in 0..2 {
                    grads.table[2 * c.entry + k] += c.w * de[2 * l + k] + t.g[2 * l + k] * dot3(c.dw, sdv);
                }
            }
        }
    }
}

/// `grad[off + r * stride + c] += d[r] x[c]`.
fn outer_add(grad: &mut [f64], off: usize, stride: usize, d: &[f64], x: &[f64]) {
    for (r, dv) in d.iter().enumerate() {
        for (c, xv) in x.iter().enumerate() {
            grad[off + r * stride + c] += dv * xv;
        }
    }
}
