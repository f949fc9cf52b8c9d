//! Test helpers shared by the loss kernels' tests: the check that a kernel *added* a
//! reference's per-ray depth and opacity gradients to pre-filled ones.

use crate::layout::RayOutput;

/// Checks that a loss kernel left `d` as `prior` with `lambda` times the reference's
/// per-ray `(dL/d depth, dL/d opacity)` of rays `offset ..` added: the rays before
/// `offset` and every colour and normal gradient untouched. The tolerance is `tol`
/// times the largest weighted gradient (at least `min_scale`), plus the f32 rounding
/// of the pre-filled value the kernel adds to.
pub fn assert_added_depth_opacity_grads(
    d: &[RayOutput],
    prior: &[RayOutput],
    offset: usize,
    grads: &[(f64, f64)],
    lambda: f64,
    (tol, min_scale): (f64, f64),
    what: &str,
) {
    assert_eq!(&d[..offset], &prior[..offset], "{what}: rays before the offset");
    let scale = (grads.iter().fold(0.0f64, |m, g| m.max(g.0.abs()).max(g.1.abs())) * lambda).max(min_scale);
    let close = |got: f32, want: f64| (got as f64 - want).abs() < tol * scale + 2e-7 * want.abs();
    for (k, (gd, ga)) in grads.iter().enumerate() {
        let (got, p) = (&d[offset + k], &prior[offset + k]);
        let (want_d, want_a) = (p.depth as f64 + lambda * gd, p.opacity as f64 + lambda * ga);
        assert!(close(got.depth, want_d), "{what} ray {k}: d depth {} vs {want_d}", got.depth);
        assert!(close(got.opacity, want_a), "{what} ray {k}: d opacity {} vs {want_a}", got.opacity);
        assert_eq!((got.rgb, got.normal), (p.rgb, p.normal), "{what} ray {k}: colour and normal gradients untouched");
    }
}
