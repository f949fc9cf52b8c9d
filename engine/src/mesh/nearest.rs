//! The nearest point of a triangle mesh to a query point, through a BVH over the
//! triangles (obvhs' BVH2, the sampler's builder) and a branch-and-bound descent:
//! children are visited nearer box first, and a box no nearer than the best triangle
//! found is skipped, so the answer is exact.

use std::time::Duration;

use glam::{Vec3, Vec3A};
use obvhs::{BvhBuildParams, aabb::Aabb, bvh2::Bvh2, bvh2::builder::build_bvh2};

use super::TriMesh;

/// A mesh's triangles with a BVH over them, for nearest-point queries.
pub struct TriangleBvh {
    tris: Vec<[Vec3; 3]>,
    bvh: Option<Bvh2>,
}

/// The point of triangle `abc` nearest to `p` (Ericson, "Real-Time Collision
/// Detection", 5.1.5: by Voronoi region of the vertices, edges and face).
pub fn closest_point_on_triangle(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> Vec3 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = va + vb + vc;
    if denom.abs() < f32::MIN_POSITIVE {
        // Degenerate (zero-area) triangle: the nearest of its three edges' points.
        return [(a, b), (b, c), (c, a)]
            .map(|(s, e)| {
                let d = e - s;
                let t = if d.length_squared() > 0.0 { ((p - s).dot(d) / d.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
                s + d * t
            })
            .into_iter()
            .min_by(|x, y| x.distance_squared(p).total_cmp(&y.distance_squared(p)))
            .unwrap();
    }
    let (v, w) = (vb / denom, vc / denom);
    a + ab * v + ac * w
}

fn box_distance_squared(b: &Aabb, p: Vec3A) -> f32 {
    let d = (b.min - p).max(p - b.max).max(Vec3A::ZERO);
    d.length_squared()
}

impl TriangleBvh {
    /// Builds the BVH over `mesh`'s triangles (none: every query answers `None`).
    pub fn new(mesh: &TriMesh) -> TriangleBvh {
        let tris: Vec<[Vec3; 3]> = (0..mesh.triangles.len()).map(|t| mesh.corners(t)).collect();
        if tris.is_empty() {
            return TriangleBvh { tris, bvh: None };
        }
        let boxes: Vec<Aabb> = tris
            .iter()
            .map(|[a, b, c]| Aabb { min: Vec3A::from(a.min(*b).min(*c)), max: Vec3A::from(a.max(*b).max(*c)) })
            .collect();
        let bvh = build_bvh2(&boxes, BvhBuildParams::medium_build(), &mut Duration::default());
        TriangleBvh { tris, bvh: Some(bvh) }
    }

    /// The nearest point of the mesh to `p` and its distance.
    pub fn nearest(&self, p: Vec3) -> Option<(Vec3, f32)> {
        let bvh = self.bvh.as_ref()?;
        let pa = Vec3A::from(p);
        let mut best = (Vec3::ZERO, f32::INFINITY);
        let mut stack: Vec<(u32, f32)> = vec![(0, box_distance_squared(bvh.nodes[0].aabb(), pa))];
        while let Some((i, d2)) = stack.pop() {
            if d2 >= best.1 {
                continue;
            }
            let node = &bvh.nodes[i as usize];
            if node.prim_count > 0 {
                for k in node.first_index..node.first_index + node.prim_count {
                    let [a, b, c] = self.tris[bvh.primitive_indices[k as usize] as usize];
                    let q = closest_point_on_triangle(p, a, b, c);
                    let e = q.distance_squared(p);
                    if e < best.1 {
                        best = (q, e);
                    }
                }
            } else {
                let (l, r) = (node.first_index, node.first_index + 1);
                let (dl, dr) = (box_distance_squared(bvh.nodes[l as usize].aabb(), pa), box_distance_squared(bvh.nodes[r as usize].aabb(), pa));
                // Push the farther child first so the nearer one is visited first.
                if dl <= dr {
                    stack.extend([(r, dr), (l, dl)]);
                } else {
                    stack.extend([(l, dl), (r, dr)]);
                }
            }
        }
        best.1.is_finite().then(|| (best.0, best.1.sqrt()))
    }

    /// The distance from each of `points` to the mesh (in parallel; infinite when
    /// the mesh has no triangle).
    pub fn distances(&self, points: &[Vec3]) -> Vec<f32> {
        use rayon::prelude::*;
        points.par_iter().map(|&p| self.nearest(p).map_or(f32::INFINITY, |n| n.1)).collect()
    }
}
