//! Exact Euclidean distance transform of a binary image (MATLAB `bwdist`, SciPy
//! `distance_transform_edt(~features)`).
//!
//! Owns the one distance transform of the crate: the depth boundary error
//! ([`super::boundary`]) measures edge distances with it, and the ground-truth edge
//! map ([`super::geometry::gt_edge_map`]) dilates with it (a pixel is within `r` of an
//! edge iff its squared distance is `<= r^2`).
//!
//! Algorithm: Felzenszwalb & Huttenlocher (2012), "Distance transforms of sampled
//! functions": the squared distance `D(x, y) = min_{(x', y') feature} (x - x')^2 +
//! (y - y')^2` is separable, so a 1-D lower envelope of parabolas is taken along every
//! column, then along every row of the result. O(width * height), exact.
//!
//! Invariants: squared distances are exact integers (held in `f64`); feature pixels
//! have distance 0; with no feature pixel at all every distance is `+inf` (as `bwdist`).

/// Stand-in for "no feature in this line yet" inside the 1-D passes: larger than any
/// squared distance of an image that fits in memory, small enough to stay finite.
const FAR: f64 = 1e20;

/// Squared Euclidean distance from every pixel to the nearest `true` pixel of
/// `features` (row-major, `width * height`); `+inf` everywhere when there is none.
///
/// Panics if `features.len() != width * height` (callers check sizes first).
pub fn squared_distance_transform(width: u32, height: u32, features: &[bool]) -> Vec<f64> {
    let (w, h) = (width as usize, height as usize);
    assert_eq!(features.len(), w * h, "feature map is not {w}x{h}");
    if !features.iter().any(|&f| f) {
        return vec![f64::INFINITY; w * h];
    }
    let n = w.max(h);
    let (mut f, mut d) = (vec![0.0; n], vec![0.0; n]);
    let (mut v, mut z) = (vec![0usize; n], vec![0.0; n + 1]);
    let mut grid: Vec<f64> = features.iter().map(|&b| if b { 0.0 } else { FAR }).collect();
    for x in 0..w {
        for y in 0..h {
            f[y] = grid[y * w + x];
        }
        envelope_1d(&f[..h], &mut d[..h], &mut v, &mut z);
        for y in 0..h {
            grid[y * w + x] = d[y];
        }
    }
    for row in grid.chunks_exact_mut(w) {
        f[..w].copy_from_slice(row);
        envelope_1d(&f[..w], &mut d[..w], &mut v, &mut z);
        row.copy_from_slice(&d[..w]);
    }
    grid
}

/// Euclidean distance from every pixel to the nearest `true` pixel (`+inf` when
/// there is none): the square root of [`squared_distance_transform`].
pub fn distance_transform(width: u32, height: u32, features: &[bool]) -> Vec<f64> {
    let mut d = squared_distance_transform(width, height, features);
    d.iter_mut().for_each(|v| *v = v.sqrt());
    d
}

/// 1-D squared distance transform of the sampled function `f`:
/// `d[q] = min_p (q - p)^2 + f[p]`. `v` (parabola vertices) and `z` (envelope
/// boundaries) are scratch of length `>= f.len()` and `>= f.len() + 1`.
fn envelope_1d(f: &[f64], d: &mut [f64], v: &mut [usize], z: &mut [f64]) {
    let n = f.len();
    if n == 0 {
        return;
    }
    let mut k = 0usize;
    v[0] = 0;
    z[0] = f64::NEG_INFINITY;
    z[1] = f64::INFINITY;
    for q in 1..n {
        let qf = q as f64;
        let mut s;
        // Drop the parabolas the new one hides (`z[0] = -inf` stops this at `k = 0`;
        // the guard only makes that explicit).
        loop {
            let p = v[k] as f64;
            s = ((f[q] + qf * qf) - (f[v[k]] + p * p)) / (2.0 * (qf - p));
            if s <= z[k] && k > 0 {
                k -= 1;
            } else {
                break;
            }
        }
        k += 1;
        v[k] = q;
        z[k] = s;
        z[k + 1] = f64::INFINITY;
    }
    k = 0;
    for (q, out) in d.iter_mut().enumerate() {
        while z[k + 1] < q as f64 {
            k += 1;
        }
        let p = v[k] as f64;
        *out = (q as f64 - p) * (q as f64 - p) + f[v[k]];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Tiny deterministic generator (xorshift) for random test images.
    fn rng(seed: u64) -> impl FnMut() -> u64 {
        let mut s = seed.max(1);
        move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        }
    }

    fn brute_force(w: usize, h: usize, features: &[bool]) -> Vec<f64> {
        let pts: Vec<(i64, i64)> =
            (0..w * h).filter(|&i| features[i]).map(|i| ((i % w) as i64, (i / w) as i64)).collect();
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as i64, (i / w) as i64);
                pts.iter().map(|&(px, py)| ((x - px).pow(2) + (y - py).pow(2)) as f64).fold(f64::INFINITY, f64::min)
            })
            .collect()
    }

    #[test]
    fn matches_brute_force_on_random_binary_images() {
        let mut next = rng(0x5eed);
        for case in 0..60 {
            let w = 1 + (next() % 23) as usize;
            let h = 1 + (next() % 19) as usize;
            // Densities from very sparse (single points) to dense.
            let per_mille = [2, 10, 50, 200, 600][case % 5];
            let features: Vec<bool> = (0..w * h).map(|_| next() % 1000 < per_mille).collect();
            let got = squared_distance_transform(w as u32, h as u32, &features);
            let want = brute_force(w, h, &features);
            assert_eq!(got, want, "case {case}: {w}x{h}, density {per_mille}/1000");
        }
    }

    #[test]
    fn no_features_is_infinite_and_single_point_is_euclidean() {
        assert!(distance_transform(4, 3, &[false; 12]).iter().all(|d| d.is_infinite()));
        let mut f = vec![false; 5 * 4];
        f[0] = true;
        let d = distance_transform(5, 4, &f);
        assert_eq!(d[0], 0.0);
        assert_eq!(d[3 * 5 + 4], 5.0); // (4, 3): a 3-4-5 triangle
        assert!((d[5 + 1] - 2f64.sqrt()).abs() < 1e-12);
    }
}
