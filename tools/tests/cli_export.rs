//! `edgenerf export mesh` / `export points` and `eval`'s mesh metrics on a short dense
//! run of the committed `creases`: counts, bounds, colours and normals of the PLY
//! files as the engine's reader parses them, and clear errors for bad flags.

mod common;

use std::path::Path;

use common::{edgenerf, repo, text};
use edgenerf::mesh::TriMesh;
use edgenerf::mesh::ply::read_ply;
use glam::Vec3;

/// The creases box (`transforms_train.json`'s aabb).
const LO: Vec3 = Vec3::new(-1.3, -1.3, -0.1);
const HI: Vec3 = Vec3::new(1.3, 1.3, 1.0);

fn inside(m: &TriMesh, lo: Vec3, hi: Vec3) -> bool {
    let eps = Vec3::splat(1e-4);
    m.positions.iter().all(|p| p.cmpge(lo - eps).all() && p.cmple(hi + eps).all())
}

/// The number printed before `word` in `t` (`"1234 vertices"`).
fn count_before(t: &str, word: &str) -> usize {
    let at = t.find(&format!(" {word}")).unwrap_or_else(|| panic!("no {word:?} in {t}"));
    t[..at].rsplit([' ', ':']).next().unwrap().parse().unwrap_or_else(|_| panic!("count before {word:?} in {t}"))
}

fn read(path: &Path) -> TriMesh {
    read_ply(&std::fs::read(path).unwrap()).unwrap()
}

#[test]
fn export_mesh_and_points_of_a_short_run_and_eval_scores_the_mesh() {
    let out = tempfile::tempdir().unwrap();
    let run = out.path().join("run");
    let scene = repo().join("synthetic-scenes/small/creases");
    let o = edgenerf(&[
        "train",
        scene.to_str().unwrap(),
        "--out",
        run.to_str().unwrap(),
        "--config",
        repo().join("tools/configs/demo.toml").to_str().unwrap(),
        "--iters",
        "30",
        "--no-eval",
        // An untrained grid is occupied everywhere: march coarsely to keep renders short.
        "--set",
        "sampler.steps_per_diagonal=48",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let r = run.to_str().unwrap();

    // 30 steps leave the density below the default level (ln 2 / step = 8.67): the
    // error says so and gives the range; half the largest density meshes the scene.
    let o = edgenerf(&["export", "mesh", r, "--resolution", "40"]);
    let t = text(&o);
    assert!(!o.status.success() && t.contains("never crosses level 8.66"), "{t}");
    let max: f32 = t.split(" to ").nth(1).and_then(|s| s.split(' ').next()).and_then(|s| s.parse().ok()).unwrap_or_else(|| panic!("{t}"));
    assert!(max > 1.0, "{t}");
    let level = format!("{}", max / 2.0);
    assert!(!run.join("mesh.ply").exists(), "nothing written on an error");

    // Just under the largest density the surface is a speck: written, with a note that
    // a lower level meshes more.
    let speck = run.join("speck.ply");
    let o = edgenerf(&["export", "mesh", r, "--resolution", "40", "--level", &format!("{}", max * 0.99), "--out", speck.to_str().unwrap()]);
    let t = text(&o);
    assert!(o.status.success() && speck.exists(), "{t}");
    assert!(t.contains("a lower --level meshes"), "{t}");

    // The mesh: beside the checkpoint by default, every vertex in the box, colours and
    // unit normals per vertex, the counts printed.
    let o = edgenerf(&["export", "mesh", r, "--resolution", "40", "--level", &level]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("grid 41x41x18 points"), "{t}");
    assert!(!t.contains("a lower --level"), "the scene's surfaces are meshed: no note\n{t}");
    let mesh = read(&run.join("mesh.ply"));
    assert_eq!(mesh.positions.len(), count_before(&t, "vertices"), "{t}");
    assert_eq!(mesh.triangles.len(), count_before(&t, "triangles"), "{t}");
    assert!(mesh.triangles.len() > 100, "{t}");
    assert!(inside(&mesh, LO, HI), "{t}");
    assert_eq!((mesh.normals.len(), mesh.colors.len()), (mesh.positions.len(), mesh.positions.len()));
    assert!(mesh.normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-3));
    assert!(mesh.edge_counts().non_manifold == 0 && mesh.edge_counts().misoriented == 0);
    // The scene is grey and white shapes on a light floor: a light, coloured-by-field mesh.
    let mean = mesh.colors.iter().map(|c| c.map(f64::from)).fold([0.0; 3], |a, c| [a[0] + c[0], a[1] + c[1], a[2] + c[2]]);
    let mean = mean.map(|s| s / mesh.colors.len() as f64);
    assert!(mean.iter().all(|&m| (60.0..250.0).contains(&m)), "mean colour {mean:?}");
    assert!(mesh.colors.iter().any(|c| c != &mesh.colors[0]));

    // A box of its own, an explicit level and file.
    let upper = out.path().join("sub/upper.ply");
    let o = edgenerf(&["export", "mesh", r, "--resolution", "24", "--bbox", "-1.3,-1.3,0.3,1.3,1.3,1.0", "--level", &level, "--out", upper.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    let part = read(&upper);
    assert!(!part.triangles.is_empty() && inside(&part, Vec3::new(-1.3, -1.3, 0.3), HI));

    // Points: two views' opaque pixels, inside the box the rays were clipped to.
    let points = out.path().join("points.ply");
    let o = edgenerf(&["export", "points", r, "--views", "0,5", "--out", points.to_str().unwrap()]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    let cloud = read(&points);
    assert_eq!(cloud.positions.len(), count_before(&t, "of"), "{t}");
    assert!(t.contains(&format!("of {} pixels of 2 view(s)", 2 * 128 * 128)), "{t}");
    assert!(cloud.positions.len() > 128 * 128 && cloud.triangles.is_empty(), "{t}");
    assert!(inside(&cloud, LO, HI));
    assert_eq!((cloud.normals.len(), cloud.colors.len()), (cloud.positions.len(), cloud.positions.len()));

    // Bad flags: clear errors, nothing written.
    for (args, says) in [
        (&["mesh", r, "--level", "1e9"][..], "no surface"),
        (&["mesh", r, "--bbox", "1,2,3"], "six finite numbers"),
        (&["mesh", r, "--bbox", "1,0,0,0,1,1"], "below the upper"),
        (&["points", r, "--views", "0,99"], "view 99 does not exist"),
        (&["points", r, "--min-opacity", "2"], "between 0 and 1"),
    ] {
        let mut a = vec!["export"];
        a.extend_from_slice(args);
        let o = edgenerf(&a);
        assert!(!o.status.success() && text(&o).contains(says), "{args:?}: {}", text(&o));
    }

    // eval adds the mesh figures against the scene's gt_mesh.ply.
    let o = edgenerf(&["eval", r, "--lpips", "none", "--mesh-resolution", "40", "--mesh-level", &level, "--out", out.path().join("eval").to_str().unwrap()]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("mesh vs gt_mesh.ply: Chamfer"), "{t}");
    let m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.path().join("eval/metrics.json")).unwrap()).unwrap();
    let chamfer = m["metrics"]["mesh.chamfer"].as_f64().unwrap();
    let f = m["metrics"]["mesh.fscore"].as_f64().unwrap();
    assert!(chamfer > 0.0 && chamfer < 1.0 && (0.0..=1.0).contains(&f), "{t}");
    assert!(m["mesh"]["gt_samples"].as_u64().unwrap() > 1000, "{}", m["mesh"]);
}
