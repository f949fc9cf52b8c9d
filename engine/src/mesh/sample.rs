//! Uniform, area-weighted random points on a mesh's surface.

use glam::Vec3;

use super::TriMesh;
use crate::rng::SplitMix64;

/// `n` points uniformly distributed over the surface of `mesh` (each triangle chosen
/// with probability proportional to its area, then a uniform point in it by the
/// square-root barycentric map), deterministic in `seed`. Empty for a mesh without
/// area.
pub fn sample_surface(mesh: &TriMesh, n: usize, seed: u64) -> Vec<Vec3> {
    let mut cdf = Vec::with_capacity(mesh.triangles.len());
    let mut total = 0.0f64;
    for t in 0..mesh.triangles.len() {
        total += mesh.triangle_area(t);
        cdf.push(total);
    }
    if !(total > 0.0) {
        return Vec::new();
    }
    let mut rng = SplitMix64::mixed(seed);
    let mut unit = move || rng.uniform(0.5) + 0.5;
    (0..n)
        .map(|_| {
            let u = unit() * total;
            let t = cdf.partition_point(|&c| c <= u).min(cdf.len() - 1);
            let [a, b, c] = mesh.corners(t).map(|p| p.as_dvec3());
            let (r1, r2) = (unit().sqrt(), unit());
            (a * (1.0 - r1) + b * (r1 * (1.0 - r2)) + c * (r1 * r2)).as_vec3()
        })
        .collect()
}
