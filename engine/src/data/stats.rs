//! Numpy's `quantile`, the one order statistic the engine needs: the robust colour
//! ranges of `viz`, the medians of `metrics`, and the spiral path's radii (`paths`).
//!
//! Invariant: exactly numpy's default (`method="linear"`) on the finite values given.

/// Numpy's `quantile(values, q)` (linear interpolation between the two nearest ranks,
/// `q` in `[0, 1]`); `None` when empty. Sorts `values`.
pub fn quantile(values: &mut [f64], q: f64) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_unstable_by(f64::total_cmp);
    let pos = q.clamp(0.0, 1.0) * (values.len() - 1) as f64;
    let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
    Some(values[lo] + (pos - lo as f64) * (values[hi] - values[lo]))
}
