//! The occupancy grid: a `resolution`^3 density grid over the scene AABB, its
//! occupancy bitfield, and the brick BVH built from it.
//!
//! Owner of `kernels/sampler/occupancy.wgsl`. Updating is two-phase so that the grid never
//! knows the field: [`OccupancyGrid::query_points`] chooses cells and one jittered
//! point in each; the caller evaluates density there; [`OccupancyGrid::update`] takes
//! the densities back and, on the GPU: scatters the maximum density per queried cell
//! (`atomicMax` on the bits of non-negative floats: order-independent), applies
//! `cell <- max(decay * cell, density)` to the queried cells, sums the grid with a
//! fixed-order reduction for the mean, and writes the bitfield `cell > min(threshold / step,
//! mean)` (the threshold is on one step's opacity, see `SamplerConfig::threshold`). The bitfield is then read back (res^3 / 8 bytes, 256 KiB at 128^3) and,
//! when it changed, the occupied-cell list (for the next query) and the brick BVH
//! ([`super::bricks`]) are rebuilt and uploaded.
//!
//! Cell selection (nerfacc's `_sample_uniform_and_occupied_cells`): during warm-up
//! (`step < warmup_steps`) every cell, point `i` in cell `i mod n^3`
//! (`warmup_points_per_cell` rounds over the grid); afterwards `n/4` cells
//! drawn uniformly, then the occupied cells: all of them in index order when there
//! are at most `n/4`, else `n/4` drawn uniformly from them. Draws and jitter use the
//! PCG hash of `(seed, point, k)`: deterministic for a seed.
//!
//! **Seen cells.** [`OccupancyGrid::restrict_to_seen`] (Instant-NGP's
//! `mark_untrained_density_grid`) takes a mask of the cells some training camera sees;
//! every bitfield is ANDed with it from then on (on the host after the readback, and
//! written back to the GPU), so space no training ray can reach is never marched: its
//! density is whatever initialisation left there, fog or floaters in novel views.
//!
//! **The render grid.** [`OccupancyGrid::refined`] builds a finer grid for rendering
//! (`sampler.render_resolution`) inside this one's occupied cells, from the densities
//! its caller evaluates at a few jittered points per cell (the model builds it before
//! its first render and drops it after each training step).
//!
//! Invariants: `host_bits` equals the GPU bitfield and is a subset of the seen mask; the BVH and the occupied list
//! were built from `host_bits`; before the first update every cell is occupied (so an
//! untrained grid samples like the uniform marcher restricted to the AABB).

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use crate::gpu::{Binding, Encoder, Gpu, GpuBuffer, KernelSpec, ReadBatch};

use super::bricks::{BrickBvh, BrickLayout, GpuBvhNode};
use super::{SamplerConfig, SamplerError, fold_groups};

const FILE: &str = "sampler/occupancy.wgsl";

const QUERY: KernelSpec = KernelSpec {
    file: FILE,
    entry: "query_points",
    bindings: &[Binding::Params, Binding::ReadOnly, Binding::ReadWrite, Binding::ReadWrite],
};
const SCATTER_MAX: KernelSpec = KernelSpec {
    file: FILE,
    entry: "scatter_max",
    bindings: &[Binding::Params, Binding::ReadOnly, Binding::ReadOnly, Binding::ReadWrite],
};
const EMA: KernelSpec =
    KernelSpec { file: FILE, entry: "ema", bindings: &[Binding::Params, Binding::ReadWrite, Binding::ReadWrite] };
const REDUCE: KernelSpec = KernelSpec {
    file: FILE,
    entry: "reduce_sum",
    bindings: &[Binding::Params, Binding::ReadOnly, Binding::ReadWrite],
};
const THRESHOLD: KernelSpec = KernelSpec {
    file: FILE,
    entry: "threshold_bits",
    bindings: &[Binding::Params, Binding::ReadOnly, Binding::ReadOnly, Binding::ReadWrite],
};

/// Workgroups of the first reduction pass (each sums a strided share); the second
/// pass sums their partials in one workgroup of the same size.
const REDUCE_GROUPS: u32 = 256;
const REDUCE_WG: u32 = 256;

/// Grid geometry as the kernels read it (`OccupancyGeom` in `kernels/sampler/common.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct OccupancyGeom {
    pub aabb_min: [f32; 3],
    pub res: u32,
    pub aabb_max: [f32; 3],
    pub n_cells: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct QueryParams {
    geom: OccupancyGeom,
    count: u32,
    seed: u32,
    all_cells: u32,
    n_uniform: u32,
    list_len: u32,
    _pad: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct CountParams {
    n: u32,
    n_cells: u32,
    decay: f32,
    threshold: f32,
}

/// The points of one update: evaluate density at `positions[..count]` (xyz; w = 0)
/// and pass it to [`OccupancyGrid::update`] with `cells`.
pub struct OccupancyQuery {
    pub positions: GpuBuffer<[f32; 4]>,
    pub cells: GpuBuffer<u32>,
    pub count: u32,
    /// The EMA decay of this update ([`SamplerConfig::decay_at`] its step).
    pub decay: f32,
}

/// What an update did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OccupancyUpdate {
    /// Mean of all cells after the EMA.
    pub mean_density: f32,
    /// Occupied cells and bricks after the update.
    pub occupied_cells: u32,
    pub occupied_bricks: u32,
    /// Whether the bitfield changed (and the BVH was rebuilt).
    pub changed: bool,
}

/// The occupancy grid with its bitfield and brick BVH (see the module doc).
pub struct OccupancyGrid {
    config: SamplerConfig,
    layout: BrickLayout,
    geom: OccupancyGeom,
    density: GpuBuffer<f32>,
    scratch: GpuBuffer<u32>,
    partials: GpuBuffer<f32>,
    sum: GpuBuffer<f32>,
    bits: GpuBuffer<u32>,
    host_bits: Vec<u32>,
    occupied: GpuBuffer<u32>,
    n_occupied: u32,
    /// Whether any update (or [`OccupancyGrid::restore_density`]) has run: before, the
    /// density buffer is all zero and every cell counts as occupied.
    updated: bool,
    bvh: BrickBvh,
    gpu_nodes: GpuBuffer<GpuBvhNode>,
    gpu_prims: GpuBuffer<GpuBvhNode>,
    /// Cells a training camera sees, as a bitfield (`None`: all).
    seen: Option<Vec<u32>>,
}

impl OccupancyGrid {
    /// A grid over `aabb` with every cell occupied and zero density.
    pub fn new(gpu: &Gpu, config: &SamplerConfig, aabb: [Vec3; 2]) -> Result<Self, SamplerError> {
        config.validate()?;
        if !(aabb[1].cmpgt(aabb[0]).all() && aabb[0].is_finite() && aabb[1].is_finite()) {
            return Err(SamplerError::Config(format!("empty or infinite AABB {aabb:?}")));
        }
        let res = config.resolution;
        let n_cells = res * res * res;
        let n_words = n_cells.div_ceil(32) as usize;
        let geom = OccupancyGeom { aabb_min: aabb[0].to_array(), res, aabb_max: aabb[1].to_array(), n_cells };
        let mut host_bits = vec![u32::MAX; n_words];
        if !n_cells.is_multiple_of(32) {
            host_bits[n_words - 1] = (1u32 << (n_cells % 32)) - 1;
        }
        let mut grid = Self {
            config: config.clone(),
            layout: BrickLayout { aabb, resolution: res, brick_size: config.brick_size },
            geom,
            density: GpuBuffer::zeros(gpu, "occupancy density", n_cells as usize)?,
            scratch: GpuBuffer::zeros(gpu, "occupancy scratch", n_cells as usize)?,
            partials: GpuBuffer::zeros(gpu, "occupancy partial sums", REDUCE_GROUPS as usize)?,
            sum: GpuBuffer::zeros(gpu, "occupancy sum", 1)?,
            bits: GpuBuffer::from_slice(gpu, "occupancy bits", &host_bits)?,
            host_bits: Vec::new(),
            occupied: GpuBuffer::zeros(gpu, "occupied cells", 0)?,
            n_occupied: 0,
            updated: false,
            bvh: BrickBvh::default(),
            gpu_nodes: GpuBuffer::zeros(gpu, "brick bvh nodes", 0)?,
            gpu_prims: GpuBuffer::zeros(gpu, "brick boxes", 0)?,
            seen: None,
        };
        grid.rebuild(gpu, host_bits)?;
        Ok(grid)
    }

    /// Whether the train loop should update the grid at `step`.
    pub fn should_update(&self, step: u32) -> bool {
        step.is_multiple_of(self.config.update_interval)
    }

    /// Chooses the cells of the update at `step` and one jittered point in each
    /// (see the module doc); deterministic for `(step < warmup, seed, occupancy)`.
    pub fn query_points(&self, gpu: &Gpu, step: u32, seed: u32) -> Result<OccupancyQuery, SamplerError> {
        gpu.submit_recorded(|enc| self.record_query_points(enc, step, seed))
    }

    /// [`OccupancyGrid::query_points`] recorded into `enc` (the caller submits).
    pub fn record_query_points(&self, enc: &mut Encoder, step: u32, seed: u32) -> Result<OccupancyQuery, SamplerError> {
        let n_cells = self.geom.n_cells;
        let (all_cells, n_uniform, count) = if step < self.config.warmup_steps {
            (1, 0, n_cells * self.config.warmup_points_per_cell)
        } else {
            let quarter = n_cells / 4;
            (0, quarter, quarter + self.n_occupied.min(quarter))
        };
        let params = QueryParams { geom: self.geom, count, seed, all_cells, n_uniform, list_len: self.n_occupied, _pad: [0; 3] };
        self.record_query(enc, &self.occupied, params, self.config.decay_at(step))
    }

    /// The query kernel with `params` over the cell list `list` (the occupied list, or
    /// [`OccupancyGrid::refined`]'s candidates), into fresh buffers of `params.count`
    /// points, for an update at `decay`.
    fn record_query(&self, enc: &mut Encoder, list: &GpuBuffer<u32>, params: QueryParams, decay: f32) -> Result<OccupancyQuery, SamplerError> {
        let gpu = enc.gpu();
        let count = params.count;
        let positions = GpuBuffer::zeros(gpu, "grid query points", count as usize)?;
        let cells = GpuBuffer::zeros(gpu, "grid query cells", count as usize)?;
        let kernel = gpu.kernel(&QUERY)?;
        let params = enc.params(&params);
        enc.dispatch_threads(&kernel, &[&params, &list.buffer, &positions.buffer, &cells.buffer], count);
        Ok(OccupancyQuery { positions, cells, count, decay })
    }

    /// Folds the densities evaluated at a query's points into the grid, rebuilds the
    /// bitfield, and the BVH if the bitfield changed. Waits for the GPU (one
    /// submission, one small readback).
    pub fn update(
        &mut self,
        gpu: &Gpu,
        cells: &GpuBuffer<u32>,
        densities: &GpuBuffer<f32>,
        count: u32,
        decay: f32,
    ) -> Result<OccupancyUpdate, SamplerError> {
        let mut enc = gpu.encoder();
        self.record_update(&mut enc, cells, densities, count, decay)?;
        self.finish_update(enc)
    }

    /// The kernels of [`OccupancyGrid::update`] recorded into `enc`, after whatever
    /// wrote `densities` there; [`OccupancyGrid::finish_update`] then submits and reads.
    pub fn record_update(
        &self,
        enc: &mut Encoder,
        cells: &GpuBuffer<u32>,
        densities: &GpuBuffer<f32>,
        count: u32,
        decay: f32,
    ) -> Result<(), SamplerError> {
        let gpu = enc.gpu();
        assert!(
            cells.len() >= count as usize && densities.len() >= count as usize,
            "update of {count} points with {} cells and {} densities",
            cells.len(),
            densities.len()
        );
        let n_cells = self.geom.n_cells;
        let threshold = self.config.density_threshold(self.layout.aabb);
        let params = CountParams { n: count, n_cells, decay, threshold };
        let p_update = enc.params(&params);
        enc.dispatch_threads(
            &*gpu.kernel(&SCATTER_MAX)?,
            &[&p_update, &cells.buffer, &densities.buffer, &self.scratch.buffer],
            count,
        );
        enc.dispatch_threads(&*gpu.kernel(&EMA)?, &[&p_update, &self.scratch.buffer, &self.density.buffer], n_cells);
        let reduce = gpu.kernel(&REDUCE)?;
        let groups = n_cells.div_ceil(REDUCE_WG).min(REDUCE_GROUPS);
        let p_cells = enc.params(&CountParams { n: n_cells, ..params });
        enc.dispatch(&reduce, &[&p_cells, &self.density.buffer, &self.partials.buffer], fold_groups(gpu, groups));
        let p_partials = enc.params(&CountParams { n: groups, ..params });
        enc.dispatch(&reduce, &[&p_partials, &self.partials.buffer, &self.sum.buffer], [1, 1, 1]);
        enc.dispatch_threads(
            &*gpu.kernel(&THRESHOLD)?,
            &[&p_update, &self.density.buffer, &self.sum.buffer, &self.bits.buffer],
            n_cells.div_ceil(32),
        );
        Ok(())
    }

    /// Submits `enc` (holding [`OccupancyGrid::record_update`]'s kernels) with the
    /// readback of the new bitfield and density sum, waits, and derives the rest on the
    /// host: the seen-cells mask, the occupied list and the BVH.
    pub fn finish_update(&mut self, enc: Encoder) -> Result<OccupancyUpdate, SamplerError> {
        let gpu = enc.gpu();
        let n_cells = self.geom.n_cells;
        let mut batch = ReadBatch::new();
        let bits_slot = batch.add(&self.bits, self.bits.len());
        let sum_slot = batch.add(&self.sum, 1);
        let read = batch.read_after(enc)?;
        let mut bits = read.get(&bits_slot);
        if let Some(seen) = &self.seen {
            let mut masked_any = false;
            for (b, m) in bits.iter_mut().zip(seen) {
                masked_any |= *b & !m != 0;
                *b &= m;
            }
            if masked_any {
                self.bits.write(gpu, &bits);
            }
        }
        let mean_density = read.get(&sum_slot)[0] / n_cells as f32;
        self.updated = true;
        let changed = bits != self.host_bits;
        if changed {
            self.rebuild(gpu, bits)?;
        }
        Ok(OccupancyUpdate {
            mean_density,
            occupied_cells: self.n_occupied,
            occupied_bricks: self.bvh.bricks.len() as u32,
            changed,
        })
    }

    /// Restricts occupancy to the cells for which `seen(cell_min, cell_max)` holds (see
    /// the module doc), from now on; returns how many cells that keeps. Call it before
    /// training; a resumed run calls it again with the same cameras.
    pub fn restrict_to_seen(&mut self, gpu: &Gpu, seen: impl Fn(Vec3, Vec3) -> bool + Sync) -> Result<u32, SamplerError> {
        use rayon::prelude::*;
        let res = self.geom.res as usize;
        let [lo, hi] = self.layout.aabb;
        let cell = (hi - lo) / res as f32;
        let n_words = (res * res * res).div_ceil(32);
        let mask: Vec<u32> = (0..n_words)
            .into_par_iter()
            .map(|w| {
                let mut word = 0u32;
                for bit in 0..32 {
                    let c = w * 32 + bit;
                    if c >= res * res * res {
                        break;
                    }
                    let ijk = Vec3::new((c % res) as f32, ((c / res) % res) as f32, (c / (res * res)) as f32);
                    let cmin = lo + ijk * cell;
                    if seen(cmin, cmin + cell) {
                        word |= 1 << bit;
                    }
                }
                word
            })
            .collect();
        let kept = mask.iter().map(|w| w.count_ones()).sum();
        let bits: Vec<u32> = self.host_bits.iter().zip(&mask).map(|(b, m)| b & m).collect();
        self.seen = Some(mask);
        if bits != self.host_bits {
            self.bits.write(gpu, &bits);
            self.rebuild(gpu, bits)?;
        }
        Ok(kept)
    }

    /// A finer grid for rendering ([`SamplerConfig::render_resolution`]): `resolution`
    /// cells per axis (a multiple of this grid's), restricted to the cells inside this
    /// grid's occupied ones (through [`OccupancyGrid::restrict_to_seen`], so it also keeps
    /// this grid's seen mask, which its bits already obey), then [`RENDER_GRID_POINTS`]
    /// updates that query each of those cells at a jittered point (`seed + k`) with no
    /// decay, so each keeps the largest density found and is occupied as a training
    /// update would mark it, at [`RENDER_GRID_THRESHOLD_SCALE`] times its threshold on
    /// one step's opacity (the cells outside stay at zero, which can only lower the
    /// mean the threshold is capped by). `density(enc, points,
    /// count, out)` records the field's densities at `points[..count]` into `out` (the
    /// grid never knows the field). Waits for the GPU once per update.
    ///
    /// [`RENDER_GRID_POINTS`]: super::RENDER_GRID_POINTS
    /// [`RENDER_GRID_THRESHOLD_SCALE`]: super::RENDER_GRID_THRESHOLD_SCALE
    pub fn refined<E: From<SamplerError>>(
        &self,
        gpu: &Gpu,
        resolution: u32,
        seed: u32,
        mut density: impl FnMut(&mut Encoder, &GpuBuffer<[f32; 4]>, u32, &GpuBuffer<f32>) -> Result<(), E>,
    ) -> Result<OccupancyGrid, E> {
        let coarse = self.geom.res;
        if resolution < coarse || !resolution.is_multiple_of(coarse) {
            return Err(SamplerError::Config(format!("a render grid of {resolution} cells per axis does not refine {coarse}")).into());
        }
        let threshold = self.config.threshold * super::RENDER_GRID_THRESHOLD_SCALE;
        // The finer grid renders through itself: no render grid of its own.
        let config = SamplerConfig { resolution, render_resolution: 0, threshold, ..self.config.clone() };
        let mut fine = OccupancyGrid::new(gpu, &config, self.layout.aabb)?;
        let [lo, hi] = self.layout.aabb;
        let coarse_cell = (hi - lo) / coarse as f32;
        let parent_occupied = |cmin: Vec3, cmax: Vec3| {
            let ijk = (((cmin + cmax) * 0.5 - lo) / coarse_cell).floor();
            let [x, y, z] = ijk.to_array().map(|v| (v.max(0.0) as u32).min(coarse - 1));
            self.is_occupied(x, y, z)
        };
        fine.restrict_to_seen(gpu, parent_occupied)?;
        // Every update probes the same cells: the occupied list before the first one
        // (each update rebuilds the list from its own bits).
        let list = occupied_list(&fine.host_bits, fine.geom.n_cells as usize);
        if list.is_empty() {
            return Ok(fine);
        }
        let candidates = GpuBuffer::from_slice(gpu, "render grid cells", &list).map_err(SamplerError::from)?;
        let n = list.len() as u32;
        let densities = GpuBuffer::<f32>::zeros(gpu, "render grid densities", n as usize).map_err(SamplerError::from)?;
        for k in 0..super::RENDER_GRID_POINTS {
            let mut enc = gpu.encoder();
            // One jittered point in each candidate (list mode: point i in cell list[i]).
            let params = QueryParams { geom: fine.geom, count: n, seed: seed.wrapping_add(k), all_cells: 0, n_uniform: 0, list_len: n, _pad: [0; 3] };
            let query = fine.record_query(&mut enc, &candidates, params, 1.0)?;
            density(&mut enc, &query.positions, query.count, &densities)?;
            fine.record_update(&mut enc, &query.cells, &densities, query.count, 1.0)?;
            fine.finish_update(enc)?;
        }
        Ok(fine)
    }

    /// How many cells the seen mask keeps ([`OccupancyGrid::restrict_to_seen`]); `None`
    /// when occupancy is not restricted.
    pub fn seen_cells(&self) -> Option<u32> {
        self.seen.as_ref().map(|mask| mask.iter().map(|w| w.count_ones()).sum())
    }

    /// The cell densities to save with a checkpoint: `None` before the first update
    /// (the grid is then "all occupied", which its zero densities do not say).
    pub fn export_density(&self, gpu: &Gpu) -> Result<Option<Vec<f32>>, SamplerError> {
        if !self.updated {
            return Ok(None);
        }
        Ok(Some(self.read_density(gpu)?))
    }

    /// Restores densities saved by [`OccupancyGrid::export_density`] and derives the
    /// bitfield, occupied list and BVH from them exactly as an update would (an update
    /// that queries no cell). Errors if `density` does not have one value per cell.
    pub fn restore_density(&mut self, gpu: &Gpu, density: &[f32]) -> Result<OccupancyUpdate, SamplerError> {
        if density.len() != self.geom.n_cells as usize {
            return Err(SamplerError::Config(format!(
                "{} saved occupancy densities for a grid of {} cells (resolution {})",
                density.len(),
                self.geom.n_cells,
                self.geom.res
            )));
        }
        self.density.write(gpu, density);
        let none_u32 = GpuBuffer::<u32>::zeros(gpu, "no query cells", 1)?;
        let none_f32 = GpuBuffer::<f32>::zeros(gpu, "no query densities", 1)?;
        self.update(gpu, &none_u32, &none_f32, 0, self.config.decay)
    }

    /// Rebuilds the occupied list and the brick BVH from `bits` and uploads them.
    fn rebuild(&mut self, gpu: &Gpu, bits: Vec<u32>) -> Result<(), SamplerError> {
        let list = occupied_list(&bits, self.geom.n_cells as usize);
        let bvh = BrickBvh::build(self.layout.occupied_bricks(&bits))?;
        self.occupied = GpuBuffer::from_slice(gpu, "occupied cells", &list)?;
        self.n_occupied = list.len() as u32;
        self.gpu_nodes = GpuBuffer::from_slice(gpu, "brick bvh nodes", &bvh.nodes)?;
        self.gpu_prims = GpuBuffer::from_slice(gpu, "brick boxes", &bvh.prims)?;
        self.bvh = bvh;
        self.host_bits = bits;
        Ok(())
    }

    pub fn config(&self) -> &SamplerConfig {
        &self.config
    }

    pub fn resolution(&self) -> u32 {
        self.geom.res
    }

    pub fn aabb(&self) -> [Vec3; 2] {
        self.layout.aabb
    }

    /// Geometry as uploaded to kernels.
    pub fn geom(&self) -> OccupancyGeom {
        self.geom
    }

    /// The occupancy bitfield on the host (equal to the GPU's).
    pub fn occupancy_bits(&self) -> &[u32] {
        &self.host_bits
    }

    /// Whether cell `(x, y, z)` is occupied.
    pub fn is_occupied(&self, x: u32, y: u32, z: u32) -> bool {
        let c = x + self.geom.res * (y + self.geom.res * z);
        (self.host_bits[(c >> 5) as usize] >> (c & 31)) & 1 != 0
    }

    pub fn occupied_cells(&self) -> u32 {
        self.n_occupied
    }

    /// The brick BVH on the host (brick boxes, obvhs BVH, flattened nodes).
    pub fn brick_bvh(&self) -> &BrickBvh {
        &self.bvh
    }

    /// GPU buffers of the brick BVH: nodes, brick boxes (leaf order), node count.
    pub fn gpu_bvh(&self) -> (&GpuBuffer<GpuBvhNode>, &GpuBuffer<GpuBvhNode>, u32) {
        (&self.gpu_nodes, &self.gpu_prims, self.bvh.nodes.len() as u32)
    }

    /// The GPU occupancy bitfield.
    pub fn gpu_bits(&self) -> &GpuBuffer<u32> {
        &self.bits
    }

    /// Reads the density grid back (tests, debugging, checkpoints).
    pub fn read_density(&self, gpu: &Gpu) -> Result<Vec<f32>, SamplerError> {
        Ok(self.density.read(gpu)?)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::rng::{rand_u32, unit_f32};

    /// CPU reference of one update (module doc): the query cells, then EMA, mean and
    /// bitfield. Returns the cells queried.
    struct CpuGrid {
        cfg: SamplerConfig,
        /// `cfg.density_threshold(aabb)`.
        threshold: f32,
        density: Vec<f32>,
        bits: Vec<bool>,
    }

    impl CpuGrid {
        fn query_cells(&self, step: u32, seed: u32) -> Vec<u32> {
            let n = self.density.len() as u32;
            if step < self.cfg.warmup_steps {
                return (0..n * self.cfg.warmup_points_per_cell).map(|i| i % n).collect();
            }
            let occupied: Vec<u32> = (0..n).filter(|&c| self.bits[c as usize]).collect();
            let quarter = n / 4;
            let mut cells: Vec<u32> = (0..quarter).map(|i| rand_u32(seed, i, 0) % n).collect();
            if occupied.len() as u32 <= quarter {
                cells.extend(&occupied);
            } else {
                let len = occupied.len() as u32;
                cells.extend((quarter..2 * quarter).map(|i| occupied[(rand_u32(seed, i, 0) % len) as usize]));
            }
            cells
        }

        /// `decay` is the rule's: `warmup_decay` before `warmup_steps`, else `decay`.
        fn update(&mut self, step: u32, cells: &[u32], dens: &[f32]) {
            let warmup = step < self.cfg.warmup_steps;
            let decay = if warmup { self.cfg.warmup_decay.unwrap_or(self.cfg.decay) } else { self.cfg.decay };
            let mut new = vec![None::<f32>; self.density.len()];
            for (&c, &d) in cells.iter().zip(dens) {
                let d = if d > 0.0 { d.min(3.0e38) } else { 0.0 };
                let e = &mut new[c as usize];
                *e = Some(e.map_or(d, |v| v.max(d)));
            }
            for (g, n) in self.density.iter_mut().zip(new) {
                if let Some(d) = n {
                    *g = (*g * decay).max(d);
                }
            }
            let mean = self.density.iter().map(|&v| v as f64).sum::<f64>() / self.density.len() as f64;
            let thr = (self.threshold as f64).min(mean) as f32;
            self.bits = self.density.iter().map(|&v| v > thr).collect();
        }
    }

    fn density_at(p: [f32; 4], step: u32) -> f32 {
        // A blob that moves with the step, plus negative values and a NaN to check
        // that they count as zero.
        let c = 0.2 * (step as f32 / 16.0) - 0.3;
        let r2 = (p[0] - c).powi(2) + p[1].powi(2) + (p[2] + 0.1).powi(2);
        let v = 3.0 * (-r2 / 0.08).exp() - 0.002;
        if p[0] > 0.9 && p[1] > 0.9 { f32::NAN } else { v }
    }

    #[test]
    fn sampler_grid_update_matches_cpu_reference_through_warmup() {
        let gpu = crate::gpu::test_gpu(false);
        for points in [1, 3] {
            grid_update_matches_cpu_reference(&gpu, points);
        }
    }

    /// The test above with `warmup_points_per_cell = points`.
    fn grid_update_matches_cpu_reference(gpu: &Gpu, points: u32) {
        // A warm-up decay of its own, so both phases' EMA are checked.
        let cfg = SamplerConfig {
            resolution: 24,
            warmup_steps: 48,
            warmup_decay: Some(0.5),
            warmup_points_per_cell: points,
            brick_size: 4,
            ..Default::default()
        };
        let aabb = [Vec3::splat(-1.0), Vec3::splat(1.0)];
        let mut grid = OccupancyGrid::new(&gpu, &cfg, aabb).unwrap();
        let n = 24u32.pow(3);
        assert_eq!(grid.occupied_cells(), n, "a new grid is fully occupied");
        let threshold = cfg.density_threshold(aabb);
        let mut cpu = CpuGrid { cfg: cfg.clone(), threshold, density: vec![0.0; n as usize], bits: vec![true; n as usize] };
        assert!(grid.should_update(0) && grid.should_update(32) && !grid.should_update(17));
        let mut saw_random_phase = false;
        for step in (0..160).step_by(16) {
            let seed = 1000 + step;
            let q = grid.query_points(&gpu, step, seed).unwrap();
            let cells = q.cells.read(&gpu).unwrap();
            let pos = q.positions.read(&gpu).unwrap();
            let want_cells = cpu.query_cells(step, seed);
            assert_eq!(cells, want_cells, "query cells at step {step}");
            assert_eq!(q.count as usize, cells.len());
            assert_eq!(q.decay, if step < 48 { 0.5 } else { 0.95 }, "decay at step {step}");
            if step >= cfg.warmup_steps {
                saw_random_phase = true;
                assert!(cells.len() < n as usize);
            } else {
                assert_eq!(cells.len(), (points * n) as usize, "{points} points a cell in the warm-up");
            }
            // Each point lies in its cell, at the jitter the hash gives.
            for (i, (&c, p)) in cells.iter().zip(&pos).enumerate() {
                let xyz = [c % 24, (c / 24) % 24, c / 576];
                for k in 0..3 {
                    let u = unit_f32(rand_u32(seed, i as u32, k as u32 + 1));
                    let want = -1.0 + 2.0 * ((xyz[k] as f32 + u) / 24.0);
                    assert!((p[k] - want).abs() < 1e-5, "point {i} axis {k}: {} vs {want}", p[k]);
                }
                assert_eq!(p[3], 0.0);
            }
            let dens: Vec<f32> = pos.iter().map(|&p| density_at(p, step)).collect();
            let dbuf = GpuBuffer::from_slice(&gpu, "dens", &dens).unwrap();
            let upd = grid.update(&gpu, &q.cells, &dbuf, q.count, q.decay).unwrap();
            cpu.update(step, &cells, &dens);
            let got = grid.read_density(&gpu).unwrap();
            assert_eq!(got, cpu.density, "EMA at step {step}");
            let mean = cpu.density.iter().map(|&v| v as f64).sum::<f64>() / n as f64;
            assert!((upd.mean_density as f64 - mean).abs() < 1e-5 * mean.max(1e-3), "{} vs {mean}", upd.mean_density);
            let thr = threshold.min(mean as f32);
            for c in 0..n {
                let (x, y, z) = (c % 24, (c / 24) % 24, c / 576);
                let v = cpu.density[c as usize];
                if (v - thr).abs() > 1e-6 {
                    assert_eq!(grid.is_occupied(x, y, z), cpu.bits[c as usize], "bit of cell {c} at step {step}");
                } else {
                    cpu.bits[c as usize] = grid.is_occupied(x, y, z);
                }
            }
            assert_eq!(upd.occupied_cells, cpu.bits.iter().filter(|&&b| b).count() as u32);
            assert!(upd.occupied_cells > 0 && upd.occupied_cells < n / 2, "blob occupies part of the grid");
        }
        assert!(saw_random_phase);
        // Same seed, same state: the same query.
        let a = grid.query_points(&gpu, 500, 7).unwrap();
        let b = grid.query_points(&gpu, 500, 7).unwrap();
        assert_eq!(a.positions.read(&gpu).unwrap(), b.positions.read(&gpu).unwrap());
    }

    #[test]
    fn several_warmup_points_per_cell_find_a_structure_thinner_than_a_cell() {
        let gpu = crate::gpu::test_gpu(false);
        let aabb = [Vec3::splat(-1.0), Vec3::splat(1.0)];
        // A slab a sixteenth of a cell thick (cells 0.125 wide), inside the column of
        // cells with x index 9: one jittered point lands in it one time in sixteen.
        let slab = |p: [f32; 4]| if (p[0] - 0.19).abs() < 0.004 { 10.0 } else { 0.0 };
        let found = |points: u32| {
            let cfg = SamplerConfig { resolution: 16, warmup_points_per_cell: points, brick_size: 4, ..Default::default() };
            let mut grid = OccupancyGrid::new(&gpu, &cfg, aabb).unwrap();
            let q = grid.query_points(&gpu, 0, 11).unwrap();
            assert_eq!(q.count, points * 16u32.pow(3));
            let dens: Vec<f32> = q.positions.read(&gpu).unwrap().into_iter().map(slab).collect();
            let dbuf = GpuBuffer::from_slice(&gpu, "dens", &dens).unwrap();
            let upd = grid.update(&gpu, &q.cells, &dbuf, q.count, q.decay).unwrap();
            let in_slab = (0..16 * 16).filter(|&yz| grid.is_occupied(9, yz % 16, yz / 16)).count();
            assert_eq!(upd.occupied_cells as usize, in_slab, "{points} points: only the slab's cells are occupied");
            in_slab
        };
        let (one, sixteen) = (found(1), found(16));
        // Expected: 1 - (15/16)^k of the 256 cells, 16 at k = 1 and 166 at k = 16.
        assert!(one < 40, "one point a cell found {one} of the slab's 256 cells");
        assert!(sixteen > 128 && sixteen > 4 * one.max(1), "16 points a cell found {sixteen} (one point: {one})");
        // Over the limit of points an update: a clear error, not an allocation failure.
        let too_many = SamplerConfig { resolution: 256, warmup_points_per_cell: 2, ..Default::default() };
        let err = too_many.validate().unwrap_err().to_string();
        assert!(err.contains("warmup_points_per_cell 2") && err.contains("lower one of them"), "{err}");
    }

    #[test]
    fn restricted_grid_occupies_only_seen_cells_through_updates() {
        let gpu = crate::gpu::test_gpu(false);
        let cfg = SamplerConfig { resolution: 16, warmup_steps: 100, brick_size: 4, ..Default::default() };
        let aabb = [Vec3::splat(-1.0), Vec3::splat(1.0)];
        let mut grid = OccupancyGrid::new(&gpu, &cfg, aabb).unwrap();
        // "Seen": the cells whose box reaches x < -0.25 (the first 6 of 16 columns).
        let kept = grid.restrict_to_seen(&gpu, |lo, _| lo.x < -0.25).unwrap();
        assert_eq!(kept, 6 * 16 * 16);
        assert_eq!(grid.occupied_cells(), kept, "restricting an untrained grid keeps the seen cells");
        let bits_of = |grid: &OccupancyGrid, gpu: &Gpu| (grid.occupancy_bits().to_vec(), grid.bits.read(gpu).unwrap());
        for step in [0u32, 16, 32] {
            // Dense everywhere: without the mask every cell would be occupied.
            let q = grid.query_points(&gpu, step, 3 + step).unwrap();
            let dens = GpuBuffer::from_slice(&gpu, "dens", &vec![50.0f32; q.count as usize]).unwrap();
            let upd = grid.update(&gpu, &q.cells, &dens, q.count, q.decay).unwrap();
            assert_eq!(upd.occupied_cells, kept, "step {step}");
            let (host, device) = bits_of(&grid, &gpu);
            assert_eq!(host, device, "the GPU bitfield is masked too");
            for c in 0..16 * 16 * 16u32 {
                assert_eq!(grid.is_occupied(c % 16, (c / 16) % 16, c / 256), c % 16 < 6, "cell {c}");
            }
        }
        // A checkpoint restore goes through the same mask.
        let saved = grid.export_density(&gpu).unwrap().unwrap();
        let upd = grid.restore_density(&gpu, &saved).unwrap();
        assert_eq!(upd.occupied_cells, kept);
    }

    #[test]
    fn render_grid_refines_only_the_training_grids_occupied_cells() {
        let gpu = crate::gpu::test_gpu(false);
        let cfg = SamplerConfig { resolution: 8, brick_size: 4, ..Default::default() };
        let aabb = [Vec3::splat(-1.0), Vec3::splat(1.0)];
        let mut coarse = OccupancyGrid::new(&gpu, &cfg, aabb).unwrap();
        // The training grid: occupied where its z < 2 (the finer grid's z < 4).
        let coarse_density: Vec<f32> = (0..512u32).map(|c| if c / 64 < 2 { 100.0 } else { 0.0 }).collect();
        coarse.restore_density(&gpu, &coarse_density).unwrap();
        assert_eq!(coarse.occupied_cells(), 2 * 64);
        // The field, per cell of the finer grid (each query's point i lies in cell i):
        // dense where x < 8, so a dense cell outside the training grid's (x < 8, z >= 4)
        // and an empty one inside it (x >= 8, z < 4) both occur.
        let n = 16u32.pow(3);
        let fine_density: Vec<f32> = (0..n).map(|c| if c % 16 < 8 { 10.0 } else { 0.0 }).collect();
        let field = GpuBuffer::from_slice(&gpu, "field", &fine_density).unwrap();
        let mut calls = 0;
        let fine = coarse
            .refined(&gpu, 16, 5, |enc, points, count, out| {
                calls += 1;
                // The cells inside the training grid's occupied ones, in index order:
                // z < 4, the first 1024 cells, so query i is in cell i.
                assert_eq!(count, 16 * 16 * 4, "only the cells inside occupied ones are queried");
                assert!(points.len() >= count as usize && out.len() >= count as usize);
                enc.copy(&field.buffer, &out.buffer, count as u64 * 4);
                Ok::<(), SamplerError>(())
            })
            .unwrap();
        assert_eq!(calls, crate::sampler::RENDER_GRID_POINTS);
        assert_eq!(fine.resolution(), 16);
        for c in 0..n {
            let (x, y, z) = (c % 16, (c / 16) % 16, c / 256);
            assert_eq!(fine.is_occupied(x, y, z), x < 8 && z < 4, "cell ({x}, {y}, {z})");
        }
        assert_eq!(fine.occupancy_bits(), fine.bits.read(&gpu).unwrap().as_slice(), "the GPU bitfield agrees");
        assert_eq!(coarse.occupied_cells(), 2 * 64, "the training grid is untouched");
        let not_a_multiple = coarse.refined(&gpu, 12, 5, |_, _, _, _| Ok::<(), SamplerError>(()));
        assert!(matches!(not_a_multiple, Err(SamplerError::Config(m)) if m.contains("does not refine 8")));
    }
}

/// The cells whose bit is set in `bits`, in index order (the first `n_cells` bits).
fn occupied_list(bits: &[u32], n_cells: usize) -> Vec<u32> {
    let mut list = Vec::new();
    for (w, &word) in bits.iter().enumerate() {
        let mut word = word;
        while word != 0 {
            let c = w * 32 + word.trailing_zeros() as usize;
            word &= word - 1;
            if c < n_cells {
                list.push(c as u32);
            }
        }
    }
    list
}

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(OccupancyGeom, "sampler/common.wgsl", "OccupancyGeom", [aabb_min, res, aabb_max, n_cells]);
        crate::assert_wgsl_mirror!(QueryParams, "sampler/occupancy.wgsl", "QueryParams", [geom, count, seed, all_cells, n_uniform, list_len]);
        crate::assert_wgsl_mirror!(CountParams, "sampler/occupancy.wgsl", "CountParams", [n, n_cells, decay, threshold]);
    }
}
