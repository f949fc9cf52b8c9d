//! Sample placement and compaction: rays in, a packed [`SampleBatch`] out.
//!
//! Owner of `kernels/sampler/march.wgsl` (and the launcher of the interval and scan
//! kernels for a batch). One [`Sampler::sample`] records, in one submission:
//! 1. occupancy mode only: the occupied intervals of every ray ([`super::intervals`]);
//! 2. `count_samples`: the walk of the module doc of [`super`] per ray, storing the
//!    count (at most `max_samples_per_ray`, the nearest samples);
//! 3. an exclusive scan of the `n_rays + 1` counts (the last is 0, so the last offset
//!    is the total);
//! 4. `write_samples`: the same walk again, writing `Sample { pos, t, dir, dt }` at
//!    the ray's offset and its `SampleRange`.
//!
//! Placement (Instant-NGP's constant step): segments of length `dt = step / |dir|`
//! in `t` on a grid anchored at `t0 = t_min - u * dt` (`u` = 0, or a per-ray random
//! fraction when a jitter seed is given), each clipped to `[t_min, t_max]`; the sample
//! is the segment's midpoint and `dt` its (clipped) length. In occupancy mode a segment
//! is kept when its midpoint is inside an occupied interval and its cell's bit is set,
//! and an empty cell is crossed in one jump. Both modes use the same segment grid.
//!
//! Invariants of the output (those of [`crate::samples`]): samples of a ray are
//! contiguous at `ranges[r].start`, in increasing `t`, non-overlapping, inside
//! `[t_min, t_max]`; rays are packed in ray order with no gaps; `count[0] <=
//! capacity` samples are written and `count[1]` were wanted (after the per-ray cap,
//! before the capacity cap). Past the capacity a ray keeps its first samples and the
//! following rays get none ([`Sampler::wanted_counts`] tells which rays were cut).

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use crate::gpu::{Binding, Gpu, GpuBuffer, KernelSpec};
use crate::samples::{GpuRay, SampleBatch};

use super::grid::GridGeom;
use super::intervals::RayIntervals;
use super::scan::ExclusiveScan;
use super::{OccupancyGrid, SamplerConfig, SamplerError};

const BINDINGS: &[Binding] = &[
    Binding::Uniform,
    Binding::ReadOnly,  // rays
    Binding::ReadOnly,  // intervals
    Binding::ReadOnly,  // interval counts
    Binding::ReadOnly,  // occupancy bits
    Binding::ReadWrite, // per-ray counts
    Binding::ReadOnly,  // offsets
    Binding::ReadWrite, // samples
    Binding::ReadWrite, // ranges
    Binding::ReadWrite, // sample count
];
const COUNT: KernelSpec = KernelSpec { file: "sampler/march.wgsl", entry: "count_samples", bindings: BINDINGS };
const WRITE: KernelSpec = KernelSpec { file: "sampler/march.wgsl", entry: "write_samples", bindings: BINDINGS };

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Params {
    geom: GridGeom,
    n_rays: u32,
    capacity: u32,
    max_per_ray: u32,
    occupancy: u32,
    step: f32,
    max_intervals: u32,
    jitter: u32,
    seed: u32,
}

/// Where samples may go.
#[derive(Clone, Copy)]
pub enum March<'a> {
    /// Every segment of `[t_min, t_max]`.
    Uniform,
    /// Only segments in occupied cells of the grid.
    Occupancy(&'a OccupancyGrid),
}

/// Per-batch scratch, grown to the largest batch seen.
struct Workspace {
    max_rays: u32,
    intervals: RayIntervals,
    counts: GpuBuffer<u32>,
    offsets: GpuBuffer<u32>,
    scan: ExclusiveScan,
}

/// Places samples along rays (see the module doc).
pub struct Sampler {
    config: SamplerConfig,
    step: f32,
    work: Option<Workspace>,
    /// Bound in place of the interval and bit buffers in uniform mode.
    dummy: Option<GpuBuffer<u32>>,
}

impl Sampler {
    /// A sampler for scenes in `aabb` (which sets the default step).
    pub fn new(config: &SamplerConfig, aabb: [Vec3; 2]) -> Result<Self, SamplerError> {
        config.validate()?;
        let step = config.step_for(aabb);
        if !(step > 0.0 && step.is_finite()) {
            return Err(SamplerError::Config(format!("step {step} from AABB {aabb:?}")));
        }
        Ok(Self { config: config.clone(), step, work: None, dummy: None })
    }

    /// The marching step (a length in the field's space).
    pub fn step_size(&self) -> f32 {
        self.step
    }

    pub fn config(&self) -> &SamplerConfig {
        &self.config
    }

    /// Per-ray sample counts of the last batch, before the capacity cap (`n_rays + 1`
    /// entries, the last 0): a ray `r` was cut by the capacity iff
    /// `ranges[r].count < wanted[r]`.
    pub fn wanted_counts(&self) -> Option<&GpuBuffer<u32>> {
        self.work.as_ref().map(|w| &w.counts)
    }

    /// Allocates the scratch buffers for `n_rays` rays (kept for smaller batches).
    fn ensure_workspace(&mut self, gpu: &Gpu, n_rays: u32) -> Result<(), SamplerError> {
        if self.dummy.is_none() {
            self.dummy = Some(GpuBuffer::zeros(gpu, "unused binding", 1)?);
        }
        if self.work.as_ref().is_none_or(|w| w.max_rays < n_rays) {
            let max_rays = n_rays.max(1);
            self.work = Some(Workspace {
                max_rays,
                intervals: RayIntervals::new(gpu, max_rays, self.config.max_intervals)?,
                counts: GpuBuffer::zeros(gpu, "ray sample counts", max_rays as usize + 1)?,
                offsets: GpuBuffer::zeros(gpu, "ray sample offsets", max_rays as usize + 1)?,
                scan: ExclusiveScan::new(gpu, max_rays + 1)?,
            });
        }
        Ok(())
    }

    /// Samples `rays[..batch.n_rays]` into `batch` (recorded and submitted; does not
    /// wait). `jitter_seed`: shift each ray's segment grid by a random fraction of a
    /// step (training); `None` for a fixed grid (evaluation, tests).
    pub fn sample(
        &mut self,
        gpu: &Gpu,
        march: March<'_>,
        rays: &GpuBuffer<GpuRay>,
        batch: &SampleBatch,
        jitter_seed: Option<u32>,
    ) -> Result<(), SamplerError> {
        let n_rays = batch.n_rays;
        assert!(rays.len() >= n_rays as usize, "{} rays for a batch of {n_rays}", rays.len());
        self.ensure_workspace(gpu, n_rays)?;
        let config = &self.config;
        let work = self.work.as_ref().unwrap();
        let dummy = &self.dummy.as_ref().unwrap().buffer;
        let mut enc = gpu.encoder();
        let (geom, occupancy, intervals, interval_counts, bits) = match march {
            March::Uniform => (GridGeom { res: 1, n_cells: 1, ..Default::default() }, 0, dummy, dummy, dummy),
            March::Occupancy(grid) => {
                work.intervals.encode(gpu, &mut enc, grid, rays, n_rays)?;
                (
                    grid.geom(),
                    1,
                    &work.intervals.intervals.buffer,
                    &work.intervals.counts.buffer,
                    &grid.gpu_bits().buffer,
                )
            }
        };
        let params = enc.uniform(&Params {
            geom,
            n_rays,
            capacity: batch.capacity,
            max_per_ray: config.max_samples_per_ray,
            occupancy,
            step: self.step,
            max_intervals: config.max_intervals,
            jitter: jitter_seed.is_some() as u32,
            seed: jitter_seed.unwrap_or(0),
        });
        let resources = [
            &params,
            &rays.buffer,
            intervals,
            interval_counts,
            bits,
            &work.counts.buffer,
            &work.offsets.buffer,
            &batch.samples.buffer,
            &batch.ranges.buffer,
            &batch.count.buffer,
        ];
        let threads = n_rays.max(1);
        enc.dispatch_threads(&*gpu.kernel(&COUNT)?, &resources, threads);
        work.scan.encode(gpu, &mut enc, &work.counts, &work.offsets, n_rays + 1)?;
        enc.dispatch_threads(&*gpu.kernel(&WRITE)?, &resources, threads);
        enc.submit();
        Ok(())
    }
}
