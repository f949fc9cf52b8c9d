//! Triangle meshes on the CPU: the [`TriMesh`] type, binary PLY files ([`ply`]),
//! isosurfaces of a scalar grid by marching tetrahedra ([`marching`]), uniform
//! area-weighted surface sampling ([`sample`]), nearest points on a mesh through a BVH
//! ([`nearest`]), and the Chamfer distance and F-score between sampled surfaces
//! ([`compare`]).
//!
//! What exports a trained field's geometry (the density grid from the GPU, vertex
//! colours) is `train`'s; which part of a scene a mesh metric counts is `metrics`'.
//!
//! # Invariants
//! * Pure CPU, no GPU, no file access: PLY is read from and written to bytes (the
//!   caller writes files atomically).
//! * A [`TriMesh`]'s triangle indices are in range ([`TriMesh::check`]); `normals` and
//!   `colors` are empty or one per vertex.
//! * Triangles are counter-clockwise seen from outside: their normals
//!   `(b - a) x (c - a)` point out of the solid (marching tetrahedra orients them
//!   from high to low values); vertex normals are unit or zero.
//! * Everything random is seeded ([`crate::rng::SplitMix64`]): the same inputs give the
//!   same samples and figures.

pub mod compare;
pub mod marching;
pub mod nearest;
pub mod ply;
pub mod sample;
#[cfg(test)]
mod tests;

use glam::Vec3;

pub use compare::{SurfaceDistances, chamfer_fscore, compare_meshes};
pub use marching::{ScalarGrid, marching_tetrahedra};
pub use nearest::TriangleBvh;
pub use sample::sample_surface;

/// Errors of the mesh room.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    #[error("PLY: {0}")]
    Ply(String),
    #[error("invalid mesh: {0}")]
    Invalid(String),
}

/// An indexed triangle mesh with optional per-vertex normals and colours.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    pub positions: Vec<Vec3>,
    /// Unit vertex normals, or empty.
    pub normals: Vec<Vec3>,
    /// 8-bit sRGB-as-stored vertex colours, or empty.
    pub colors: Vec<[u8; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

/// How a mesh's edges are used by its triangles.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EdgeCounts {
    /// Distinct edges.
    pub edges: usize,
    /// Edges of exactly one triangle (holes, open borders).
    pub boundary: usize,
    /// Edges of three or more triangles.
    pub non_manifold: usize,
    /// Edges traversed twice in the same direction by their two triangles
    /// (inconsistently oriented neighbours).
    pub misoriented: usize,
}

impl EdgeCounts {
    /// A closed, consistently oriented 2-manifold: every edge in exactly two
    /// triangles, once in each direction.
    pub fn closed_manifold(&self) -> bool {
        self.boundary == 0 && self.non_manifold == 0 && self.misoriented == 0
    }
}

impl TriMesh {
    /// A mesh of `positions` and `triangles` without normals or colours.
    pub fn new(positions: Vec<Vec3>, triangles: Vec<[u32; 3]>) -> TriMesh {
        TriMesh { positions, triangles, ..Default::default() }
    }

    /// Indices in range, attribute arrays empty or one per vertex, positions finite.
    pub fn check(&self) -> Result<(), MeshError> {
        let n = self.positions.len();
        for (what, len) in [("normals", self.normals.len()), ("colors", self.colors.len())] {
            if len != 0 && len != n {
                return Err(MeshError::Invalid(format!("{len} {what} for {n} vertices")));
            }
        }
        if let Some(t) = self.triangles.iter().find(|t| t.iter().any(|&i| i as usize >= n)) {
            return Err(MeshError::Invalid(format!("triangle {t:?} indexes past the {n} vertices")));
        }
        if self.positions.iter().any(|p| !p.is_finite()) {
            return Err(MeshError::Invalid("a vertex position is not finite".into()));
        }
        Ok(())
    }

    /// The corners of triangle `t`.
    pub fn corners(&self, t: usize) -> [Vec3; 3] {
        self.triangles[t].map(|i| self.positions[i as usize])
    }

    /// Area of triangle `t`.
    pub fn triangle_area(&self, t: usize) -> f64 {
        let [a, b, c] = self.corners(t).map(|p| p.as_dvec3());
        0.5 * (b - a).cross(c - a).length()
    }

    /// Total surface area.
    pub fn area(&self) -> f64 {
        (0..self.triangles.len()).map(|t| self.triangle_area(t)).sum()
    }

    /// Enclosed volume by the divergence theorem (positive for a closed mesh with
    /// outward triangles; meaningless for an open one).
    pub fn signed_volume(&self) -> f64 {
        (0..self.triangles.len())
            .map(|t| {
                let [a, b, c] = self.corners(t).map(|p| p.as_dvec3());
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }

    /// Axis-aligned bounds of the vertices (`None` without vertices).
    pub fn bounds(&self) -> Option<[Vec3; 2]> {
        let first = *self.positions.first()?;
        Some(self.positions.iter().fold([first, first], |[lo, hi], &p| [lo.min(p), hi.max(p)]))
    }

    /// Counts how the triangles use their edges (see [`EdgeCounts`]).
    pub fn edge_counts(&self) -> EdgeCounts {
        // Per undirected edge: (uses as a->b with a < b, uses as b->a).
        let mut uses: std::collections::HashMap<(u32, u32), (u32, u32)> = std::collections::HashMap::new();
        for t in &self.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                let e = uses.entry((a.min(b), a.max(b))).or_default();
                if a < b { e.0 += 1 } else { e.1 += 1 }
            }
        }
        let mut c = EdgeCounts { edges: uses.len(), ..Default::default() };
        for &(f, r) in uses.values() {
            match f + r {
                1 => c.boundary += 1,
                2 if f != 1 => c.misoriented += 1,
                2 => {}
                _ => c.non_manifold += 1,
            }
        }
        c
    }

    /// Area-weighted vertex normals from the triangles' orientation (unit, or zero for
    /// a vertex of degenerate triangles only).
    pub fn vertex_normals_from_faces(&self) -> Vec<Vec3> {
        let mut n = vec![Vec3::ZERO; self.positions.len()];
        for t in &self.triangles {
            let [a, b, c] = t.map(|i| self.positions[i as usize]);
            let f = (b - a).cross(c - a);
            for &i in t {
                n[i as usize] += f;
            }
        }
        n.into_iter().map(|v| v.normalize_or_zero()).collect()
    }

    /// Keeps the triangles for which `keep(t)` holds, and the vertices they use.
    pub fn retain_triangles(&mut self, mut keep: impl FnMut(&TriMesh, usize) -> bool) {
        let kept: Vec<[u32; 3]> = (0..self.triangles.len()).filter(|&t| keep(self, t)).map(|t| self.triangles[t]).collect();
        let mut remap = vec![u32::MAX; self.positions.len()];
        let mut order = Vec::new();
        let triangles = kept
            .iter()
            .map(|t| {
                t.map(|i| {
                    if remap[i as usize] == u32::MAX {
                        remap[i as usize] = order.len() as u32;
                        order.push(i as usize);
                    }
                    remap[i as usize]
                })
            })
            .collect();
        let pick = |v: &[Vec3]| if v.is_empty() { Vec::new() } else { order.iter().map(|&i| v[i]).collect() };
        self.normals = pick(&self.normals);
        self.colors = if self.colors.is_empty() { Vec::new() } else { order.iter().map(|&i| self.colors[i]).collect() };
        self.positions = order.iter().map(|&i| self.positions[i]).collect();
        self.triangles = triangles;
    }
}
