//! The render thread of `edgenerf view`: the one owner of the GPU and the model (neither
//! is `Sync`), fed by a queue where the newest request of each client wins, and the
//! follower of a run in progress (the model is reloaded when the checkpoint's mtime
//! changes).

use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant, SystemTime};

use anyhow::Context;
use edgenerf::data::{Camera, Scene};
use edgenerf::gpu::{Gpu, GpuOptions};
use edgenerf::train::model::RenderedView;
use edgenerf::train::{Checkpoint, Model};

/// Requests waiting for the render thread beyond which new ones are refused (503):
/// each waiting request holds a connection.
pub const MAX_QUEUED: usize = 32;

/// What a handler asks the render thread for.
pub struct Job {
    /// Newest wins per key: the requesting tab and the kind of request (a frame of the
    /// free camera, a dataset view for the side panel).
    pub key: String,
    pub camera: Camera,
    pub reply: mpsc::Sender<Outcome>,
}

/// What comes back.
pub enum Outcome {
    /// The render, the checkpoint step it shows and the milliseconds it took.
    Done { view: RenderedView, step: u64, ms: f64 },
    /// A newer request of the same key replaced this one before it started.
    Superseded,
    /// The queue was full.
    Busy,
    Failed(String),
}

/// Shared between the handlers and the render thread.
pub struct Queue {
    jobs: Mutex<VecDeque<Job>>,
    ready: Condvar,
    /// The step of the model now loaded.
    pub step: AtomicU64,
    /// Reloads of the checkpoint since the start.
    pub reloads: AtomicU64,
}

impl Queue {
    pub fn new(step: u64) -> Arc<Queue> {
        Arc::new(Queue { jobs: Mutex::new(VecDeque::new()), ready: Condvar::new(), step: AtomicU64::new(step), reloads: AtomicU64::new(0) })
    }

    /// Queues `job`, answering `Superseded` to a waiting job of the same key (it is
    /// replaced in place, keeping its turn) and `Busy` when the queue is full.
    pub fn push(&self, job: Job) {
        let mut jobs = self.jobs.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(old) = jobs.iter_mut().find(|j| j.key == job.key) {
            let old = std::mem::replace(old, job);
            let _ = old.reply.send(Outcome::Superseded);
        } else if jobs.len() >= MAX_QUEUED {
            let _ = job.reply.send(Outcome::Busy);
            return;
        } else {
            jobs.push_back(job);
        }
        self.ready.notify_one();
    }

    /// Whether a job of `key` is waiting (it is newer than the one being rendered).
    fn has_newer(&self, key: &str) -> bool {
        self.jobs.lock().unwrap_or_else(|p| p.into_inner()).iter().any(|j| j.key == key)
    }

    /// The next job, or `None` after `timeout` without one.
    fn pop(&self, timeout: Duration) -> Option<Job> {
        let jobs = self.jobs.lock().unwrap_or_else(|p| p.into_inner());
        let (mut jobs, _) = self.ready.wait_timeout_while(jobs, timeout, |j| j.is_empty()).unwrap_or_else(|p| p.into_inner());
        jobs.pop_front()
    }
}

/// Rays per strip of a frame (`--strip-rays`): a newer request is looked for between strips.
pub const STRIP_RAYS: u32 = 16384;

/// Renders `cam` as horizontal strips of about `strip_rays` rays (each strip's camera
/// has the same rays as those rows of the whole frame: the principal point moved up by
/// the strip's first row), giving up (`None`) when `superseded()` says a newer request
/// waits: a full-resolution LLFF frame takes seconds on a CPU, and a drag that starts
/// meanwhile should not wait for it.
fn render_in_strips(
    model: &mut Model,
    gpu: &Gpu,
    scene: &Scene,
    cam: &Camera,
    strip_rays: u32,
    superseded: impl Fn() -> bool,
) -> Result<Option<RenderedView>, edgenerf::train::TrainError> {
    let rows = (strip_rays / cam.width.max(1)).max(1);
    if rows >= cam.height {
        return model.render_camera(gpu, scene, cam).map(Some);
    }
    let n = (cam.width * cam.height) as usize;
    let mut out = RenderedView {
        width: cam.width,
        height: cam.height,
        rgb: Vec::with_capacity(n),
        opacity: Vec::with_capacity(n),
        depth: Vec::with_capacity(n),
        z_depth: Vec::with_capacity(n),
        normal: Vec::with_capacity(n),
        samples: 0,
    };
    let mut y0 = 0;
    while y0 < cam.height {
        if y0 > 0 && superseded() {
            return Ok(None);
        }
        let h = rows.min(cam.height - y0);
        let strip = Camera { height: h, cy: cam.cy - y0 as f32, ..*cam };
        let r = model.render_camera(gpu, scene, &strip)?;
        out.rgb.extend_from_slice(&r.rgb);
        out.opacity.extend_from_slice(&r.opacity);
        out.depth.extend_from_slice(&r.depth);
        out.z_depth.extend_from_slice(&r.z_depth);
        out.normal.extend_from_slice(&r.normal);
        out.samples += r.samples;
        y0 += h;
    }
    Ok(Some(out))
}

/// The model of the checkpoint at `path`, on `gpu`, for `scene`.
fn load_model(gpu: &Gpu, scene: &Scene, path: &std::path::Path) -> anyhow::Result<(Model, u64)> {
    let ckpt = Checkpoint::load(path)?;
    let model = Model::from_checkpoint(gpu, scene, &ckpt).with_context(|| format!("loading the model of {}", path.display()))?;
    Ok((model, ckpt.step))
}

fn mtime(path: &std::path::Path) -> Option<SystemTime> {
    std::fs::metadata(path).and_then(|m| m.modified()).ok()
}

/// Starts the render thread: creates the GPU context and loads the model there, then
/// answers jobs until the process ends. Returns once the model is loaded (or failed to):
/// the adapter's name and its whole description.
pub fn start(
    ckpt_path: PathBuf,
    scene: Arc<Scene>,
    gpu_opts: GpuOptions,
    queue: Arc<Queue>,
    follow: bool,
    strip_rays: u32,
) -> anyhow::Result<(String, String)> {
    let (ready_tx, ready_rx) = mpsc::channel::<anyhow::Result<(String, String)>>();
    std::thread::Builder::new()
        .name("render".into())
        .spawn(move || {
            let setup = (|| -> anyhow::Result<(Gpu, Model, u64)> {
                let gpu = Gpu::new(&gpu_opts)?;
                let (model, step) = load_model(&gpu, &scene, &ckpt_path)?;
                Ok((gpu, model, step))
            })();
            let (gpu, mut model, step) = match setup {
                Ok(s) => s,
                Err(e) => {
                    let _ = ready_tx.send(Err(e));
                    return;
                }
            };
            queue.step.store(step, Ordering::SeqCst);
            let _ = ready_tx.send(Ok((gpu.adapter().name.clone(), gpu.adapter().to_string())));
            let mut seen = mtime(&ckpt_path);
            let mut last_check = Instant::now();
            loop {
                let job = queue.pop(Duration::from_millis(500));
                // A run in progress: a new checkpoint (renamed into place atomically)
                // replaces the model; a failed load keeps the old one.
                if follow && last_check.elapsed() >= Duration::from_millis(400) {
                    last_check = Instant::now();
                    let now = mtime(&ckpt_path);
                    if now.is_some() && now != seen {
                        seen = now;
                        match load_model(&gpu, &scene, &ckpt_path) {
                            Ok((m, step)) => {
                                model = m;
                                queue.step.store(step, Ordering::SeqCst);
                                queue.reloads.fetch_add(1, Ordering::SeqCst);
                            }
                            Err(e) => {
                                use std::io::Write;
                                let _ = writeln!(std::io::stderr(), "view: keeping step {}: {e:#}", queue.step.load(Ordering::SeqCst));
                            }
                        }
                    }
                }
                let Some(job) = job else { continue };
                let t = Instant::now();
                let outcome = match render_in_strips(&mut model, &gpu, &scene, &job.camera, strip_rays, || queue.has_newer(&job.key)) {
                    Ok(Some(view)) => Outcome::Done { view, step: queue.step.load(Ordering::SeqCst), ms: t.elapsed().as_secs_f64() * 1e3 },
                    Ok(None) => Outcome::Superseded,
                    Err(e) => Outcome::Failed(format!("{e:#}")),
                };
                // The handler may be gone (its client closed the tab): nothing to do.
                let _ = job.reply.send(outcome);
            }
        })
        .context("starting the render thread")?;
    ready_rx.recv().context("the render thread stopped while loading")?
}
