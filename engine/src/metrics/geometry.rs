//! Geometry against ground truth: depth and normal errors, over all valid pixels and
//! split into edge / non-edge regions of a ground-truth edge map (NOTES.md section 5:
//! "sharp boundaries, smooth interiors" in numbers).
//!
//! # Depth (over pixels whose GT depth `g` is `> 0` and finite)
//! The prediction `d` is clamped to `d >= 1e-6` (NaN becomes `1e-6`) so logs and
//! ratios exist; `+inf` stays and makes the errors infinite.
//! * `AbsRel = mean |d - g| / g`
//! * `RMSE = sqrt(mean (d - g)^2)` (scene units)
//! * `RMSE-log = sqrt(mean (ln d - ln g)^2)` (natural log)
//! * `delta_k = fraction of pixels with max(d / g, g / d) < 1.25^k`, `k = 1, 2, 3`
//!
//! # Normals (over pixels whose GT normal is nonzero and finite)
//! `angle = atan2(|n x n*|, n . n*)` in degrees: `arccos(clamp(<n, n*>))` for unit
//! vectors, but independent of both lengths (so the prediction is in effect
//! renormalised) and exact near 0 (`acos` of a dot product of stored normals, unit
//! only to ~3e-5, would report ~0.5 deg for identical normals). A predicted normal that
//! cannot be normalised (length < 1e-12 or not finite) counts as 90 deg, the expected
//! angle of a random direction. Reported: mean, median (numpy's: mean of the middle
//! two for even counts), and the fractions (in `[0, 1]`) under 11.25, 22.5, 30 deg.
//!
//! # Edge map ([`gt_edge_map`])
//! Over every pair `(p, q)` of 4-neighbours, both pixels are marked when
//! * **depth discontinuity**: both have valid GT depth and the jump exceeds what the
//!   surface's own slope explains: with `b` the pixel before `p` and `a` the pixel after
//!   `q` on the same row or column,
//!   `e = |g_p - g_q| - min(|g_b - g_p|, |g_q - g_a|)` (over the neighbouring slopes that
//!   exist with valid depth; `e = |g_p - g_q|` when neither does), and
//!   `e / min(g_p, g_q) > depth_jump` (default 0.02). Subtracting the smaller
//!   neighbouring slope keeps planes seen at grazing angles (a floor toward the horizon
//!   grows by several % per pixel) out of the map, while a 2 % step (a panel in front of
//!   a wall in `occlusion`) is in, and a one-pixel-wide object still counts (one of its
//!   sides is flat);
//! * **validity boundary**: exactly one of them has valid GT depth (the silhouette
//!   against the background);
//! * **normal discontinuity**: both have a GT normal and the angle between them is
//!   `> normal_angle_deg` (default 30 deg: the smallest crease of the committed scenes
//!   is the 45 deg turn between faces of the octagonal base in `turntable`, those of the
//!   polyhedra in `creases` are larger; curved surfaces turn by well under 30 deg per
//!   pixel at 128 px except right at silhouettes, which are edges anyway). With normals
//!   but no depth, the boundary of the nonzero-normal region counts as the validity
//!   boundary.
//!
//! The marked set is then dilated to every pixel within Euclidean distance
//! `dilate_px` (default 2) of it, through [`super::distance`]. "Edge" statistics are
//! over valid pixels inside the dilated map, "non-edge" over valid pixels outside it.

use serde::{Deserialize, Serialize};

use super::{MetricsError, valid_depth, valid_normal};
use super::boundary::{DbeParams, DepthBoundaryError, depth_boundary_error};
use super::distance::squared_distance_transform;

/// Predicted depths are clamped to at least this before ratios and logs.
pub const MIN_PRED_DEPTH: f64 = 1e-6;
/// The angle (degrees) given to a predicted normal that cannot be normalised.
pub const DEGENERATE_NORMAL_DEG: f64 = 90.0;

/// Depth errors over one set of pixels.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DepthErrors {
    /// Pixels averaged over.
    pub pixels: usize,
    /// Mean absolute error `mean |d - d*|`, in the depth's units.
    pub abs: f64,
    pub abs_rel: f64,
    pub rmse: f64,
    pub rmse_log: f64,
    /// Fraction (in `[0, 1]`) with `max(d/g, g/d) < 1.25`.
    pub delta_1: f64,
    /// ... `< 1.25^2`.
    pub delta_2: f64,
    /// ... `< 1.25^3`.
    pub delta_3: f64,
}

/// Normal angle errors over one set of pixels, in degrees.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct NormalErrors {
    /// Pixels averaged over.
    pub pixels: usize,
    pub mean_deg: f64,
    pub median_deg: f64,
    /// Fraction (in `[0, 1]`) of pixels with an angle `< 11.25` deg.
    pub under_11_25: f64,
    /// ... `< 22.5` deg.
    pub under_22_5: f64,
    /// ... `< 30` deg.
    pub under_30: f64,
}

/// One metric over all valid pixels and over the edge / non-edge parts of them;
/// `None` where the region has no valid pixel (or no edge map was given).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Regions<T> {
    pub all: Option<T>,
    pub edge: Option<T>,
    pub non_edge: Option<T>,
}

/// How [`gt_edge_map`] finds ground-truth edges (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct EdgeMapParams {
    /// Relative depth jump between 4-neighbours, beyond the neighbouring slope, that
    /// makes a depth edge.
    pub depth_jump: f32,
    /// Angle between neighbouring GT normals (degrees) that makes a normal edge.
    pub normal_angle_deg: f32,
    /// Euclidean dilation radius in pixels (0: the marked pixels only).
    pub dilate_px: f32,
}

impl Default for EdgeMapParams {
    fn default() -> Self {
        Self { depth_jump: 0.02, normal_angle_deg: 30.0, dilate_px: 2.0 }
    }
}

/// Parameters of [`evaluate_geometry`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct GeometryParams {
    pub edges: EdgeMapParams,
    pub dbe: DbeParams,
}

/// Ground truth and prediction of one view for [`evaluate_geometry`]; every slice has
/// `width * height` entries.
#[derive(Clone, Copy, Debug)]
pub struct GeometryInputs<'a> {
    pub width: u32,
    pub height: u32,
    pub gt_depth: Option<&'a [f32]>,
    pub gt_normal: Option<&'a [[f32; 3]]>,
    /// Predicted ray distance, in the ground truth's units.
    pub depth: Option<&'a [f32]>,
    /// Predicted normals (any length), same space as the ground truth.
    pub normal: Option<&'a [[f32; 3]]>,
}

/// Every geometry metric of one view.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GeometryMetrics {
    pub params: GeometryParams,
    /// Pixels in the (dilated) ground-truth edge map.
    pub edge_pixels: usize,
    /// Pixels in the image.
    pub pixels: usize,
    /// Present when both GT and predicted depth are.
    pub depth: Option<Regions<DepthErrors>>,
    /// Present when both GT and predicted normals are.
    pub normal: Option<Regions<NormalErrors>>,
    /// Present when both GT and predicted depth are.
    pub boundary: Option<DepthBoundaryError>,
}

/// Angle in degrees between a ground-truth normal and a prediction of any length
/// (see the module docs; [`DEGENERATE_NORMAL_DEG`] for a prediction with no direction).
pub fn normal_angle_deg(gt: &[f32; 3], pred: &[f32; 3]) -> f64 {
    let g = glam::DVec3::new(gt[0] as f64, gt[1] as f64, gt[2] as f64);
    let p = glam::DVec3::new(pred[0] as f64, pred[1] as f64, pred[2] as f64);
    if !p.is_finite() || p.length() < 1e-12 {
        return DEGENERATE_NORMAL_DEG;
    }
    g.cross(p).length().atan2(g.dot(p)).to_degrees()
}

/// Depth errors of `pred` against `gt` over valid GT pixels, split by `edges` when
/// given.
pub fn depth_errors(gt: &[f32], pred: &[f32], edges: Option<&[bool]>) -> Result<Regions<DepthErrors>, MetricsError> {
    MetricsError::check_len("predicted depth", gt.len(), pred.len())?;
    check_edges(edges, gt.len())?;
    let region = |want: Option<bool>| {
        let pixels = (0..gt.len()).filter(|&i| valid_depth(gt[i]) && in_region(edges, i, want));
        depth_stats(pixels.map(|i| (gt[i] as f64, (pred[i] as f64).max(MIN_PRED_DEPTH))))
    };
    Ok(split(edges, region))
}

/// Normal angle errors of `pred` against `gt` over pixels with a GT normal, split by
/// `edges` when given.
pub fn normal_errors(
    gt: &[[f32; 3]],
    pred: &[[f32; 3]],
    edges: Option<&[bool]>,
) -> Result<Regions<NormalErrors>, MetricsError> {
    MetricsError::check_len("predicted normals", gt.len(), pred.len())?;
    check_edges(edges, gt.len())?;
    let angles: Vec<Option<f64>> =
        gt.iter().zip(pred).map(|(g, p)| valid_normal(g).then(|| normal_angle_deg(g, p))).collect();
    let region = |want: Option<bool>| {
        let mut a: Vec<f64> = (0..gt.len()).filter(|&i| in_region(edges, i, want)).filter_map(|i| angles[i]).collect();
        normal_stats(&mut a)
    };
    Ok(split(edges, region))
}

/// The ground-truth edge map (see the module docs) from GT depth and/or normals,
/// `width * height` booleans. With neither, no pixel is an edge.
pub fn gt_edge_map(
    width: u32,
    height: u32,
    depth: Option<&[f32]>,
    normal: Option<&[[f32; 3]]>,
    params: &EdgeMapParams,
) -> Result<Vec<bool>, MetricsError> {
    let (w, h) = (width as usize, height as usize);
    if let Some(d) = depth {
        MetricsError::check_len("GT depth", w * h, d.len())?;
    }
    if let Some(n) = normal {
        MetricsError::check_len("GT normals", w * h, n.len())?;
    }
    // `p`, `q` neighbours; `before` precedes `p` and `after` follows `q` on their line.
    let is_edge = |p: usize, q: usize, before: Option<usize>, after: Option<usize>| -> bool {
        if let Some(d) = depth {
            let (a, b) = (d[p], d[q]);
            match (valid_depth(a), valid_depth(b)) {
                (true, true) => {
                    // The smaller slope on either side (of those that exist): what a
                    // continuous surface would step by (0 when neither side exists).
                    let slope = |i: Option<usize>, j: usize| i.filter(|&i| valid_depth(d[i])).map(|i| (d[i] - d[j]).abs());
                    let expected = match (slope(before, p), slope(after, q)) {
                        (Some(s), Some(t)) => s.min(t),
                        (s, t) => s.or(t).unwrap_or(0.0),
                    };
                    let excess = (a - b).abs() - expected;
                    if excess / a.min(b) > params.depth_jump {
                        return true;
                    }
                }
                (false, false) => {}
                _ => return true,
            }
        }
        if let Some(n) = normal {
            match (valid_normal(&n[p]), valid_normal(&n[q])) {
                (true, true) => {
                    if normal_angle_deg(&n[p], &n[q]) > params.normal_angle_deg as f64 {
                        return true;
                    }
                }
                (false, false) => {}
                _ => return depth.is_none(),
            }
        }
        false
    };
    let mut marked = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            // (step, p has a neighbour along it, p has a predecessor, q has a successor)
            let lines = [(1, x + 1 < w, x > 0, x + 2 < w), (w, y + 1 < h, y > 0, y + 2 < h)];
            for (step, has_q, has_before, has_after) in lines {
                let q = p + step;
                if has_q && is_edge(p, q, has_before.then(|| p - step), has_after.then(|| q + step)) {
                    marked[p] = true;
                    marked[q] = true;
                }
            }
        }
    }
    Ok(dilate(width, height, &marked, params.dilate_px))
}

/// Every pixel within Euclidean distance `radius` of a `true` pixel of `map`.
pub fn dilate(width: u32, height: u32, map: &[bool], radius: f32) -> Vec<bool> {
    let r2 = (radius.max(0.0) as f64).powi(2);
    squared_distance_transform(width, height, map).into_iter().map(|d2| d2 <= r2).collect()
}

/// Depth, normal and boundary metrics of one view, the GT edge map built from the
/// view's own ground truth with `params.edges`.
pub fn evaluate_geometry(inputs: &GeometryInputs, params: &GeometryParams) -> Result<GeometryMetrics, MetricsError> {
    let GeometryInputs { width, height, gt_depth, gt_normal, depth, normal } = *inputs;
    let edges = gt_edge_map(width, height, gt_depth, gt_normal, &params.edges)?;
    let depth_metrics = match (gt_depth, depth) {
        (Some(g), Some(d)) => Some(depth_errors(g, d, Some(&edges))?),
        _ => None,
    };
    let normal_metrics = match (gt_normal, normal) {
        (Some(g), Some(n)) => Some(normal_errors(g, n, Some(&edges))?),
        _ => None,
    };
    let boundary = match (gt_depth, depth) {
        (Some(g), Some(d)) => Some(depth_boundary_error(width, height, g, d, &params.dbe)?),
        _ => None,
    };
    Ok(GeometryMetrics {
        params: *params,
        edge_pixels: edges.iter().filter(|&&e| e).count(),
        pixels: edges.len(),
        depth: depth_metrics,
        normal: normal_metrics,
        boundary,
    })
}

fn check_edges(edges: Option<&[bool]>, n: usize) -> Result<(), MetricsError> {
    edges.map_or(Ok(()), |e| MetricsError::check_len("edge map", n, e.len()))
}

/// Whether pixel `i` belongs to the region `want`: all pixels (`None`), edge pixels
/// (`Some(true)`) or non-edge pixels (`Some(false)`).
fn in_region(edges: Option<&[bool]>, i: usize, want: Option<bool>) -> bool {
    match (want, edges) {
        (None, _) => true,
        (Some(w), Some(e)) => e[i] == w,
        (Some(_), None) => false,
    }
}

fn split<T>(edges: Option<&[bool]>, region: impl Fn(Option<bool>) -> Option<T>) -> Regions<T> {
    Regions {
        all: region(None),
        edge: edges.and_then(|_| region(Some(true))),
        non_edge: edges.and_then(|_| region(Some(false))),
    }
}

/// Statistics of `(gt, clamped prediction)` pairs; `None` when there is none.
fn depth_stats(pairs: impl Iterator<Item = (f64, f64)>) -> Option<DepthErrors> {
    let (mut n, mut abs, mut abs_rel, mut se, mut se_log) = (0usize, 0.0, 0.0, 0.0, 0.0);
    let mut within = [0usize; 3];
    for (g, d) in pairs {
        n += 1;
        abs += (d - g).abs();
        abs_rel += (d - g).abs() / g;
        se += (d - g) * (d - g);
        se_log += (d.ln() - g.ln()).powi(2);
        let ratio = (d / g).max(g / d);
        for (k, count) in within.iter_mut().enumerate() {
            *count += (ratio < 1.25f64.powi(k as i32 + 1)) as usize;
        }
    }
    (n > 0).then(|| {
        let nf = n as f64;
        DepthErrors {
            pixels: n,
            abs: abs / nf,
            abs_rel: abs_rel / nf,
            rmse: (se / nf).sqrt(),
            rmse_log: (se_log / nf).sqrt(),
            delta_1: within[0] as f64 / nf,
            delta_2: within[1] as f64 / nf,
            delta_3: within[2] as f64 / nf,
        }
    })
}

/// Statistics of per-pixel angles (degrees); `None` when there is none.
fn normal_stats(angles: &mut [f64]) -> Option<NormalErrors> {
    let n = angles.len() as f64;
    let frac = |t: f64| angles.iter().filter(|&&a| a < t).count() as f64 / n;
    let (mean, u1, u2, u3) = (angles.iter().sum::<f64>() / n, frac(11.25), frac(22.5), frac(30.0));
    let median = super::median(angles)?;
    Some(NormalErrors {
        pixels: angles.len(),
        mean_deg: mean,
        median_deg: median,
        under_11_25: u1,
        under_22_5: u2,
        under_30: u3,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-9
    }

    #[test]
    fn depth_errors_by_hand() {
        // GT 1, 2, 4, invalid 0; predictions 1.1, 2, 2, anything.
        let gt = [1.0, 2.0, 4.0, 0.0];
        let pred = [1.1, 2.0, 2.0, 7.0];
        let r = depth_errors(&gt, &pred, None).unwrap();
        let e = r.all.unwrap();
        assert_eq!(e.pixels, 3);
        // (|0.1|/1 + 0 + 2/4) / 3 = 0.2 (up to f32 rounding of 1.1)
        assert!((e.abs_rel - 0.2).abs() < 1e-7, "{}", e.abs_rel);
        // sqrt((0.01 + 0 + 4) / 3)
        assert!((e.rmse - ((0.01 + 4.0) / 3.0f64).sqrt()).abs() < 1e-7);
        // sqrt((ln 1.1)^2 + 0 + (ln 0.5)^2) / 3)
        let want_log = ((1.1f64.ln().powi(2) + 0.5f64.ln().powi(2)) / 3.0).sqrt();
        assert!((e.rmse_log - want_log).abs() < 1e-7);
        // ratios 1.1, 1, 2: < 1.25: 2; < 1.5625: 2; < 1.953: 2 (2 is not < 1.953)
        assert!(close(e.delta_1, 2.0 / 3.0) && close(e.delta_2, 2.0 / 3.0) && close(e.delta_3, 2.0 / 3.0));
        assert!(r.edge.is_none() && r.non_edge.is_none());
    }

    #[test]
    fn depth_errors_split_by_edges_and_clamp_bad_predictions() {
        let gt = [1.0, 1.0, 1.0, 1.0];
        let pred = [1.0, 1.5, f32::NAN, 1.0];
        let edges = [false, true, true, false];
        let r = depth_errors(&gt, &pred, Some(&edges)).unwrap();
        let non = r.non_edge.unwrap();
        assert_eq!((non.pixels, non.abs_rel, non.delta_1), (2, 0.0, 1.0));
        let edge = r.edge.unwrap();
        assert_eq!(edge.pixels, 2);
        assert!(close(edge.abs_rel, (0.5 + (1.0 - MIN_PRED_DEPTH)) / 2.0));
        assert_eq!((edge.delta_1, edge.delta_3), (0.0, 0.5)); // ratios 1.5 and 1e6
        // An edge map with no edge pixel: the edge region is empty.
        let r = depth_errors(&gt, &pred, Some(&[false; 4])).unwrap();
        assert!(r.edge.is_none() && r.non_edge.unwrap().pixels == 4);
        assert!(depth_errors(&gt, &pred[..3], None).is_err());
    }

    #[test]
    fn normal_errors_by_hand() {
        let z = [0.0, 0.0, 1.0];
        let s = std::f32::consts::FRAC_1_SQRT_2;
        let gt = [z, z, z, z, [0.0; 3]];
        // 0 deg (scaled prediction: renormalised), 45 deg, 90 deg, degenerate (90), ignored.
        let pred = [[0.0, 0.0, 3.0], [0.0, s, s], [1.0, 0.0, 0.0], [0.0; 3], [1.0, 0.0, 0.0]];
        let e = normal_errors(&gt, &pred, None).unwrap().all.unwrap();
        assert_eq!(e.pixels, 4);
        assert!((e.mean_deg - 225.0 / 4.0).abs() < 1e-5, "{}", e.mean_deg);
        assert!((e.median_deg - 67.5).abs() < 1e-5);
        assert_eq!((e.under_11_25, e.under_22_5, e.under_30), (0.25, 0.25, 0.25));
        assert_eq!(normal_angle_deg(&z, &z), 0.0);
        let edges = [true, false, false, false, true];
        let r = normal_errors(&gt, &pred, Some(&edges)).unwrap();
        assert_eq!(r.edge.unwrap().pixels, 1);
        assert_eq!(r.edge.unwrap().mean_deg, 0.0);
        assert_eq!(r.non_edge.unwrap().pixels, 3);
    }

    #[test]
    fn edge_map_finds_depth_steps_silhouettes_and_creases() {
        let (w, h) = (8u32, 6u32);
        let no_dilation = EdgeMapParams { dilate_px: 0.0, ..EdgeMapParams::default() };
        // A step from 1.0 to 1.2 between columns 3 and 4, a slow ramp elsewhere.
        let depth: Vec<f32> =
            (0..48).map(|i| if i % 8 < 4 { 1.0 + 0.01 * (i % 8) as f32 } else { 1.2 }).collect();
        let e = gt_edge_map(w, h, Some(&depth), None, &no_dilation).unwrap();
        let want: Vec<bool> = (0..48).map(|i| i % 8 == 3 || i % 8 == 4).collect();
        assert_eq!(e, want);
        // Dilation by 2 px widens the band to columns 1..=6.
        let e = gt_edge_map(w, h, Some(&depth), None, &EdgeMapParams::default()).unwrap();
        assert_eq!(e, (0..48).map(|i| (1..=6).contains(&(i % 8))).collect::<Vec<_>>());
        // Background (0) below row 3: the silhouette rows 2 and 3 are edges.
        let depth: Vec<f32> = (0..48).map(|i| if i / 8 < 3 { 2.0 } else { 0.0 }).collect();
        let e = gt_edge_map(w, h, Some(&depth), None, &no_dilation).unwrap();
        assert_eq!(e, (0..48).map(|i| i / 8 == 2 || i / 8 == 3).collect::<Vec<_>>());
        // A 90 deg crease between rows 1 and 2 of constant depth; 10 deg is not an edge.
        let t = 10f32.to_radians();
        let normal: Vec<[f32; 3]> = (0..48)
            .map(|i| match i / 8 {
                0 => [t.sin(), 0.0, t.cos()],
                1 => [0.0, 0.0, 1.0],
                _ => [1.0, 0.0, 0.0],
            })
            .collect();
        let flat = vec![3.0f32; 48];
        let e = gt_edge_map(w, h, Some(&flat), Some(&normal), &no_dilation).unwrap();
        assert_eq!(e, (0..48).map(|i| i / 8 == 1 || i / 8 == 2).collect::<Vec<_>>());
        assert!(gt_edge_map(w, h, None, None, &EdgeMapParams::default()).unwrap().iter().all(|&b| !b));
        assert!(gt_edge_map(w, h, Some(&flat[1..]), None, &no_dilation).is_err());
    }

    #[test]
    fn edge_map_ignores_grazing_planes_but_keeps_small_steps_and_thin_objects() {
        let (w, h) = (12u32, 3u32);
        let no_dilation = EdgeMapParams { dilate_px: 0.0, ..EdgeMapParams::default() };
        let edges = |row: &[f32]| -> Vec<usize> {
            let depth: Vec<f32> = (0..h).flat_map(|_| row.iter().copied()).collect();
            let e = gt_edge_map(w, h, Some(&depth), None, &no_dilation).unwrap();
            (0..w as usize).filter(|&x| e[x]).collect()
        };
        // A plane at a grazing angle: depth grows 6 % per pixel, smoothly. No edge.
        let grazing: Vec<f32> = (0..12).map(|x| 1.06f32.powi(x)).collect();
        assert_eq!(edges(&grazing), Vec::<usize>::new());
        // A 3 % step on a flat wall: an edge on both sides of it.
        let step: Vec<f32> = (0..12).map(|x| if x < 6 { 3.0 } else { 3.09 }).collect();
        assert_eq!(edges(&step), [5, 6]);
        // A one-pixel rod in front of a flat wall.
        let rod: Vec<f32> = (0..12).map(|x| if x == 4 { 2.0 } else { 3.0 }).collect();
        assert_eq!(edges(&rod), [3, 4, 5]);
    }

    #[test]
    fn evaluate_geometry_of_ground_truth_against_itself_is_perfect() {
        let (w, h) = (16u32, 12u32);
        let depth: Vec<f32> = (0..192).map(|i| if i % 16 < 8 { 2.0 } else { 3.0 + 0.01 * (i / 16) as f32 }).collect();
        let normal: Vec<[f32; 3]> = (0..192).map(|i| if i % 16 < 8 { [0.0, 0.0, 1.0] } else { [0.0, 1.0, 0.0] }).collect();
        let inputs = GeometryInputs {
            width: w,
            height: h,
            gt_depth: Some(&depth),
            gt_normal: Some(&normal),
            depth: Some(&depth),
            normal: Some(&normal),
        };
        let m = evaluate_geometry(&inputs, &GeometryParams::default()).unwrap();
        assert_eq!((m.pixels, m.edge_pixels), (192, 12 * 6)); // columns 5..=10
        let d = m.depth.unwrap();
        assert_eq!(d.all.unwrap().abs_rel, 0.0);
        assert_eq!(d.edge.unwrap().pixels, 72);
        assert_eq!(m.normal.unwrap().non_edge.unwrap().under_11_25, 1.0);
        let json = serde_json::to_string(&m).unwrap();
        assert!(json.contains("\"abs_rel\":0.0"), "{json}");
    }
}
