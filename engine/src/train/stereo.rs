//! Plane-sweep stereo over the training views, on the host, once before training: the
//! per-pixel depth targets of the stereo depth prior ([`crate::loss::stereo_depth`]).
//!
//! For each training view `s` and each of `planes` depths `t_k` (uniform in inverse depth
//! over the view's rays' span inside the scene box), every pixel's point `o + t_k d` is
//! projected into the other training views; its cost is the smallest (over those views)
//! mean absolute colour difference from the pixel's own colour, averaged over a
//! `(2 window + 1)^2` square of pixels (a point no other view sees costs 1). The depth of
//! least cost wins (winner takes all). A winner is kept only where another view's own
//! winner at the pixel the point projects to lands within `consistency` times the
//! depth of the same 3D point (a left-right check): repeated texture and flat colour,
//! where the sweep guesses, rarely agree across views.
//!
//! Measured offline on DTU scan 24 (3 views, 400 x 300, 128 planes, window 2): the
//! winners show the building's faces as smooth ramps where the field's own depth is
//! blobs; 19-27 % of the object's pixels pass the check at one plane's tolerance
//! (docs/results/dtu.md).
//!
//! With `uniqueness` below 1 (`priors.stereo_uniqueness`), a winner whose cost is not
//! clearly below that of every plane more than two planes away is dropped before the
//! check (SGBM's uniqueness ratio): flat colour, where every depth matches, and
//! repeated texture, where several do, give no depth.
//!
//! With `horizontal` (`priors.stereo_horizontal`), a second family of `planes` planes is
//! swept: planes across the training cameras' mean up vector ([`up_direction`]), uniform
//! in height over what the view sees of the box. A pixel's window then lies on one
//! floor or table top in every view, where the first family's planes (one depth along
//! every ray) shear it: on a floor seen from cameras 120 degrees apart, a 5 x 5 window
//! at one depth covers different texture in each view. Each pixel takes the cheaper of
//! the two families' winners, and the uniqueness check compares depths across both.
//!
//! With `fill` (`priors.stereo_fill`), the gaps are filled from the confirmed depths
//! around them inside the same region of the view's edge mask (the paper's premise:
//! depth is smooth between edges): a Gaussian-weighted mean over a `fill`-pixel radius,
//! with the weight's share of confirmed pixels as the target's confidence (a confirmed
//! depth has confidence 1). Edge pixels are neither filled nor read by a fill.
//!
//! Forward-facing scenes (NDC rays, an LLFF capture) are swept along their NDC rays: the
//! ray parameter `t` there is linear in inverse depth (`depth = near / (1 - t)`), so the
//! planes are uniform in `t` over `[0, NDC_SWEEP_FAR]`, every point is mapped back to world
//! space before it is projected into the other views, the left-right check's tolerance is
//! a share of the point's distance from the camera, and the targets are NDC ray
//! parameters, the depth the trainer renders there. The planes across up and the
//! ground-truth targets stay world-space only.
//!
//! Invariants: a target is `[0, 0]` (none) or `[t, c]` with `t` inside its ray's span in
//! the box (in NDC: `[0, NDC_SWEEP_FAR]`) and `c` in `(0, 1]` (1 exactly for a confirmed
//! depth).

use glam::{Mat4, Vec3};

use crate::data::Scene;
use crate::edges::EdgeMask;

use super::rays::to_gpu_ray;

/// What the sweep needs to know (`priors.stereo_*`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SweepSettings {
    pub planes: u32,
    pub window: u32,
    pub consistency: f32,
    /// Radius of the edge-aware fill in pixels (0: off).
    pub fill: u32,
    /// The uniqueness check (1: off): a winner is kept only where its cost is below
    /// this fraction of the least cost more than [`UNIQUE_APART`] planes away.
    pub uniqueness: f32,
    /// Also sweep planes across the cameras' up direction (see the module doc).
    pub horizontal: bool,
}

/// Depths within this many plane spacings (of the first family, in inverse depth) of
/// the winner's count as the same minimum in the uniqueness check.
pub const UNIQUE_APART: u32 = 2;

/// The training cameras' mean up vector (their `c2w` `+y` axes averaged), normalised;
/// `None` where they disagree (the mean shorter than 1/2: cameras rolled every which
/// way), so no family of planes across it is swept.
pub fn up_direction(scene: &Scene) -> Option<Vec3> {
    let n = scene.split.train.len();
    if n == 0 {
        return None;
    }
    let mean = scene.train_views().map(|v| v.camera.c2w.y_axis.truncate()).sum::<Vec3>() / n as f32;
    (mean.length() >= 0.5).then(|| mean.normalize())
}

/// The stereo priors' targets from the scene's ground-truth depth
/// (`priors.stereo_targets = "ground_truth"`): every training pixel with a true surface
/// gets its ray distance, confirmed (confidence 1); a training view without depth is
/// refused. The sweep's rays have unit directions, so ray parameters are distances.
pub fn ground_truth(scene: &Scene) -> Result<StereoTargets, String> {
    if scene.ndc.is_some() {
        return Err("priors.stereo_targets = \"ground_truth\" reads ray distances; this scene's rays are NDC (a forward-facing LLFF capture): use \"sweep\"".into());
    }
    (0..scene.views.len())
        .map(|v| {
            if !scene.split.train.contains(&v) {
                return Ok(None);
            }
            let view = &scene.views[v];
            let depth = view.depth.as_ref().ok_or_else(|| {
                format!(
                    "priors.stereo_targets = \"ground_truth\" needs the training views' ground-truth depth (a synthetic scene's *_depth.exr); view {} has none: use \"sweep\"",
                    view.name
                )
            })?;
            Ok(Some(depth.iter().map(|&d| if d > 0.0 && d.is_finite() { [d, 1.0] } else { [0.0, 0.0] }).collect()))
        })
        .collect()
}

/// How well the confirmed stereo depths of a scene with ground-truth depth (a synthetic
/// scene) agree with it ([`accuracy`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Accuracy {
    /// Confirmed pixels with a ground-truth surface.
    pub pixels: usize,
    /// The median of `|t - d| / d` over them (`t` the target, `d` the true ray distance).
    pub median_error: f32,
    /// The share of them off by more than [`ACCURACY_OUTLIER`] of the true depth.
    pub outliers: f32,
}

/// [`Accuracy::outliers`]: a confirmed depth off by more than this share of the true
/// depth counts as an outlier.
pub const ACCURACY_OUTLIER: f32 = 0.1;

/// The confirmed targets (confidence 1) of `targets` against the ground-truth ray
/// distances of the views that have them (`View::depth`, 0: no surface); `None` where no
/// confirmed pixel has one (real photographs). Ray parameters are distances: the sweep's
/// rays have unit directions.
pub fn accuracy(scene: &Scene, targets: &StereoTargets) -> Option<Accuracy> {
    accuracy_where(scene, targets, |c| c >= 1.0)
}

/// [`accuracy`] over the targets whose confidence `keep` accepts (the monocular
/// targets' confidence, say) instead of the confirmed ones.
pub fn accuracy_where(scene: &Scene, targets: &StereoTargets, keep: impl Fn(f32) -> bool) -> Option<Accuracy> {
    // NDC targets are ray parameters, not distances.
    if scene.ndc.is_some() {
        return None;
    }
    let mut errors: Vec<f64> = targets
        .iter()
        .zip(&scene.views)
        .filter_map(|(t, v)| Some((t.as_ref()?, v.depth.as_ref()?)))
        .flat_map(|(t, d)| t.iter().zip(d).filter(|(t, d)| t[1] > 0.0 && keep(t[1]) && **d > 0.0).map(|(t, &d)| ((t[0] - d).abs() / d) as f64))
        .collect();
    let n = errors.len();
    let outliers = errors.iter().filter(|&&e| e > ACCURACY_OUTLIER as f64).count() as f32 / n.max(1) as f32;
    let median_error = crate::data::quantile(&mut errors, 0.5)? as f32;
    Some(Accuracy { pixels: n, median_error, outliers })
}

/// A family of planes the sweep tries at every pixel.
#[derive(Clone, Copy, Debug)]
enum Family {
    /// One depth `t` along every ray (uniform in inverse depth over the view's span).
    Ray,
    /// Planes `normal . x = c`, `c` uniform over `lo..=hi`: what the view sees of the box.
    Across { normal: Vec3, lo: f32, hi: f32 },
}

/// Per scene view (index into `Scene::views`): the stereo target `[depth, confidence]`
/// of each pixel (row major, `[0, 0]` = none) for training views with another training
/// view, `None` otherwise.
pub type StereoTargets = Vec<Option<Vec<[f32; 2]>>>;

/// The farthest NDC ray parameter the sweep tries on a forward-facing scene: 50 times
/// the near plane's depth (`t = 1` is infinitely far).
pub const NDC_SWEEP_FAR: f32 = 0.98;

/// Refuses a sweep the scene cannot take, with what to do; from the cameras and the
/// settings alone, so `train` can say so before it spends time on edge maps. On NDC rays
/// (a forward-facing LLFF capture) the planes across up are world-space planes the NDC
/// sweep does not have.
pub fn check_scene(scene: &Scene, horizontal: bool) -> Result<(), String> {
    if scene.ndc.is_some() && horizontal {
        return Err("priors.stereo_horizontal sweeps world-space planes; this scene's rays are NDC (a forward-facing LLFF capture): set priors.stereo_horizontal = false (the depth planes along the rays still run)".into());
    }
    Ok(())
}

/// The point at ray parameter `t` of the ray `origin + t dir` in world space: the ray's
/// own point, or on an NDC scene that point mapped back from NDC.
fn world_point(scene: &Scene, origin: Vec3, dir: Vec3, t: f32) -> Vec3 {
    let q = origin + t * dir;
    match &scene.ndc {
        Some(ndc) => ndc.ndc_to_world(q),
        None => q,
    }
}

/// The sweep's measure of where along a ray a depth lies, in which the first family's
/// planes are uniform: inverse depth in world space, the ray parameter itself in NDC
/// (linear in inverse depth there). Its own inverse in both cases.
fn disparity(scene: &Scene, t: f32) -> f32 {
    if scene.ndc.is_some() { t } else { 1.0 / t }
}

/// The sweep of every training view (see the module doc); `masks` are the training
/// views' edge masks in `scene.split.train` order, which the fill needs.
pub fn sweep(scene: &Scene, settings: SweepSettings, masks: Option<&[EdgeMask]>) -> Result<StereoTargets, String> {
    check_scene(scene, settings.horizontal)?;
    let train = &scene.split.train;
    if settings.fill > 0 && masks.is_none_or(|m| m.len() != train.len()) {
        return Err("priors.stereo_fill needs the training views' edge masks".into());
    }
    let w2c: Vec<Mat4> = scene.views.iter().map(|v| v.camera.w2c()).collect();
    let up = up_direction(scene);
    let winners: Vec<Option<Winners>> = (0..scene.views.len())
        .map(|v| if train.contains(&v) && train.len() > 1 { winners(scene, v, &w2c, up, settings) } else { None })
        .collect();
    Ok((0..scene.views.len())
        .map(|v| {
            let win = winners[v].as_ref()?;
            let depth = consistent(scene, v, win, &winners, &w2c, settings.consistency);
            let mask = masks.and_then(|m| train.iter().position(|&t| t == v).map(|i| &m[i]));
            Some(match mask {
                Some(mask) if settings.fill > 0 => fill(&depth, &win.span, mask, settings.fill),
                _ => depth.iter().map(|&t| if t > 0.0 { [t, 1.0] } else { [0.0, 0.0] }).collect(),
            })
        })
        .collect())
}

/// Confirmed depths `depth` (0: none) of one view, their gaps filled from the confirmed
/// depths within `radius` pixels in the same region of `mask` (see the module doc);
/// `span` is each pixel's ray span in the box (`None`: it misses the box).
fn fill(depth: &[f32], span: &[Option<(f32, f32)>], mask: &EdgeMask, radius: u32) -> Vec<[f32; 2]> {
    let (w, h) = (mask.width as usize, mask.height as usize);
    assert_eq!(depth.len(), w * h, "an edge mask per view at the view's size");
    let region = regions(mask);
    let r = radius as i64;
    let sigma = (radius as f32 / 2.0).max(0.5);
    let kernel: Vec<f32> = (-r..=r).flat_map(|dy| (-r..=r).map(move |dx| (dx, dy))).map(|(dx, dy)| (-((dx * dx + dy * dy) as f32) / (2.0 * sigma * sigma)).exp()).collect();
    (0..w * h)
        .map(|p| {
            if depth[p] > 0.0 {
                return [depth[p], 1.0];
            }
            let (Some((lo, hi)), Some(label)) = (span[p], region[p]) else { return [0.0, 0.0] };
            let (x, y) = ((p % w) as i64, (p / w) as i64);
            let (mut num, mut confirmed, mut all) = (0.0f32, 0.0f32, 0.0f32);
            for dy in -r..=r {
                let yy = y + dy;
                if yy < 0 || yy >= h as i64 {
                    continue;
                }
                for dx in -r..=r {
                    let xx = x + dx;
                    if xx < 0 || xx >= w as i64 {
                        continue;
                    }
                    let q = yy as usize * w + xx as usize;
                    if region[q] != Some(label) {
                        continue;
                    }
                    let g = kernel[((dy + r) * (2 * r + 1) + dx + r) as usize];
                    all += g;
                    if depth[q] > 0.0 {
                        confirmed += g;
                        num += g * depth[q];
                    }
                }
            }
            let t = if confirmed > 0.0 { num / confirmed } else { 0.0 };
            if t >= lo && t <= hi && t > 0.0 { [t, confirmed / all] } else { [0.0, 0.0] }
        })
        .collect()
}

/// The connected regions (4-neighbours) of a mask's non-edge pixels: a label per pixel,
/// `None` on edges.
fn regions(mask: &EdgeMask) -> Vec<Option<u32>> {
    let (w, h) = (mask.width as usize, mask.height as usize);
    let mut label = vec![None; w * h];
    let mut next = 0u32;
    let mut stack = Vec::new();
    for start in 0..w * h {
        if mask.non_edge[start] == 0 || label[start].is_some() {
            continue;
        }
        label[start] = Some(next);
        stack.push(start);
        while let Some(p) = stack.pop() {
            let (x, y) = (p % w, p / w);
            let neighbours = [(x > 0).then(|| p - 1), (x + 1 < w).then(|| p + 1), (y > 0).then(|| p - w), (y + 1 < h).then(|| p + w)];
            for q in neighbours.into_iter().flatten() {
                if mask.non_edge[q] != 0 && label[q].is_none() {
                    label[q] = Some(next);
                    stack.push(q);
                }
            }
        }
        next += 1;
    }
    label
}

/// One view's winner-take-all depths: per pixel the ray's origin, direction, span in
/// the box and depth (0 where the ray misses the box).
struct Winners {
    origin: Vec<Vec3>,
    dir: Vec<Vec3>,
    span: Vec<Option<(f32, f32)>>,
    depth: Vec<f32>,
}

/// The winner-take-all depth of every pixel of view `s`; `up` is the training cameras'
/// [`up_direction`], which `settings.horizontal` sweeps planes across.
fn winners(scene: &Scene, s: usize, w2c: &[Mat4], up: Option<Vec3>, settings: SweepSettings) -> Option<Winners> {
    let view = &scene.views[s];
    let (w, h) = (view.camera.width, view.camera.height);
    let n = (w * h) as usize;
    let (mut origin, mut dir, mut span) = (Vec::with_capacity(n), Vec::with_capacity(n), Vec::with_capacity(n));
    for y in 0..h {
        for x in 0..w {
            let ray = to_gpu_ray(scene, &scene.ray(s, x, y));
            origin.push(Vec3::from(ray.origin));
            dir.push(Vec3::from(ray.dir));
            span.push(match scene.ndc {
                Some(_) => Some((ray.t_min.max(0.0), ray.t_max.min(NDC_SWEEP_FAR))),
                None => (ray.t_max > ray.t_min && ray.t_min > 0.0).then_some((ray.t_min, ray.t_max)),
            });
        }
    }
    let (near, far) = span.iter().flatten().fold((f32::INFINITY, 0.0f32), |(a, b), &(lo, hi)| (a.min(lo), b.max(hi)));
    if !(near.is_finite() && far > near) {
        return None;
    }
    let others: Vec<usize> = scene.split.train.iter().copied().filter(|&j| j != s).collect();
    let planes = settings.planes.max(2);
    let mut families = vec![Family::Ray];
    if let Some(normal) = up.filter(|_| settings.horizontal) {
        // The heights (along `normal`) of the view's rays' spans in the box; a view that
        // sees no range of heights gets no second family.
        let (lo, hi) = span
            .iter()
            .zip(origin.iter().zip(&dir))
            .filter_map(|(s, (&o, &d))| s.map(|(t0, t1)| (normal.dot(o + t0 * d), normal.dot(o + t1 * d))))
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), (c0, c1)| (a.min(c0).min(c1), b.max(c0).max(c1)));
        if hi > lo {
            families.push(Family::Across { normal, lo, hi });
        }
    }
    // The depth of plane `k` of a family at pixel `p` (0: the ray never meets it).
    let plane_depth = |family: Family, k: u32, p: usize| -> f32 {
        let f = k as f32 / (planes - 1) as f32;
        match family {
            Family::Ray => {
                let (a, b) = (disparity(scene, near), disparity(scene, far));
                disparity(scene, a + f * (b - a))
            }
            Family::Across { normal, lo, hi } => {
                let along = normal.dot(dir[p]);
                let t = (lo + (hi - lo) * f - normal.dot(origin[p])) / along;
                if along.abs() > 1e-6 && t.is_finite() && t > 0.0 { t } else { 0.0 }
            }
        }
    };
    let mut best = vec![f32::INFINITY; n];
    let mut depth = vec![0.0f32; n];
    let mut cost = vec![0.0f32; n];
    let mut t = vec![0.0f32; n];
    // Every plane's window cost, kept only for the uniqueness check (families x planes
    // x pixels).
    let unique = settings.uniqueness < 1.0;
    let mut volume = if unique { Vec::with_capacity(families.len() * planes as usize * n) } else { Vec::new() };
    let own: Vec<[f32; 3]> = (0..n as u32).map(|p| view.image.get(p % w, p / w)).collect();
    for &family in &families {
        for k in 0..planes {
            for p in 0..n {
                t[p] = plane_depth(family, k, p);
                let own = own[p];
                let x = world_point(scene, origin[p], dir[p], t[p]);
                cost[p] = others
                    .iter()
                    .filter_map(|&j| {
                        let (px, _) = scene.views[j].camera.project_with(&w2c[j], x)?;
                        bilinear(&scene.views[j].image, px.x, px.y)
                    })
                    .map(|c| ((c[0] - own[0]).abs() + (c[1] - own[1]).abs() + (c[2] - own[2]).abs()) / 3.0)
                    .fold(1.0, f32::min);
            }
            let mean = box_mean(&cost, w as usize, h as usize, settings.window as usize);
            for p in 0..n {
                let inside = span[p].is_some_and(|(lo, hi)| t[p] >= lo && t[p] <= hi);
                if inside && mean[p] < best[p] {
                    best[p] = mean[p];
                    depth[p] = t[p];
                }
                if unique {
                    volume.push(if inside { mean[p] } else { f32::INFINITY });
                }
            }
        }
    }
    if unique {
        // The least cost of the planes whose depth lies more than UNIQUE_APART of the
        // first family's plane spacings (in inverse depth) from the winner's: for the
        // first family alone, the planes more than UNIQUE_APART planes away.
        let apart = (UNIQUE_APART as f32 + 0.5) * (disparity(scene, near) - disparity(scene, far)).abs() / (planes - 1) as f32;
        for p in 0..n {
            if depth[p] <= 0.0 {
                continue;
            }
            let mut second = f32::INFINITY;
            for (i, &family) in families.iter().enumerate() {
                for k in 0..planes {
                    let c = volume[(i * planes as usize + k as usize) * n + p];
                    if c < second && (disparity(scene, plane_depth(family, k, p)) - disparity(scene, depth[p])).abs() > apart {
                        second = c;
                    }
                }
            }
            if best[p] >= settings.uniqueness * second {
                depth[p] = 0.0;
            }
        }
    }
    Some(Winners { origin, dir, span, depth })
}

/// View `s`'s winners that another view's winners confirm (0 elsewhere).
fn consistent(scene: &Scene, s: usize, win: &Winners, all: &[Option<Winners>], w2c: &[Mat4], tolerance: f32) -> Vec<f32> {
    (0..win.depth.len())
        .map(|p| {
            let t = win.depth[p];
            if t <= 0.0 {
                return 0.0;
            }
            let x = world_point(scene, win.origin[p], win.dir[p], t);
            // The point's distance from the camera: `t` itself on unit world-space rays
            // from the camera centre.
            let distance = if scene.ndc.is_some() { (x - scene.views[s].camera.origin()).length() } else { t };
            let confirmed = scene.split.train.iter().filter(|&&j| j != s).any(|&j| {
                let (Some(other), cam) = (all[j].as_ref(), &scene.views[j].camera) else { return false };
                let Some((px, _)) = cam.project_with(&w2c[j], x) else { return false };
                if !cam.in_frame(px) {
                    return false;
                }
                let q = (px.y as u32).min(cam.height - 1) * cam.width + (px.x as u32).min(cam.width - 1);
                let tj = other.depth[q as usize];
                tj > 0.0 && (world_point(scene, other.origin[q as usize], other.dir[q as usize], tj) - x).length() <= tolerance * distance
            });
            if confirmed { t } else { 0.0 }
        })
        .collect()
}

/// `image` at continuous pixel coordinates (pixel centres at `+1/2`); `None` outside
/// the span of the centres.
fn bilinear(image: &crate::data::ImageRgb, px: f32, py: f32) -> Option<[f32; 3]> {
    let (w, h) = (image.width, image.height);
    let (x, y) = (px - 0.5, py - 0.5);
    if w < 2 || h < 2 || !(x >= 0.0 && y >= 0.0 && x <= (w - 1) as f32 && y <= (h - 1) as f32) {
        return None;
    }
    let (x0, y0) = ((x as u32).min(w - 2), (y as u32).min(h - 2));
    let (a, b) = (x - x0 as f32, y - y0 as f32);
    let (c00, c10, c01, c11) = (image.get(x0, y0), image.get(x0 + 1, y0), image.get(x0, y0 + 1), image.get(x0 + 1, y0 + 1));
    Some(std::array::from_fn(|c| (c00[c] * (1.0 - a) + c10[c] * a) * (1.0 - b) + (c01[c] * (1.0 - a) + c11[c] * a) * b))
}

/// The mean of `values` (a `w x h` image) over the `(2r + 1)^2` square around each
/// pixel, clipped at the borders (the mean of what lies inside).
fn box_mean(values: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    // Summed-area table with a zero row and column in front.
    let mut sat = vec![0.0f64; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0.0f64;
        for x in 0..w {
            row += values[y * w + x] as f64;
            sat[(y + 1) * (w + 1) + x + 1] = sat[y * (w + 1) + x + 1] + row;
        }
    }
    let mut out = vec![0.0f32; w * h];
    for y in 0..h {
        let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(h));
        for x in 0..w {
            let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(w));
            let s = sat[y1 * (w + 1) + x1] - sat[y0 * (w + 1) + x1] - sat[y1 * (w + 1) + x0] + sat[y0 * (w + 1) + x0];
            out[y * w + x] = (s / ((y1 - y0) * (x1 - x0)) as f64) as f32;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::{Camera, ImageRgb, SceneFormat, Split, View};

    /// View `i`: a `w x h` camera at `c2w` seeing a textured floor (z = 0), each pixel
    /// the texture where its ray meets the floor (grey where it does not).
    fn floor_view(i: usize, c2w: Mat4, w: u32, h: u32) -> View {
        let texture = |p: Vec3| -> [f32; 3] {
            let a = (p.x * 7.3).sin() * (p.y * 5.1).cos();
            let b = (p.x * 2.9 + p.y * 3.7).sin();
            [0.5 + 0.4 * a, 0.5 + 0.4 * b, 0.5 + 0.2 * (a * b)]
        };
        let camera = Camera::from_fov_x(w, h, 1.0, c2w);
        let mut image = ImageRgb::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let r = camera.pixel_ray(x as f32 + 0.5, y as f32 + 0.5);
                let t = -r.origin.z / r.dir.z;
                image.set(x, y, if t > 0.0 { texture(r.origin + t * r.dir) } else { [0.5; 3] });
            }
        }
        View { name: format!("v{i}"), path: format!("v{i}.png").into(), camera, image, mask: None, alpha: None, depth: None, normal: None, train_mask: None }
    }

    /// Three cameras looking down at a textured floor (z = 0) from 2 m; the images are
    /// the floor's texture where each pixel's ray meets it.
    fn floor_scene() -> Scene {
        let eyes = [Vec3::new(0.0, 0.0, 2.0), Vec3::new(0.3, 0.0, 2.0), Vec3::new(0.0, 0.3, 2.0)];
        let views = eyes.iter().enumerate().map(|(i, &eye)| floor_view(i, crate::data::paths::look_at(eye, eye - Vec3::Z, Vec3::Y), 48, 40)).collect();
        Scene {
            root: ".".into(),
            format: SceneFormat::Blender,
            views,
            split: Split { train: vec![0, 1, 2], test: vec![] },
            near: 0.5,
            far: 4.0,
            ndc: None,
            aabb: [Vec3::new(-2.0, -2.0, -0.5), Vec3::new(2.0, 2.0, 1.5)],
            background: None,
        }
    }

    #[test]
    fn the_sweep_finds_a_textured_floor_and_keeps_only_confirmed_depths() {
        let scene = floor_scene();
        let settings = SweepSettings { planes: 96, window: 1, consistency: 0.02, fill: 0, uniqueness: 1.0, horizontal: false };
        let targets = sweep(&scene, settings, None).unwrap();
        let depth = targets[0].as_ref().unwrap();
        let cam = &scene.views[0].camera;
        let (mut kept, mut close) = (0, 0);
        for y in 0..cam.height {
            for x in 0..cam.width {
                let [t, c] = depth[(y * cam.width + x) as usize];
                assert!(c == 0.0 || c == 1.0, "without the fill a target is confirmed or none");
                if t > 0.0 {
                    kept += 1;
                    let r = scene.ray(0, x, y);
                    let truth = -r.origin.z / r.dir.z;
                    close += ((t - truth).abs() < 0.03 * truth) as u32;
                }
            }
        }
        let n = cam.width * cam.height;
        assert!(kept > n / 3, "most of a textured floor seen by three views is confirmed: {kept} of {n}");
        assert!(close as f32 > 0.95 * kept as f32, "confirmed depths lie on the floor: {close} of {kept}");
        // A view alone has nothing to compare with.
        let alone = Scene { split: Split { train: vec![0], test: vec![1, 2] }, ..scene.clone() };
        assert!(sweep(&alone, settings, None).unwrap().iter().all(Option::is_none));
        assert!(sweep(&scene, SweepSettings { fill: 4, ..settings }, None).unwrap_err().contains("edge masks"));
    }

    /// The floor scene as a forward-facing LLFF capture: the cameras moved to `z = 0`
    /// (the floor 2 m in front of them at `z = -2`, the images unchanged) and NDC rays
    /// with the near plane at 1.
    fn ndc_floor_scene() -> Scene {
        let floor = floor_scene();
        let views = floor
            .views
            .into_iter()
            .map(|mut v| {
                v.camera.c2w = Mat4::from_translation(-2.0 * Vec3::Z) * v.camera.c2w;
                v
            })
            .collect::<Vec<_>>();
        let c = views[0].camera;
        let ndc = crate::data::NdcParams { focal_x: c.fx, focal_y: c.fy, width: c.width as f32, height: c.height as f32, near: 1.0 };
        Scene { views, near: 0.0, far: 1.0, ndc: Some(ndc), aabb: [Vec3::new(-1.5, -1.5, -1.0), Vec3::new(1.5, 1.5, 1.0)], ..floor }
    }

    #[test]
    fn the_sweep_runs_along_ndc_rays_and_gives_ndc_ray_parameters() {
        let scene = ndc_floor_scene();
        let settings = SweepSettings { planes: 96, window: 1, consistency: 0.02, fill: 0, uniqueness: 1.0, horizontal: false };
        let targets = sweep(&scene, settings, None).unwrap();
        // The floor lies 2 m along -z from every camera: NDC t = 1 - near / 2 = 0.5 on
        // every pixel (NDC depth depends on z alone).
        let ndc = scene.ndc.unwrap();
        let depth = targets[0].as_ref().unwrap();
        let kept: Vec<f32> = depth.iter().filter(|d| d[0] > 0.0).map(|d| d[0]).collect();
        let n = depth.len();
        assert!(kept.len() > n / 3, "most of a textured floor seen by three views is confirmed: {} of {n}", kept.len());
        let close = kept.iter().filter(|&&t| (ndc.ndc_t_to_world_depth(t) - 2.0).abs() < 0.03 * 2.0).count();
        assert!(close as f32 > 0.95 * kept.len() as f32, "confirmed NDC depths lie on the floor: {close} of {}", kept.len());
        assert!(kept.iter().all(|&t| (0.0..=NDC_SWEEP_FAR).contains(&t)), "targets are NDC ray parameters in the sweep's span");
        // No accuracy against ground truth (the targets are not distances) and no
        // world-space planes or ground-truth targets on NDC rays, each with what to do.
        assert!(accuracy(&scene, &targets).is_none());
        let across = sweep(&scene, SweepSettings { horizontal: true, ..settings }, None).unwrap_err();
        assert!(across.contains("priors.stereo_horizontal = false"), "{across}");
        assert!(ground_truth(&scene).unwrap_err().contains("\"sweep\""));
    }

    #[test]
    fn the_fill_reads_only_its_own_region_and_keeps_the_confirmed_depths() {
        // 12 x 5 pixels, an edge down column 6: left confirmed at 2 on column 1, right
        // at 5 on column 10; the rest of each side empty.
        let (w, h) = (12usize, 5usize);
        let mut mask = EdgeMask::all_non_edge(w as u32, h as u32);
        let mut depth = vec![0.0f32; w * h];
        for y in 0..h {
            mask.non_edge[y * w + 6] = 0;
            depth[y * w + 1] = 2.0;
            depth[y * w + 10] = 5.0;
        }
        let mut span = vec![Some((0.5, 10.0)); w * h];
        span[w * 2 + 3] = None; // this pixel's ray misses the box
        span[w * 2 + 4] = Some((2.5, 10.0)); // the fill would land short of the box
        let out = fill(&depth, &span, &mask, 4);
        for y in 0..h {
            for x in 0..w {
                let [t, c] = out[y * w + x];
                let p = (x, y);
                match x {
                    1 | 10 => assert_eq!([t, c], [depth[y * w + x], 1.0], "{p:?} confirmed, kept"),
                    6 => assert_eq!([t, c], [0.0, 0.0], "{p:?} on the edge: not filled"),
                    3 | 4 if y == 2 => assert_eq!([t, c], [0.0, 0.0], "{p:?} outside its span"),
                    0 | 2..=5 => assert!((t - 2.0).abs() < 1e-6 && c > 0.0 && c < 1.0, "{p:?} left of the edge: {t} {c}"),
                    _ => assert!((t - 5.0).abs() < 1e-6 && c > 0.0 && c < 1.0, "{p:?} right of the edge: {t} {c}"),
                }
            }
        }
        // Farther from the confirmed column, less confidence.
        assert!(out[2 * w + 2][1] > out[2 * w + 5][1]);
        // Beyond the radius, nothing.
        let out = fill(&depth, &span, &mask, 1);
        assert_eq!(out[4], [0.0, 0.0]);
        // The sweep with the fill: every confirmed depth kept, more pixels with a target.
        let scene = floor_scene();
        let masks: Vec<EdgeMask> = (0..3).map(|_| EdgeMask::all_non_edge(48, 40)).collect();
        let settings = SweepSettings { planes: 96, window: 1, consistency: 0.02, fill: 0, uniqueness: 1.0, horizontal: false };
        let plain = sweep(&scene, settings, None).unwrap();
        let filled = sweep(&scene, SweepSettings { fill: 6, ..settings }, Some(&masks)).unwrap();
        let count = |t: &StereoTargets| t.iter().flatten().flatten().filter(|v| v[1] > 0.0).count();
        assert!(count(&filled) > count(&plain), "{} against {}", count(&filled), count(&plain));
        for (a, b) in plain.iter().flatten().flatten().zip(filled.iter().flatten().flatten()) {
            if a[1] > 0.0 {
                assert_eq!(a, b);
            }
        }
    }

    #[test]
    fn the_uniqueness_check_drops_flat_colour_and_keeps_texture() {
        // The floor scene with its left half painted one flat grey in every view.
        let mut scene = floor_scene();
        for view in &mut scene.views {
            for y in 0..40 {
                for x in 0..48 {
                    let r = view.camera.pixel_ray(x as f32 + 0.5, y as f32 + 0.5);
                    let t = -r.origin.z / r.dir.z;
                    if (r.origin + t * r.dir).x < -0.2 {
                        view.image.set(x, y, [0.5; 3]);
                    }
                }
            }
        }
        let settings = SweepSettings { planes: 96, window: 1, consistency: 0.02, fill: 0, uniqueness: 1.0, horizontal: false };
        let w2c: Vec<Mat4> = scene.views.iter().map(|v| v.camera.w2c()).collect();
        // The winners before the left-right check: on flat colour every plane costs the
        // same and the first wins.
        let count = |win: &Winners, flat: bool| {
            let cam = &scene.views[0].camera;
            (0..40u32)
                .flat_map(|y| (0..48u32).map(move |x| (x, y)))
                .filter(|&(x, y)| {
                    let r = cam.pixel_ray(x as f32 + 0.5, y as f32 + 0.5);
                    let px = (r.origin + (-r.origin.z / r.dir.z) * r.dir).x;
                    let region = if flat { px < -0.3 } else { px > -0.1 };
                    region && win.depth[(y * 48 + x) as usize] > 0.0
                })
                .count()
        };
        let plain = winners(&scene, 0, &w2c, None, settings).unwrap();
        let unique = winners(&scene, 0, &w2c, None, SweepSettings { uniqueness: 0.8, ..settings }).unwrap();
        let (flat_plain, flat_unique) = (count(&plain, true), count(&unique, true));
        assert!(flat_unique * 4 < flat_plain, "the flat half: {flat_unique} depths with the check, {flat_plain} without");
        let (kept, all) = (count(&unique, false), count(&plain, false));
        assert!(all > 100 && kept as f32 > 0.8 * all as f32, "the textured half keeps its depths: {kept} of {all}");
    }

    /// The floor scene's texture seen by three cameras 120 degrees apart around the
    /// origin, 1.2 above the floor at 2 from the axis, looking at the origin (`room`'s
    /// layout): a window at one depth along the rays covers different texture in each.
    fn ring_scene() -> Scene {
        let floor = floor_scene();
        let views = (0..3)
            .map(|i| {
                let phi = i as f32 * std::f32::consts::TAU / 3.0;
                let eye = Vec3::new(2.0 * phi.cos(), 2.0 * phi.sin(), 1.2);
                floor_view(i, crate::data::paths::look_at(eye, Vec3::ZERO, Vec3::Z), 64, 48)
            })
            .collect();
        Scene { views, aabb: [Vec3::new(-2.5, -2.5, -0.05), Vec3::new(2.5, 2.5, 1.5)], near: 0.3, ..floor }
    }

    #[test]
    fn planes_across_the_up_direction_find_a_floor_the_views_see_from_far_apart() {
        let scene = ring_scene();
        assert!((up_direction(&scene).unwrap() - Vec3::Z).length() < 1e-5, "the cameras' mean up is the world's");
        // (confirmed, within 3 % of the floor's depth), over the three views.
        let score = |horizontal: bool| {
            let settings = SweepSettings { planes: 96, window: 2, consistency: 0.01, fill: 0, uniqueness: 0.9, horizontal };
            let targets = sweep(&scene, settings, None).unwrap();
            let (mut kept, mut close) = (0, 0);
            for (v, target) in targets.iter().enumerate() {
                for (p, &[t, _]) in target.as_ref().unwrap().iter().enumerate() {
                    if t > 0.0 {
                        kept += 1;
                        let r = scene.ray(v, p as u32 % 64, p as u32 / 64);
                        let truth = -r.origin.z / r.dir.z;
                        close += (truth > 0.0 && (t - truth).abs() < 0.03 * truth) as u32;
                    }
                }
            }
            (kept, close)
        };
        let (along, across) = (score(false), score(true));
        eprintln!("along the rays {along:?}, with planes across up {across:?}");
        assert!(across.1 > 2 * along.1, "more of the floor found: {across:?} against {along:?}");
        assert!(across.1 as f32 > 0.9 * across.0 as f32, "and what is found lies on it: {across:?}");
        // Cameras that disagree about up get no second family.
        let mut rolled = scene.clone();
        for (i, view) in rolled.views.iter_mut().enumerate() {
            let roll = glam::Mat4::from_rotation_z(i as f32 * std::f32::consts::TAU / 3.0);
            view.camera.c2w = view.camera.c2w * roll;
        }
        assert!(up_direction(&rolled).is_none());
    }

    #[test]
    fn box_mean_is_the_mean_over_the_clipped_square() {
        let v: Vec<f32> = (0..12).map(|i| i as f32).collect();
        let m = box_mean(&v, 4, 3, 1);
        assert_eq!(m[5], (0.0 + 1.0 + 2.0 + 4.0 + 5.0 + 6.0 + 8.0 + 9.0 + 10.0) / 9.0);
        assert_eq!(m[0], (0.0 + 1.0 + 4.0 + 5.0) / 4.0);
        assert_eq!(box_mean(&v, 4, 3, 0), v);
    }

    /// The accuracy report: the median relative error and the outliers' share over the
    /// confirmed targets of the views with ground-truth depth, nothing without it.
    #[test]
    fn accuracy_is_measured_on_the_confirmed_targets_against_the_true_depth() {
        let mut scene = floor_scene();
        let n = scene.views[0].image.data.len() / 3;
        assert!(accuracy(&scene, &vec![Some(vec![[2.0, 1.0]; n]); 3]).is_none(), "no ground truth, no report");
        scene.views[0].depth = Some(vec![2.0; n]);
        scene.views[1].depth = Some(vec![2.0; n]);
        // View 0: 5 targets, 1 % / 2 % / 3 % / 20 % / 50 % off; a filled target (confidence
        // under 1) and a pixel without a true surface are not counted. View 1: none
        // confirmed. View 2: confirmed but without ground truth.
        let mut t0 = vec![[0.0, 0.0]; n];
        for (i, e) in [0.01f32, 0.02, 0.03, 0.2, -0.5].iter().enumerate() {
            t0[i] = [2.0 * (1.0 + e), 1.0];
        }
        t0[5] = [9.0, 0.5];
        t0[6] = [9.0, 1.0];
        scene.views[0].depth.as_mut().unwrap()[6] = 0.0;
        let targets = vec![Some(t0), Some(vec![[0.0, 0.0]; n]), Some(vec![[9.0, 1.0]; n])];
        let a = accuracy(&scene, &targets).unwrap();
        assert_eq!(a.pixels, 5);
        assert!((a.median_error - 0.03).abs() < 1e-5, "{a:?}");
        assert!((a.outliers - 0.4).abs() < 1e-6, "{a:?}");
    }

    /// Ground-truth targets: each training pixel's true distance, confirmed; pixels
    /// without a surface get none, test views nothing; a training view without depth
    /// is refused with what to do.
    #[test]
    fn ground_truth_targets_are_the_training_views_true_depths() {
        let mut scene = floor_scene();
        let n = scene.views[0].image.data.len() / 3;
        let err = ground_truth(&scene).unwrap_err();
        assert!(err.contains("ground_truth") && err.contains("v0") && err.contains("sweep"), "{err}");
        for (i, v) in scene.views.iter_mut().enumerate() {
            let mut d: Vec<f32> = (0..n).map(|p| 2.0 + 0.001 * (p + i) as f32).collect();
            d[3] = 0.0;
            v.depth = Some(d);
        }
        scene.split = Split { train: vec![0, 2], test: vec![1] };
        let t = ground_truth(&scene).unwrap();
        assert!(t[1].is_none(), "a test view gets no targets");
        for v in [0, 2] {
            let t = t[v].as_ref().unwrap();
            assert_eq!(t[3], [0.0, 0.0], "no surface, no target");
            assert_eq!(t[10], [2.0 + 0.001 * (10 + v) as f32, 1.0]);
        }
        let a = accuracy(&scene, &t).unwrap();
        assert_eq!((a.pixels, a.median_error, a.outliers), (2 * (n - 1), 0.0, 0.0));
    }
}
