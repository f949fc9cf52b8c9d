//! `edgenerf view`: a local web viewer of a trained run (or one in progress). A small
//! HTTP server (tiny_http) serves one page (`tools/assets/viewer/index.html`, embedded)
//! and a few fixed routes; the frames are rendered by the engine on one render thread
//! ([`worker`]) that owns the GPU and the model.
//!
//! Routes (GET only; everything else is 404, so no file path ever comes from a URL):
//! * `/` the page; `/api/info` the scene, its views and cameras; `/api/status` the step
//!   shown; `/api/log` the run's loss and PSNR curves (`log.csv`).
//! * `/api/frame?mode=rgb|depth|normals|opacity&view=N&c2w=16 numbers&scale=S&client=ID`:
//!   a PNG of the camera of dataset view `N` (intrinsics and lens; default the first
//!   training view), posed at `c2w` (row-major camera-to-world, OpenGL frame; default
//!   the view's own pose), at `S` times its size. The newest request of each client
//!   wins: a waiting one that a newer one replaces gets 204.
//! * `/api/view?view=N` that view's PSNR and SSIM under the scene's protocol;
//!   `/api/image?view=N&kind=...` its render, ground truth, error maps and edge mask.
//!
//! Malformed parameters get 400 with a message. Binds 127.0.0.1 unless `--host`.

mod worker;

use std::collections::HashMap;
use std::io::Write;
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex, mpsc};

use anyhow::{Context, bail};
use edgenerf::data::{Camera, ImageRgb, Scene};
use edgenerf::gpu::GpuOptions;
use edgenerf::train::Checkpoint;
use edgenerf::train::model::RenderedView;
use glam::{Mat4, Vec3};
use worker::{Job, Outcome, Queue};

/// The page, embedded in the binary (no build step, no files served from disk).
const INDEX_HTML: &str = include_str!("../../assets/viewer/index.html");

/// Handler threads: requests waiting for a render each hold one, so there are more than
/// the queue's [`worker::MAX_QUEUED`] plus the one rendering, and `/api/status` or the
/// page itself are answered however many frames wait.
const HANDLERS: usize = worker::MAX_QUEUED + 16;
/// Largest frame (pixels) a request may ask for.
const MAX_PIXELS: u64 = 4096 * 4096;

#[derive(clap::Args)]
pub struct Args {
    /// A run directory holding checkpoint.safetensors (and log.csv), or a checkpoint file.
    run: PathBuf,
    /// TCP port (0: any free port; the address is printed).
    #[arg(long, default_value_t = 8765)]
    port: u16,
    /// Address to listen on. The default serves this machine only; `0.0.0.0` serves the
    /// network (the viewer has no authentication).
    #[arg(long, default_value = "127.0.0.1")]
    host: String,
    /// Scene directory (default: the path recorded in the checkpoint's config).
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Do not reload the checkpoint when training writes a new one.
    #[arg(long)]
    no_follow: bool,
    /// Rays per strip of a frame; a newer request is looked for between strips (tests
    /// make frames of several strips with it).
    #[arg(long, hide = true, default_value_t = worker::STRIP_RAYS, value_parser = clap::value_parser!(u32).range(1..))]
    strip_rays: u32,
}

/// What every handler thread reads.
struct State {
    scene: Arc<Scene>,
    queue: Arc<Queue>,
    /// `/api/info`'s JSON, built once.
    info: String,
    log_path: PathBuf,
    edges: edgenerf::edges::EdgeConfig,
    /// The last dataset view rendered for the side panel: (step, view, render).
    view_cache: Mutex<Option<(u64, usize, Arc<RenderedView>)>>,
}

pub fn run(args: Args, gpu_opts: &GpuOptions) -> anyhow::Result<()> {
    // A client that closes its connection must not end the process (main sets SIGPIPE's
    // default action for `edgenerf info | head`); writes to it fail instead.
    #[cfg(unix)]
    // SAFETY: no other thread exists yet; SIG_IGN is a valid action.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_IGN);
    }
    let ckpt_path = if args.run.is_dir() { args.run.join("checkpoint.safetensors") } else { args.run.clone() };
    if !ckpt_path.is_file() {
        bail!("{} has no checkpoint ({} missing); pass a run directory of `edgenerf train` or a checkpoint file", args.run.display(), ckpt_path.display());
    }
    let run_dir = ckpt_path.parent().map(PathBuf::from).unwrap_or_default();
    let ckpt = Checkpoint::load(&ckpt_path)?;
    let scene_path = args.scene.clone().unwrap_or_else(|| ckpt.config.scene.path.clone());
    let scene = Scene::load(&scene_path, &ckpt.config.scene.load_options()).with_context(|| {
        format!("loading the scene {} of {} (pass --scene to point elsewhere)", scene_path.display(), ckpt_path.display())
    })?;
    let scene = Arc::new(scene);
    let edges = ckpt.config.edges.clone();
    drop(ckpt);

    let queue = Queue::new(0);
    let (adapter_name, adapter) = worker::start(ckpt_path.clone(), scene.clone(), gpu_opts.clone(), queue.clone(), !args.no_follow, args.strip_rays)?;
    let info = info_json(&scene, &run_dir, &adapter_name).to_string();
    let state = Arc::new(State { scene, queue, info, log_path: run_dir.join("log.csv"), edges, view_cache: Mutex::new(None) });

    let addr = format!("{}:{}", args.host, args.port);
    let server = tiny_http::Server::http(&addr).map_err(|e| anyhow::anyhow!("listening on {addr}: {e}"))?;
    let server = Arc::new(server);
    let bound = server.server_addr().to_ip().map_or(addr.clone(), |a| a.to_string());
    {
        let mut out = std::io::stdout().lock();
        let _ = writeln!(
            out,
            "edgenerf view: http://{bound}/ ({} at step {}, on {adapter}; Ctrl-C stops)",
            ckpt_path.display(),
            state.queue.step.load(Ordering::SeqCst)
        );
        let _ = out.flush();
    }
    let handlers: Vec<_> = (0..HANDLERS)
        .map(|i| {
            let (server, state) = (server.clone(), state.clone());
            std::thread::Builder::new()
                .name(format!("http-{i}"))
                .spawn(move || {
                    while let Ok(request) = server.recv() {
                        // A panic in one request (a bug) answers nothing but keeps the thread.
                        let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| handle(&state, request)));
                    }
                })
                .expect("spawning an HTTP handler thread")
        })
        .collect();
    for h in handlers {
        let _ = h.join();
    }
    Ok(())
}

/// A response: status, content type, body and extra headers.
struct Reply {
    status: u16,
    kind: &'static str,
    body: Vec<u8>,
    headers: Vec<(&'static str, String)>,
}

impl Reply {
    fn text(status: u16, msg: impl Into<String>) -> Reply {
        Reply { status, kind: "text/plain; charset=utf-8", body: msg.into().into_bytes(), headers: vec![] }
    }
    fn json(v: String) -> Reply {
        Reply { status: 200, kind: "application/json", body: v.into_bytes(), headers: vec![] }
    }
    fn png(body: Vec<u8>) -> Reply {
        Reply { status: 200, kind: "image/png", body, headers: vec![] }
    }
}

/// A 400 with its message.
struct BadRequest(String);

impl From<BadRequest> for Reply {
    fn from(b: BadRequest) -> Reply {
        Reply::text(400, format!("bad request: {}\n", b.0))
    }
}

fn handle(state: &State, request: tiny_http::Request) {
    let reply = if *request.method() != tiny_http::Method::Get {
        Reply::text(405, "only GET\n")
    } else {
        let url = request.url().to_string();
        let (path, query) = url.split_once('?').unwrap_or((&url, ""));
        match parse_query(query) {
            Err(b) => b.into(),
            Ok(q) => route(state, path, &q),
        }
    };
    let mut response = tiny_http::Response::from_data(reply.body).with_status_code(reply.status);
    let mut add = |k: &str, v: &str| {
        if let Ok(h) = tiny_http::Header::from_bytes(k.as_bytes(), v.as_bytes()) {
            response.add_header(h);
        }
    };
    add("Content-Type", reply.kind);
    add("Cache-Control", "no-store");
    add("X-Content-Type-Options", "nosniff");
    for (k, v) in &reply.headers {
        add(k, v);
    }
    // The client may be gone (a closed tab): nothing to do.
    let _ = request.respond(response);
}

fn route(state: &State, path: &str, q: &Query) -> Reply {
    let result = match path {
        "/" | "/index.html" => {
            return Reply { status: 200, kind: "text/html; charset=utf-8", body: INDEX_HTML.as_bytes().to_vec(), headers: vec![] };
        }
        "/api/info" => q.only(&[]).map(|()| Reply::json(state.info.clone())),
        "/api/status" => q.only(&[]).map(|()| {
            Reply::json(
                serde_json::json!({
                    "step": state.queue.step.load(Ordering::SeqCst),
                    "reloads": state.queue.reloads.load(Ordering::SeqCst),
                })
                .to_string(),
            )
        }),
        "/api/log" => q.only(&[]).map(|()| Reply::json(log_json(&state.log_path).to_string())),
        "/api/frame" => frame(state, q),
        "/api/view" => view_metrics(state, q),
        "/api/image" => view_image(state, q),
        _ => return Reply::text(404, "not found\n"),
    };
    result.unwrap_or_else(Reply::from)
}

/// The query's parameters (percent-decoded), each at most once.
struct Query(HashMap<String, String>);

fn parse_query(query: &str) -> Result<Query, BadRequest> {
    let mut map = HashMap::new();
    for pair in query.split('&').filter(|p| !p.is_empty()) {
        let (k, v) = pair.split_once('=').unwrap_or((pair, ""));
        let (k, v) = (percent_decode(k)?, percent_decode(v)?);
        if map.insert(k.clone(), v).is_some() {
            return Err(BadRequest(format!("parameter {k} given twice")));
        }
    }
    Ok(Query(map))
}

fn percent_decode(s: &str) -> Result<String, BadRequest> {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        match bytes[i] {
            b'%' => {
                let hex = bytes.get(i + 1..i + 3).and_then(|h| std::str::from_utf8(h).ok()).and_then(|h| u8::from_str_radix(h, 16).ok());
                out.push(hex.ok_or_else(|| BadRequest(format!("bad percent escape in {s:?}")))?);
                i += 3;
            }
            b'+' => {
                out.push(b' ');
                i += 1;
            }
            b => {
                out.push(b);
                i += 1;
            }
        }
    }
    String::from_utf8(out).map_err(|_| BadRequest(format!("{s:?} is not UTF-8")))
}

impl Query {
    /// Refuses parameters outside `allowed`.
    fn only(&self, allowed: &[&str]) -> Result<(), BadRequest> {
        let mut unknown: Vec<&str> = self.0.keys().map(String::as_str).filter(|k| !allowed.contains(k)).collect();
        unknown.sort();
        match unknown.first() {
            None => Ok(()),
            Some(k) if allowed.is_empty() => Err(BadRequest(format!("unknown parameter {k} (this route takes none)"))),
            Some(k) => Err(BadRequest(format!("unknown parameter {k} (this route takes {})", allowed.join(", ")))),
        }
    }

    fn get(&self, k: &str) -> Option<&str> {
        self.0.get(k).map(String::as_str)
    }

    /// Dataset view `view` (`default` when absent), checked against the scene.
    fn view(&self, scene: &Scene, default: Option<usize>) -> Result<usize, BadRequest> {
        let n = scene.views.len();
        match self.get("view") {
            None => default.ok_or_else(|| BadRequest("missing parameter view (a dataset view index)".into())),
            Some(s) => match s.parse::<usize>() {
                Ok(v) if v < n => Ok(v),
                Ok(v) => Err(BadRequest(format!("view {v} does not exist (the scene has views 0..{})", n.saturating_sub(1)))),
                Err(_) => Err(BadRequest(format!("view {s:?} is not a view index"))),
            },
        }
    }

    /// The client key (newest request wins per key): letters, digits, `-` and `_`.
    fn client(&self) -> Result<String, BadRequest> {
        let c = self.get("client").unwrap_or("");
        if c.len() > 64 || !c.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_') {
            return Err(BadRequest("client must be at most 64 letters, digits, '-' or '_'".into()));
        }
        Ok(c.to_string())
    }
}

/// Parses `c2w`: 16 finite numbers separated by commas, row-major, a rigid transform.
fn parse_c2w(s: &str) -> Result<Mat4, BadRequest> {
    let vals: Vec<f32> = s
        .split(',')
        .map(|v| v.trim().parse::<f32>().map_err(|_| BadRequest(format!("c2w: {v:?} is not a number"))))
        .collect::<Result<_, _>>()?;
    if vals.len() != 16 {
        return Err(BadRequest(format!("c2w needs 16 numbers (a row-major 4x4 camera-to-world matrix), got {}", vals.len())));
    }
    if vals.iter().any(|v| !v.is_finite()) {
        return Err(BadRequest("c2w contains NaN or infinite values".into()));
    }
    let mut cols = [0f32; 16];
    cols.copy_from_slice(&vals);
    Ok(Mat4::from_cols_array(&cols).transpose())
}

/// The camera a frame request describes (see the module doc), checked.
fn request_camera(scene: &Scene, q: &Query) -> Result<(usize, Camera), BadRequest> {
    let v = q.view(scene, Some(scene.split.train.first().copied().unwrap_or(0)))?;
    let mut cam = scene.views[v].camera;
    if let Some(s) = q.get("c2w") {
        cam.c2w = parse_c2w(s)?;
    }
    let scale = match q.get("scale") {
        None => 1.0,
        Some(s) => match s.parse::<f32>() {
            Ok(x) if (0.01..=4.0).contains(&x) => x,
            _ => return Err(BadRequest(format!("scale {s:?} must be a number in [0.01, 4] (1 = the view's size)"))),
        },
    };
    if scale != 1.0 {
        let size = |n: u32| ((n as f32 * scale).round() as u32).max(1);
        cam = cam.resized(size(cam.width), size(cam.height));
    }
    if u64::from(cam.width) * u64::from(cam.height) > MAX_PIXELS {
        return Err(BadRequest(format!("{}x{} is larger than the {MAX_PIXELS} pixels a frame may have", cam.width, cam.height)));
    }
    cam.check().map_err(|e| BadRequest(format!("camera: {e}")))?;
    Ok((v, cam))
}

/// Renders `camera` on the render thread (newest wins per `key`).
fn render(state: &State, key: String, camera: Camera) -> Result<(RenderedView, u64, f64), Reply> {
    let (tx, rx) = mpsc::channel();
    state.queue.push(Job { key, camera, reply: tx });
    match rx.recv() {
        Ok(Outcome::Done { view, step, ms }) => Ok((view, step, ms)),
        Ok(Outcome::Superseded) => Err(Reply { status: 204, kind: "text/plain", body: vec![], headers: vec![("X-Superseded", "1".into())] }),
        Ok(Outcome::Busy) => Err(Reply::text(503, "too many requests waiting for the renderer; retry\n")),
        Ok(Outcome::Failed(e)) => Err(Reply::text(500, format!("render failed: {e}\n"))),
        Err(_) => Err(Reply::text(500, "the render thread stopped\n")),
    }
}

const MODES: [&str; 4] = ["rgb", "depth", "normals", "opacity"];

fn frame(state: &State, q: &Query) -> Result<Reply, BadRequest> {
    q.only(&["mode", "view", "c2w", "scale", "client"])?;
    let mode = q.get("mode").unwrap_or("rgb");
    if !MODES.contains(&mode) {
        return Err(BadRequest(format!("mode {mode:?} is not one of {}", MODES.join(", "))));
    }
    let (_, camera) = request_camera(&state.scene, q)?;
    let key = format!("frame/{}", q.client()?);
    let (r, step, ms) = match render(state, key, camera) {
        Ok(x) => x,
        Err(reply) => return Ok(reply),
    };
    let img = match mode {
        "rgb" => edgenerf::train::output::rgb_image(&r),
        "depth" => {
            let (d, valid) = edgenerf::train::output::shown_depth(&r);
            edgenerf::viz::depth_image(r.width, r.height, &d, Some(&valid)).0
        }
        "normals" => edgenerf::viz::normal_image(r.width, r.height, &r.unit_normals()),
        _ => edgenerf::viz::grey_image(r.width, r.height, &r.opacity),
    };
    let mut reply = Reply::png(png_bytes(&img));
    reply.headers.push(("X-Step", step.to_string()));
    reply.headers.push(("X-Render-Ms", format!("{ms:.1}")));
    reply.headers.push(("X-Samples-Per-Ray", format!("{:.2}", r.samples as f64 / (r.width as f64 * r.height as f64))));
    Ok(reply)
}

/// The render of dataset view `v` at the step now loaded, from the cache or rendered
/// (one at a time: concurrent requests for the same view wait for one render).
fn view_render(state: &State, v: usize) -> Result<(u64, Arc<RenderedView>), Reply> {
    let mut cache = state.view_cache.lock().unwrap_or_else(|p| p.into_inner());
    let step = state.queue.step.load(Ordering::SeqCst);
    if let Some((s, cv, r)) = cache.as_ref()
        && *s == step
        && *cv == v
    {
        return Ok((step, r.clone()));
    }
    let (r, step, _) = render(state, "view-panel".into(), state.scene.views[v].camera)?;
    let r = Arc::new(r);
    *cache = Some((step, v, r.clone()));
    Ok((step, r))
}

fn split_of(scene: &Scene, v: usize) -> &'static str {
    if scene.split.train.contains(&v) {
        "train"
    } else if scene.split.test.contains(&v) {
        "test"
    } else {
        "unused"
    }
}

fn view_metrics(state: &State, q: &Query) -> Result<Reply, BadRequest> {
    q.only(&["view", "client"])?;
    let v = q.view(&state.scene, None)?;
    let (step, r) = match view_render(state, v) {
        Ok(x) => x,
        Err(reply) => return Ok(reply),
    };
    let view = &state.scene.views[v];
    let rgb: Vec<f32> = r.rgb.iter().flatten().copied().collect();
    let score = if view.image.is_empty() { None } else { edgenerf::metrics::score_view(&state.scene, v, &rgb).ok() };
    let finite = |x: f64| if x.is_finite() { serde_json::json!(x) } else { serde_json::Value::Null };
    Ok(Reply::json(
        serde_json::json!({
            "view": v,
            "name": view.name,
            "split": split_of(&state.scene, v),
            "step": step,
            "psnr": score.map(|s| finite(s.psnr)),
            "ssim": score.map(|s| finite(s.ssim)),
            "protocol": score.map(|s| s.protocol),
            "samples_per_ray": r.samples as f64 / (r.width as f64 * r.height as f64),
            "gt_depth": view.depth.is_some(),
            "gt_normal": view.normal.is_some(),
        })
        .to_string(),
    ))
}

const KINDS: [&str; 11] =
    ["render", "gt", "error", "depth", "gt-depth", "depth-error", "normals", "gt-normals", "normal-error", "opacity", "edges"];

fn view_image(state: &State, q: &Query) -> Result<Reply, BadRequest> {
    q.only(&["view", "kind", "client"])?;
    let v = q.view(&state.scene, None)?;
    let kind = q.get("kind").unwrap_or("render");
    if !KINDS.contains(&kind) {
        return Err(BadRequest(format!("kind {kind:?} is not one of {}", KINDS.join(", "))));
    }
    let scene = &state.scene;
    let view = &scene.views[v];
    let (w, h) = (view.camera.width, view.camera.height);
    let missing = |what: &str| Ok(Reply::text(404, format!("view {v} has no {what}\n")));
    // Images without a render first.
    match kind {
        "gt" if view.image.is_empty() => return missing("image"),
        "gt" => return Ok(Reply::png(png_bytes(&view.image))),
        "edges" => {
            if view.image.is_empty() {
                return missing("image");
            }
            return Ok(match edgenerf::edges::edge_mask(scene, v, &state.edges) {
                Ok(mask) => Reply::png(png_bytes(&edge_overlay(&view.image, &mask))),
                Err(e) => Reply::text(500, format!("edge mask of view {v}: {e}\n")),
            });
        }
        "gt-depth" => {
            let Some(gt) = &view.depth else { return missing("ground-truth depth") };
            let valid: Vec<bool> = gt.iter().map(|&d| edgenerf::metrics::valid_depth(d)).collect();
            return Ok(Reply::png(png_bytes(&edgenerf::viz::depth_image(w, h, gt, Some(&valid)).0)));
        }
        "gt-normals" => {
            let Some(gt) = &view.normal else { return missing("ground-truth normals") };
            return Ok(Reply::png(png_bytes(&edgenerf::viz::normal_image(w, h, gt))));
        }
        "depth-error" if view.depth.is_none() => return missing("ground-truth depth"),
        "normal-error" if view.normal.is_none() => return missing("ground-truth normals"),
        "error" if view.image.is_empty() => return missing("image"),
        _ => {}
    }
    let (step, r) = match view_render(state, v) {
        Ok(x) => x,
        Err(reply) => return Ok(reply),
    };
    let (shown, valid) = edgenerf::train::output::shown_depth(&r);
    let img = match kind {
        "render" => edgenerf::train::output::rgb_image(&r),
        "depth" => {
            // On the ground truth's colour range where there is one, so the two compare.
            let range = match &view.depth {
                Some(gt) => {
                    let gvalid: Vec<bool> = gt.iter().map(|&d| edgenerf::metrics::valid_depth(d)).collect();
                    edgenerf::viz::depth_range(gt, Some(&gvalid))
                }
                None => edgenerf::viz::depth_range(&shown, Some(&valid)),
            };
            edgenerf::viz::depth_image_in_range(w, h, &shown, Some(&valid), range)
        }
        "normals" => edgenerf::viz::normal_image(w, h, &r.unit_normals()),
        "opacity" => edgenerf::viz::grey_image(w, h, &r.opacity),
        "error" => rgb_error_map(&r, &view.image),
        "depth-error" => {
            let gt = view.depth.as_ref().expect("checked above");
            match edgenerf::metrics::maps::depth_error_map(w, h, gt, &shown, None) {
                Ok((img, _)) => img,
                Err(e) => return Ok(Reply::text(500, format!("{e}\n"))),
            }
        }
        _ => {
            let gt = view.normal.as_ref().expect("checked above");
            match edgenerf::metrics::maps::normal_error_map(w, h, gt, &r.unit_normals()) {
                Ok(img) => img,
                Err(e) => return Ok(Reply::text(500, format!("{e}\n"))),
            }
        }
    };
    let mut reply = Reply::png(png_bytes(&img));
    reply.headers.push(("X-Step", step.to_string()));
    Ok(reply)
}

/// Largest colour error the error map shows (red); 0 is dark blue.
const RGB_ERROR_MAX: f32 = 0.25;

/// `|render - GT|` averaged over the channels, through the turbo map over `[0, 0.25]`.
fn rgb_error_map(r: &RenderedView, gt: &ImageRgb) -> ImageRgb {
    let mut img = ImageRgb::new(r.width, r.height);
    for (i, px) in r.rgb.iter().enumerate() {
        let e = (0..3).map(|c| (px[c] - gt.data[3 * i + c]).abs()).sum::<f32>() / 3.0;
        img.data[3 * i..3 * i + 3].copy_from_slice(&edgenerf::viz::turbo(e / RGB_ERROR_MAX));
    }
    img
}

/// The training image dimmed, with the edge pixels of `mask` in red (what the
/// edge-guided terms do not smooth across).
fn edge_overlay(image: &ImageRgb, mask: &edgenerf::edges::EdgeMask) -> ImageRgb {
    let mut img = ImageRgb::new(image.width, image.height);
    for (i, &ne) in mask.non_edge.iter().enumerate() {
        let px = if ne != 0 {
            let g = 0.15 + 0.5 * (image.data[3 * i] + image.data[3 * i + 1] + image.data[3 * i + 2]) / 3.0;
            [g, g, g]
        } else {
            [1.0, 0.15, 0.1]
        };
        img.data[3 * i..3 * i + 3].copy_from_slice(&px);
    }
    img
}

/// An RGB PNG of `img`, quantised as [`ImageRgb::save_png`] does (`round(255 v)`).
fn png_bytes(img: &ImageRgb) -> Vec<u8> {
    use image::ImageEncoder;
    let bytes: Vec<u8> = img.data.iter().map(|&v| (v.clamp(0.0, 1.0) * 255.0).round() as u8).collect();
    let mut out = Vec::new();
    let enc = image::codecs::png::PngEncoder::new_with_quality(
        &mut out,
        image::codecs::png::CompressionType::Fast,
        image::codecs::png::FilterType::Sub,
    );
    enc.write_image(&bytes, img.width, img.height, image::ExtendedColorType::Rgb8).expect("encoding a PNG in memory");
    out
}

/// `/api/info`: the scene, its views with their poses, and the orbit's centre and up.
fn info_json(scene: &Scene, run_dir: &std::path::Path, adapter: &str) -> serde_json::Value {
    let train: Vec<Camera> = scene.train_views().map(|v| v.camera).collect();
    let cams: Vec<Camera> = if train.is_empty() { scene.views.iter().map(|v| v.camera).collect() } else { train };
    let focus = edgenerf::data::camera::focus_point(&cams);
    // Orbits turn about the world axis nearest the cameras' mean up (Blender's +Z,
    // LLFF's +Y): a few views looking down at an object tilt their mean up inward.
    let up = cams.iter().map(|c| c.c2w.y_axis.truncate()).sum::<Vec3>().normalize_or(Vec3::Y);
    let axis = up.abs().max_position();
    let up = if up[axis].abs() > 0.7 { Vec3::AXES[axis] * up[axis].signum() } else { up };
    let row_major = |m: &Mat4| m.transpose().to_cols_array().to_vec();
    let views: Vec<_> = scene
        .views
        .iter()
        .enumerate()
        .map(|(i, v)| {
            serde_json::json!({
                "index": i, "name": v.name, "split": split_of(scene, i), "c2w": row_major(&v.camera.c2w),
                "width": v.camera.width, "height": v.camera.height,
            })
        })
        .collect();
    let (w, h) = scene.image_size();
    serde_json::json!({
        "run": run_dir.display().to_string(),
        "scene": scene.root.display().to_string(),
        "format": format!("{:?}", scene.format),
        "adapter": adapter,
        "width": w, "height": h,
        "ndc": scene.ndc.is_some(),
        "focus": focus.to_array(),
        "up": up.to_array(),
        "views": views,
        "default_view": scene.split.train.first().copied().unwrap_or(0),
        "gt_depth": scene.views.iter().any(|v| v.depth.is_some()),
        "gt_normal": scene.views.iter().any(|v| v.normal.is_some()),
    })
}

/// Most points of a curve `/api/log` returns (a long run's log is thinned evenly).
const LOG_POINTS: usize = 1500;

/// `/api/log`: step, loss and training PSNR from `log.csv` (`null` for values that are
/// not finite); empty lists when there is no log.
fn log_json(path: &std::path::Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or("").split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name);
    let (cs, cl, cp) = (col("step"), col("loss"), col("psnr"));
    // The last line may be half-written by a run in progress: keep full rows only.
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect::<Vec<_>>()).filter(|r| r.len() == header.len()).collect();
    let stride = rows.len().div_ceil(LOG_POINTS).max(1);
    let pick = |c: Option<usize>| -> Vec<serde_json::Value> {
        rows.iter()
            .enumerate()
            .filter(|(i, _)| i % stride == 0 || *i + 1 == rows.len())
            .map(|(_, r)| match c.and_then(|c| r[c].parse::<f64>().ok()).filter(|x| x.is_finite()) {
                Some(x) => serde_json::json!(x),
                None => serde_json::Value::Null,
            })
            .collect()
    };
    serde_json::json!({ "step": pick(cs), "loss": pick(cl), "psnr": pick(cp) })
}
