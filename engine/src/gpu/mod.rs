//! The compute runtime: one [`Gpu`] context on wgpu/Vulkan, typed buffers, kernels.
//!
//! Owns adapter selection, device creation, the pipeline cache and the float-atomic
//! path. Every other room reaches the GPU only through this module.
//!
//! # Adapter selection
//! 1. `GpuOptions::adapter` (the CLI's `--adapter`), else the `WGPU_ADAPTER_NAME`
//!    environment variable: the first adapter whose name contains it
//!    (case-insensitive); an error lists the adapters present when none matches.
//! 2. Otherwise a discrete NVIDIA GPU, then any discrete GPU, then an integrated one,
//!    then a CPU implementation (Mesa lavapipe, "llvmpipe").
//!
//! Only the Vulkan backend is enabled (`WGPU_BACKEND` may override, for experiments).
//!
//! # Invariants
//! * The device is created with the adapter's own limits (so lavapipe's 128 MiB
//!   storage bindings and NVIDIA's larger ones are both usable) and with
//!   `SHADER_FLOAT32_ATOMIC` when the adapter has it and it is not disabled.
//! * [`Gpu::float_atomics`] says which atomic path kernels are built for; the choice
//!   is made once per context and applied at pipeline build time (see [`kernel`]).
//! * Nothing here assumes a subgroup size (lavapipe runs 8 lanes, NVIDIA 32).
//!
//! # Threads
//! A [`Gpu`] may be used from several threads (the test harness shares one per
//! process), but the engine never calls into the driver from two threads at once:
//! pipeline creation ([`Kernel`]'s build), submission (`Gpu::submit`) and the waits
//! ([`Gpu::wait`], [`Gpu::wait_for`]) take one process-wide lock (process-wide because
//! the tests' two contexts share one driver). Without it NVIDIA's driver lost the
//! device when the library tests ran at 8-16 threads: on an H100 and an H200
//! (2026-11-27, driver 580) 6 of 12 runs of the test binary lost it and one more
//! stalled, most often while the kernels were being compiled (an empty shader cache).
//! With the lock, 4 of 4 runs at 16 threads passed (pipeline creation alone under it:
//! 3 of 3; submission and waits alone: 1 of 1, so both are kept). wgpu has open
//! reports of the same for concurrent pipeline creation (gfx-rs/wgpu#10234) and
//! multi-threaded submission (#4877). The training loop runs on one thread, so it
//! never waits on the lock; a test process does, and runs slower on NVIDIA (42-54 s
//! against 32-38 s at 16 threads). Recording (encoders, bind groups, buffer creation)
//! and buffer writes stay outside it (wgpu serialises those itself), except an
//! encoder's parameter bytes, written into the shared parameter arena in the same
//! locked section as its submission (`gpu::kernel`, "The parameter arena").

pub mod bind_cache;
mod buffer;
pub mod selftest;
mod indirect;
pub mod kernel;
mod kernel_timing;
mod readback;

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

pub use buffer::GpuBuffer;
pub use indirect::IndirectArgs;
pub use kernel::{BindResource, Binding, Encoder, Kernel, KernelSpec, Params};
pub use kernel_timing::{KernelTimes, KernelTotal};
pub use readback::{PendingRead, ReadBack, ReadBatch, ReadSlot};

/// What to install when no Vulkan driver is found.
pub const DRIVER_HINT: &str = "install a Vulkan driver: on Debian/Ubuntu without a GPU run \
`apt-get install mesa-vulkan-drivers libvulkan1` (software Vulkan, lavapipe); with an \
NVIDIA GPU install the NVIDIA driver with its Vulkan ICD";

/// Errors of the compute runtime.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error("no Vulkan adapter found: {DRIVER_HINT}")]
    NoAdapter,
    #[error("no Vulkan adapter matches {wanted:?} (from {source_of_name}); adapters present: {available}")]
    AdapterNotFound { wanted: String, source_of_name: &'static str, available: String },
    #[error("could not create a device on adapter {adapter:?}: {message}")]
    RequestDevice { adapter: String, message: String },
    #[error("kernel {kernel} does not compile: {message}")]
    Shader { kernel: String, message: String },
    #[error(
        "kernel {kernel} binds {count} {kind} buffers, above this adapter's limit of {limit} per shader stage: \
         use an adapter with a higher limit (`edgenerf info --check-gpu` shows the one in use; --adapter picks another)"
    )]
    TooManyBindings { kernel: String, kind: &'static str, count: u32, limit: u32 },
    #[error("kernel {kernel}: its Rust bind layout does not match the WGSL: {message}")]
    BindLayout { kernel: String, message: String },
    #[error("no kernel named {0:?} under kernels/")]
    UnknownKernel(String),
    #[error("buffer {label:?} needs {bytes} bytes, above this device's storage binding limit of {limit} bytes")]
    BufferTooLarge { label: String, bytes: u64, limit: u64 },
    #[error("GPU readback failed: {0}")]
    Readback(String),
    #[error("GPU device error: {0}")]
    Device(String),
}

/// How to pick and configure the GPU.
#[derive(Clone, Debug, Default)]
pub struct GpuOptions {
    /// Substring of the adapter name to use (overrides `WGPU_ADAPTER_NAME`).
    pub adapter: Option<String>,
    /// Build kernels for the compare-exchange float-add path even when the adapter
    /// supports `SHADER_FLOAT32_ATOMIC` (tests use this to cover both paths).
    pub disable_float_atomics: bool,
}

/// Facts about the adapter in use, for logs, `edgenerf info` and benchmark rows.
#[derive(Clone, Debug, serde::Serialize)]
pub struct AdapterSummary {
    pub name: String,
    pub device_type: String,
    pub driver: String,
    pub driver_info: String,
    pub backend: String,
    pub float_atomics: bool,
    /// GPU timestamps around a compute pass (`TIMESTAMP_QUERY`): per-kernel timing
    /// then measures the kernels' execution, not their submissions and waits.
    pub timestamps: bool,
    pub max_storage_binding_bytes: u64,
}

impl AdapterSummary {
    /// Whether the adapter is a CPU implementation (lavapipe, SwiftShader).
    pub fn is_cpu(&self) -> bool {
        self.device_type == format!("{:?}", wgpu::DeviceType::Cpu)
    }
}

impl std::fmt::Display for AdapterSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} ({}, {} {} {}; float atomics: {}; timestamps: {}; max storage binding {} MiB)",
            self.name,
            self.device_type,
            self.backend,
            self.driver,
            self.driver_info,
            if self.float_atomics { "native" } else { "compare-exchange fallback" },
            if self.timestamps { "yes" } else { "no" },
            self.max_storage_binding_bytes >> 20
        )
    }
}

/// The GPU context: device, queue and the kernels built for it. Cheap to clone.
#[derive(Clone)]
pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    summary: Arc<AdapterSummary>,
    limits: wgpu::Limits,
    kernels: Arc<Mutex<HashMap<(KernelSpec, String), Arc<Kernel>>>>,
    /// Per-kernel wall times while timing is on ([`Gpu::set_kernel_timing`]).
    kernel_times: Arc<Mutex<Option<KernelTimes>>>,
    /// Command buffers submitted so far, by this context and its clones.
    submissions: Arc<AtomicU64>,
    /// Nanoseconds the host spent in the driver's submission and waits ([`DriverTime`]).
    submit_nanos: Arc<AtomicU64>,
    wait_nanos: Arc<AtomicU64>,
    /// The parameter arena's buffers (`gpu::kernel`, "The parameter arena"), made on
    /// first use and kept: an encoder's `i`-th chunk of parameters is `params_chunks[i]`.
    params_chunks: Arc<Mutex<Vec<wgpu::Buffer>>>,
    /// The timestamp queries of per-kernel timing, made on first use where the adapter
    /// has them (`kernel_timing`); locked for the whole of a timed dispatch.
    kernel_timer: Arc<Mutex<Option<kernel_timing::GpuTimer>>>,
    /// The bind groups of recent dispatches ([`bind_cache`]).
    bind_groups: Arc<Mutex<bind_cache::BindGroupCache>>,
}

const NVIDIA_VENDOR_ID: u32 = 0x10de;

fn device_type_rank(info: &wgpu::AdapterInfo) -> u32 {
    use wgpu::DeviceType::*;
    match info.device_type {
        DiscreteGpu if info.vendor == NVIDIA_VENDOR_ID => 0,
        DiscreteGpu => 1,
        IntegratedGpu => 2,
        VirtualGpu => 3,
        Cpu => 4,
        Other => 5,
    }
}

impl Gpu {
    /// Opens the adapter chosen as the module doc describes.
    pub fn new(opts: &GpuOptions) -> Result<Gpu, GpuError> {
        let backends = wgpu::Backends::from_env().unwrap_or(wgpu::Backends::VULKAN);
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.backends = backends;
        // The same instance in every build profile: wgpu's default turns on Vulkan's
        // validation layer (when installed) and SPIR-V debug info in debug builds, which
        // made test builds slower and older validation layers reject the debug info.
        // `WGPU_VALIDATION=1` / `WGPU_DEBUG=1` opt in (tools/tests/other_vulkan.rs runs the
        // layer explicitly).
        desc.flags = wgpu::InstanceFlags::empty().with_env();
        let instance = wgpu::Instance::new(desc);
        let mut adapters = pollster::block_on(instance.enumerate_adapters(backends));
        if adapters.is_empty() {
            return Err(GpuError::NoAdapter);
        }
        let wanted = match (&opts.adapter, std::env::var("WGPU_ADAPTER_NAME")) {
            (Some(name), _) => Some((name.clone(), "--adapter")),
            (None, Ok(name)) if !name.is_empty() => Some((name, "WGPU_ADAPTER_NAME")),
            _ => None,
        };
        let adapter = match wanted {
            Some((name, source_of_name)) => {
                let lower = name.to_lowercase();
                let pos = adapters.iter().position(|a| a.get_info().name.to_lowercase().contains(&lower));
                match pos {
                    Some(i) => adapters.swap_remove(i),
                    None => {
                        let available = adapters.iter().map(|a| format!("{:?}", a.get_info().name)).collect::<Vec<_>>().join(", ");
                        return Err(GpuError::AdapterNotFound { wanted: name, source_of_name, available });
                    }
                }
            }
            None => {
                adapters.sort_by_key(|a| device_type_rank(&a.get_info()));
                adapters.swap_remove(0)
            }
        };
        Self::from_adapter(adapter, opts)
    }

    fn from_adapter(adapter: wgpu::Adapter, opts: &GpuOptions) -> Result<Gpu, GpuError> {
        let info = adapter.get_info();
        let float_atomics =
            !opts.disable_float_atomics && adapter.features().contains(wgpu::Features::SHADER_FLOAT32_ATOMIC);
        let timestamps = adapter.features().contains(wgpu::Features::TIMESTAMP_QUERY);
        let mut required_features =
            if float_atomics { wgpu::Features::SHADER_FLOAT32_ATOMIC } else { wgpu::Features::empty() };
        if timestamps {
            required_features |= wgpu::Features::TIMESTAMP_QUERY;
        }
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("edgenerf"),
            required_features,
            required_limits: limits.clone(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| GpuError::RequestDevice { adapter: info.name.clone(), message: e.to_string() })?;
        // A lost device (a driver fault, a GPU reset) turns every later buffer and
        // readback into a validation error that names a buffer, not the cause. The
        // callback is the only place the cause shows up, and it runs inside a poll, with
        // no caller to return it to: say it on stderr, once, with where to look next.
        let adapter_name = info.name.clone();
        device.set_device_lost_callback(move |reason, message| {
            if reason != wgpu::DeviceLostReason::Destroyed {
                eprintln!("{}", device_lost_message(&adapter_name, &message));
            }
        });
        let summary = AdapterSummary {
            name: info.name.clone(),
            device_type: format!("{:?}", info.device_type),
            driver: info.driver.clone(),
            driver_info: info.driver_info.clone(),
            backend: format!("{:?}", info.backend),
            float_atomics,
            timestamps,
            max_storage_binding_bytes: limits.max_storage_buffer_binding_size as u64,
        };
        Ok(Gpu { device, queue, summary: Arc::new(summary), limits, kernels: Default::default(), kernel_times: Default::default(), submissions: Default::default(), submit_nanos: Default::default(), wait_nanos: Default::default(), params_chunks: Default::default(), kernel_timer: Default::default(), bind_groups: Default::default() })
    }

    /// The adapter in use.
    pub fn adapter(&self) -> &AdapterSummary {
        &self.summary
    }

    /// Whether kernels use native `atomic<f32>` adds (else a compare-exchange loop).
    pub fn float_atomics(&self) -> bool {
        self.summary.float_atomics
    }

    /// The device limits (equal to the adapter's).
    pub fn limits(&self) -> &wgpu::Limits {
        &self.limits
    }

    /// Returns the compute kernel for `spec`, building and caching it on first use.
    pub fn kernel(&self, spec: &KernelSpec) -> Result<Arc<Kernel>, GpuError> {
        self.specialized_kernel(spec, String::new())
    }

    /// Returns the compute kernel for `spec` completed by `generated` WGSL (see
    /// `gpu::kernel`, "Generated code"), building and caching it on first use of that
    /// text.
    pub fn specialized_kernel(&self, spec: &KernelSpec, generated: String) -> Result<Arc<Kernel>, GpuError> {
        let key = (spec.clone(), generated);
        if let Some(k) = self.kernels.lock().unwrap().get(&key) {
            return Ok(k.clone());
        }
        let started = std::time::Instant::now();
        let kernel = Arc::new(Kernel::build(self, spec, &key.1)?);
        log::debug!("built kernel {}:{} in {:.0} ms", spec.file, spec.entry, started.elapsed().as_secs_f64() * 1e3);
        self.kernels.lock().unwrap().insert(key, kernel.clone());
        Ok(kernel)
    }

    /// Arena buffer `i` of dispatch parameters (`gpu::kernel`, "The parameter arena").
    fn params_chunk(&self, i: usize) -> wgpu::Buffer {
        let mut chunks = self.params_chunks.lock().unwrap();
        while chunks.len() <= i {
            chunks.push(self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("params arena"),
                size: kernel::PARAMS_CHUNK_BYTES,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }));
        }
        chunks[i].clone()
    }

    /// The bind group of `resources` for `layout`, made or reused ([`bind_cache`]).
    fn bind_group(&self, label: &str, layout: &wgpu::BindGroupLayout, resources: &[&dyn BindResource]) -> wgpu::BindGroup {
        let submissions = self.submissions();
        let mut cache = self.bind_groups.lock().unwrap_or_else(|p| p.into_inner());
        cache.get(&self.device, label, layout, resources, submissions)
    }

    /// Bind groups made so far by this context and its clones ([`bind_cache`]).
    pub fn bind_groups_made(&self) -> u64 {
        self.bind_groups.lock().unwrap_or_else(|p| p.into_inner()).created()
    }

    /// Starts recording a sequence of dispatches and copies.
    pub fn encoder(&self) -> Encoder<'_> {
        Encoder::new(self)
    }

    /// Records with `record` into a fresh encoder and submits it (does not wait); on
    /// error nothing is submitted.
    pub fn submit_recorded<R, E>(&self, record: impl FnOnce(&mut Encoder) -> Result<R, E>) -> Result<R, E> {
        let mut enc = self.encoder();
        let result = record(&mut enc)?;
        enc.submit();
        Ok(result)
    }

    /// Switches per-kernel timing on (from zero) or off, for this context and its
    /// clones (see [`kernel_timing`]). Slows every dispatch down; changes no result.
    pub fn set_kernel_timing(&self, on: bool) {
        *self.kernel_times.lock().unwrap() = on.then(KernelTimes::default);
    }

    /// The kernel times accumulated since timing was switched on (`None`: off).
    pub fn kernel_times(&self) -> Option<KernelTimes> {
        self.kernel_times.lock().unwrap().clone()
    }

    /// Whether per-kernel timing is on.
    pub(crate) fn kernel_timing(&self) -> bool {
        self.kernel_times.lock().unwrap().is_some()
    }

    /// Charges `elapsed` to `kernel` when timing is on.
    fn charge_kernel(&self, kernel: &KernelSpec, elapsed: std::time::Duration) {
        if let Some(t) = self.kernel_times.lock().unwrap().as_mut() {
            t.charge(&format!("{}:{}", kernel.file, kernel.entry), elapsed);
        }
    }

    /// Submits one command buffer (every submission of the engine goes through here, so
    /// [`Gpu::submissions`] counts them).
    /// The encoder's parameters are written into the arena in the same locked section
    /// (`gpu::kernel`, "The parameter arena").
    pub(crate) fn submit(&self, commands: wgpu::CommandBuffer, params: &kernel::ParamBytes) -> wgpu::SubmissionIndex {
        let submissions = self.submissions.fetch_add(1, Ordering::Relaxed) + 1;
        self.bind_groups.lock().unwrap_or_else(|p| p.into_inner()).sweep(submissions);
        let start = std::time::Instant::now();
        let _driver = driver_lock();
        for (chunk, bytes) in params.chunks.iter().zip(&params.bytes) {
            self.queue.write_buffer(chunk, 0, bytes);
        }
        let index = self.queue.submit([commands]);
        self.submit_nanos.fetch_add(start.elapsed().as_nanos() as u64, Ordering::Relaxed);
        index
    }

    /// Command buffers submitted so far by this context and its clones: a training step
    /// submits one ([`crate::train::Trainer::step`]).
    pub fn submissions(&self) -> u64 {
        self.submissions.load(Ordering::Relaxed)
    }

    /// Blocks until `submission` (and every earlier one) is done; later ones may still run.
    pub fn wait_for(&self, submission: wgpu::SubmissionIndex) -> Result<(), GpuError> {
        self.timed_wait(wgpu::PollType::Wait { submission_index: Some(submission), timeout: None })
    }

    /// Blocks until all submitted work is done.
    pub fn wait(&self) -> Result<(), GpuError> {
        self.timed_wait(wgpu::PollType::wait_indefinitely())
    }

    /// Time the host has spent in the driver's submission and waits so far, by this
    /// context and its clones (`edgenerf speed` reports it per step).
    pub fn driver_time(&self) -> DriverTime {
        let of = |n: &AtomicU64| std::time::Duration::from_nanos(n.load(Ordering::Relaxed));
        DriverTime { submit: of(&self.submit_nanos), wait: of(&self.wait_nanos) }
    }

    fn timed_wait(&self, poll: wgpu::PollType) -> Result<(), GpuError> {
        let start = std::time::Instant::now();
        let _driver = driver_lock();
        let done = self.device.poll(poll).map(|_| ()).map_err(|e| GpuError::Device(e.to_string()));
        self.wait_nanos.fetch_add(start.elapsed().as_nanos() as u64, Ordering::Relaxed);
        done
    }
}

/// Host time spent in the driver ([`Gpu::driver_time`]). On a GPU a submission only
/// queues the work and the host waits for it in `wait`; lavapipe (Mesa 22.3) runs a
/// submission's commands before `queue.submit` returns, so there the GPU's work shows
/// as `submit`. A step's wall time minus both is the host's own work (drawing the
/// batch, recording the commands).
#[derive(Clone, Copy, Debug, Default)]
pub struct DriverTime {
    pub submit: std::time::Duration,
    pub wait: std::time::Duration,
}

/// The process-wide driver lock: held while a pipeline is created, a command buffer
/// is submitted or a thread waits for the device (module doc, "Threads").
static DRIVER_LOCK: Mutex<()> = Mutex::new(());

/// Takes the driver lock. A thread that panicked while holding it left no state behind
/// it (the lock guards no data), so a poisoned lock is simply taken.
pub(crate) fn driver_lock() -> std::sync::MutexGuard<'static, ()> {
    DRIVER_LOCK.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// What a lost device prints: the adapter, the driver's words, and where to look.
fn device_lost_message(adapter: &str, driver_message: &str) -> String {
    format!(
        "error: the GPU device on {adapter} was lost ({driver_message}); every GPU result after this is invalid. \
         The driver's log says why (NVIDIA: `dmesg | grep -i xid`); checkpoints already written are intact, \
         so a run can continue with `edgenerf train --resume`."
    )
}

/// Opens the default GPU for tests, once per test process; panics with the driver
/// hint when none is available (the test suite needs a Vulkan driver, lavapipe is
/// enough).
pub fn test_gpu(disable_float_atomics: bool) -> Gpu {
    static NATIVE: std::sync::OnceLock<Gpu> = std::sync::OnceLock::new();
    static FALLBACK: std::sync::OnceLock<Gpu> = std::sync::OnceLock::new();
    let cell = if disable_float_atomics { &FALLBACK } else { &NATIVE };
    cell.get_or_init(|| {
        Gpu::new(&GpuOptions { adapter: None, disable_float_atomics })
            .unwrap_or_else(|e| panic!("tests need a Vulkan device: {e}"))
    })
    .clone()
}
