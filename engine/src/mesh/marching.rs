//! Isosurfaces of a scalar grid by marching tetrahedra.
//!
//! Each grid cell is split into the six tetrahedra around its main diagonal (Kuhn's
//! triangulation). Every cell is split the same way, so the tetrahedra of neighbouring
//! cells share their faces and the diagonals on them: the surface has no cracks and no
//! ambiguous cases (unlike marching cubes' tables), and is a 2-manifold wherever it
//! stays inside the grid (it is open where it leaves the grid).
//!
//! A grid point is *inside* where its value is above the level (a density: the solid
//! is where it is high; NaN counts as outside). Surface vertices lie on tetrahedron
//! edges between an inside and an outside point, linearly interpolated, and are shared
//! by every triangle on that edge (keyed by the edge's two grid points). Triangles are
//! oriented so that their normal `(b - a) x (c - a)` points from the inside points of
//! their tetrahedron to its outside points: outward, toward lower values.

use std::collections::HashMap;

use glam::Vec3;

use super::TriMesh;

/// Values on a regular grid of `dims` points spanning the box `lo..hi` (corners
/// included), `x` fastest: `values[x + nx (y + ny z)]`.
#[derive(Clone, Debug)]
pub struct ScalarGrid {
    pub dims: [usize; 3],
    pub lo: Vec3,
    pub hi: Vec3,
    pub values: Vec<f32>,
}

impl ScalarGrid {
    /// The position of grid point `(x, y, z)`.
    pub fn point(&self, x: usize, y: usize, z: usize) -> Vec3 {
        let f = |i: usize, n: usize| if n > 1 { i as f32 / (n - 1) as f32 } else { 0.5 };
        self.lo + (self.hi - self.lo) * Vec3::new(f(x, self.dims[0]), f(y, self.dims[1]), f(z, self.dims[2]))
    }

    /// Every grid point's position, in the order of `values`.
    pub fn points(&self) -> impl Iterator<Item = Vec3> + '_ {
        let [nx, ny, nz] = self.dims;
        (0..nz).flat_map(move |z| (0..ny).flat_map(move |y| (0..nx).map(move |x| self.point(x, y, z))))
    }

    /// The grid of `dims` points over `lo..hi` with `f` evaluated at each point.
    pub fn from_fn(dims: [usize; 3], lo: Vec3, hi: Vec3, f: impl Fn(Vec3) -> f32) -> ScalarGrid {
        let mut g = ScalarGrid { dims, lo, hi, values: Vec::new() };
        g.values = g.points().map(f).collect();
        g
    }
}

/// The six tetrahedra of a cell around its diagonal from corner 0 to corner 7, as
/// corner numbers (bit 0: +x, bit 1: +y, bit 2: +z): `0, e_a, e_a + e_b, 7` for each
/// order `(a, b)` of two distinct axes.
const TETS: [[usize; 4]; 6] = {
    let orders = [(0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)];
    let mut t = [[0; 4]; 6];
    let mut i = 0;
    while i < 6 {
        let (a, b) = orders[i];
        t[i] = [0, 1 << a, (1 << a) | (1 << b), 7];
        i += 1;
    }
    t
};

/// The surface where `grid`'s values cross `level` (see the module doc); vertex
/// normals are the area-weighted normals of their triangles.
pub fn marching_tetrahedra(grid: &ScalarGrid, level: f32) -> TriMesh {
    let [nx, ny, nz] = grid.dims;
    let mut mesh = TriMesh::default();
    if nx < 2 || ny < 2 || nz < 2 || grid.values.len() != nx * ny * nz {
        return mesh;
    }
    let index = |x: usize, y: usize, z: usize| x + nx * (y + ny * z);
    let inside = |v: f32| v > level;
    let total = (nx * ny * nz) as u64;
    let mut vertex_of: HashMap<u64, u32> = HashMap::new();
    // The shared vertex on the edge between grid points `a` (inside) and `b` (outside).
    let mut edge_vertex = |mesh: &mut TriMesh, a: (usize, Vec3), b: (usize, Vec3)| -> u32 {
        let key = a.0.min(b.0) as u64 * total + a.0.max(b.0) as u64;
        *vertex_of.entry(key).or_insert_with(|| {
            let (va, vb) = (grid.values[a.0], grid.values[b.0]);
            let vb = if vb.is_nan() { f32::NEG_INFINITY } else { vb };
            let t = if vb.is_finite() { ((level - va) / (vb - va)).clamp(0.0, 1.0) } else { 1.0 };
            mesh.positions.push(a.1.lerp(b.1, t));
            (mesh.positions.len() - 1) as u32
        })
    };
    for z in 0..nz - 1 {
        for y in 0..ny - 1 {
            for x in 0..nx - 1 {
                let corner = |c: usize| (x + (c & 1), y + ((c >> 1) & 1), z + ((c >> 2) & 1));
                let ids: [usize; 8] = std::array::from_fn(|c| {
                    let (i, j, k) = corner(c);
                    index(i, j, k)
                });
                let ins: [bool; 8] = ids.map(|i| inside(grid.values[i]));
                if ins.iter().all(|&b| b) || ins.iter().all(|&b| !b) {
                    continue;
                }
                let pos: [Vec3; 8] = std::array::from_fn(|c| {
                    let (i, j, k) = corner(c);
                    grid.point(i, j, k)
                });
                for tet in TETS {
                    let (inn, out): (Vec<usize>, Vec<usize>) = tet.iter().partition(|&&c| ins[c]);
                    if inn.is_empty() || out.is_empty() {
                        continue;
                    }
                    let at = |c: usize| (ids[c], pos[c]);
                    let mut v = |a: usize, b: usize| edge_vertex(&mut mesh, at(a), at(b));
                    let tris: Vec<[u32; 3]> = match (inn.as_slice(), out.as_slice()) {
                        (&[a], &[b, c, d]) => vec![[v(a, b), v(a, c), v(a, d)]],
                        (&[a, b, c], &[d]) => vec![[v(a, d), v(b, d), v(c, d)]],
                        (&[a, b], &[c, d]) => {
                            let (ac, ad, bd, bc) = (v(a, c), v(a, d), v(b, d), v(b, c));
                            vec![[ac, ad, bd], [ac, bd, bc]]
                        }
                        _ => unreachable!("a tetrahedron has four corners"),
                    };
                    let centre = |cs: &[usize]| cs.iter().map(|&c| pos[c]).sum::<Vec3>() / cs.len() as f32;
                    let outward = centre(&out) - centre(&inn);
                    for mut t in tris {
                        let [p, q, r] = t.map(|i| mesh.positions[i as usize]);
                        if (q - p).cross(r - p).dot(outward) < 0.0 {
                            t.swap(1, 2);
                        }
                        mesh.triangles.push(t);
                    }
                }
            }
        }
    }
    mesh.normals = mesh.vertex_normals_from_faces();
    mesh
}
