//! Ground-truth consistency of the committed Mitsuba scenes (`synthetic-scenes/small/`),
//! read through the engine's Blender loader.
//!
//! Validates cameras, intrinsics, the pixel-centre convention and the depth / normal
//! conventions together, the way the trainer and the metrics will use them:
//! * every scene loads with depth, normals and a mask on every view, sizes and
//!   near / far / aabb as written;
//! * mask == (depth > 0); normals unit length on hits, zero on misses, facing the camera;
//!   hit points inside the aabb and depths inside [near, far];
//! * reprojection: the GT depth of each view, back-projected with `Camera::pixel_ray`
//!   and projected into its nearest view with `Camera::project`, agrees with that view's
//!   GT depth wherever it sees a continuous surface and the point is not occluded there
//!   (>= 95 % within 0.5 %, median < 1e-4), with < 2 % free-space violations;
//! * normals from depth: on flat regions the normal of the back-projected point grid
//!   matches the GT normal (median < 0.1 deg, 95th percentile < 0.5 deg);
//! * every scene's `gt_mesh.ply` holds the surface its GT depth shows, and the mesh
//!   metrics score it against itself and against a shifted copy as they should;
//! * a fresh Mitsuba render of one scene matches the committed one (`render.py --check`),
//!   when a Mitsuba venv is available (see `fresh_render_matches_committed`).

use std::path::{Path, PathBuf};
use std::process::Command;

use edgenerf::data::{LoadOptions, Scene, SceneFormat, View};
use glam::Vec3;

const SCENES: [&str; 8] = ["occlusion", "creases", "texture", "thin", "smooth", "table", "turntable", "room"];

fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn scene_dir(name: &str) -> PathBuf {
    repo_root().join("synthetic-scenes").join("small").join(name)
}

fn load(name: &str) -> Scene {
    let dir = scene_dir(name);
    Scene::load(&dir, &LoadOptions::default()).unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
}

fn json(name: &str, file: &str) -> serde_json::Value {
    let p = scene_dir(name).join(file);
    serde_json::from_str(&std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display())))
        .unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

fn gt(v: &View) -> (&[f32], &[[f32; 3]], &[f32]) {
    (
        v.depth.as_deref().unwrap_or_else(|| panic!("{}: no depth", v.name)),
        v.normal.as_deref().unwrap_or_else(|| panic!("{}: no normals", v.name)),
        v.mask.as_deref().unwrap_or_else(|| panic!("{}: no mask", v.name)),
    )
}

/// World point seen at pixel `(x, y)` of `v` (GT depth = ray distance).
fn point(v: &View, depth: &[f32], x: u32, y: u32) -> Vec3 {
    let t = depth[(y * v.camera.width + x) as usize];
    v.camera.pixel_ray(x as f32 + 0.5, y as f32 + 0.5).at(t)
}

/// Angle between two vectors in degrees, robust near 0 and independent of their lengths
/// (the stored normals are unit only to ~3e-5, which `acos` of a dot product would turn
/// into a spurious ~0.5 deg).
fn angle_deg(a: Vec3, b: Vec3) -> f32 {
    a.cross(b).length().atan2(a.dot(b)).to_degrees()
}

fn median(v: &mut [f32]) -> f32 {
    assert!(!v.is_empty());
    v.sort_by(f32::total_cmp);
    v[v.len() / 2]
}

fn percentile(v: &mut [f32], p: f32) -> f32 {
    v.sort_by(f32::total_cmp);
    v[((v.len() - 1) as f32 * p).round() as usize]
}

#[test]
fn every_scene_loads_with_ground_truth() {
    for name in SCENES {
        let scene = load(name);
        let train = json(name, "transforms_train.json");
        let test = json(name, "transforms_test.json");
        let (n_train, n_test) = (train["frames"].as_array().unwrap().len(), test["frames"].as_array().unwrap().len());
        assert_eq!(scene.format, SceneFormat::Blender, "{name}");
        assert_eq!((scene.split.train.len(), scene.split.test.len()), (n_train, n_test), "{name}");
        assert!(n_train >= 20 && n_test >= 6, "{name}: {n_train} train / {n_test} test views");
        let (w, h) = (train["w"].as_u64().unwrap() as u32, train["h"].as_u64().unwrap() as u32);
        assert_eq!(scene.image_size(), (w, h), "{name}");
        assert_eq!(scene.near, train["near"].as_f64().unwrap() as f32, "{name}");
        assert_eq!(scene.far, train["far"].as_f64().unwrap() as f32, "{name}");
        let aabb: Vec<Vec3> = train["aabb"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| {
                let c: Vec<f32> = c.as_array().unwrap().iter().map(|x| x.as_f64().unwrap() as f32).collect();
                Vec3::new(c[0], c[1], c[2])
            })
            .collect();
        assert_eq!(scene.aabb, [aabb[0], aabb[1]], "{name}");
        let transparent = train["background"] == "transparent";
        assert_eq!(scene.background.is_some(), transparent, "{name}: RGBA exactly for transparent scenes");
        let fx = train["fl_x"].as_f64().unwrap() as f32;
        for v in &scene.views {
            let (d, n, m) = gt(v);
            let px = (w * h) as usize;
            assert_eq!((d.len(), n.len(), m.len(), v.image.data.len()), (px, px, px, 3 * px), "{name}/{}", v.name);
            assert!((v.camera.fx - fx).abs() < 1e-4 && (v.camera.cx - w as f32 / 2.0).abs() < 1e-6, "{name}");
            assert!(v.image.data.iter().all(|c| (0.0..=1.0).contains(c)), "{name}/{}: pixel outside [0,1]", v.name);
        }
    }
}

#[test]
fn masks_normals_and_depth_ranges_are_consistent() {
    for name in SCENES {
        let scene = load(name);
        let (lo, hi) = (scene.aabb[0] - Vec3::splat(1e-3), scene.aabb[1] + Vec3::splat(1e-3));
        let (mut hits, mut dmin, mut dmax) = (0usize, f32::INFINITY, 0.0f32);
        for v in &scene.views {
            let (d, n, m) = gt(v);
            let (w, h) = (v.camera.width, v.camera.height);
            for y in 0..h {
                for x in 0..w {
                    let i = (y * w + x) as usize;
                    let hit = d[i] > 0.0;
                    assert_eq!(m[i] > 0.5, hit, "{name}/{} ({x},{y}): mask {} vs depth {}", v.name, m[i], d[i]);
                    assert!(m[i] == 0.0 || m[i] == 1.0, "{name}/{}: mask is binary", v.name);
                    let nv = Vec3::from(n[i]);
                    if !hit {
                        assert_eq!(nv, Vec3::ZERO, "{name}/{} ({x},{y}): normal on a miss", v.name);
                        continue;
                    }
                    hits += 1;
                    dmin = dmin.min(d[i]);
                    dmax = dmax.max(d[i]);
                    assert!((nv.length() - 1.0).abs() < 1e-3, "{name}/{} ({x},{y}): |n| = {}", v.name, nv.length());
                    let ray = v.camera.pixel_ray(x as f32 + 0.5, y as f32 + 0.5);
                    assert!(nv.dot(ray.dir) <= 2e-4, "{name}/{} ({x},{y}): normal faces away", v.name);
                    let p = ray.at(d[i]);
                    assert!(p.cmpge(lo).all() && p.cmple(hi).all(), "{name}/{} ({x},{y}): {p} outside aabb", v.name);
                }
            }
        }
        assert!(hits > 0, "{name}: no surface at all");
        assert!(scene.near <= dmin && dmax <= scene.far, "{name}: depth [{dmin}, {dmax}] vs near/far");
    }
}

/// Nearest other view by camera centre.
fn nearest_view(scene: &Scene, i: usize) -> usize {
    let o = scene.views[i].camera.origin();
    (0..scene.views.len())
        .filter(|&j| j != i)
        .min_by(|&a, &b| {
            let da = scene.views[a].camera.origin().distance(o);
            let db = scene.views[b].camera.origin().distance(o);
            da.total_cmp(&db)
        })
        .unwrap()
}

#[test]
fn depth_reprojects_consistently_between_views() {
    for name in SCENES {
        let scene = load(name);
        let (mut rel, mut violations, mut projected) = (Vec::new(), 0usize, 0usize);
        for i in 0..scene.views.len() {
            let (a, b) = (&scene.views[i], &scene.views[nearest_view(&scene, i)]);
            let (da, _, _) = gt(a);
            let (db, _, _) = gt(b);
            let (w, h) = (b.camera.width as i64, b.camera.height as i64);
            let w2c = b.camera.w2c();
            for y in 0..a.camera.height {
                for x in 0..a.camera.width {
                    if da[(y * a.camera.width + x) as usize] <= 0.0 {
                        continue;
                    }
                    let p = point(a, da, x, y);
                    let Some((uv, _z)) = b.camera.project_with(&w2c, p) else { continue };
                    // bilinear cell of pixel centres around uv
                    let (fx, fy) = (uv.x - 0.5, uv.y - 0.5);
                    let (x0, y0) = (fx.floor() as i64, fy.floor() as i64);
                    if x0 < 0 || y0 < 0 || x0 + 1 >= w || y0 + 1 >= h {
                        continue;
                    }
                    projected += 1;
                    let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
                    let at = |xx: i64, yy: i64| db[(yy * w + xx) as usize];
                    let c = [at(x0, y0), at(x0 + 1, y0), at(x0, y0 + 1), at(x0 + 1, y0 + 1)];
                    let dist = p.distance(b.camera.origin());
                    let (cmin, cmax) = c.iter().fold((f32::INFINITY, 0.0f32), |(l, u), &v| (l.min(v), u.max(v)));
                    if c.iter().any(|&v| v > 0.0) {
                        let nearest_surface = if cmin > 0.0 { cmin } else { cmax };
                        if dist < nearest_surface * 0.98 {
                            violations += 1; // b sees through a point that a says is solid
                        }
                    }
                    if cmin <= 0.0 || (cmax - cmin) / cmin > 0.02 {
                        continue; // not a continuous surface around uv in b
                    }
                    let interp = c[0] * (1.0 - tx) * (1.0 - ty) + c[1] * tx * (1.0 - ty) + c[2] * (1.0 - tx) * ty + c[3] * tx * ty;
                    let r = (interp - dist) / dist;
                    if r < -5e-3 {
                        continue; // the point lies behind the surface b sees: occluded in b
                    }
                    rel.push(r.abs());
                }
            }
        }
        assert!(rel.len() > 10_000, "{name}: only {} co-visible pixels", rel.len());
        let within = rel.iter().filter(|&&r| r < 5e-3).count() as f32 / rel.len() as f32;
        let vfrac = violations as f32 / projected.max(1) as f32;
        let med = median(&mut rel);
        println!(
            "{name:10} reprojection: {} px, {:.2}% within 0.5%, median rel {med:.1e}, free-space violations {:.2}%",
            rel.len(),
            100.0 * within,
            100.0 * vfrac
        );
        assert!(within >= 0.95, "{name}: only {:.2}% of co-visible pixels agree within 0.5%", 100.0 * within);
        // clean renders: 1e-5 to 4e-5; a half-pixel principal-point error: >= 2e-4
        assert!(med < 1e-4, "{name}: median relative reprojection error {med}");
        assert!(vfrac < 0.02, "{name}: {:.2}% free-space violations", 100.0 * vfrac);
    }
}

#[test]
fn normals_match_depth_on_flat_regions() {
    for name in SCENES {
        let scene = load(name);
        let mut angles = Vec::new();
        for v in &scene.views {
            let (d, n, _) = gt(v);
            let (w, h) = (v.camera.width, v.camera.height);
            let idx = |x: u32, y: u32| (y * w + x) as usize;
            for y in 1..h - 1 {
                for x in 1..w - 1 {
                    let c = idx(x, y);
                    let nc = Vec3::from(n[c]);
                    // flat: 3x3 all hits with equal GT normals and no depth kink
                    let mut flat = true;
                    for dy in -1i32..=1 {
                        for dx in -1i32..=1 {
                            let k = idx((x as i32 + dx) as u32, (y as i32 + dy) as u32);
                            flat &= d[k] > 0.0 && angle_deg(Vec3::from(n[k]), nc) < 0.5;
                        }
                    }
                    if !flat {
                        continue;
                    }
                    let t = d[c];
                    let ku = (d[idx(x + 1, y)] + d[idx(x - 1, y)] - 2.0 * t).abs();
                    let kv = (d[idx(x, y + 1)] + d[idx(x, y - 1)] - 2.0 * t).abs();
                    if ku > 0.01 * t || kv > 0.01 * t {
                        continue;
                    }
                    let du = point(v, d, x + 1, y) - point(v, d, x - 1, y);
                    let dv = point(v, d, x, y + 1) - point(v, d, x, y - 1);
                    let mut nd = du.cross(dv).normalize();
                    if nd.dot(v.camera.pixel_ray(x as f32 + 0.5, y as f32 + 0.5).dir) > 0.0 {
                        nd = -nd;
                    }
                    angles.push(angle_deg(nd, nc));
                }
            }
        }
        assert!(angles.len() > 10_000, "{name}: only {} flat pixels", angles.len());
        let n = angles.len();
        let med = median(&mut angles);
        let p95 = percentile(&mut angles, 0.95);
        println!("{name:10} normals vs depth: {n} flat px, median {med:.3} deg, 95th pct {p95:.3} deg");
        // clean renders: ~0.03 / ~0.1 deg (the limit of the stored depth's precision); a
        // half-pixel principal-point error gives > 0.12 deg median even on forward scenes
        assert!(med < 0.1, "{name}: median angle {med} deg between GT normals and depth-derived normals");
        assert!(p95 < 0.5, "{name}: 95th percentile angle {p95} deg");
    }
}

/// The Mitsuba venv's python: `EDGENERF_MITSUBA_PYTHON`, else `synthetic-scenes/.venv`.
fn mitsuba_python() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("EDGENERF_MITSUBA_PYTHON").filter(|p| !p.is_empty()) {
        return Some(PathBuf::from(p));
    }
    let venv = repo_root().join("synthetic-scenes/.venv/bin/python");
    venv.is_file().then_some(venv)
}

fn python_has_mitsuba(py: &Path) -> bool {
    Command::new(py)
        .args(["-c", "import mitsuba, drjit, numpy"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false)
}

/// Re-renders one small scene from scratch with Mitsuba and compares it with the
/// committed files (`render.py --check`: depth / normals / mask tightly, RGB within
/// path-tracing noise, plus the Python-side consistency checks). Needs the Mitsuba
/// venv (`bash synthetic-scenes/setup-venv.sh`); without it the test is skipped, unless
/// `EDGENERF_REQUIRE_MITSUBA=1`, which turns the skip into a failure (CI).
#[test]
fn fresh_render_matches_committed() {
    let require = std::env::var("EDGENERF_REQUIRE_MITSUBA").is_ok_and(|v| v == "1");
    let py = match mitsuba_python() {
        Some(p) if python_has_mitsuba(&p) => p,
        other => {
            let msg = format!(
                "no Mitsuba python ({}): run `bash synthetic-scenes/setup-venv.sh` or set EDGENERF_MITSUBA_PYTHON",
                other.map_or("none found".into(), |p| format!("{} cannot import mitsuba", p.display()))
            );
            assert!(!require, "EDGENERF_REQUIRE_MITSUBA=1 but {msg}");
            eprintln!("SKIPPED fresh_render_matches_committed: {msg}");
            return;
        }
    };
    let root = repo_root().join("synthetic-scenes");
    let out = Command::new(&py)
        .arg(root.join("render.py"))
        .args(["--check"])
        .arg(root.join("small"))
        .args(["--scene", "creases", "--progress-lines"])
        .output()
        .expect("run render.py --check");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let report: Vec<&str> = stdout.lines().filter(|l| !l.starts_with("progress ")).collect();
    println!("{}", report.join("\n"));
    assert!(
        out.status.success(),
        "render.py --check failed ({}):\n{}\n{}",
        out.status,
        report.join("\n"),
        String::from_utf8_lossy(&out.stderr)
    );
}

fn gt_mesh(name: &str) -> edgenerf::mesh::TriMesh {
    let p = scene_dir(name).join("gt_mesh.ply");
    let bytes = std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e} (synthetic-scenes/render.py --gt-mesh-only writes it)", p.display()));
    edgenerf::mesh::ply::read_ply(&bytes).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// Every scene's `gt_mesh.ply` is the surface its GT depth maps show: small (under
/// 800 kB), inside the aabb, and the back-projected GT depth of every hit pixel lies
/// on it (within 0.1 % of the depth; spheres are icospheres within 0.24 % of their
/// radius).
#[test]
fn gt_mesh_is_the_surface_of_the_gt_depth() {
    for name in SCENES {
        let size = std::fs::metadata(scene_dir(name).join("gt_mesh.ply")).unwrap().len();
        assert!(size < 800_000, "{name}: gt_mesh.ply is {size} bytes");
        let mesh = gt_mesh(name);
        let scene = load(name);
        let [lo, hi] = mesh.bounds().unwrap();
        let slack = Vec3::splat(1e-4);
        assert!(lo.cmpge(scene.aabb[0] - slack).all() && hi.cmple(scene.aabb[1] + slack).all(), "{name}: mesh [{lo}, {hi}]");
        let bvh = edgenerf::mesh::TriangleBvh::new(&mesh);
        let mut rel = Vec::new();
        for v in scene.views.iter().step_by(4) {
            let (depth, _, _) = gt(v);
            for y in (0..v.camera.height).step_by(3) {
                for x in (0..v.camera.width).step_by(3) {
                    let d = depth[(y * v.camera.width + x) as usize];
                    if d > 0.0 {
                        rel.push(bvh.nearest(point(v, depth, x, y)).unwrap().1 / d);
                    }
                }
            }
        }
        let (med, p99) = (median(&mut rel.clone()), percentile(&mut rel, 0.99));
        assert!(med < 1e-4 && p99 < 1e-3, "{name}: distance / depth median {med:.1e}, 99th percentile {p99:.1e}");
    }
}

/// The mesh metrics over the surface the cameras see: the GT mesh against itself
/// scores 0 and 1; shifted up by 2 % of the box diagonal it scores that distance
/// where the shift is normal to the surface (the floor, the tops), and a lower F-score
/// at a tenth of the threshold; the
/// hidden underside of `creases`' solids is left out of recall.
#[test]
fn mesh_metrics_of_the_gt_mesh_against_itself_and_shifted() {
    use edgenerf::metrics::mesh::{MeshMetricParams, mesh_metrics};
    let scene = load("creases");
    let gt = gt_mesh("creases");
    let params = MeshMetricParams { samples: 20_000, ..Default::default() };
    let same = mesh_metrics(&gt, &gt, &scene, &params).unwrap();
    let d = same.distances;
    assert!(d.chamfer < 1e-5 && d.fscore == 1.0, "{d:?}");
    let seen = d.gt_samples as f64 / 20_000.0;
    assert!((0.3..0.97).contains(&seen), "fraction of the GT surface seen: {seen}");
    let diag = (scene.aabb[1] - scene.aabb[0]).length();
    let mut up = gt.clone();
    for p in &mut up.positions {
        p.z += 0.02 * diag;
    }
    let shifted = mesh_metrics(&up, &gt, &scene, &params).unwrap().distances;
    assert!(shifted.chamfer > 0.005 * diag as f64 && shifted.chamfer < 0.021 * diag as f64, "{shifted:?}");
    assert!(shifted.fscore > 0.3 && shifted.fscore < 0.75, "{shifted:?}");
    let tight = mesh_metrics(&up, &gt, &scene, &MeshMetricParams { threshold_rel: 0.001, ..params }).unwrap().distances;
    // Only the vertical faces (which a vertical shift slides along) stay within it.
    assert!(tight.fscore < 0.25 && tight.fscore < shifted.fscore, "{tight:?}");
}
