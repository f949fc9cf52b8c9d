//! `f64` CPU reference of the MLP field's forward pass (encoding, trunk, heads and the
//! analytic normal through forward-mode tangents), following the module doc of
//! [`mlp`](super) line by line. The tests compare the GPU kernels with it and its
//! normals and parameter gradients with central finite differences.

use super::gemm::Dense;
use super::{Footprint, MlpConfig, MlpLayout, PositionEncoding};

/// The field's outputs at one sample.
#[derive(Clone, Debug, PartialEq)]
pub struct Trace {
    pub sigma: f64,
    pub rgb: [f64; 3],
    pub normal: [f64; 3],
}

/// Parameters and settings of an [`MlpField`](super::MlpField), on the host.
#[derive(Clone, Debug)]
pub struct MlpModel {
    pub config: MlpConfig,
    pub layout: MlpLayout,
    pub center: [f64; 3],
    pub scale: f64,
    pub footprint: Footprint,
    pub active_bands: u32,
    pub params: Vec<f64>,
}

fn softplus(x: f64) -> f64 {
    x.max(0.0) + (-x.abs()).exp().ln_1p()
}

fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

impl MlpModel {
    /// `W x (+ b)`.
    fn dense(&self, d: Dense, x: &[f64], bias: bool) -> Vec<f64> {
        assert_eq!(x.len(), d.n_in as usize);
        (0..d.n_out as usize)
            .map(|o| {
                let row = &self.params[d.w_off as usize + o * d.n_in as usize..][..d.n_in as usize];
                let b = if bias { self.params[d.bias_off() as usize + o] } else { 0.0 };
                b + row.iter().zip(x).map(|(w, v)| w * v).sum::<f64>()
            })
            .collect()
    }

    /// Diagonal covariance of a sample's conical frustum in normalized space.
    pub fn frustum_var(&self, t: f64, dt: f64, dir: [f64; 3]) -> [f64; 3] {
        let (mu, hw) = (t, 0.5 * dt);
        let (mu2, hw2) = (mu * mu, hw * hw);
        let den = 3.0 * mu2 + hw2;
        let t_var = hw2 / 3.0 - (4.0 / 15.0) * (hw2 * hw2 * (12.0 * mu2 - hw2)) / (den * den);
        let (r0, r1) = (self.footprint.radius0 as f64, self.footprint.radius1 as f64);
        let r_var = r1 * r1 * (mu2 / 4.0 + (5.0 / 12.0) * hw2 - (4.0 / 15.0) * hw2 * hw2 / den) + 0.25 * r0 * r0;
        let dn = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).max(1e-10);
        dir.map(|d| (t_var * d * d + r_var * (1.0 - d * d / dn)).max(0.0) * self.scale * self.scale)
    }

    /// The position encoding of the normalized point `p` and its derivatives along
    /// each axis (the variance held fixed).
    pub fn encode(&self, p: [f64; 3], var: [f64; 3]) -> (Vec<f64>, [Vec<f64>; 3]) {
        let c = &self.config;
        let ipe = c.encoding == PositionEncoding::Integrated;
        let dim = c.pos_dim() as usize;
        let mut e = vec![0.0; dim];
        let mut t = [vec![0.0; dim], vec![0.0; dim], vec![0.0; dim]];
        let mut col = 0;
        if !ipe {
            for d in 0..3 {
                e[d] = p[d];
                t[d][d] = 1.0;
            }
            col = 3;
        }
        let bands = c.pos_bands() as usize;
        let half = 3 * bands;
        for k in 0..bands {
            let f = 2f64.powi((c.pos_min_deg as usize + k) as i32);
            for d in 0..3 {
                let y = f * p[d];
                let mut att = if ipe { (-0.5 * f * f * var[d]).exp() } else { 1.0 };
                if k as u32 >= self.active_bands {
                    att = 0.0;
                }
                let cs = col + 3 * k + d;
                e[cs] = y.sin() * att;
                e[cs + half] = y.cos() * att;
                t[d][cs] = f * y.cos() * att;
                t[d][cs + half] = -f * y.sin() * att;
            }
        }
        (e, t)
    }

    /// The direction encoding of `dir` (normalized first).
    pub fn encode_dir(&self, dir: [f64; 3]) -> Vec<f64> {
        let n = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt();
        let v = dir.map(|x| x / n);
        let deg = self.config.dir_max_deg as usize;
        let mut out = vec![0.0; 3 + 6 * deg];
        out[..3].copy_from_slice(&v);
        for k in 0..deg {
            let f = 2f64.powi(k as i32);
            for d in 0..3 {
                out[3 + 3 * k + d] = (f * v[d]).sin();
                out[3 + 3 * deg + 3 * k + d] = (f * v[d]).cos();
            }
        }
        out
    }

    /// Trunk output and its tangents for an encoding and its tangents.
    fn trunk(&self, e: &[f64], te: &[Vec<f64>; 3]) -> (Vec<f64>, [Vec<f64>; 3]) {
        let mut h = e.to_vec();
        let mut th = te.clone();
        for (l, layer) in self.layout.trunk.iter().enumerate() {
            if l > 0 && self.layout.skip == Some(l as u32) {
                h.extend_from_slice(e);
                for d in 0..3 {
                    th[d].extend_from_slice(&te[d]);
                }
            }
            let z = self.dense(*layer, &h, true);
            for d in 0..3 {
                let tz = self.dense(*layer, &th[d], false);
                th[d] = tz.iter().zip(&z).map(|(t, z)| if *z > 0.0 { *t } else { 0.0 }).collect();
            }
            h = z.into_iter().map(|z| z.max(0.0)).collect();
        }
        (h, th)
    }

    fn normalize(&self, pos: [f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|d| (pos[d] - self.center[d]) * self.scale)
    }

    /// Density (and its gradient in world space) at `pos` with encoding variance `var`.
    pub fn density_with_var(&self, pos: [f64; 3], var: [f64; 3]) -> (f64, [f64; 3], Vec<f64>) {
        let (e, te) = self.encode(self.normalize(pos), var);
        let (h, th) = self.trunk(&e, &te);
        let raw = self.dense(self.layout.density, &h, true)[0] + self.config.density_bias as f64;
        let s1 = sigmoid(raw);
        let grad = [0, 1, 2].map(|d| s1 * self.scale * self.dense(self.layout.density, &th[d], false)[0]);
        (softplus(raw), grad, h)
    }

    /// Density of a point query (isotropic `point_var`).
    pub fn density_at(&self, pos: [f64; 3]) -> f64 {
        self.density_with_var(pos, [self.footprint.point_var as f64 * self.scale * self.scale; 3]).0
    }

    /// Density, colour and unit normal of a sample.
    pub fn forward(&self, pos: [f64; 3], dir: [f64; 3], t: f64, dt: f64) -> Trace {
        let (sigma, u, h) = self.density_with_var(pos, self.frustum_var(t, dt, dir));
        let len = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
        let normal = if len > self.config.normal_eps as f64 { u.map(|v| -v / len) } else { [0.0; 3] };
        let mut cin = self.dense(self.layout.bottleneck, &h, true);
        cin.extend(self.encode_dir(dir));
        let c1: Vec<f64> = self.dense(self.layout.color, &cin, true).into_iter().map(|v| v.max(0.0)).collect();
        let o = self.dense(self.layout.rgb, &c1, true);
        Trace { sigma, rgb: [sigmoid(o[0]), sigmoid(o[1]), sigmoid(o[2])], normal }
    }
}
