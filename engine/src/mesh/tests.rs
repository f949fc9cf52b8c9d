use glam::Vec3;

use super::nearest::closest_point_on_triangle;
use super::ply::{mesh_to_ply, points_to_ply, read_ply};
use super::*;
use crate::rng::SplitMix64;

/// Marching tetrahedra of the "density" `r - |p|` (inside the ball of radius `r`) on
/// `n^3` points over `[-1.3, 1.3]^3`.
fn sphere(r: f32, n: usize) -> TriMesh {
    let grid = ScalarGrid::from_fn([n; 3], Vec3::splat(-1.3), Vec3::splat(1.3), |p| r - p.length());
    marching_tetrahedra(&grid, 0.0)
}

#[test]
fn marching_tetrahedra_of_a_sphere_is_a_closed_outward_manifold_of_its_area_and_volume() {
    let m = sphere(1.0, 40);
    m.check().unwrap();
    let edges = m.edge_counts();
    assert!(edges.closed_manifold(), "{edges:?}");
    // Euler characteristic of a sphere: V - E + F = 2.
    assert_eq!(m.positions.len() as i64 - edges.edges as i64 + m.triangles.len() as i64, 2);
    let (area, volume) = (m.area(), m.signed_volume());
    let (a0, v0) = (4.0 * std::f64::consts::PI, 4.0 / 3.0 * std::f64::consts::PI);
    assert!((area / a0 - 1.0).abs() < 0.01, "area {area} vs {a0}");
    assert!((volume / v0 - 1.0).abs() < 0.01, "volume {volume} vs {v0}");
    // Every vertex on the sphere (to interpolation accuracy), every normal outward.
    for (p, n) in m.positions.iter().zip(&m.normals) {
        assert!((p.length() - 1.0).abs() < 5e-3, "{p}");
        assert!(n.dot(p.normalize()) > 0.97, "normal {n} at {p}");
    }
    for t in 0..m.triangles.len() {
        let [a, b, c] = m.corners(t);
        assert!((b - a).cross(c - a).dot(a + b + c) >= 0.0, "triangle {t} faces inward");
    }
    // Vertices are shared: about one per two triangles on a closed surface.
    assert_eq!(m.positions.len() * 2, m.triangles.len() + 4);
}

#[test]
fn marching_tetrahedra_leaves_an_open_border_where_the_surface_leaves_the_grid() {
    // A half-space z < 0.1 cut by the grid: one flat sheet with a border, facing +z.
    let grid = ScalarGrid::from_fn([6, 7, 5], Vec3::splat(-1.0), Vec3::splat(1.0), |p| 0.1 - p.z);
    let m = marching_tetrahedra(&grid, 0.0);
    let e = m.edge_counts();
    assert!(e.boundary > 0 && e.non_manifold == 0 && e.misoriented == 0, "{e:?}");
    assert!((m.area() - 4.0).abs() < 1e-4, "area {}", m.area());
    assert!(m.positions.iter().all(|p| (p.z - 0.1).abs() < 1e-5));
    assert!(m.normals.iter().all(|n| n.z > 0.999), "normals point to the lower values (+z)");
    // Nothing to extract: all inside, all outside, a flat grid.
    assert!(marching_tetrahedra(&grid, 10.0).triangles.is_empty());
    assert!(marching_tetrahedra(&grid, -10.0).triangles.is_empty());
    let flat = ScalarGrid::from_fn([1, 4, 4], Vec3::ZERO, Vec3::ONE, |p| p.y);
    assert!(marching_tetrahedra(&flat, 0.5).triangles.is_empty());
}

fn colored_mesh() -> TriMesh {
    let mut m = sphere(0.8, 12);
    m.colors = (0..m.positions.len()).map(|i| [(i * 7 % 256) as u8, (i * 13 % 256) as u8, 255 - (i % 256) as u8]).collect();
    m
}

#[test]
fn ply_round_trips_positions_normals_colours_and_faces() {
    let m = colored_mesh();
    let bytes = mesh_to_ply(&m).unwrap();
    let head = String::from_utf8_lossy(&bytes[..400]);
    assert!(head.starts_with("ply\nformat binary_little_endian 1.0\n"), "{head}");
    assert!(head.contains("property uchar red") && head.contains("property list uchar int vertex_indices"));
    // 3 + 3 floats and 3 bytes per vertex, 13 bytes per triangle.
    let header_len = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    assert_eq!(bytes.len() - header_len, m.positions.len() * 27 + m.triangles.len() * 13);
    assert_eq!(read_ply(&bytes).unwrap(), m);
    // A point cloud: vertices only.
    let pts = read_ply(&points_to_ply(&m).unwrap()).unwrap();
    assert_eq!((pts.positions.len(), pts.triangles.len(), pts.colors.len()), (m.positions.len(), 0, m.positions.len()));
}

#[test]
fn ply_reads_ascii_polygons_and_refuses_what_it_cannot_read() {
    let ascii = "ply\nformat ascii 1.0\nelement vertex 4\nproperty double x\nproperty double y\nproperty double z\n\
                 property float red\nproperty float green\nproperty float blue\nelement face 1\n\
                 property list uchar uint vertex_index\nend_header\n\
                 0 0 0 1 0 0\n1 0 0 0 1 0\n1 1 0 0 0 1\n0 1 0 0.5 0.5 0.5\n4 0 1 2 3\n";
    let m = read_ply(ascii.as_bytes()).unwrap();
    assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]], "a quad is fanned into two triangles");
    assert_eq!(m.colors[0], [255, 0, 0]);
    assert_eq!(m.colors[3], [128, 128, 128]);
    assert!((m.area() - 1.0).abs() < 1e-9);
    let err = |b: &[u8]| read_ply(b).unwrap_err().to_string();
    assert!(err(ascii.replace("ascii", "binary_big_endian").as_bytes()).contains("not supported"));
    assert!(err(b"hello").contains("end_header"));
    assert!(err(ascii.replace("4 0 1 2 3", "3 0 1 9").as_bytes()).contains("indexes past"));
    let bytes = mesh_to_ply(&colored_mesh()).unwrap();
    assert!(err(&bytes[..bytes.len() - 5]).contains("truncated"));
}

#[test]
fn surface_samples_are_area_weighted_and_deterministic() {
    // Two triangles of areas 0.5 and 1.5.
    let m = TriMesh::new(
        vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::new(10.0, 0.0, 0.0), Vec3::new(13.0, 0.0, 0.0), Vec3::new(10.0, 1.0, 0.0)],
        vec![[0, 1, 2], [3, 4, 5]],
    );
    let s = sample_surface(&m, 20000, 7);
    assert_eq!(s, sample_surface(&m, 20000, 7));
    assert_ne!(s, sample_surface(&m, 20000, 8));
    let far = s.iter().filter(|p| p.x >= 10.0).count() as f64 / s.len() as f64;
    assert!((far - 0.75).abs() < 0.015, "{far}");
    // Uniform inside a triangle: the mean is its centroid.
    let near: Vec<Vec3> = s.iter().copied().filter(|p| p.x < 10.0).collect();
    let mean = near.iter().sum::<Vec3>() / near.len() as f32;
    assert!((mean - Vec3::new(1.0 / 3.0, 1.0 / 3.0, 0.0)).length() < 0.01, "{mean}");
    assert!(near.iter().all(|p| p.x >= 0.0 && p.y >= 0.0 && p.x + p.y <= 1.0 + 1e-6));
    assert!(sample_surface(&TriMesh::default(), 10, 0).is_empty());
}

#[test]
fn nearest_point_queries_match_brute_force() {
    let m = sphere(0.9, 14);
    let bvh = TriangleBvh::new(&m);
    let mut rng = SplitMix64::new(3);
    for _ in 0..300 {
        let p = Vec3::new(rng.uniform(2.0) as f32, rng.uniform(2.0) as f32, rng.uniform(2.0) as f32);
        let brute = (0..m.triangles.len())
            .map(|t| {
                let [a, b, c] = m.corners(t);
                closest_point_on_triangle(p, a, b, c).distance(p)
            })
            .fold(f32::INFINITY, f32::min);
        let (q, d) = bvh.nearest(p).unwrap();
        assert!((d - brute).abs() < 1e-5 && (q.distance(p) - d).abs() < 1e-5, "{p}: {d} vs {brute}");
    }
    // Regions of a triangle: a vertex, an edge, the face.
    let (a, b, c) = (Vec3::ZERO, Vec3::X, Vec3::Y);
    assert_eq!(closest_point_on_triangle(Vec3::new(-1.0, -1.0, 0.0), a, b, c), a);
    assert!((closest_point_on_triangle(Vec3::new(0.5, -2.0, 1.0), a, b, c) - Vec3::new(0.5, 0.0, 0.0)).length() < 1e-6);
    assert!((closest_point_on_triangle(Vec3::new(0.2, 0.3, 5.0), a, b, c) - Vec3::new(0.2, 0.3, 0.0)).length() < 1e-6);
    assert!(TriangleBvh::new(&TriMesh::default()).nearest(Vec3::ZERO).is_none());
}

#[test]
fn chamfer_and_fscore_of_concentric_spheres_measure_their_gap() {
    let (a, b) = (sphere(1.0, 48), sphere(1.1, 48));
    let same = compare_meshes(&a, &a, 20000, 1, 0.01, |_| true, |_| true);
    assert!(same.chamfer < 1e-5 && same.fscore == 1.0, "{same:?}");
    assert_eq!((same.pred_samples, same.gt_samples), (20000, 20000));
    // Radius 1 against 1.1: every distance is 0.1 (to the tessellation's accuracy).
    let gap = compare_meshes(&a, &b, 20000, 1, 0.12, |_| true, |_| true);
    assert!((gap.chamfer - 0.1).abs() < 0.003, "{gap:?}");
    assert!((gap.accuracy - 0.1).abs() < 0.003 && (gap.completeness - 0.1).abs() < 0.003, "{gap:?}");
    assert_eq!((gap.precision, gap.recall, gap.fscore), (1.0, 1.0, 1.0));
    let tight = compare_meshes(&a, &b, 20000, 1, 0.08, |_| true, |_| true);
    assert_eq!((tight.precision, tight.recall, tight.fscore), (0.0, 0.0, 0.0));
    // The region filter: only the upper half of the reference counts.
    let half = compare_meshes(&a, &b, 20000, 1, 0.12, |_| true, |p| p.z > 0.0);
    assert!((half.gt_samples as f64 / 20000.0 - 0.5).abs() < 0.02, "{half:?}");
    // A prediction with half its samples 0.1 off and half exact: precision 0.5.
    let f = chamfer_fscore(&[0.0, 0.1, 0.0, 0.1], &[0.0; 4], 0.05);
    assert_eq!((f.precision, f.recall), (0.5, 1.0));
    assert!((f.fscore - 2.0 / 3.0).abs() < 1e-12 && (f.chamfer - 0.025).abs() < 1e-9);
    assert_eq!(chamfer_fscore(&[], &[0.0], 0.1).fscore, 0.0);
}

#[test]
fn retain_triangles_keeps_the_vertices_they_use() {
    let mut m = colored_mesh();
    let before = m.triangles.len();
    m.normals = m.vertex_normals_from_faces();
    m.retain_triangles(|m, t| m.corners(t).iter().all(|p| p.z > 0.0));
    m.check().unwrap();
    assert!(m.triangles.len() < before && !m.triangles.is_empty());
    assert!(m.positions.iter().all(|p| p.z > 0.0));
    assert_eq!((m.normals.len(), m.colors.len()), (m.positions.len(), m.positions.len()));
}
