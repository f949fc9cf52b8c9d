//! Sparse-view priors on a ray's sample weights and densities, evaluated inside the
//! compositing kernels because they need every sample of a ray in order, which only
//! the renderer walks: mip-NeRF 360's distortion loss, FreeNeRF's occlusion
//! regularization and Ref-NeRF's orientation penalty. The first two fight the fog and
//! floaters that few views leave in space no training ray pins down; the third makes the
//! analytic normals (the density gradient) face the camera wherever a ray puts weight.
//!
//! # The terms (per ray, over its `K` contributing samples, midpoints `m_i = t_i`)
//! ```text
//! distortion  D = sum_{i,j} w_i w_j |m_i - m_j| + 1/3 sum_i w_i^2 dt_i
//! occlusion   O = sum_{i : t_i < t_occ} sigma_i dt_i
//! orientation R = sum_i w_i max(0, <n_i, d_i>)^2
//! free space  F = sum_{i : t_i < e_r} sigma_i dt_i       (e_r = RayAux::free_end)
//! ```
//! `D` is small when a ray's weight is one compact blob (a surface) and large when it is
//! spread along the ray (fog, floaters in front of a surface). `O` is the optical
//! thickness of the first stretch of the ray, where FreeNeRF observed sparse-view
//! floaters sit (density right in front of the cameras explains a training pixel from
//! that camera alone).
//!
//! Batch losses, `n` rays, scene depth range `S = far - near` (1 in NDC), occlusion
//! range `t_occ = near + f S`:
//! ```text
//! L_dist = lambda_dist / n  sum_r D_r / S          (ray parameter normalised to [0, 1],
//!                                                   as mip-NeRF 360's s-space)
//! L_occ  = lambda_occ  / n  sum_r O_r / (f S)      (the mean density over the range,
//!                                                   FreeNeRF's mean over its first samples)
//! L_ori  = lambda_ori  / n  sum_r R_r              (Ref-NeRF's mean over rays)
//! L_free = lambda_free / n  sum_r F_r / S          (stereo free space)
//! ```
//! `n_i` is the field's unit analytic normal (outward: minus the normalised density
//! gradient) and `d_i` the sample's unit ray direction, both in the field's space (NDC
//! for LLFF: the map to NDC keeps which side of a surface a ray comes from). A normal
//! facing away from the ray at a sample with weight is a density that falls toward the
//! camera inside what the ray sees as surface: the penalty pushes density to rise along
//! the ray up to the surface. Samples with a zero normal (zero gradient) pay nothing.
//!
//! `F` is space carving from the plane sweep of `crate::train::stereo`: where the
//! training photographs agree on a depth `t*` at a ray's pixel, the caller sets `e_r =
//! (1 - margin) t*` and the density in front of it is pushed out (0 elsewhere: no
//! term). The stereo depth prior alone pulls only the depth given termination, which
//! a fog centred on `t*` satisfies; this term leaves such fog nowhere to stand in
//! front of the surface.
//!
//! # Gradients (in `composite.wgsl::backward`)
//! With `W_<i, M_<i` the prefix sums of `w` and `w m` and `W_>i, M_>i` the suffix sums
//! (taken from the forward's `opacity` and `depth`):
//! `dD/dw_i = 2 (m_i W_<i - M_<i + M_>i - m_i W_>i) + 2/3 w_i dt_i`, which joins the
//! per-sample `u_i` of the compositing backward, and `sum_i w_i dD/dw_i = 2 D` (`D` is
//! homogeneous of degree 2 in the weights) joins its suffix-sum total; so the one
//! front-to-back pass stays one pass. `dO/dsigma_i = dt_i` goes to the density gradient
//! directly, as does `dF/dsigma_i = dt_i`. `dR/dw_i = max(0, <n_i, d_i>)^2` joins `u_i` and `sum_i w_i dR/dw_i = R`
//! the total (degree 1); `dR/dn_i = 2 w_i max(0, <n_i, d_i>) d_i` joins the normal
//! gradient, which the field takes to its parameters through the normal's second-order
//! backward (so the field must compute normals when the term is on).
//!
//! Invariants: the forward pass always stores `D`, `O` and `R` of every ray in
//! [`super::RayAux`] (with the renderer's `occlusion_end`); the backward adds the terms
//! only with non-zero weights, so a renderer without priors computes exactly what it
//! did before.

/// The priors' settings in a run configuration (`[priors]`). All off by default.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PriorConfig {
    /// Weight of mip-NeRF 360's distortion loss (0: off; mip-NeRF 360 uses 0.01).
    pub distortion: f32,
    /// Weight of FreeNeRF's occlusion regularization (0: off; FreeNeRF uses 0.01).
    pub occlusion: f32,
    /// The occlusion range as a fraction of `far - near` from `near` (FreeNeRF: its
    /// first 10 of 128 samples, 0.08 of the range).
    pub occlusion_range: f32,
    /// Weight of Ref-NeRF's orientation penalty on the analytic normals (0: off; Ref-NeRF
    /// uses 0.1 with its predicted normals).
    pub orientation: f32,
    /// Weight of the opacity penalty `L_sp = mean_r opacity_r` over the photometric
    /// rays (0: off): space that nothing in the images needs stays empty, so where a
    /// learned background already explains a pixel (a capture without alpha) no fog
    /// forms in front of it. Applied through the photometric loss's `dL/d opacity`
    /// (`loss::photometric`); its value is not logged.
    pub sparsity: f32,
    /// Steps over which the opacity penalty falls linearly from `sparsity` to 0 (0:
    /// constant over the run). Early on it keeps fog from forming while the field finds
    /// the object; later it would only erode the object's own opacity (a white
    /// backdrop then shows through it).
    pub sparsity_steps: u64,
    /// Weight of the opacity entropy `L_H = mean_r H(opacity_r)` over the photometric
    /// rays, `H(o) = -o ln o - (1 - o) ln(1 - o)` (0: off): each ray is pushed toward
    /// fully opaque or fully transparent, whichever it is nearer, so an object is not
    /// left half transparent with a learned background showing through it. Applied
    /// through the photometric loss's `dL/d opacity` (`loss::photometric`) from
    /// `opacity_entropy_start` on; its value is not logged.
    pub opacity_entropy: f32,
    /// The first step of the opacity entropy: before it the field is still fog, which the
    /// entropy would make opaque.
    pub opacity_entropy_start: u64,
    /// Weight of the foreground opacity prior (0: off): each photometric ray is pushed
    /// toward opaque by `foreground_opacity * g * (1 - opacity)`, with the gate
    /// `g = 1 - exp(-|c* - b|^2 / (3 tol^2))` of the target `c*` against the background
    /// `b` the renderer puts behind the ray, over the whole run. A pixel the background
    /// cannot show belongs to the object; against a known backdrop (a learned one, a
    /// photograph's white) a translucent surface of a darker colour fits the training
    /// views as well as an opaque one, and shows the backdrop through the object from
    /// new views. Pixels that match the background are left alone. Applied through the
    /// photometric loss's `dL/d opacity` (`loss::photometric`); its value is not logged.
    pub foreground_opacity: f32,
    /// The gate's colour tolerance `tol`, a per-channel RMS difference from the
    /// background: a pixel this far off gets `1 - 1/e` of the weight.
    pub foreground_tolerance: f32,
    /// Weight of the stereo depth prior (0: off): each photometric ray's depth given
    /// termination is pulled toward the depth a plane sweep over the training views found
    /// at its pixel, where another view confirms it (`crate::train::stereo`,
    /// `crate::loss::stereo_depth`). Needs two or more training views; on LLFF's NDC
    /// rays the sweep runs along them and its targets are NDC ray parameters.
    pub stereo_depth: f32,
    /// Depth planes of the sweep (uniform in inverse depth over the box).
    pub stereo_planes: u32,
    /// Half-width of the sweep's cost window, in pixels (a `(2w + 1)^2` square).
    pub stereo_window: u32,
    /// The left-right check: another view's depth must meet the same 3D point within
    /// this fraction of the depth.
    pub stereo_consistency: f32,
    /// The Charbonnier scale of the prior's relative depth error.
    pub stereo_delta: f32,
    /// Weight of the stereo free-space prior (0: off): along each photometric ray whose
    /// pixel the sweep gave a confirmed depth `t*`, the optical thickness in front of
    /// `(1 - stereo_free_margin) t*` is penalised (space carving: the photographs agree
    /// that nothing stands there). Runs the sweep as `stereo_depth` does (either or
    /// both on); applied in the compositing backward, its value is not logged.
    pub stereo_free_space: f32,
    /// The free-space prior stops this fraction of the stereo depth short of it.
    pub stereo_free_margin: f32,
    /// Edge-aware fill of the sweep's gaps, in pixels (0: off): a pixel without a
    /// confirmed depth gets the Gaussian-weighted mean (sigma half this radius) of the
    /// confirmed depths within this radius that lie in its own region of the view's edge
    /// mask (non-edge pixels joined through non-edge pixels), with the weight's share
    /// of confirmed pixels as its confidence. The free-space prior reads confirmed
    /// depths only.
    pub stereo_fill: u32,
    /// The sweep's uniqueness check (1: off): a pixel's winning depth is kept only
    /// where its window cost is below this fraction of the least cost of the planes
    /// more than two planes away (flat colour and repeated texture give no depth).
    pub stereo_uniqueness: f32,
    /// Also sweep as many planes across the training cameras' mean up vector (floors,
    /// table tops), whose windows the sweep along the rays shears where the views stand
    /// far apart (`crate::train::stereo`). Off: the sweep along the rays alone.
    pub stereo_horizontal: bool,
    /// Where the stereo priors' targets come from: `sweep` (the default: the plane
    /// sweep over the training photographs) or `ground_truth`: the scene's own
    /// ground-truth depth on every training pixel with a surface, as if confirmed (a
    /// synthetic scene's `*_depth.exr`; refused on a scene without it). Not a prior but
    /// an upper bound: what a perfect depth prior would give the same run.
    pub stereo_targets: StereoTargetSource,
    /// A folder of monocular depth maps, one per training image (`<image stem>.npy` or
    /// a grey `.png`; Depth Anything's or MiDaS's output, say): each view's map is fitted
    /// to the sweep's confirmed depths and gives the stereo depth prior a target on the
    /// pixels the sweep left without one, at confidence `mono_depth_confidence`
    /// (`crate::train::mono_depth`). Needs `stereo_depth` above 0 and the sweep's targets.
    /// Relative paths are taken from the working directory. Default: none.
    pub mono_depth_dir: Option<std::path::PathBuf>,
    /// What the maps hold: `disparity` (relative inverse depth, as MiDaS and Depth
    /// Anything write it; the default) or `depth`.
    pub mono_depth_kind: MonoDepthKind,
    /// The monocular targets' confidence, their weight in the stereo depth prior
    /// against a confirmed depth's 1.
    pub mono_depth_confidence: f32,
}

/// [`PriorConfig::mono_depth_kind`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MonoDepthKind {
    /// Inverse depth up to scale and shift (MiDaS, DPT, Depth Anything's relative models).
    #[default]
    Disparity,
    /// Depth up to scale and shift (metric models, ZoeDepth, a sensor).
    Depth,
}

/// [`PriorConfig::stereo_targets`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StereoTargetSource {
    #[default]
    Sweep,
    GroundTruth,
}

impl Default for PriorConfig {
    fn default() -> Self {
        Self {
            distortion: 0.0,
            occlusion: 0.0,
            occlusion_range: 0.08,
            orientation: 0.0,
            sparsity: 0.0,
            sparsity_steps: 0,
            opacity_entropy: 0.0,
            opacity_entropy_start: 0,
            foreground_opacity: 0.0,
            foreground_tolerance: 0.1,
            stereo_depth: 0.0,
            stereo_planes: 128,
            stereo_window: 2,
            stereo_consistency: 0.01,
            stereo_delta: 0.01,
            stereo_free_space: 0.0,
            stereo_free_margin: 0.05,
            stereo_fill: 0,
            stereo_uniqueness: 1.0,
            stereo_horizontal: false,
            stereo_targets: StereoTargetSource::Sweep,
            mono_depth_dir: None,
            mono_depth_kind: MonoDepthKind::Disparity,
            mono_depth_confidence: 0.5,
        }
    }
}

impl PriorConfig {
    pub fn validate(&self) -> Result<(), String> {
        for (name, v) in [
            ("priors.distortion", self.distortion),
            ("priors.occlusion", self.occlusion),
            ("priors.orientation", self.orientation),
            ("priors.sparsity", self.sparsity),
            ("priors.opacity_entropy", self.opacity_entropy),
            ("priors.foreground_opacity", self.foreground_opacity),
            ("priors.stereo_depth", self.stereo_depth),
            ("priors.stereo_free_space", self.stereo_free_space),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("{name} must be a finite weight >= 0, got {v}"));
            }
        }
        if self.stereo_targets == StereoTargetSource::GroundTruth && !self.stereo_on() {
            return Err("priors.stereo_targets = \"ground_truth\" feeds the stereo priors, which are off: set priors.stereo_depth or priors.stereo_free_space above 0".into());
        }
        let tol = self.foreground_tolerance;
        if !(tol.is_finite() && tol > 0.0) {
            return Err(format!("priors.foreground_tolerance must be a colour difference > 0, got {tol}"));
        }
        if !(2..=4096).contains(&self.stereo_planes) || self.stereo_window > 32 || self.stereo_fill > 64 {
            return Err(format!(
                "priors.stereo_planes = {} must be 2 to 4096, priors.stereo_window = {} and priors.stereo_fill = {} at most 32 and 64 pixels",
                self.stereo_planes, self.stereo_window, self.stereo_fill
            ));
        }
        for (name, v) in [
            ("priors.stereo_consistency", self.stereo_consistency),
            ("priors.stereo_delta", self.stereo_delta),
            ("priors.stereo_free_margin", self.stereo_free_margin),
        ] {
            if !(v.is_finite() && v > 0.0 && v < 1.0) {
                return Err(format!("{name} must be a fraction in (0, 1), got {v}"));
            }
        }
        let u = self.stereo_uniqueness;
        if !(u.is_finite() && u > 0.0 && u <= 1.0) {
            return Err(format!("priors.stereo_uniqueness must be in (0, 1] (1: off), got {u}"));
        }
        if self.mono_depth_dir.is_some() {
            if self.stereo_depth <= 0.0 {
                return Err("priors.mono_depth_dir feeds the stereo depth prior, which is off: set priors.stereo_depth above 0 (0.1, say)".into());
            }
            if self.stereo_targets != StereoTargetSource::Sweep {
                return Err("priors.mono_depth_dir is fitted to the plane sweep's depths: it needs priors.stereo_targets = \"sweep\"".into());
            }
        }
        let mc = self.mono_depth_confidence;
        if !(mc.is_finite() && mc > 0.0 && mc < 1.0) {
            return Err(format!("priors.mono_depth_confidence must be in (0, 1) (a confirmed stereo depth has 1), got {mc}"));
        }
        let f = self.occlusion_range;
        if !(f.is_finite() && f > 0.0 && f <= 1.0) {
            return Err(format!("priors.occlusion_range must be in (0, 1] (a fraction of far - near), got {f}"));
        }
        Ok(())
    }

    /// The opacity penalty's weight at `step` (see [`PriorConfig::sparsity_steps`]).
    pub fn sparsity_at(&self, step: u64) -> f32 {
        match self.sparsity_steps {
            0 => self.sparsity,
            n => self.sparsity * (1.0 - step as f32 / n as f32).max(0.0),
        }
    }

    /// The opacity entropy's weight at `step` (see [`PriorConfig::opacity_entropy_start`]).
    pub fn opacity_entropy_at(&self, step: u64) -> f32 {
        if step >= self.opacity_entropy_start { self.opacity_entropy } else { 0.0 }
    }

    /// Whether the plane sweep runs: the stereo depth or free-space prior is on.
    pub fn stereo_on(&self) -> bool {
        self.stereo_depth > 0.0 || self.stereo_free_space > 0.0
    }

    /// Whether any term is on.
    pub fn active(&self) -> bool {
        self.distortion > 0.0 || self.occlusion > 0.0 || self.orientation > 0.0
    }

    /// The kernel weights for batches of `n_rays` rays of a scene whose rays span
    /// `near ..= far` (see the module doc).
    pub fn weights(&self, n_rays: u32, near: f32, far: f32) -> RayPriors {
        let span = (far - near).max(f32::MIN_POSITIVE);
        let n = n_rays.max(1) as f32;
        let range = self.occlusion_range * span;
        RayPriors {
            lambda_distortion: self.distortion,
            lambda_occlusion: self.occlusion,
            distortion_scale: 1.0 / (n * span),
            occlusion_scale: 1.0 / (n * range),
            occlusion_end: if self.occlusion > 0.0 { near + range } else { f32::MIN },
            lambda_orientation: self.orientation,
            orientation_scale: 1.0 / n,
            lambda_free_space: self.stereo_free_space,
            free_space_scale: 1.0 / (n * span),
        }
    }
}

/// What the compositing kernels apply: the batch loss is
/// `lambda_distortion distortion_scale sum_r D_r + lambda_occlusion occlusion_scale sum_r O_r
/// + lambda_orientation orientation_scale sum_r R_r`, with `O` over the samples whose ray
/// parameter is below `occlusion_end`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayPriors {
    pub lambda_distortion: f32,
    pub lambda_occlusion: f32,
    pub distortion_scale: f32,
    pub occlusion_scale: f32,
    pub occlusion_end: f32,
    pub lambda_orientation: f32,
    pub orientation_scale: f32,
    /// The stereo free-space prior: `lambda_free_space free_space_scale sum_r F_r`, `F`
    /// over the samples before each ray's `RayAux::free_end`.
    pub lambda_free_space: f32,
    pub free_space_scale: f32,
}

impl Default for RayPriors {
    fn default() -> Self {
        Self {
            lambda_distortion: 0.0,
            lambda_occlusion: 0.0,
            distortion_scale: 0.0,
            occlusion_scale: 0.0,
            occlusion_end: f32::MIN,
            lambda_orientation: 0.0,
            orientation_scale: 0.0,
            lambda_free_space: 0.0,
            free_space_scale: 0.0,
        }
    }
}

/// The coefficients of the per-ray measures in the batch loss, or (from
/// [`RayPriors::losses`]) the batch losses themselves without their lambdas.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PriorTerms {
    pub distortion: f32,
    pub occlusion: f32,
    pub orientation: f32,
    /// Only as a coefficient (the kernels do not store `F`): 0 in [`RayPriors::losses`].
    pub free_space: f32,
}

impl RayPriors {
    /// The coefficients of the per-ray `D`, `O` and `R` in the batch loss.
    pub fn coefficients(&self) -> PriorTerms {
        PriorTerms {
            distortion: self.lambda_distortion * self.distortion_scale,
            occlusion: self.lambda_occlusion * self.occlusion_scale,
            orientation: self.lambda_orientation * self.orientation_scale,
            free_space: self.lambda_free_space * self.free_space_scale,
        }
    }

    /// Whether the field must compute normals for these priors (the orientation term).
    pub fn needs_normals(&self) -> bool {
        self.lambda_orientation > 0.0
    }

    /// The unweighted batch losses `L_dist`, `L_occ`, `L_ori` (without their lambdas) from
    /// the forward pass's per-ray [`super::RayAux`].
    pub fn losses(&self, aux: &[super::RayAux]) -> PriorTerms {
        let (mut d, mut o, mut r) = (0.0f64, 0.0f64, 0.0f64);
        for a in aux {
            d += a.distortion as f64;
            o += a.occlusion as f64;
            r += a.orientation as f64;
        }
        PriorTerms {
            distortion: (self.distortion_scale as f64 * d) as f32,
            occlusion: (self.occlusion_scale as f64 * o) as f32,
            orientation: (self.orientation_scale as f64 * r) as f32,
            free_space: 0.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{PriorConfig, StereoTargetSource};

    #[test]
    fn the_opacity_penalty_falls_to_zero_over_its_steps() {
        let constant = PriorConfig { sparsity: 0.04, ..Default::default() };
        assert_eq!([constant.sparsity_at(0), constant.sparsity_at(10_000)], [0.04, 0.04]);
        let falling = PriorConfig { sparsity: 0.04, sparsity_steps: 400, ..Default::default() };
        assert_eq!([falling.sparsity_at(0), falling.sparsity_at(100), falling.sparsity_at(400), falling.sparsity_at(900)], [0.04, 0.03, 0.0, 0.0]);
        assert!(PriorConfig { sparsity: -1.0, ..Default::default() }.validate().is_err());
        let entropy = PriorConfig { opacity_entropy: 0.01, opacity_entropy_start: 300, ..falling };
        assert_eq!([entropy.opacity_entropy_at(299), entropy.opacity_entropy_at(300)], [0.0, 0.01]);
        assert_eq!(entropy.sparsity_at(100), 0.03);
        assert!(PriorConfig { opacity_entropy: f32::NAN, ..Default::default() }.validate().is_err());
    }

    #[test]
    fn the_stereo_prior_checks_its_sweep_settings() {
        let on = PriorConfig { stereo_depth: 0.03, ..Default::default() };
        assert!(on.validate().is_ok());
        assert!(PriorConfig { stereo_depth: -0.1, ..on.clone() }.validate().unwrap_err().contains("priors.stereo_depth"));
        assert!(PriorConfig { stereo_planes: 1, ..on.clone() }.validate().unwrap_err().contains("priors.stereo_planes"));
        assert!(PriorConfig { stereo_window: 33, ..on.clone() }.validate().unwrap_err().contains("priors.stereo_window"));
        assert!(PriorConfig { stereo_fill: 65, ..on.clone() }.validate().unwrap_err().contains("priors.stereo_fill"));
        assert!(PriorConfig { stereo_uniqueness: 0.0, ..on.clone() }.validate().unwrap_err().contains("priors.stereo_uniqueness"));
        for bad in [0.0, 1.0, f32::NAN] {
            assert!(PriorConfig { stereo_consistency: bad, ..on.clone() }.validate().unwrap_err().contains("priors.stereo_consistency"));
            assert!(PriorConfig { stereo_delta: bad, ..on.clone() }.validate().unwrap_err().contains("priors.stereo_delta"));
        }
    }

    #[test]
    fn monocular_depth_maps_need_the_stereo_depth_prior_and_its_sweep() {
        let mono = PriorConfig { mono_depth_dir: Some("maps".into()), ..Default::default() };
        assert!(mono.clone().validate().unwrap_err().contains("priors.stereo_depth"));
        let on = PriorConfig { stereo_depth: 0.1, ..mono };
        assert!(on.clone().validate().is_ok());
        let gt = PriorConfig { stereo_targets: StereoTargetSource::GroundTruth, ..on.clone() };
        assert!(gt.validate().unwrap_err().contains("stereo_targets"));
        for bad in [0.0, 1.0, f32::NAN] {
            assert!(PriorConfig { mono_depth_confidence: bad, ..on.clone() }.validate().unwrap_err().contains("priors.mono_depth_confidence"));
        }
    }

    #[test]
    fn ground_truth_stereo_targets_need_a_stereo_prior() {
        let gt = PriorConfig { stereo_targets: StereoTargetSource::GroundTruth, ..Default::default() };
        assert!(gt.validate().unwrap_err().contains("priors.stereo_depth"));
        assert!(PriorConfig { stereo_depth: 0.1, ..gt.clone() }.validate().is_ok());
        assert!(PriorConfig { stereo_free_space: 0.03, ..gt.clone() }.validate().is_ok());
    }

    #[test]
    fn the_foreground_prior_needs_a_weight_and_a_positive_tolerance() {
        assert!(PriorConfig { foreground_opacity: 0.01, ..Default::default() }.validate().is_ok());
        assert!(PriorConfig { foreground_opacity: -0.01, ..Default::default() }.validate().is_err());
        for tol in [0.0, -0.1, f32::INFINITY, f32::NAN] {
            let err = PriorConfig { foreground_opacity: 0.01, foreground_tolerance: tol, ..Default::default() }.validate().unwrap_err();
            assert!(err.contains("priors.foreground_tolerance"), "{err}");
        }
    }
}
