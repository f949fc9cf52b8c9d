//! Fuzzing the loaders (issue 16): random and mutated inputs must give `Err` or a valid
//! result, never a panic, an abort or a hang.
//!
//! Targets, one test each: `npy` (`parse_npy`), `npz` (`Npz::read`), `transforms` (a
//! Blender / nerfstudio scene's `transforms_train.json` through `Scene::load`),
//! `nerfstudio` (a single `transforms.json` with lenses, masks, depth and a COLMAP model
//! beside it), `colmap` (each file of a binary or text sparse model), `llff`
//! (the values of `poses_bounds.npy`), `dtu` (the matrices of `cameras.npz`), `exr`
//! (depth and normal ground truth), `png` (images, masks, headers), `checkpoint`
//! (`Checkpoint::load`), `edge_maps` (external edge maps and cached masks) and `config`
//! (`RunConfig::from_file` of JSON and TOML, `RunConfig::set`).
//!
//! Inputs come from proptest strategies over valid seeds: byte mutations (bit flips,
//! bytes and 32/64-bit words set to boundary values, insertions, deletions, chunk
//! duplication, truncation, a number in text replaced by one that overflows) or random
//! bytes, and for JSON structure-aware mutations
//! (a value replaced by a boundary number, a string, `null` or a container, a key or an
//! element removed or added). What a target checks when the loader succeeds is the
//! loader's invariant (an array holds `shape.product()` values, an image `3 w h`
//! floats, every camera passes `Camera::check`, a config validates without panicking).
//!
//! Each target runs for `EDGENERF_FUZZ_SECS` seconds (default 2: what CI runs).
//! Longer, in release, one line per target (cases, seconds, slowest case):
//!
//! ```sh
//! EDGENERF_FUZZ_SECS=60 cargo test --release -p edgenerf-suite --test fuzz_loaders -- --nocapture --test-threads 1
//! ```
//!
//! A panic fails the target with the smallest input recipe proptest's shrinking finds
//! (a seed index and the mutations, so it reproduces). A case running longer than
//! `EDGENERF_FUZZ_CASE_SECS` (default 20) is a hang: a watchdog prints the case and
//! aborts the test process.

mod common;

use std::cell::Cell;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use edgenerf::data::npy::{Npz, npy_bytes_f64, parse_npy, write_npy_f64, write_npz_f64};
use edgenerf::data::{ImageRgb, LoadOptions, Scene};
use proptest::prelude::*;
use proptest::test_runner::{Config, TestError, TestRunner};

// ------------------------------------------------------------------------- the runner

fn env_secs(name: &str, default: f64) -> f64 {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// Aborts the process when one case runs past the per-case limit (a hang would
/// otherwise block the test until CI's own timeout, saying nothing).
struct Watchdog {
    case_start_ms: Arc<AtomicU64>,
    current: Arc<Mutex<String>>,
    done: Arc<AtomicBool>,
    epoch: Instant,
}

impl Watchdog {
    fn start(target: &'static str, limit: f64) -> Watchdog {
        let w = Watchdog {
            case_start_ms: Arc::new(AtomicU64::new(u64::MAX)),
            current: Arc::new(Mutex::new(String::new())),
            done: Arc::new(AtomicBool::new(false)),
            epoch: Instant::now(),
        };
        let (start, current, done, epoch) = (w.case_start_ms.clone(), w.current.clone(), w.done.clone(), w.epoch);
        std::thread::spawn(move || {
            while !done.load(Ordering::Relaxed) {
                std::thread::sleep(Duration::from_millis(250));
                let s = start.load(Ordering::Relaxed);
                if s != u64::MAX && epoch.elapsed().as_millis() as u64 > s + (limit * 1000.0) as u64 {
                    eprintln!(
                        "fuzz target {target}: a case ran past {limit} s (hang); input: {}",
                        current.lock().map(|c| c.clone()).unwrap_or_default()
                    );
                    std::process::abort();
                }
            }
        });
        w
    }

    fn begin(&self, case: String) {
        *self.current.lock().unwrap() = case;
        self.case_start_ms.store(self.epoch.elapsed().as_millis() as u64, Ordering::Relaxed);
    }

    fn end(&self) {
        self.case_start_ms.store(u64::MAX, Ordering::Relaxed);
    }
}

impl Drop for Watchdog {
    fn drop(&mut self) {
        self.done.store(true, Ordering::Relaxed);
    }
}

/// Runs `check` on inputs drawn from `strategy` for the time budget; panics with the
/// minimal failing input if any case panics.
fn fuzz<S>(target: &'static str, strategy: S, check: impl Fn(&S::Value))
where
    S: Strategy,
    S::Value: std::fmt::Debug,
{
    let budget = env_secs("EDGENERF_FUZZ_SECS", 2.0);
    let limit = env_secs("EDGENERF_FUZZ_CASE_SECS", 20.0);
    let watchdog = Watchdog::start(target, limit);
    let cases = Cell::new(0u64);
    let slowest = Cell::new(0.0f64);
    let config = Config { cases: 64, failure_persistence: None, max_shrink_iters: 4096, ..Config::default() };
    let start = Instant::now();
    while start.elapsed().as_secs_f64() < budget {
        // A runner runs `cases` cases once: a fresh one (fresh random seed) per batch.
        let mut runner = TestRunner::new(config.clone());
        let result = runner.run(&strategy, |input| {
            watchdog.begin(format!("{input:?}"));
            let t = Instant::now();
            check(&input);
            slowest.set(slowest.get().max(t.elapsed().as_secs_f64()));
            watchdog.end();
            cases.set(cases.get() + 1);
            Ok(())
        });
        match result {
            Ok(()) => {}
            Err(TestError::Fail(reason, input)) => panic!("fuzz target {target}: {reason}\nminimal input: {input:?}"),
            Err(e) => panic!("fuzz target {target}: {e}"),
        }
    }
    println!(
        "fuzz target {target}: {} cases in {:.1} s, 0 crashes, slowest case {:.3} s",
        cases.get(),
        start.elapsed().as_secs_f64(),
        slowest.get()
    );
}

// ------------------------------------------------------------------------- byte mutations

/// 32/64-bit values that break size arithmetic.
const WORDS: [u64; 8] = [0, 1, 0x7fff_ffff, 0x8000_0000, 0xffff_ffff, 1 << 32, u64::MAX / 2, u64::MAX];
const BYTES: [u8; 6] = [0, 1, 0x7f, 0x80, 0xfe, 0xff];
/// Numbers written over a run of digits in text (headers, TOML): sizes that overflow.
const NUMBERS: [&str; 8] = ["0", "-1", "65536", "4294967296", "4611686018427387904", "18446744073709551615", "99999999999999999999", "1e309"];

#[derive(Clone, Debug)]
enum Mutation {
    Flip(usize, u8),
    Set(usize, u8),
    Boundary(usize, usize),
    Word32(usize, usize),
    Word64(usize, usize),
    Insert(usize, Vec<u8>),
    Delete(usize, usize),
    Duplicate(usize, usize, usize),
    Truncate(usize),
    /// The run of ASCII digits at or after the position replaced by one of [`NUMBERS`].
    Number(usize, usize),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        3 => (any::<usize>(), 0u8..8).prop_map(|(p, b)| Mutation::Flip(p, b)),
        2 => (any::<usize>(), any::<u8>()).prop_map(|(p, v)| Mutation::Set(p, v)),
        2 => (any::<usize>(), 0..BYTES.len()).prop_map(|(p, i)| Mutation::Boundary(p, i)),
        2 => (any::<usize>(), 0..WORDS.len()).prop_map(|(p, i)| Mutation::Word32(p, i)),
        1 => (any::<usize>(), 0..WORDS.len()).prop_map(|(p, i)| Mutation::Word64(p, i)),
        1 => (any::<usize>(), prop::collection::vec(any::<u8>(), 1..16)).prop_map(|(p, b)| Mutation::Insert(p, b)),
        1 => (any::<usize>(), 1usize..64).prop_map(|(p, n)| Mutation::Delete(p, n)),
        1 => (any::<usize>(), 1usize..64, any::<usize>()).prop_map(|(p, n, at)| Mutation::Duplicate(p, n, at)),
        1 => any::<usize>().prop_map(Mutation::Truncate),
        2 => (any::<usize>(), 0..NUMBERS.len()).prop_map(|(p, i)| Mutation::Number(p, i)),
    ]
}

fn apply(bytes: &mut Vec<u8>, m: &Mutation) {
    let len = bytes.len();
    let at = |p: usize| if len == 0 { 0 } else { p % len };
    match m {
        Mutation::Flip(p, b) if len > 0 => bytes[at(*p)] ^= 1 << b,
        Mutation::Set(p, v) if len > 0 => bytes[at(*p)] = *v,
        Mutation::Boundary(p, i) if len > 0 => bytes[at(*p)] = BYTES[*i],
        Mutation::Word32(p, i) if len >= 4 => {
            let p = p % (len - 3);
            bytes[p..p + 4].copy_from_slice(&(WORDS[*i] as u32).to_le_bytes());
        }
        Mutation::Word64(p, i) if len >= 8 => {
            let p = p % (len - 7);
            bytes[p..p + 8].copy_from_slice(&WORDS[*i].to_le_bytes());
        }
        Mutation::Insert(p, b) => {
            let p = if len == 0 { 0 } else { p % (len + 1) };
            bytes.splice(p..p, b.iter().copied());
        }
        Mutation::Delete(p, n) if len > 0 => {
            let p = at(*p);
            bytes.drain(p..(p + n).min(len));
        }
        Mutation::Duplicate(p, n, to) if len > 0 => {
            let p = at(*p);
            let chunk: Vec<u8> = bytes[p..(p + n).min(len)].to_vec();
            let to = to % (len + 1);
            bytes.splice(to..to, chunk);
        }
        Mutation::Truncate(p) => bytes.truncate(if len == 0 { 0 } else { p % len }),
        Mutation::Number(p, i) if len > 0 => {
            if let Some(start) = (at(*p)..len).chain(0..at(*p)).find(|&j| bytes[j].is_ascii_digit()) {
                let end = (start..len).find(|&j| !bytes[j].is_ascii_digit()).unwrap_or(len);
                bytes.splice(start..end, NUMBERS[*i].bytes());
            }
        }
        _ => {}
    }
}

/// A seed mutated a few times, or random bytes.
#[derive(Clone, Debug)]
enum Bytes {
    Mutated { seed: usize, ops: Vec<Mutation> },
    Random(Vec<u8>),
}

fn bytes_input(n_seeds: usize) -> impl Strategy<Value = Bytes> {
    prop_oneof![
        9 => (0..n_seeds, prop::collection::vec(mutation(), 1..8)).prop_map(|(seed, ops)| Bytes::Mutated { seed, ops }),
        1 => prop::collection::vec(any::<u8>(), 0..256).prop_map(Bytes::Random),
    ]
}

impl Bytes {
    fn build(&self, seeds: &[Vec<u8>]) -> Vec<u8> {
        match self {
            Bytes::Mutated { seed, ops } => {
                let mut b = seeds[*seed].clone();
                for m in ops {
                    apply(&mut b, m);
                }
                b
            }
            Bytes::Random(b) => b.clone(),
        }
    }
}

// ------------------------------------------------------------------------- JSON mutations

/// Values a JSON field is set to: boundary numbers, wrong types, odd paths.
fn pool(i: usize) -> serde_json::Value {
    use serde_json::json;
    let values = [
        json!(0),
        json!(-1),
        json!(1),
        json!(0.5),
        json!(-0.0),
        json!(1e-45),
        json!(3.5e38),
        json!(-3.5e38),
        json!(1e308),
        json!(4294967296u64),
        json!(u64::MAX),
        json!(i64::MIN),
        json!(""),
        json!("x"),
        json!("../x"),
        json!("NaN"),
        json!(true),
        json!(null),
        json!([]),
        json!({}),
        json!([0, 0, 0]),
        json!([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
        json!([[0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0]]),
        json!([[1e30, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
        json!({"kind": "constant", "lr": 0.01}),
    ];
    values[i % values.len()].clone()
}

#[derive(Clone, Debug)]
struct JsonOp {
    at: usize,
    action: u8,
    value: usize,
}

/// A JSON seed with structural edits, then (sometimes) byte mutations of its text.
#[derive(Clone, Debug)]
struct Json {
    seed: usize,
    ops: Vec<JsonOp>,
    bytes: Vec<Mutation>,
}

fn json_input(n_seeds: usize) -> impl Strategy<Value = Json> {
    let op = (any::<usize>(), 0u8..4, any::<usize>()).prop_map(|(at, action, value)| JsonOp { at, action, value });
    (0..n_seeds, prop::collection::vec(op, 0..6), prop::collection::vec(mutation(), 0..3))
        .prop_map(|(seed, ops, bytes)| Json { seed, ops, bytes })
}

/// JSON pointers of every value in `v`.
fn pointers(v: &serde_json::Value, at: String, out: &mut Vec<String>) {
    out.push(at.clone());
    match v {
        serde_json::Value::Object(m) => m.iter().for_each(|(k, c)| pointers(c, format!("{at}/{}", k.replace('~', "~0").replace('/', "~1")), out)),
        serde_json::Value::Array(a) => a.iter().enumerate().for_each(|(i, c)| pointers(c, format!("{at}/{i}"), out)),
        _ => {}
    }
}

impl Json {
    fn build_value(&self, seeds: &[serde_json::Value]) -> serde_json::Value {
        let mut v = seeds[self.seed].clone();
        for op in &self.ops {
            let mut ptrs = Vec::new();
            pointers(&v, String::new(), &mut ptrs);
            let ptr = &ptrs[op.at % ptrs.len()];
            let (parent, key) = ptr.rsplit_once('/').unwrap_or(("", ""));
            match op.action {
                0 => {
                    if let Some(slot) = v.pointer_mut(ptr) {
                        *slot = pool(op.value);
                    }
                }
                1 => match v.pointer_mut(parent) {
                    Some(serde_json::Value::Object(m)) => {
                        m.remove(&key.replace("~1", "/").replace("~0", "~"));
                    }
                    Some(serde_json::Value::Array(a)) if !a.is_empty() => {
                        a.remove(key.parse::<usize>().unwrap_or(0) % a.len());
                    }
                    _ => {}
                },
                2 => match v.pointer_mut(ptr) {
                    Some(serde_json::Value::Object(m)) => {
                        m.insert(format!("k{}", op.value % 7), pool(op.value / 7));
                    }
                    Some(serde_json::Value::Array(a)) => {
                        let copy = a.first().cloned().unwrap_or_else(|| pool(op.value));
                        a.push(copy);
                    }
                    _ => {}
                },
                _ => {
                    // Swap in another subtree of the document (a matrix where a path was).
                    let other = ptrs[op.value % ptrs.len()].clone();
                    if let (Some(src), false) = (v.pointer(&other).cloned(), other.starts_with(ptr.as_str())) {
                        if let Some(slot) = v.pointer_mut(ptr) {
                            *slot = src;
                        }
                    }
                }
            }
        }
        v
    }

    fn build(&self, seeds: &[serde_json::Value]) -> Vec<u8> {
        let mut bytes = serde_json::to_vec_pretty(&self.build_value(seeds)).unwrap();
        for m in &self.bytes {
            apply(&mut bytes, m);
        }
        bytes
    }
}

// ------------------------------------------------------------------------- fixtures

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn png_bytes(img: image::DynamicImage) -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

fn rgb_png(w: u32, h: u32) -> Vec<u8> {
    png_bytes(image::DynamicImage::ImageRgb8(image::RgbImage::from_fn(w, h, |x, y| image::Rgb([x as u8 * 30, y as u8 * 40, 7]))))
}

/// Seeds of the PNG targets: 8-bit RGB, RGBA, grey and 16-bit grey images.
fn png_seeds() -> Vec<Vec<u8>> {
    vec![
        rgb_png(8, 6),
        png_bytes(image::DynamicImage::ImageRgba8(image::RgbaImage::from_fn(8, 6, |x, _| image::Rgba([9, 8, 7, x as u8 * 30])))),
        png_bytes(image::DynamicImage::ImageLuma8(image::GrayImage::from_fn(8, 6, |x, y| image::Luma([((x + y) % 2 * 255) as u8])))),
        png_bytes(image::DynamicImage::ImageLuma16(image::ImageBuffer::from_fn(8, 6, |x, _| image::Luma([x as u16 * 9000])))),
    ]
}

/// A Blender scene of two 8x6 frames with every ground-truth map; returns the seeds of
/// its transforms file (full, nerfstudio-style with per-frame intrinsics, minimal).
fn blender_fixture(root: &Path) -> Vec<serde_json::Value> {
    use serde_json::json;
    for i in 0..2 {
        std::fs::write(root.join(format!("r_{i}.png")), rgb_png(8, 6)).unwrap();
        std::fs::write(root.join(format!("m_{i}.png")), &png_seeds()[2]).unwrap();
        edgenerf::data::save_depth_exr(root.join(format!("d_{i}.exr")), 8, 6, &[2.0; 48]).unwrap();
        edgenerf::data::save_normal_exr(root.join(format!("n_{i}.exr")), 8, 6, &[[0.0, 0.0, 1.0]; 48]).unwrap();
    }
    let pose = |z: f64| json!([[1.0, 0.0, 0.0, 0.1], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, z], [0.0, 0.0, 0.0, 1.0]]);
    let frame = |i: usize| {
        json!({"file_path": format!("./r_{i}"), "transform_matrix": pose(4.0 + i as f64),
               "depth_path": format!("d_{i}.exr"), "normal_path": format!("n_{i}.exr"), "mask_path": format!("m_{i}.png")})
    };
    let full = json!({"camera_angle_x": 0.7, "fl_x": 10.0, "fl_y": 10.5, "cx": 4.0, "cy": 3.0, "w": 8, "h": 6,
                      "near": 1.0, "far": 8.0, "aabb": [[-1, -1, -1], [1, 1, 1]], "frames": [frame(0), frame(1)]});
    let mut ns = json!({"camera_model": "OPENCV", "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "frames": [frame(0), frame(1)]});
    for f in ns["frames"].as_array_mut().unwrap() {
        for (k, v) in [("fl_x", json!(10.0)), ("fl_y", json!(10.0)), ("cx", json!(4.0)), ("cy", json!(3.0)), ("w", json!(8)), ("h", json!(6))] {
            f[k] = v;
        }
    }
    let minimal = json!({"camera_angle_x": 0.7, "frames": [{"file_path": "r_0.png", "transform_matrix": pose(4.0)}]});
    vec![full, ns, minimal]
}

/// Checks what every loaded scene must satisfy.
fn check_scene(scene: &Scene) {
    for v in &scene.views {
        if let Err(m) = v.camera.check() {
            panic!("loaded a camera that fails Camera::check ({m}): {:?}", v.camera);
        }
    }
    assert!(scene.split.train.iter().chain(&scene.split.test).all(|&i| i < scene.views.len()), "split out of range");
    assert!(scene.near.is_finite() && scene.far.is_finite() && scene.near < scene.far, "near {} far {}", scene.near, scene.far);
}

// ------------------------------------------------------------------------- targets

#[test]
fn fuzz_npy() {
    let mut seeds = vec![npy_bytes_f64(&[3, 17], &[0.5; 51]), npy_bytes_f64(&[2], &[1.0, -2.0]), npy_bytes_f64(&[], &[3.0])];
    // Other dtypes, versions and orders, hand-built.
    for (descr, fortran, shape, body) in [
        ("<f4", "False", "(2, 2)", vec![0u8; 16]),
        (">i8", "True", "(2, 3)", vec![1u8; 48]),
        ("|u1", "False", "(5,)", vec![9u8; 5]),
        ("<f2", "False", "(1, 1, 2)", vec![0, 0x3c, 0, 0xc0]),
    ] {
        let dict = format!("{{'descr': '{descr}', 'fortran_order': {fortran}, 'shape': {shape}, }}        \n");
        let mut b = b"\x93NUMPY\x02\x00".to_vec();
        b.extend_from_slice(&(dict.len() as u32).to_le_bytes());
        b.extend_from_slice(dict.as_bytes());
        b.extend_from_slice(&body);
        seeds.push(b);
    }
    fuzz("npy", bytes_input(seeds.len()), |input| {
        if let Ok(a) = parse_npy(&input.build(&seeds)) {
            assert_eq!(a.data.len(), a.shape.iter().product::<usize>(), "shape {:?}", a.shape);
        }
    });
}

#[test]
fn fuzz_npz() {
    let dir = tempfile::tempdir().unwrap();
    let seed = dir.path().join("seed.npz");
    write_npz_f64(&seed, &[("world_mat_0", &[4, 4], &[1.0; 16]), ("x", &[3], &[1.0, 2.0, 3.0])]).unwrap();
    let seeds = vec![std::fs::read(&seed).unwrap()];
    let path = dir.path().join("case.npz");
    fuzz("npz", bytes_input(seeds.len()), |input| {
        std::fs::write(&path, input.build(&seeds)).unwrap();
        if let Ok(npz) = Npz::read(&path) {
            for name in npz.names() {
                let a = npz.get(name).unwrap();
                assert_eq!(a.data.len(), a.shape.iter().product::<usize>());
            }
        }
    });
}

#[test]
fn fuzz_transforms() {
    let dir = tempfile::tempdir().unwrap();
    let seeds = blender_fixture(dir.path());
    let json = dir.path().join("transforms_train.json");
    fuzz("transforms", (json_input(seeds.len()), any::<bool>()), |(input, images)| {
        std::fs::write(&json, input.build(&seeds)).unwrap();
        let opts = LoadOptions { load_images: *images, ..Default::default() };
        if let Ok(scene) = Scene::load(dir.path(), &opts) {
            check_scene(&scene);
        }
    });
}

/// A nerfstudio scene of two 8x6 frames (mask, 16-bit depth) beside a COLMAP model in
/// colmap/sparse/0; returns the seeds of its transforms.json (orbit with distortion,
/// fisheye with an explicit split, forward-facing with `near`).
fn nerfstudio_fixture(root: &Path) -> Vec<serde_json::Value> {
    use serde_json::json;
    for i in 0..2 {
        std::fs::create_dir_all(root.join("images")).unwrap();
        std::fs::write(root.join(format!("images/f{i}.png")), rgb_png(8, 6)).unwrap();
        std::fs::write(root.join(format!("m{i}.png")), &png_seeds()[2]).unwrap();
        std::fs::write(root.join(format!("d{i}.png")), &png_seeds()[3]).unwrap();
    }
    let (cams, imgs, points) = colmap_seed_model();
    common::colmap::write_binary(&root.join("colmap/sparse/0"), &cams, &imgs, &points);
    let frame = |i: usize, m: serde_json::Value| json!({"file_path": format!("images/f{i}.png"), "transform_matrix": m,
                                                       "mask_path": format!("m{i}.png"), "depth_file_path": format!("d{i}.png")});
    let front = json!([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 4.0], [0.0, 0.0, 0.0, 1.0]]);
    let side = json!([[0.0, 0.0, 1.0, 4.0], [0.0, 1.0, 0.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]);
    let orbit = json!({"camera_model": "OPENCV", "fl_x": 10.0, "fl_y": 10.5, "cx": 4.0, "cy": 3.0, "w": 8, "h": 6,
                       "k1": -0.1, "k2": 0.01, "p1": 0.001, "p2": 0.0, "frames": [frame(0, front.clone()), frame(1, side)],
                       "applied_transform": [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0]]});
    let fisheye = json!({"camera_model": "OPENCV_FISHEYE", "fl_x": 6.0, "k1": 0.02, "k4": -0.001,
                         "train_filenames": ["images/f0.png"], "test_filenames": ["images/f1.png"],
                         "frames": [frame(0, front.clone()), frame(1, json!([[0.0, 0.0, -1.0, -4.0], [0.0, 1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]))]});
    let forward = json!({"fl_x": 10.0, "near": 1.0, "far": 9.0, "frames": [frame(0, front.clone()), frame(1, front)]});
    vec![orbit, fisheye, forward]
}

/// A two-camera COLMAP model (OPENCV and OPENCV_FISHEYE, 8x6) looking at the origin from
/// +z and +x, with three points.
fn colmap_seed_model() -> (Vec<common::colmap::Cam>, Vec<common::colmap::Img>, Vec<glam::DVec3>) {
    use common::colmap::{Cam, Img, pose_of};
    use glam::{DMat4, DVec4};
    let cams = vec![
        Cam { id: 1, model: "OPENCV", model_id: 4, width: 8, height: 6, params: vec![10.0, 10.0, 4.0, 3.0, -0.1, 0.01, 0.001, 0.0] },
        Cam { id: 2, model: "OPENCV_FISHEYE", model_id: 5, width: 8, height: 6, params: vec![6.0, 6.0, 4.0, 3.0, 0.02, 0.0, 0.0, -0.001] },
    ];
    let front = DMat4::from_cols(DVec4::X, DVec4::Y, DVec4::Z, DVec4::new(0.0, 0.0, 4.0, 1.0));
    let side = DMat4::from_cols(DVec4::new(0.0, 0.0, -1.0, 0.0), DVec4::Y, DVec4::X, DVec4::new(4.0, 0.0, 0.0, 1.0));
    let imgs = [front, side]
        .iter()
        .enumerate()
        .map(|(i, &c2w)| {
            let (q, t) = pose_of(c2w);
            Img { id: i as u32 + 1, q, t, camera: i as u32 + 1, name: format!("f{i}.png") }
        })
        .collect();
    (cams, imgs, vec![glam::DVec3::ZERO, glam::DVec3::new(0.3, 0.2, -0.1), glam::DVec3::new(-0.2, 0.1, 0.3)])
}

/// Values a pose entry is replaced by.
fn odd_f64() -> impl Strategy<Value = f64> {
    prop_oneof![
        Just(0.0),
        Just(-0.0),
        Just(-1.0),
        Just(f64::NAN),
        Just(f64::INFINITY),
        Just(f64::NEG_INFINITY),
        Just(1e308),
        Just(1e-308),
        Just(f64::MIN_POSITIVE),
        any::<f64>(),
        -10.0f64..10.0,
    ]
}

#[test]
fn fuzz_llff() {
    let dir = tempfile::tempdir().unwrap();
    let mut rows = Vec::new();
    for i in 0..3 {
        rows.extend_from_slice(&[1.0, 0.0, 0.0, i as f64 * 0.1, 6.0, 0.0, 1.0, 0.0, 0.0, 8.0, 0.0, 0.0, 1.0, 0.0, 10.0, 2.0, 20.0]);
        std::fs::create_dir_all(dir.path().join("images_8")).unwrap();
        std::fs::write(dir.path().join(format!("images_8/img{i}.png")), rgb_png(8, 6)).unwrap();
    }
    let npy = dir.path().join("poses_bounds.npy");
    let edits = prop::collection::vec((0usize..51, odd_f64()), 1..6);
    fuzz("llff", (edits, any::<bool>()), |(edits, images)| {
        let mut r = rows.clone();
        for &(i, v) in edits {
            r[i] = v;
        }
        write_npy_f64(&npy, &[3, 17], &r).unwrap();
        let opts = LoadOptions { load_images: *images, views: Some(2), ..Default::default() };
        if let Ok(scene) = Scene::load(dir.path(), &opts) {
            check_scene(&scene);
        }
    });
}

#[test]
fn fuzz_dtu() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("image")).unwrap();
    let n = 29; // the 3-view DTU split trains on views 25, 22 and 28
    let mats = common::dtu_camera_matrices(n, 8, 6, 1.5);
    for i in 0..n {
        std::fs::write(dir.path().join(format!("image/{i:06}.png")), rgb_png(8, 6)).unwrap();
    }
    let path = dir.path().join("cameras.npz");
    let edits = prop::collection::vec((0..mats.len(), 0usize..16, odd_f64()), 0..6);
    fuzz("dtu", (edits, prop::option::of(0..mats.len()), any::<bool>()), |(edits, drop, images)| {
        let mut m = mats.clone();
        for &(a, i, v) in edits {
            m[a].1[i] = v;
        }
        if let Some(d) = drop {
            m.remove(*d);
        }
        let arrays: Vec<(&str, &[usize], &[f64])> = m.iter().map(|(n, d)| (n.as_str(), &[4usize, 4][..], d.as_slice())).collect();
        write_npz_f64(&path, &arrays).unwrap();
        let opts = LoadOptions { load_images: *images, views: Some(3), ..Default::default() };
        if let Ok(scene) = Scene::load(dir.path(), &opts) {
            check_scene(&scene);
        }
    });
}

#[test]
fn fuzz_nerfstudio() {
    let dir = tempfile::tempdir().unwrap();
    let seeds = nerfstudio_fixture(dir.path());
    let json = dir.path().join("transforms.json");
    fuzz("nerfstudio", (json_input(seeds.len()), any::<bool>()), |(input, images)| {
        std::fs::write(&json, input.build(&seeds)).unwrap();
        let opts = LoadOptions { load_images: *images, ..Default::default() };
        if let Ok(scene) = Scene::load(dir.path(), &opts) {
            check_scene(&scene);
        }
    });
}

/// The six files of a COLMAP model (binary, then text), one mutated per case, the
/// others valid.
#[test]
fn fuzz_colmap() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("images")).unwrap();
    for i in 0..2 {
        std::fs::write(dir.path().join(format!("images/f{i}.png")), rgb_png(8, 6)).unwrap();
    }
    let (cams, imgs, points) = colmap_seed_model();
    let text = dir.path().join("text");
    common::colmap::write_text(&text, &cams, &imgs, &points);
    let (c, i, p) = common::colmap::binary_bytes(&cams, &imgs, &points);
    let names = ["cameras.bin", "images.bin", "points3D.bin", "cameras.txt", "images.txt", "points3D.txt"];
    let mut seeds = vec![c, i, p];
    seeds.extend(names[3..].iter().map(|n| std::fs::read(text.join(n)).unwrap()));
    let model = dir.path().join("sparse/0");
    std::fs::create_dir_all(&model).unwrap();
    fuzz("colmap", (bytes_input(seeds.len()), 0..seeds.len(), any::<bool>()), |(input, pick, images)| {
        let file = match input {
            Bytes::Mutated { seed, .. } => *seed,
            Bytes::Random(_) => *pick,
        };
        let kind = if file < 3 { 0..3 } else { 3..6 };
        for n in names {
            let _ = std::fs::remove_file(model.join(n));
        }
        for k in kind {
            let bytes = if k == file { input.build(&seeds) } else { seeds[k].clone() };
            std::fs::write(model.join(names[k]), bytes).unwrap();
        }
        let opts = LoadOptions { load_images: *images, ..Default::default() };
        if let Ok(scene) = Scene::load(dir.path(), &opts) {
            check_scene(&scene);
        }
    });
}

#[test]
fn fuzz_exr() {
    let dir = tempfile::tempdir().unwrap();
    let (d, n) = (dir.path().join("d.exr"), dir.path().join("n.exr"));
    edgenerf::data::save_depth_exr(&d, 8, 6, &(0..48).map(|i| i as f32 * 0.1).collect::<Vec<_>>()).unwrap();
    edgenerf::data::save_normal_exr(&n, 8, 6, &[[0.0, 1.0, 0.0]; 48]).unwrap();
    let seeds = vec![std::fs::read(&d).unwrap(), std::fs::read(&n).unwrap()];
    let path = dir.path().join("case.exr");
    fuzz("exr", bytes_input(seeds.len()), |input| {
        std::fs::write(&path, input.build(&seeds)).unwrap();
        if let Ok((w, h, v)) = edgenerf::data::load_depth_exr(&path) {
            assert_eq!(v.len(), w as usize * h as usize);
        }
        if let Ok((w, h, v)) = edgenerf::data::load_normal_exr(&path) {
            assert_eq!(v.len(), w as usize * h as usize);
        }
    });
}

#[test]
fn fuzz_png() {
    let dir = tempfile::tempdir().unwrap();
    let seeds = png_seeds();
    let path = dir.path().join("case.png");
    fuzz("png", bytes_input(seeds.len()), |input| {
        std::fs::write(&path, input.build(&seeds)).unwrap();
        let _ = edgenerf::data::image_info(&path);
        if let Ok((img, alpha)) = ImageRgb::load(&path, [1.0, 1.0, 1.0]) {
            let n = img.width as usize * img.height as usize;
            assert_eq!(img.data.len(), 3 * n);
            assert!(alpha.is_none_or(|a| a.len() == n));
        }
        if let Ok((w, h, m)) = edgenerf::data::load_mask(&path) {
            assert_eq!(m.len(), w as usize * h as usize);
        }
    });
}

#[test]
fn fuzz_checkpoint() {
    use edgenerf::field::NamedArray;
    use edgenerf::train::{Checkpoint, RunConfig};
    let dir = tempfile::tempdir().unwrap();
    let seed = dir.path().join("seed.safetensors");
    let ckpt = Checkpoint {
        step: 7,
        config: RunConfig::default(),
        field: vec![NamedArray { name: "table".into(), shape: vec![2, 3], data: vec![0.5; 6] }],
        optimizer: vec![("adam.m.table".into(), vec![0.0; 6])],
        occupancy: Some(vec![1.0; 8]),
        background: vec![("background.logits".into(), vec![0.25; 3])],
    };
    ckpt.save(&seed).unwrap();
    let seeds = vec![std::fs::read(&seed).unwrap()];
    let path = dir.path().join("case.safetensors");
    fuzz("checkpoint", bytes_input(seeds.len()), |input| {
        std::fs::write(&path, input.build(&seeds)).unwrap();
        if let Ok(c) = Checkpoint::load(&path) {
            for a in &c.field {
                assert_eq!(a.data.len(), a.shape.iter().product::<usize>(), "{}", a.name);
            }
        }
    });
}

#[test]
fn fuzz_edge_maps() {
    use edgenerf::edges::{EdgeConfig, EdgeMask, EdgeSource, edge_masks};
    let dir = tempfile::tempdir().unwrap();
    let scene_dir = dir.path().join("scene");
    std::fs::create_dir_all(&scene_dir).unwrap();
    let t = blender_fixture(&scene_dir);
    std::fs::write(scene_dir.join("transforms_train.json"), t[2].to_string()).unwrap();
    let scene = Scene::load(&scene_dir, &LoadOptions::default()).unwrap();
    let maps = dir.path().join("maps");
    std::fs::create_dir_all(&maps).unwrap();
    let cfg = EdgeConfig { source: EdgeSource::External, dir: Some(maps.clone()), ..EdgeConfig::default() };
    let mut seeds = png_seeds();
    EdgeMask::all_non_edge(8, 6).save_png(&dir.path().join("m.png")).unwrap();
    seeds.push(std::fs::read(dir.path().join("m.png")).unwrap());
    let path = maps.join("r_0.png");
    fuzz("edge_maps", bytes_input(seeds.len()), |input| {
        std::fs::write(&path, input.build(&seeds)).unwrap();
        if let Ok(m) = EdgeMask::load_png(&path) {
            assert_eq!(m.non_edge.len(), m.width as usize * m.height as usize);
        }
        if let Ok(masks) = edge_masks(&scene, &[0], &cfg) {
            assert_eq!((masks[0].width, masks[0].height), (8, 6), "an external map of another size was accepted");
        }
    });
}

#[test]
fn fuzz_config() {
    use edgenerf::train::{Backend, RunConfig};
    let dir = tempfile::tempdir().unwrap();
    // Structure seeds: the defaults and every committed preset, as JSON.
    let mut json_seeds = vec![serde_json::to_value(RunConfig::default()).unwrap(), serde_json::to_value(RunConfig::defaults_for(Backend::Mlp)).unwrap()];
    let mut toml_seeds = Vec::new();
    let mut presets: Vec<PathBuf> = std::fs::read_dir(repo().join("tools/configs")).unwrap().map(|e| e.unwrap().path()).collect();
    presets.sort();
    for p in presets.iter().filter(|p| p.extension().is_some_and(|e| e == "toml")) {
        toml_seeds.push(std::fs::read(p).unwrap());
        json_seeds.push(serde_json::from_str(&RunConfig::from_file(p).unwrap().to_json()).unwrap());
    }
    let keys: Vec<String> = {
        let mut ptrs = Vec::new();
        pointers(&json_seeds[0], String::new(), &mut ptrs);
        ptrs.iter().filter(|p| !p.is_empty()).map(|p| p[1..].replace('/', ".")).collect()
    };
    let (json_path, toml_path) = (dir.path().join("case.json"), dir.path().join("case.toml"));
    let check = |c: RunConfig| {
        let mut c = c;
        c.resolve();
        let _ = c.validate();
        let _ = (c.to_json(), c.hash());
    };
    let input = (json_input(json_seeds.len()), bytes_input(toml_seeds.len()), any::<usize>(), any::<usize>());
    fuzz("config", input, |(json, toml, key, value)| {
        std::fs::write(&json_path, json.build(&json_seeds)).unwrap();
        if let Ok(c) = RunConfig::from_file(&json_path) {
            check(c);
        }
        std::fs::write(&toml_path, toml.build(&toml_seeds)).unwrap();
        if let Ok(c) = RunConfig::from_file(&toml_path) {
            check(c);
        }
        let mut c = RunConfig::default();
        if c.set(&format!("{}={}", keys[key % keys.len()], pool(*value))).is_ok() {
            check(c);
        }
    });
}
