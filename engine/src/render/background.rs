//! A learned background for captures without alpha: what a ray that leaves the scene
//! box sees, as a function of its direction (or of where it crosses a shell around the
//! box), trained with the field.
//!
//! Photographs have no alpha: whatever lies beyond the field's box (DTU's backdrop, a
//! room behind an object, the white a capture was composited on) must be explained by
//! something. With a fixed black background the only explanation the field has is
//! fog inside the box, in front of the object. [`LearnedBackground`] gives those rays
//! a colour of their own: a multiresolution equirectangular map of the ray direction
//! (`levels` maps of `h x 2h` texels, `h` from `finest_height / 4^(levels-1)` up to
//! `finest_height`), whose bilinear lookups are summed and passed through a sigmoid,
//! `bg(d) = sigmoid(sum_l bilerp(M_l, uv(d)))`. By default one coarse map of 4 x 8
//! texels: a smooth function of direction (a dark backdrop above, a bright table
//! below), too coarse to learn each camera's view of the object in the directions only
//! that camera looks through. (A direction-only background cannot show parallax; what is
//! near enough to move between views stays the field's to explain, as in Instant-NGP
//! and nerfacto.) Before training, [`LearnedBackground::prefit`] fits it to the frames
//! of the training images, which mostly show background in object-centric captures;
//! `prefit` limits it to the coarsest map or turns it off (inside-out captures, where
//! the frames show the room's furniture and a start from them leaves the floor and
//! walls to the map instead of the field).
//!
//! The map lives on the host: the renderer reads each ray's background from
//! [`crate::layout::RayAux::background`], which the caller fills with
//! [`LearnedBackground::colors`] before the forward pass (`Background::Learned`), and
//! training reads back the photometric rays' `dL/d rgb` and opacity to form the map's
//! gradient, `dL/d bg = (1 - opacity) dL/d rgb` (the forward writes
//! `rgb = sum w c + (1 - opacity) bg`), through the sigmoid and the bilinear weights
//! ([`LearnedBackground::step`], on the host: a few hundred thousand values; each
//! direction's texture coordinates are found once for all maps, the rays in parallel,
//! the gradient scattered in the rays' order, so a run does not depend on the core
//! count: at 16384 rays a step on an H200, `room`'s host work a step fell from 12.4 to
//! 5.5 ms). The step is Adam's with a floor under its denominator, a tenth of its map's
//! largest, so a texel with faint evidence moves in proportion to it; the prefit is a splat
//! (weighted means, no overshoot), whose finer maps are then sharpened toward a
//! least-squares fit. Both keep a texel that no ray sees unoccluded from drifting to a
//! colour no view shows (docs/results/real-captures.md, "The background's texels").
//!
//! Direction to texture: `u = atan2(d.y, d.x) / 2 pi + 1/2` (wrapping), `v =
//! acos(d.z) / pi` (clamped at the poles); texel centres at `(i + 1/2) / w`.
//!
//! **The shell** (`shell_radius > 1`): the map lies on a sphere around the box, and a
//! ray reads it in the direction from the sphere's centre to where the ray leaves the
//! sphere ([`LearnedBackground::lookup_dir`]; the callers map every ray through it before
//! [`LearnedBackground::colors`] and [`LearnedBackground::step`]). A backdrop at a
//! finite distance then shows parallax between views, so a finer map can hold it
//! without being each camera's own picture of the object.
//!
//! Invariants: [`LearnedBackground::prefit`] leaves each texel of the coarsest map
//! within the colours that reach it and the median (a test checks it);
//! [`LearnedBackground::colors`] is a pure function of the parameters and the
//! directions; the gradient of [`LearnedBackground::step`] is the exact derivative of
//! `sum_r <g_r, bg(d_r)>` (a finite-difference test checks it).

use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Directions a thread takes at least, in the parallel lookups and gradient (a
/// training step's batch of 1024 rays splits in a few parts; an evaluation chunk in
/// many).
const PAR_MIN_RAYS: usize = 256;

/// Settings of the learned background (`render.learned_background`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LearnedBackgroundConfig {
    /// Maps of `h x 2h` texels, the finest `finest_height` high, each coarser one a
    /// quarter of the next.
    pub levels: u32,
    /// Height (latitude texels) of the finest map. The default map (one of 4 x 8
    /// texels, 45 degrees each) is deliberately coarse: cameras around an object look
    /// at it through directions no other camera uses, so a fine map learns each view's
    /// image of the object as "background" (measured: docs/results/real-captures.md).
    pub finest_height: u32,
    /// The map's Adam learning rate is the field's schedule times this.
    pub lr_scale: f32,
    /// The background every direction starts at, in `(0, 1)`, where no
    /// [`LearnedBackground::prefit`] runs (renders of a map that was never trained).
    pub init: f32,
    /// Where the map lies: 0 (the default) at infinity, read by the ray's direction;
    /// `r > 1`: on a sphere about the box's centre of radius `r` times the box's half
    /// diagonal, read by the direction from the centre to where the ray leaves that
    /// sphere ([`LearnedBackground::lookup_dir`]): a backdrop at a finite distance, with
    /// parallax between views (NeRF++'s outer sphere, as one textured shell).
    pub shell_radius: f32,
    /// The shell's shape (with `shell_radius` > 0): `sphere` (the default), or `box`:
    /// the scene box scaled by `shell_radius` (1 or more) about its centre, read by the
    /// direction from the centre to where the ray leaves that box. For captures whose
    /// box is bounded by what the photos show behind everything (a room's walls and
    /// floor): the map is then a texture on those surfaces, at the right distance from
    /// every camera, including cameras inside the box.
    pub shell_shape: ShellShape,
    /// Which maps [`LearnedBackground::prefit`] starts from the training frames:
    /// `all` (the default), `coarsest` (the finer maps start at 0, their detail left
    /// to training), or `none` (every direction starts at `init`).
    pub prefit: Prefit,
}

/// [`LearnedBackgroundConfig::prefit`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Prefit {
    #[default]
    All,
    Coarsest,
    None,
}

/// [`LearnedBackgroundConfig::shell_shape`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ShellShape {
    #[default]
    Sphere,
    Box,
}

impl Default for LearnedBackgroundConfig {
    fn default() -> Self {
        Self { levels: 1, finest_height: 4, lr_scale: 1.0, init: 0.5, shell_radius: 0.0, shell_shape: ShellShape::Sphere, prefit: Prefit::All }
    }
}

impl LearnedBackgroundConfig {
    pub fn validate(&self) -> Result<(), String> {
        if !(1..=6).contains(&self.levels) {
            return Err(format!("render.learned_background.levels = {} must be 1 to 6", self.levels));
        }
        let coarsest = self.finest_height >> (2 * (self.levels - 1));
        if !(2..=1024).contains(&self.finest_height) || coarsest < 1 {
            return Err(format!(
                "render.learned_background.finest_height = {} must be 2 to 1024, with at least 2 texels in the coarsest of its {} maps",
                self.finest_height, self.levels
            ));
        }
        if !(self.lr_scale.is_finite() && self.lr_scale >= 0.0) {
            return Err(format!("render.learned_background.lr_scale = {} must be finite and >= 0", self.lr_scale));
        }
        match self.shell_shape {
            ShellShape::Sphere if !(self.shell_radius == 0.0 || (self.shell_radius > 1.0 && self.shell_radius <= 1000.0)) => {
                return Err(format!(
                    "render.learned_background.shell_radius = {}: 0 (at infinity) or above 1 (outside the box), at most 1000",
                    self.shell_radius
                ));
            }
            ShellShape::Box if !(self.shell_radius >= 1.0 && self.shell_radius <= 1000.0) => {
                return Err(format!(
                    "render.learned_background.shell_radius = {} with shell_shape = \"box\": the box's scale about its centre, 1 (the scene box itself) to 1000",
                    self.shell_radius
                ));
            }
            _ => {}
        }
        if !(self.init > 0.0 && self.init < 1.0) {
            return Err(format!("render.learned_background.init = {} must lie in (0, 1)", self.init));
        }
        Ok(())
    }

    /// `(height, width)` of each map, coarsest first.
    fn sizes(&self) -> Vec<(usize, usize)> {
        (0..self.levels)
            .map(|l| {
                let h = (self.finest_height >> (2 * (self.levels - 1 - l))) as usize;
                (h, 2 * h)
            })
            .collect()
    }
}

/// Adam's moment decay rates and epsilon for the map.
const BETA1: f32 = 0.9;
const BETA2: f32 = 0.99;
const EPS: f32 = 1e-8;
/// [`LearnedBackground::step`]: the floor of Adam's denominator, relative to the map's
/// largest (see there). Chosen on the val views of `creases`, `thin` and `turntable` on
/// white and DTU scan 24 with 3 views (with 9 DTU views the splat start and this floor
/// lost 0.5 dB on the val views until the finer maps were sharpened after their splat:
/// docs/results/real-captures.md).
const RELATIVE_FLOOR: f32 = 0.1;

/// [`LearnedBackground::prefit`]: how many pixels' worth of weight the prior (the
/// median colour, or no change for the finer maps) has in each texel's mean. A texel
/// that a few directions graze with small bilinear weights stays near the prior.
const PREFIT_PRIOR_WEIGHT: f64 = 1.0;

/// [`LearnedBackground::prefit`]: rounds of least squares (SART) that sharpen each
/// finer map after its splat ([`LearnedBackground::sharpen`]). Chosen on DTU scan 24's
/// val views (9 views: 16.94 dB masked against 16.26 with the splat alone).
const PREFIT_SHARPEN_ROUNDS: usize = 30;

/// Checkpoint tensor names.
pub const LOGITS: &str = "background.logits";
const ADAM_M: &str = "background.adam_m";
const ADAM_V: &str = "background.adam_v";
const ADAM_T: &str = "background.adam_t";

/// The learned background (see the module doc).
#[derive(Clone, Debug)]
pub struct LearnedBackground {
    config: LearnedBackgroundConfig,
    /// The shell in the field's space (`config.shell_radius` > 0).
    shell: Option<Shell>,
    /// Per map: offset of its first texel (RGB triples) in `logits`, height, width.
    maps: Vec<(usize, usize, usize)>,
    /// Pre-sigmoid values, 3 per texel, the maps one after the other (row-major, `v`
    /// rows of `u` texels).
    logits: Vec<f32>,
    m: Vec<f32>,
    v: Vec<f32>,
    t: u32,
}

/// Where [`LearnedBackground`]'s map lies, in the field's space.
#[derive(Clone, Copy, Debug)]
enum Shell {
    /// A sphere: centre and radius.
    Sphere(Vec3, f32),
    /// A box: centre and half extents.
    Box(Vec3, Vec3),
}

/// A direction's texture coordinates ([`uv`]) and `dL/d logit` there.
type TexelGrad = ((f32, f32), [f32; 3]);

/// Where direction `d` (need not be unit length) reads the maps: `(u, v)` in `[0, 1]`
/// (u wrapping), the same for every map (module doc).
fn uv(d: [f32; 3]) -> (f32, f32) {
    let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-20);
    let z = (d[2] / len).clamp(-1.0, 1.0);
    (d[1].atan2(d[0]) / std::f32::consts::TAU + 0.5, z.acos() / std::f32::consts::PI)
}

/// The texels and bilinear weights of one direction in one map.
fn taps(d: [f32; 3], h: usize, w: usize) -> [(usize, f32); 4] {
    taps_at(uv(d), h, w)
}

/// [`taps`] of a direction's [`uv`]: what every map's lookup of one direction shares
/// is computed once (module doc).
fn taps_at((u, v): (f32, f32), h: usize, w: usize) -> [(usize, f32); 4] {
    let x = u * w as f32 - 0.5;
    let y = (v * h as f32 - 0.5).clamp(0.0, (h - 1) as f32);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let col = |i: f32| (i as i64).rem_euclid(w as i64) as usize;
    let (c0, c1) = (col(x0), col(x0 + 1.0));
    let r0 = y0 as usize;
    let r1 = (r0 + 1).min(h - 1);
    [
        (r0 * w + c0, (1.0 - fx) * (1.0 - fy)),
        (r0 * w + c1, fx * (1.0 - fy)),
        (r1 * w + c0, (1.0 - fx) * fy),
        (r1 * w + c1, fx * fy),
    ]
}

/// Where the ray `o + t d` (`o` relative to the box's centre) leaves the box of half
/// extents `half`, if it crosses it ahead of `o` (`t > 0`).
fn box_exit(o: Vec3, d: Vec3, half: Vec3) -> Option<Vec3> {
    let (mut t_in, mut t_out) = (f32::NEG_INFINITY, f32::INFINITY);
    for k in 0..3 {
        if d[k] == 0.0 {
            // Parallel to this slab: inside it throughout, or never.
            if o[k].abs() > half[k] {
                return None;
            }
            continue;
        }
        let (a, b) = ((-half[k] - o[k]) / d[k], (half[k] - o[k]) / d[k]);
        t_in = t_in.max(a.min(b));
        t_out = t_out.min(a.max(b));
    }
    (t_out.is_finite() && t_out > 0.0 && t_in <= t_out).then(|| o + t_out * d)
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

impl LearnedBackground {
    /// A map at its initial colour (`config.init` everywhere) for a scene box `aabb` (the
    /// shell's centre and size). Call [`LearnedBackgroundConfig::validate`] first.
    pub fn new(config: LearnedBackgroundConfig, aabb: [Vec3; 2]) -> Self {
        let mut maps = Vec::new();
        let mut n = 0;
        for (h, w) in config.sizes() {
            maps.push((n, h, w));
            n += h * w;
        }
        // The coarsest map carries the initial logit, the others start at 0.
        let init = (config.init / (1.0 - config.init)).ln();
        let mut logits = vec![0.0; 3 * n];
        let (_, h0, w0) = maps[0];
        logits[..3 * h0 * w0].fill(init);
        let [lo, hi] = aabb;
        let centre = (lo + hi) * 0.5;
        let shell = (config.shell_radius > 0.0).then(|| match config.shell_shape {
            ShellShape::Sphere => Shell::Sphere(centre, config.shell_radius * (hi - lo).length() * 0.5),
            ShellShape::Box => Shell::Box(centre, config.shell_radius * (hi - lo) * 0.5),
        });
        Self { config, shell, maps, logits, m: vec![0.0; 3 * n], v: vec![0.0; 3 * n], t: 0 }
    }

    /// The direction the map is read in for the ray `origin + t dir`: `dir` for a map
    /// at infinity; for a shell, the direction from its centre to the point where the
    /// ray leaves the sphere (the larger root of `|o + t d - c| = R`), or `dir` for a ray
    /// that misses it (an origin outside the shell, looking away). A box shell: the
    /// direction from its centre to where the ray leaves the box (the nearest of the
    /// far crossings of its three slabs), or `dir` for a ray that misses it.
    pub fn lookup_dir(&self, origin: [f32; 3], dir: [f32; 3]) -> [f32; 3] {
        let (c, r) = match self.shell {
            None => return dir,
            Some(Shell::Sphere(c, r)) => (c, r),
            Some(Shell::Box(c, half)) => return box_exit(Vec3::from(origin) - c, Vec3::from(dir), half).map_or(dir, |p| p.to_array()),
        };
        let (o, d) = (Vec3::from(origin) - c, Vec3::from(dir));
        let (a, b, cc) = (d.dot(d), o.dot(d), o.dot(o) - r * r);
        let disc = b * b - a * cc;
        if !(a > 0.0 && disc >= 0.0) {
            return dir;
        }
        let t = (-b + disc.sqrt()) / a;
        if t <= 0.0 {
            return dir;
        }
        (o + t * d).to_array()
    }

    /// [`LearnedBackground::lookup_dir`] of each ray: what every caller hands
    /// [`LearnedBackground::colors`], [`LearnedBackground::step`] and
    /// [`LearnedBackground::prefit`], so that training and rendering read the same texels.
    pub fn ray_dirs(&self, rays: &[crate::layout::GpuRay]) -> Vec<[f32; 3]> {
        rays.par_iter().with_min_len(PAR_MIN_RAYS).map(|r| self.lookup_dir(r.origin, r.dir)).collect()
    }

    pub fn config(&self) -> &LearnedBackgroundConfig {
        &self.config
    }

    /// The pre-sigmoid value of direction `d` (need not be unit length).
    fn logit(&self, d: [f32; 3]) -> [f32; 3] {
        self.logit_at(uv(d))
    }

    /// [`LearnedBackground::logit`] of a direction's [`uv`].
    fn logit_at(&self, at: (f32, f32)) -> [f32; 3] {
        let mut s = [0.0f32; 3];
        for &map in &self.maps {
            let m = self.map_logit_at(map, at);
            for c in 0..3 {
                s[c] += m[c];
            }
        }
        s
    }

    /// One map's share (`(offset, height, width)` of [`LearnedBackground::maps`]) of
    /// [`LearnedBackground::logit`].
    fn map_logit(&self, map: (usize, usize, usize), d: [f32; 3]) -> [f32; 3] {
        self.map_logit_at(map, uv(d))
    }

    /// [`LearnedBackground::map_logit`] of a direction's [`uv`].
    fn map_logit_at(&self, (off, h, w): (usize, usize, usize), at: (f32, f32)) -> [f32; 3] {
        let mut s = [0.0f32; 3];
        for (texel, weight) in taps_at(at, h, w) {
            let i = 3 * (off + texel);
            for c in 0..3 {
                s[c] += weight * self.logits[i + c];
            }
        }
        s
    }

    /// The background colour of each direction (in parallel over the directions: a
    /// training step asks for every ray's).
    pub fn colors(&self, dirs: &[[f32; 3]]) -> Vec<[f32; 3]> {
        dirs.par_iter().with_min_len(PAR_MIN_RAYS).map(|&d| self.logit(d).map(sigmoid)).collect()
    }

    /// The gradient of `sum_r <g_r, bg(d_r)>` with respect to the map's values. Each
    /// direction's texels and `dL/d logit` are found in parallel, then scattered in
    /// the directions' order, so the sum is the same on any number of threads.
    pub fn gradient(&self, dirs: &[[f32; 3]], g: &[[f32; 3]]) -> Vec<f32> {
        // Per direction: its texture coordinates and dL/d logit (None: no gradient).
        let per_ray: Vec<Option<TexelGrad>> = dirs
            .par_iter()
            .zip(g)
            .with_min_len(PAR_MIN_RAYS)
            .map(|(&d, g)| {
                if g.iter().all(|&x| x == 0.0) {
                    return None;
                }
                let at = uv(d);
                let c = self.logit_at(at).map(sigmoid);
                Some((at, std::array::from_fn(|k| g[k] * c[k] * (1.0 - c[k]))))
            })
            .collect();
        let mut grad = vec![0.0f32; self.logits.len()];
        for (at, dl) in per_ray.into_iter().flatten() {
            for &(off, h, w) in &self.maps {
                for (texel, weight) in taps_at(at, h, w) {
                    let i = 3 * (off + texel);
                    for k in 0..3 {
                        grad[i + k] += weight * dl[k];
                    }
                }
            }
        }
        grad
    }

    /// One Adam step on the photometric rays of a training batch: their directions,
    /// `dL/d rgb` and opacity (`dL/d bg = (1 - opacity) dL/d rgb`), at the field's
    /// learning rate `lr` (times `lr_scale`). Non-finite inputs leave the map alone.
    pub fn step(&mut self, dirs: &[[f32; 3]], d_rgb: &[[f32; 3]], opacity: &[f32], lr: f32) {
        let g: Vec<[f32; 3]> = d_rgb.iter().zip(opacity).map(|(g, &a)| g.map(|x| x * (1.0 - a.clamp(0.0, 1.0)))).collect();
        let grad = self.gradient(dirs, &g);
        if !grad.iter().all(|x| x.is_finite()) {
            return;
        }
        self.t += 1;
        let lr = lr * self.config.lr_scale;
        let (b1t, b2t) = (1.0 - BETA1.powi(self.t as i32), 1.0 - BETA2.powi(self.t as i32));
        for i in 0..self.logits.len() {
            self.m[i] = BETA1 * self.m[i] + (1.0 - BETA1) * grad[i];
            self.v[i] = BETA2 * self.v[i] + (1.0 - BETA2) * grad[i] * grad[i];
        }
        // Adam's denominator with a floor of [`RELATIVE_FLOOR`] times the largest one of
        // the same map: per-value Adam turns the faint, one-sided gradient of a texel
        // seen only through an almost opaque object ((1 - opacity) dL/d rgb) into
        // full-size steps and walks it to black or white over a run (`creases` on
        // white: a texel beside the floor went from 0.96 to 0.64 in training, and the
        // views looking past the object there rendered it). Texels with at least a
        // tenth of their map's best-seen texel's gradient still move at half Adam's rate
        // or more; fainter ones in proportion to their evidence. Per map, because a
        // finer map's texels each collect a fraction of a coarser one's rays (one floor
        // for all maps slowed DTU's 16 x 32 map: docs/results/real-captures.md). Texels
        // no ray has reached keep their value.
        for &(off, h, w) in &self.maps {
            let values = 3 * off..3 * (off + h * w);
            let v_max = self.v[values.clone()].iter().fold(0.0f32, |a, &b| a.max(b));
            let floor = RELATIVE_FLOOR * (v_max / b2t).sqrt() + EPS;
            for i in values {
                self.logits[i] -= lr / b1t * self.m[i] / ((self.v[i] / b2t).sqrt() + floor);
            }
        }
    }

    /// Fits the map to colours seen in known directions before training: pixels that
    /// most likely show background (the trainer passes the frames of the training
    /// images). Without this, a capture whose backdrop is uniform (white paper, a
    /// composited background) fits it with fog from the first steps and the background
    /// never learns it: docs/results/real-captures.md.
    ///
    /// The fit is a splat, coarsest map first, in logit space (colours clamped to
    /// `[0.02, 0.98]`): each texel takes the bilinear-weighted mean of what the
    /// directions reaching it still miss (the target's logit less the coarser maps'
    /// sum), shrunk toward the colour of median luminance (the coarsest map) or toward 0
    /// (the finer maps) with the weight of [`PREFIT_PRIOR_WEIGHT`] pixels. Every value is
    /// a weighted mean of what was seen, so one map's texel lies within the range of the
    /// colours reaching it: a texel at the edge of what the frames show cannot overshoot
    /// to black to fit a sharp edge, as a least-squares fit does (a frame that shows the
    /// floor under the object beside white sky, `creases` on white: one texel went
    /// black, and every view looking past the object there rendered black instead of
    /// white). Each finer map is then sharpened toward a least-squares fit of what the
    /// coarser ones leave ([`LearnedBackground::sharpen`]): its texels are a quarter of
    /// the coarsest's size or less, and a splat blurs the detail they exist to hold.
    /// Texels no direction reaches keep the median colour (robust to the object
    /// reaching into some frames). The optimizer state is reset, so training starts its
    /// own. `config.prefit` says which maps are fitted: all of them, the coarsest alone
    /// (the finer ones then start at 0), or none, in which case the map and its
    /// optimizer state are left as they are (every direction at `init` before training).
    pub fn prefit(&mut self, dirs: &[[f32; 3]], colors: &[[f32; 3]]) {
        self.prefit_with(dirs, colors, PREFIT_SHARPEN_ROUNDS);
    }

    /// [`LearnedBackground::prefit`] with `rounds` of [`LearnedBackground::sharpen`].
    fn prefit_with(&mut self, dirs: &[[f32; 3]], colors: &[[f32; 3]], rounds: usize) {
        let fitted = match self.config.prefit {
            Prefit::All => self.maps.len(),
            Prefit::Coarsest => 1,
            Prefit::None => 0,
        };
        if dirs.is_empty() || fitted == 0 {
            return;
        }
        let to_logit = |c: f32| {
            let c = c.clamp(0.02, 0.98);
            (c / (1.0 - c)).ln()
        };
        // The colour of median luminance: a colour of the frames (a per-channel median of
        // black and white frames could be red).
        let luminance = |c: &[f32; 3]| 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
        let mut order: Vec<&[f32; 3]> = colors.iter().collect();
        order.sort_by(|a, b| luminance(a).total_cmp(&luminance(b)));
        let median = order[order.len() / 2].map(to_logit);
        let targets: Vec<[f32; 3]> = colors.iter().map(|c| c.map(to_logit)).collect();
        self.logits.fill(0.0);
        for level in 0..fitted {
            let (off, h, w) = self.maps[level];
            let prior = if level == 0 { median } else { [0.0; 3] };
            // What each direction's target leaves to this map: the coarser maps are
            // final, this map is still 0.
            let residuals: Vec<[f32; 3]> = dirs
                .iter()
                .zip(&targets)
                .map(|(&d, t)| {
                    let have = self.logit(d);
                    std::array::from_fn(|k| t[k] - have[k])
                })
                .collect();
            let mut sum = vec![0.0f64; 3 * h * w];
            let mut weight = vec![0.0f64; h * w];
            for (&d, r) in dirs.iter().zip(&residuals) {
                for (texel, wt) in taps(d, h, w) {
                    weight[texel] += wt as f64;
                    for k in 0..3 {
                        sum[3 * texel + k] += wt as f64 * r[k] as f64;
                    }
                }
            }
            for texel in 0..h * w {
                let n = weight[texel] + PREFIT_PRIOR_WEIGHT;
                for k in 0..3 {
                    self.logits[3 * (off + texel) + k] = ((sum[3 * texel + k] + PREFIT_PRIOR_WEIGHT * prior[k] as f64) / n) as f32;
                }
            }
            if level > 0 {
                self.sharpen(self.maps[level], dirs, &residuals, &weight, rounds);
            }
        }
        self.m.fill(0.0);
        self.v.fill(0.0);
        self.t = 0;
    }

    /// [`LearnedBackground::prefit`] of a finer map after its splat: `rounds` of SART
    /// toward the least-squares fit of `residuals` (what the coarser maps leave in each
    /// direction). Each round moves every texel by the bilinear-weighted mean of its
    /// directions' remaining residual, damped by the splat's prior weight; `weight` is
    /// each texel's sum of bilinear weights (the splat's). A splat blurs what a finer map
    /// exists to hold: DTU's backdrop on the shell, 9 views, lost 0.8 dB on the val views
    /// against the least-squares start of before, and the rounds take it back
    /// (docs/results/real-captures.md, "The background's texels"). The coarsest map
    /// stays a splat: there a least-squares fit overshot to black (tests check both).
    fn sharpen(&mut self, map: (usize, usize, usize), dirs: &[[f32; 3]], residuals: &[[f32; 3]], weight: &[f64], rounds: usize) {
        let (off, h, w) = map;
        for _ in 0..rounds {
            let mut sum = vec![0.0f64; 3 * h * w];
            for (&d, r) in dirs.iter().zip(residuals) {
                let have = self.map_logit(map, d);
                for (texel, wt) in taps(d, h, w) {
                    for k in 0..3 {
                        sum[3 * texel + k] += wt as f64 * (r[k] - have[k]) as f64;
                    }
                }
            }
            for texel in 0..h * w {
                let n = weight[texel] + PREFIT_PRIOR_WEIGHT;
                for k in 0..3 {
                    self.logits[3 * (off + texel) + k] += (sum[3 * texel + k] / n) as f32;
                }
            }
        }
    }

    /// The map and its optimizer state as named arrays (for checkpoints).
    pub fn export(&self) -> Vec<(String, Vec<f32>)> {
        vec![
            (LOGITS.into(), self.logits.clone()),
            (ADAM_M.into(), self.m.clone()),
            (ADAM_V.into(), self.v.clone()),
            (ADAM_T.into(), vec![self.t as f32]),
        ]
    }

    /// Restores [`LearnedBackground::export`]'s arrays; an error names what does not fit.
    pub fn import(&mut self, arrays: &[(String, Vec<f32>)]) -> Result<(), String> {
        let get = |name: &str| arrays.iter().find(|(n, _)| n == name).map(|(_, d)| d);
        let n = self.logits.len();
        for (name, target) in [(LOGITS, &mut self.logits), (ADAM_M, &mut self.m), (ADAM_V, &mut self.v)] {
            let data = get(name).ok_or_else(|| format!("no {name} tensor (the run's config has a learned background)"))?;
            if data.len() != n {
                return Err(format!("{name} holds {} values, the configured maps {n}", data.len()));
            }
            if !data.iter().all(|x| x.is_finite()) {
                return Err(format!("{name} holds non-finite values"));
            }
            target.copy_from_slice(data);
        }
        self.t = get(ADAM_T).and_then(|t| t.first()).map_or(0, |&t| t.max(0.0) as u32);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const UNIT_BOX: [Vec3; 2] = [Vec3::splat(-1.0), Vec3::splat(1.0)];

    /// A map at infinity is read by the ray's direction; a shell by the direction from
    /// its centre to the exit point, which lies on the sphere and along the ray.
    #[test]
    fn shell_lookup_is_where_the_ray_leaves_the_sphere() {
        let at_infinity = LearnedBackground::new(LearnedBackgroundConfig::default(), UNIT_BOX);
        assert_eq!(at_infinity.lookup_dir([0.5, 2.0, -1.0], [0.3, -0.2, 0.9]), [0.3, -0.2, 0.9]);
        let aabb = [Vec3::new(1.0, 0.0, -2.0), Vec3::new(3.0, 4.0, 2.0)];
        let shell = LearnedBackground::new(LearnedBackgroundConfig { shell_radius: 2.0, ..Default::default() }, aabb);
        let (c, r) = ([2.0f32, 2.0, 0.0], 2.0 * 3.0); // half diagonal |(1, 2, 2)| = 3
        let norm = |v: [f32; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        for (o, d) in [([2.0, 2.0, 0.0], [0.0, 0.0, 2.0]), ([1.5, 3.0, -1.0], [0.3, -0.2, 0.9]), ([6.0, 2.0, 0.0], [-1.0, 0.1, 0.0])] {
            let p = shell.lookup_dir(o, d);
            assert!((norm(p) - r).abs() < 1e-4, "{p:?} is not on the sphere");
            // p + c - o is parallel to d and ahead of the origin.
            let q = [0, 1, 2].map(|k| p[k] + c[k] - o[k]);
            let cross = [q[1] * d[2] - q[2] * d[1], q[2] * d[0] - q[0] * d[2], q[0] * d[1] - q[1] * d[0]];
            assert!(norm(cross) < 1e-4 * norm(q) * norm(d) && q.iter().zip(&d).map(|(a, b)| a * b).sum::<f32>() > 0.0, "{p:?}");
        }
        // From the centre the exit point is along the direction itself.
        let p = shell.lookup_dir(c, [0.0, 3.0, 4.0]);
        assert!((p[1] / p[2] - 0.75).abs() < 1e-5 && p[0].abs() < 1e-5);
        // Outside the shell and looking away: the ray's direction.
        assert_eq!(shell.lookup_dir([20.0, 2.0, 0.0], [1.0, 0.0, 0.0]), [1.0, 0.0, 0.0]);
    }

    /// A box shell is read by the direction from the box's centre to where the ray
    /// leaves the (scaled) box, from inside it (a room's cameras) and from outside.
    #[test]
    fn box_shell_lookup_is_where_the_ray_leaves_the_box() {
        let aabb = [Vec3::new(-2.0, -2.0, 0.0), Vec3::new(2.0, 2.0, 2.0)];
        let config = |r| LearnedBackgroundConfig { shell_radius: r, shell_shape: ShellShape::Box, ..Default::default() };
        let room = LearnedBackground::new(config(1.0), aabb);
        // The centre is (0, 0, 1). From a camera inside, looking at the +x wall.
        assert_eq!(room.lookup_dir([1.0, 0.5, 1.5], [1.0, 0.0, 0.0]), [2.0, 0.5, 0.5]);
        // Looking down at the floor at 45 degrees: leaves through z = 0 at x = 0.5.
        let p = room.lookup_dir([-1.0, 0.0, 1.5], [1.0, 0.0, -1.0]);
        assert!((Vec3::from(p) - Vec3::new(0.5, 0.0, -1.0)).length() < 1e-5, "{p:?}");
        // Into a corner: the nearer of the two walls.
        let p = room.lookup_dir([0.0, 0.0, 1.0], [1.0, 2.0, 0.0]);
        assert!((Vec3::from(p) - Vec3::new(1.0, 2.0, 0.0)).length() < 1e-5, "{p:?}");
        // From outside, through the box: where it comes out on the far side.
        let p = room.lookup_dir([-5.0, 0.0, 1.0], [1.0, 0.0, 0.0]);
        assert!((Vec3::from(p) - Vec3::new(2.0, 0.0, 0.0)).length() < 1e-5, "{p:?}");
        // A box twice the size.
        let p = LearnedBackground::new(config(2.0), aabb).lookup_dir([0.0, 0.0, 1.0], [0.0, -1.0, 0.0]);
        assert!((Vec3::from(p) - Vec3::new(0.0, -4.0, 0.0)).length() < 1e-5, "{p:?}");
        // Missing the box, or leaving it behind: the ray's direction.
        assert_eq!(room.lookup_dir([-5.0, 3.0, 1.0], [1.0, 0.0, 0.0]), [1.0, 0.0, 0.0]);
        assert_eq!(room.lookup_dir([5.0, 0.0, 1.0], [1.0, 0.2, 0.0]), [1.0, 0.2, 0.0]);
        // Validation: a box shell needs a scale of 1 or more, a sphere more than 1.
        assert!(config(1.0).validate().is_ok() && config(0.0).validate().is_err() && config(0.5).validate().is_err());
        let sphere = LearnedBackgroundConfig { shell_radius: 1.0, ..Default::default() };
        assert!(sphere.validate().is_err());
    }

    fn trained_map() -> LearnedBackground {
        let mut bg = LearnedBackground::new(LearnedBackgroundConfig { levels: 2, finest_height: 8, ..Default::default() }, UNIT_BOX);
        // Non-trivial values everywhere.
        for (i, x) in bg.logits.iter_mut().enumerate() {
            *x = ((i * 7919) % 23) as f32 / 23.0 - 0.5;
        }
        bg
    }

    fn dirs() -> Vec<[f32; 3]> {
        vec![[0.3, -0.2, 0.9], [-1.0, 0.1, -0.2], [0.0, 0.0, 1.0], [0.2, 0.5, -3.0], [-0.7, -0.7, 0.05]]
    }

    #[test]
    fn starts_at_its_initial_colour_everywhere() {
        let bg = LearnedBackground::new(LearnedBackgroundConfig { init: 0.8, ..Default::default() }, UNIT_BOX);
        for c in bg.colors(&dirs()) {
            for x in c {
                assert!((x - 0.8).abs() < 1e-5, "{x}");
            }
        }
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let bg = trained_map();
        let d = dirs();
        let g: Vec<[f32; 3]> = (0..d.len()).map(|r| [0.3 + r as f32 * 0.1, -0.5, 0.2 * r as f32]).collect();
        let loss = |b: &LearnedBackground| -> f64 {
            b.colors(&d).iter().zip(&g).map(|(c, g)| (0..3).map(|k| c[k] as f64 * g[k] as f64).sum::<f64>()).sum()
        };
        let grad = bg.gradient(&d, &g);
        let mut checked = 0;
        for i in 0..bg.logits.len() {
            let eps = 1e-2;
            let (mut plus, mut minus) = (bg.clone(), bg.clone());
            plus.logits[i] += eps;
            minus.logits[i] -= eps;
            let fd = (loss(&plus) - loss(&minus)) / (2.0 * eps as f64);
            assert!((fd - grad[i] as f64).abs() < 1e-4 + 1e-3 * fd.abs(), "value {i}: fd {fd} analytic {}", grad[i]);
            checked += (grad[i] != 0.0) as usize;
        }
        assert!(checked >= 20, "only {checked} values carry gradient");
    }

    /// The parallel lookups and gradient give, bit for bit, what one direction at a
    /// time gives (the serial reference below: each map's lookup from the direction
    /// itself, the gradient scattered in the directions' order), on one thread or
    /// several: a run does not depend on the machine's core count.
    #[test]
    fn parallel_lookups_match_the_serial_reference_on_any_number_of_threads() {
        let mut bg = LearnedBackground::new(LearnedBackgroundConfig { levels: 3, finest_height: 16, ..Default::default() }, UNIT_BOX);
        for (i, x) in bg.logits.iter_mut().enumerate() {
            *x = ((i * 7919) % 29) as f32 / 29.0 - 0.5;
        }
        let mut rng = crate::rng::SplitMix64::new(7);
        let mut u3 = || [rng.range_f32(-0.5, 0.5), rng.range_f32(-0.5, 0.5), rng.range_f32(-0.5, 0.5)];
        let n = 5000;
        let d: Vec<[f32; 3]> = (0..n).map(|_| u3()).collect();
        let g: Vec<[f32; 3]> = (0..n).map(|r| if r % 7 == 0 { [0.0; 3] } else { u3() }).collect();
        let reference_colors: Vec<[f32; 3]> = d
            .iter()
            .map(|&d| {
                let mut s = [0.0f32; 3];
                for &map in &bg.maps {
                    let m = bg.map_logit(map, d);
                    (0..3).for_each(|k| s[k] += m[k]);
                }
                s.map(sigmoid)
            })
            .collect();
        let mut reference_grad = vec![0.0f32; bg.logits.len()];
        for ((&d, g), c) in d.iter().zip(&g).zip(&reference_colors) {
            if g.iter().all(|&x| x == 0.0) {
                continue;
            }
            for &(off, h, w) in &bg.maps {
                for (texel, weight) in taps(d, h, w) {
                    for k in 0..3 {
                        reference_grad[3 * (off + texel) + k] += weight * (g[k] * c[k] * (1.0 - c[k]));
                    }
                }
            }
        }
        for threads in [1, 4] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let (colors, grad) = pool.install(|| (bg.colors(&d), bg.gradient(&d, &g)));
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(colors.as_flattened()), bits(reference_colors.as_flattened()), "colours on {threads} threads");
            assert_eq!(bits(&grad), bits(&reference_grad), "gradient on {threads} threads");
        }
    }

    #[test]
    fn training_moves_the_seen_directions_to_the_target() {
        let mut bg = LearnedBackground::new(LearnedBackgroundConfig::default(), UNIT_BOX);
        let d = dirs();
        let target = [1.0, 1.0, 1.0];
        for _ in 0..600 {
            let c = bg.colors(&d);
            // d/d rgb of the mean squared error with opacity 0: the background is the colour.
            let g: Vec<[f32; 3]> = c.iter().map(|c| std::array::from_fn(|k| 2.0 * (c[k] - target[k]))).collect();
            bg.step(&d, &g, &vec![0.0; d.len()], 0.05);
        }
        for c in bg.colors(&d) {
            assert!(c.iter().all(|&x| x > 0.95), "{c:?}");
        }
        // An opaque ray teaches the background nothing.
        let mut opaque = LearnedBackground::new(LearnedBackgroundConfig::default(), UNIT_BOX);
        opaque.step(&d, &vec![[1.0; 3]; d.len()], &vec![1.0; d.len()], 0.05);
        assert!(opaque.colors(&d).iter().all(|c| c.iter().all(|&x| (x - 0.5).abs() < 1e-6)));
    }

    /// A texel that only ever gets a faint, one-sided gradient (a direction seen only
    /// through an almost opaque object) hardly moves, while a well-seen one moves at
    /// Adam's rate: per-value Adam would walk both the same distance.
    #[test]
    fn faint_gradients_move_the_map_in_proportion() {
        let mut bg = LearnedBackground::new(LearnedBackgroundConfig::default(), UNIT_BOX);
        // Texel centres of the 4 x 8 map, two rows and four columns apart.
        let (seen, faint) = ([1.0, 0.0, 0.3], [-1.0, 0.0, -0.3]);
        let before = bg.colors(&[seen, faint]);
        for _ in 0..200 {
            // The same dL/d rgb; the faint ray is 99.9 % opaque.
            bg.step(&[seen, faint], &[[-0.01; 3], [-0.01; 3]], &[0.0, 0.999], 0.01);
        }
        let after = bg.colors(&[seen, faint]);
        let moved = |k: usize| after[k][0] - before[k][0];
        assert!(moved(0) > 0.3, "the well-seen texel moved {}", moved(0));
        assert!(moved(1).abs() < 0.03 * moved(0), "the faint texel moved {} against {}", moved(1), moved(0));
    }

    /// Each map's floor is its own: a finer map's texels each collect a fraction of a
    /// coarser texel's rays, and still move at Adam's rate where they are best seen.
    #[test]
    fn each_map_moves_at_its_own_rate() {
        let config = LearnedBackgroundConfig { levels: 2, finest_height: 16, ..Default::default() };
        let mut bg = LearnedBackground::new(config, UNIT_BOX);
        // 64 directions spread over one texel of the 4 x 8 map (45 degrees each way).
        let dirs: Vec<[f32; 3]> = (0..64)
            .map(|i| {
                let (az, pol) = ((5.0 + (i % 8) as f32 * 5.0).to_radians(), (50.0 + (i / 8) as f32 * 5.0).to_radians());
                [az.cos() * pol.sin(), az.sin() * pol.sin(), pol.cos()]
            })
            .collect();
        let before = bg.logits.clone();
        for _ in 0..20 {
            bg.step(&dirs, &vec![[-0.01; 3]; dirs.len()], &vec![0.0; dirs.len()], 0.01);
        }
        let (_, h0, w0) = bg.maps[0];
        let moved = |range: std::ops::Range<usize>| range.map(|i| (bg.logits[i] - before[i]).abs()).fold(0.0f32, f32::max);
        let (coarse, fine) = (moved(0..3 * h0 * w0), moved(3 * h0 * w0..bg.logits.len()));
        assert!(coarse > 0.15 && fine > 0.8 * coarse, "the coarse map moved {coarse}, the fine one {fine}");
    }

    #[test]
    fn prefit_takes_the_median_and_shapes_it_by_direction() {
        let mut bg = LearnedBackground::new(LearnedBackgroundConfig { levels: 1, finest_height: 4, ..Default::default() }, UNIT_BOX);
        // Upward directions see black, downward ones white, and one odd colour.
        let mut dirs = Vec::new();
        let mut colors = Vec::new();
        for i in 0..200 {
            let a = i as f32 * 0.1;
            let up = i % 2 == 0;
            dirs.push([a.cos(), a.sin(), if up { 0.9 } else { -0.9 }]);
            colors.push(if up { [0.05; 3] } else { [0.95; 3] });
        }
        dirs.push([1.0, 0.0, 0.0]);
        colors.push([1.0, 0.0, 0.0]);
        bg.m.fill(0.5);
        bg.prefit(&dirs, &colors);
        let c = bg.colors(&[[-1.0, 0.05, 0.9], [-1.0, -0.05, -0.9]]);
        assert!(c[0].iter().all(|&x| x < 0.2) && c[1].iter().all(|&x| x > 0.8), "{c:?}");
        assert_eq!((bg.t, bg.m.iter().all(|&m| m == 0.0)), (0, true), "optimizer state reset");
    }

    /// `prefit = "coarsest"` fits only the coarsest map (the finer ones stay at 0) and
    /// `prefit = "none"` leaves every texel at `init`; `all` changes the finer maps too.
    #[test]
    fn prefit_fits_the_maps_it_is_told_to() {
        let (dirs, colors): (Vec<[f32; 3]>, Vec<[f32; 3]>) = (0..400)
            .map(|i| {
                let a = i as f32 * 0.05;
                let up = (i / 7) % 2 == 0;
                ([a.cos(), a.sin(), if up { 0.5 } else { -0.5 }], if up { [0.1, 0.3, 0.9] } else { [0.9, 0.6, 0.1] })
            })
            .unzip();
        let fitted = |prefit| {
            let config = LearnedBackgroundConfig { levels: 2, finest_height: 16, init: 0.3, prefit, ..Default::default() };
            let mut bg = LearnedBackground::new(config, UNIT_BOX);
            let start = bg.logits.clone();
            bg.prefit(&dirs, &colors);
            let (_, h0, w0) = bg.maps[0];
            let changed = |r: std::ops::Range<usize>| r.filter(|&i| bg.logits[i] != start[i]).count();
            (changed(0..3 * h0 * w0), changed(3 * h0 * w0..bg.logits.len()))
        };
        let (all, coarsest, none) = (fitted(Prefit::All), fitted(Prefit::Coarsest), fitted(Prefit::None));
        assert!(all.0 > 0 && all.1 > 0, "all: {all:?}");
        assert!(coarsest.0 > 0 && coarsest.1 == 0, "coarsest: {coarsest:?}");
        assert_eq!(none, (0, 0), "none");
    }

    /// Frames that show a sharp edge between two colours in the middle of a texel (a
    /// floor's edge against white sky): every texel stays within the colours seen (a
    /// least-squares fit drives the texel beside the edge past them, to black), texels
    /// no frame reaches keep the median colour, and a finer map fits the edge closer.
    #[test]
    fn prefit_stays_within_the_colours_seen() {
        let (white, grey) = (0.98f32, 0.6f32);
        let (mut dirs, mut colors) = (Vec::new(), Vec::new());
        // A band of directions around the horizon, azimuths 0 to 90 degrees: above 5
        // degrees below the horizon white, under it grey (the floor), more of it white.
        for i in 0..60 {
            for j in 0..40 {
                let (az, el) = ((i as f32 * 1.5).to_radians(), (-30.0 + j as f32 * 1.5).to_radians());
                dirs.push([az.cos() * el.cos(), az.sin() * el.cos(), el.sin()]);
                colors.push([if el.to_degrees() > -5.0 { white } else { grey }; 3]);
            }
        }
        let fit_error = |bg: &LearnedBackground| -> f32 {
            bg.colors(&dirs).iter().zip(&colors).map(|(c, t)| (c[0] - t[0]).abs()).sum::<f32>() / dirs.len() as f32
        };
        let mut errors = Vec::new();
        for (levels, finest_height) in [(1, 4), (2, 16)] {
            let mut bg = LearnedBackground::new(LearnedBackgroundConfig { levels, finest_height, ..Default::default() }, UNIT_BOX);
            bg.prefit(&dirs, &colors);
            // Each map's texels (alone, through the sigmoid for the coarsest) and the
            // rendered colour in every direction lie within the colours seen.
            let (_, h0, w0) = bg.maps[0];
            for x in &bg.logits[..3 * h0 * w0] {
                let c = sigmoid(*x);
                assert!((grey - 1e-3..=white + 1e-3).contains(&c), "coarsest texel {c} outside [{grey}, {white}]");
            }
            let everywhere: Vec<[f32; 3]> = (0..64 * 128)
                .map(|i| {
                    let (u, v) = ((i % 128) as f32 / 128.0, (i / 128) as f32 / 64.0 + 0.5 / 64.0);
                    let (az, pol) = (u * std::f32::consts::TAU, v * std::f32::consts::PI);
                    [az.cos() * pol.sin(), az.sin() * pol.sin(), pol.cos()]
                })
                .collect();
            // With one map (a splat) every direction; with two, the finer map is sharpened
            // toward a least-squares fit, which may ring in directions next to those the
            // frames reach (a texel there is extrapolated from its seen half), so only
            // the seen directions are held to the colours seen, with a quarter of the
            // edge's contrast for a least-squares fit's ringing where the edge meets the
            // end of the frames' coverage (a fifth here, 0.075). The failure this guards
            // against, a texel past every colour seen, was the whole contrast and more.
            let (check, slack): (&[[f32; 3]], f32) = if levels == 1 { (&everywhere, 0.02) } else { (&dirs, (white - grey) / 4.0) };
            for c in bg.colors(check) {
                assert!((grey - slack..=white + slack).contains(&c[0]), "levels {levels}: colour {} outside [{grey}, {white}]", c[0]);
            }
            // Opposite the band, level and downward: no frame reaches them; the median
            // colour (white: most frames are) holds there.
            for c in bg.colors(&[[-1.0, -1.0, 0.0], [-1.0, -1.0, -0.8]]) {
                assert!((c[0] - white).abs() < 1e-3, "levels {levels}: unseen direction {}", c[0]);
            }
            errors.push(fit_error(&bg));
        }
        assert!(errors[1] < 0.7 * errors[0], "a finer map fits the edge closer: {errors:?}");

    }

    /// A backdrop with detail at the finer map's scale (stripes 22.5 degrees wide, a
    /// 16 x 32 map's texels are 11.25): the splat blurs it (each texel a weighted mean
    /// over neighbours of both colours), the sharpening rounds take it back.
    #[test]
    fn finer_maps_are_sharpened_past_their_splat() {
        let (mut dirs, mut colors) = (Vec::new(), Vec::new());
        for i in 0..240 {
            for j in 0..40 {
                let (az, el) = ((i as f32 * 1.5).to_radians(), (-30.0 + j as f32 * 1.5).to_radians());
                dirs.push([az.cos() * el.cos(), az.sin() * el.cos(), el.sin()]);
                let stripe = (i as f32 * 1.5 / 22.5) as usize % 2 == 0;
                colors.push([if stripe { 0.8 } else { 0.3 }; 3]);
            }
        }
        let fit_error = |bg: &LearnedBackground| -> f32 {
            bg.colors(&dirs).iter().zip(&colors).map(|(c, t)| (c[0] - t[0]).abs()).sum::<f32>() / dirs.len() as f32
        };
        let config = LearnedBackgroundConfig { levels: 2, finest_height: 16, ..Default::default() };
        let (mut splat, mut sharp) = (LearnedBackground::new(config, UNIT_BOX), LearnedBackground::new(config, UNIT_BOX));
        splat.prefit_with(&dirs, &colors, 0);
        sharp.prefit_with(&dirs, &colors, PREFIT_SHARPEN_ROUNDS);
        let (e_splat, e_sharp) = (fit_error(&splat), fit_error(&sharp));
        assert!(e_sharp < 0.8 * e_splat, "sharpened {e_sharp} against the splat's {e_splat}");
        for c in sharp.colors(&dirs) {
            assert!((0.3 - 0.05..=0.8 + 0.05).contains(&c[0]), "sharpened colour {} outside [0.3, 0.8]", c[0]);
        }
    }

    #[test]
    fn export_and_import_round_trip() {
        let mut bg = trained_map();
        bg.step(&dirs(), &vec![[0.1, -0.2, 0.3]; 5], &vec![0.2; 5], 0.01);
        let mut restored = LearnedBackground::new(*bg.config(), UNIT_BOX);
        restored.import(&bg.export()).unwrap();
        assert_eq!(restored.colors(&dirs()), bg.colors(&dirs()));
        assert_eq!((restored.m.clone(), restored.v.clone(), restored.t), (bg.m.clone(), bg.v.clone(), bg.t));
        let mut other = LearnedBackground::new(LearnedBackgroundConfig::default(), UNIT_BOX);
        assert!(other.import(&bg.export()).unwrap_err().contains("background.logits"));
    }
}
