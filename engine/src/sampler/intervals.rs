//! Occupied intervals per ray: BVH traversal on the GPU.
//!
//! Owner of `kernels/sampler/intervals.wgsl`. One thread per ray walks the brick BVH
//! ([`super::bricks`]) with a stack (no front-to-back order: the hits are sorted
//! afterwards), collects `[max(t_enter, t_min), min(t_exit, t_max)]` of every brick
//! it crosses (non-empty ones only), sorts them by entry, merges intervals that
//! overlap or touch (gap `<= 1e-5 * max(1, |t_exit|)`, the float noise where a ray
//! passes into a neighbouring brick), and while more than `max_intervals` remain,
//! merges the pair with the smallest gap (the first on ties). Collecting all hits
//! before merging (at most `3 * 32 - 2` bricks per ray, guaranteed by the 32 bricks
//! per axis limit) makes the result independent of traversal order.
//!
//! Output: `intervals[r * max_intervals + i]` for `i < counts[r]`, sorted, disjoint.
//! The tests compare with a CPU traversal of the same obvhs BVH.

use bytemuck::{Pod, Zeroable};

use crate::gpu::{Binding, Encoder, Gpu, GpuBuffer, KernelSpec};
use crate::layout::GpuRay;

use super::{OccupancyGrid, SamplerError};

const SPEC: KernelSpec = KernelSpec {
    file: "sampler/intervals.wgsl",
    entry: "ray_intervals",
    bindings: &[
        Binding::Params,
        Binding::ReadOnly,
        Binding::ReadOnly,
        Binding::ReadOnly,
        Binding::ReadWrite,
        Binding::ReadWrite,
    ],
};

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Params {
    n_rays: u32,
    n_nodes: u32,
    max_intervals: u32,
    _pad: u32,
}

/// Per-ray interval lists for up to `max_rays` rays.
pub struct RayIntervals {
    pub intervals: GpuBuffer<[f32; 2]>,
    pub counts: GpuBuffer<u32>,
    pub max_rays: u32,
    pub max_intervals: u32,
}

impl RayIntervals {
    pub fn new(gpu: &Gpu, max_rays: u32, max_intervals: u32) -> Result<Self, SamplerError> {
        assert!((1..=super::MAX_INTERVALS_LIMIT).contains(&max_intervals));
        Ok(Self {
            intervals: GpuBuffer::zeros(gpu, "ray intervals", max_rays as usize * max_intervals as usize)?,
            counts: GpuBuffer::zeros(gpu, "ray interval counts", max_rays as usize)?,
            max_rays,
            max_intervals,
        })
    }

    /// Records the traversal of `rays[..n_rays]` against `grid`'s brick BVH.
    pub fn encode(
        &self,
        gpu: &Gpu,
        enc: &mut Encoder<'_>,
        grid: &OccupancyGrid,
        rays: &GpuBuffer<GpuRay>,
        n_rays: u32,
    ) -> Result<(), SamplerError> {
        assert!(n_rays <= self.max_rays && rays.len() >= n_rays as usize, "{n_rays} rays for {}", self.max_rays);
        let (nodes, prims, n_nodes) = grid.gpu_bvh();
        let kernel = gpu.kernel(&SPEC)?;
        let params = enc.params(&Params { n_rays, n_nodes, max_intervals: self.max_intervals, _pad: 0 });
        enc.dispatch_threads(
            &kernel,
            &[&params, &rays.buffer, &nodes.buffer, &prims.buffer, &self.intervals.buffer, &self.counts.buffer],
            n_rays,
        );
        Ok(())
    }

    /// Reads back the lists of the first `n_rays` rays.
    pub fn read(&self, gpu: &Gpu, n_rays: u32) -> Result<Vec<Vec<[f32; 2]>>, SamplerError> {
        let all = self.intervals.read(gpu)?;
        let counts = self.counts.read(gpu)?;
        let m = self.max_intervals as usize;
        Ok((0..n_rays as usize).map(|r| all[r * m..r * m + counts[r] as usize].to_vec()).collect())
    }
}

/// Runs the interval kernel on `rays` and reads the result (tests, tools).
pub fn ray_intervals(
    gpu: &Gpu,
    grid: &OccupancyGrid,
    rays: &[GpuRay],
    max_intervals: u32,
) -> Result<Vec<Vec<[f32; 2]>>, SamplerError> {
    let n = rays.len() as u32;
    let out = RayIntervals::new(gpu, n, max_intervals)?;
    let ray_buf = GpuBuffer::from_slice(gpu, "rays", rays)?;
    let mut enc = gpu.encoder();
    out.encode(gpu, &mut enc, grid, &ray_buf, n)?;
    enc.submit();
    out.read(gpu, n)
}

#[cfg(test)]
pub(crate) mod tests {
    use glam::{Vec3, Vec3A};
    use obvhs::aabb::Aabb;

    use super::super::SamplerConfig;
    use super::super::bricks::BrickBvh;
    use crate::rng::{rand_u32, unit_f32};
    use super::*;

    /// The reference's answer for one ray, and whether closing gaps over the cap met a
    /// near-tie. Bricks sit on a regular lattice, so two gaps along a ray are often equal
    /// up to rounding: which one is "smallest" then depends on how the implementation
    /// rounds the slab tests (NVIDIA's Vulkan picks the other one of a tie than the CPU
    /// on a few rays), and either choice is correct.
    pub(crate) struct Merged {
        pub ivs: Vec<[f32; 2]>,
        pub tie: bool,
    }

    /// Gap below which two intervals touch, and the length below which one is a
    /// sliver: the kernel's `merge_tolerance`.
    fn touch_tolerance(t: f32) -> f32 {
        1e-5 * t.abs().max(1.0)
    }

    /// Gaps closer than this count as equal when choosing which one to close.
    fn gap_tie_tolerance(t: f32) -> f32 {
        1e-4 * t.abs().max(1.0)
    }

    /// The reference: sort, merge touching, close smallest gaps over the cap.
    fn merge(mut raw: Vec<[f32; 2]>, cap: usize) -> Merged {
        raw.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
        let mut out: Vec<[f32; 2]> = Vec::new();
        for iv in raw {
            match out.last_mut() {
                Some(last) if iv[0] <= last[1] + touch_tolerance(last[1]) => last[1] = last[1].max(iv[1]),
                _ => out.push(iv),
            }
        }
        let mut tie = false;
        while out.len() > cap {
            let gap = |i: usize| out[i + 1][0] - out[i][1];
            let best = (0..out.len() - 1).min_by(|&i, &j| gap(i).total_cmp(&gap(j))).unwrap();
            tie |= (0..out.len() - 1).any(|i| i != best && gap(i) - gap(best) <= gap_tie_tolerance(out[i][1]));
            out[best][1] = out[best + 1][1];
            out.remove(best + 1);
        }
        Merged { ivs: out, tie }
    }

    fn clip(ray: &GpuRay, b: &Aabb) -> Option<[f32; 2]> {
        let h = ray.box_range(b.min.into(), b.max.into());
        let iv = [h[0].max(ray.t_min), h[1].min(ray.t_max)];
        // Slivers shorter than the touching tolerance are dropped, as in the kernel.
        (iv[1] - iv[0] > touch_tolerance(iv[1])).then_some(iv)
    }

    /// CPU traversal of the same obvhs BVH with obvhs's own any-hit traversal.
    fn cpu_bvh_intervals(bvh: &BrickBvh, ray: &GpuRay, cap: usize) -> Merged {
        let mut raw = Vec::new();
        if let Some(tree) = &bvh.bvh {
            let r =
                obvhs::ray::Ray::new(Vec3A::from_array(ray.origin), Vec3A::from_array(ray.dir), ray.t_min, ray.t_max);
            tree.ray_traverse_anyhit(r, |_, id| {
                let b = &bvh.bricks[tree.primitive_indices[id] as usize];
                raw.extend(clip(ray, b));
            });
        }
        merge(raw, cap)
    }

    fn brute_force_intervals(bvh: &BrickBvh, ray: &GpuRay, cap: usize) -> Merged {
        merge(bvh.bricks.iter().filter_map(|b| clip(ray, b)).collect(), cap)
    }

    /// A grid whose occupancy is a random set of blobs of cells, built through the
    /// public two-phase update (warm-up: every cell queried once, density 0 or 1).
    pub(crate) fn random_grid(gpu: &Gpu, cfg: &SamplerConfig, aabb: [Vec3; 2], seed: u32) -> OccupancyGrid {
        let mut grid = OccupancyGrid::new(gpu, cfg, aabb).unwrap();
        let q = grid.query_points(gpu, 0, seed).unwrap();
        let res = cfg.resolution;
        let cells = q.cells.read(gpu).unwrap();
        let centers: Vec<[f32; 3]> =
            (0..12).map(|i| [0, 1, 2].map(|k| unit_f32(rand_u32(seed, i, k + 10)) * res as f32)).collect();
        let dens: Vec<f32> = cells
            .iter()
            .map(|&c| {
                let p = [c % res, (c / res) % res, c / (res * res)].map(|v| v as f32 + 0.5);
                let near = centers.iter().any(|ctr| (0..3).map(|k| (p[k] - ctr[k]).powi(2)).sum::<f32>() < 9.0);
                // About a fifth of the bricks get a lone occupied cell.
                let speckle = rand_u32(seed, c, 99).is_multiple_of(4 * cfg.brick_size.pow(3));
                if near || speckle { 1.0 } else { 0.0 }
            })
            .collect();
        let d = GpuBuffer::from_slice(gpu, "dens", &dens).unwrap();
        let upd = grid.update(gpu, &q.cells, &d, q.count, q.decay).unwrap();
        assert!(upd.changed && upd.occupied_bricks > 10, "{upd:?}");
        grid
    }

    pub(crate) fn random_rays(n: u32, seed: u32, aabb: [Vec3; 2]) -> Vec<GpuRay> {
        let ext = aabb[1] - aabb[0];
        (0..n)
            .map(|i| {
                let u = |k: u32| unit_f32(rand_u32(seed, i, k));
                // Origins in a box twice the AABB's size (inside and outside), random
                // directions, random [t_min, t_max] (some rays stop inside the grid).
                let o = aabb[0] - 0.5 * ext + 2.0 * ext * Vec3::new(u(0), u(1), u(2));
                let d = (0..)
                    .map(|j| Vec3::new(u(3 + 3 * j), u(4 + 3 * j), u(5 + 3 * j)) * 2.0 - 1.0)
                    .find(|v| v.length() > 0.1)
                    .unwrap()
                    .normalize();
                let d = if i % 3 == 0 { ((aabb[0] + aabb[1]) * 0.5 - o).normalize() } else { d };
                let t_min = u(100) * 0.5;
                let t_max = t_min + ext.length() * (0.3 + 1.5 * u(101));
                GpuRay { origin: o.to_array(), t_min, dir: d.to_array(), t_max }
            })
            .collect()
    }

    fn close(a: f32, b: f32) -> bool {
        (a - b).abs() <= 1e-4 * b.abs().max(1.0)
    }

    /// `got` must equal the reference ray by ray, except where the reference closed one
    /// of two (near-)equal gaps: there `got` must be another valid answer, with as many
    /// intervals, the same ends, every interval of the uncapped answer `all` inside one
    /// of its intervals, and the same covered length up to the tie tolerance. Returns
    /// how many rays were such ties.
    fn compare(got: &[Vec<[f32; 2]>], want: &[Merged], all: &[Merged], what: &str) -> usize {
        let mut ties = 0;
        for (r, ((g, w), a)) in got.iter().zip(want).zip(all).enumerate() {
            let w_ivs = &w.ivs;
            assert_eq!(g.len(), w_ivs.len(), "{what}: ray {r}: {g:?} vs {w_ivs:?}");
            let same = g.iter().zip(w_ivs).all(|(x, y)| close(x[0], y[0]) && close(x[1], y[1]));
            if same {
                continue;
            }
            assert!(w.tie, "{what}: ray {r}: {g:?} vs {w_ivs:?}");
            ties += 1;
            let (first, last) = (g.first().unwrap(), g.last().unwrap());
            assert!(close(first[0], w_ivs[0][0]) && close(last[1], w_ivs[w_ivs.len() - 1][1]), "{what}: ray {r}: ends of {g:?} vs {w_ivs:?}");
            for iv in &a.ivs {
                assert!(
                    g.iter().any(|x| x[0] <= iv[0] + 1e-4 && iv[1] <= x[1] + 1e-4),
                    "{what}: ray {r}: {iv:?} of the uncapped {:?} is not covered by {g:?}",
                    a.ivs
                );
            }
            let length = |v: &[[f32; 2]]| v.iter().map(|x| x[1] - x[0]).sum::<f32>();
            let slack = g.len() as f32 * gap_tie_tolerance(last[1]) + 1e-4;
            assert!((length(g) - length(w_ivs)).abs() <= slack, "{what}: ray {r}: covered length of {g:?} vs {w_ivs:?}");
        }
        ties
    }

    #[test]
    fn sampler_gpu_intervals_match_cpu_obvhs_traversal() {
        let gpu = crate::gpu::test_gpu(false);
        let aabb = [Vec3::new(-1.5, -1.0, -0.5), Vec3::new(2.5, 1.0, 1.5)];
        for (res, brick, seed) in [(64u32, 4u32, 3u32), (48, 8, 11), (96, 4, 5)] {
            let cfg = SamplerConfig { resolution: res, brick_size: brick, ..Default::default() };
            let grid = random_grid(&gpu, &cfg, aabb, seed);
            let bvh = grid.brick_bvh();
            let rays = random_rays(3000, seed + 1, aabb);
            let uncapped: Vec<_> = rays.iter().map(|r| brute_force_intervals(bvh, r, usize::MAX)).collect();
            let mut multi = 0;
            for cap in [16u32, 3] {
                let got = ray_intervals(&gpu, &grid, &rays, cap).unwrap();
                let want: Vec<_> = rays.iter().map(|r| cpu_bvh_intervals(bvh, r, cap as usize)).collect();
                let ties = compare(&got, &want, &uncapped, &format!("res {res} brick {brick} cap {cap}"));
                assert!(ties * 100 <= rays.len(), "{ties} rays differ at near-ties of the gaps");
                let brute: Vec<_> = rays.iter().map(|r| brute_force_intervals(bvh, r, cap as usize)).collect();
                let want_ivs: Vec<_> = want.into_iter().map(|m| m.ivs).collect();
                // The same float arithmetic on both sides: no tie may resolve differently.
                assert_eq!(compare(&want_ivs, &brute, &uncapped, "obvhs traversal vs brute force"), 0);
                for (ray, ivs) in rays.iter().zip(&got) {
                    assert!(ivs.len() <= cap as usize);
                    for w in ivs.windows(2) {
                        assert!(w[0][1] < w[1][0], "sorted and disjoint: {ivs:?}");
                    }
                    assert!(ivs.iter().all(|iv| iv[0] >= ray.t_min && iv[1] <= ray.t_max && iv[0] < iv[1]));
                }
                if cap == 16 {
                    multi = got.iter().filter(|v| v.len() > 3).count();
                    assert!(got.iter().filter(|v| v.is_empty()).count() > 100, "some rays miss everything");
                }
            }
            assert!(multi > 50, "the cap of 3 is exercised: {multi} rays with more than 3 intervals");
            let b = grid.brick_bvh();
            eprintln!(
                "res {res} brick {brick}: {} bricks, {} nodes, depth {}, {multi} rays with > 3 intervals",
                b.bricks.len(),
                b.nodes.len(),
                b.depth
            );
        }
    }

    #[test]
    fn sampler_intervals_of_empty_and_full_grids() {
        let gpu = crate::gpu::test_gpu(false);
        let aabb = [Vec3::splat(-1.0), Vec3::splat(1.0)];
        let cfg = SamplerConfig { resolution: 32, ..Default::default() };
        let mut grid = OccupancyGrid::new(&gpu, &cfg, aabb).unwrap();
        // Full grid: one interval, the ray's chord through the box.
        let ray = GpuRay { origin: [-3.0, 0.1, 0.2], t_min: 0.5, dir: [1.0, 0.0, 0.0], t_max: 10.0 };
        let got = ray_intervals(&gpu, &grid, &[ray], 16).unwrap();
        assert_eq!(got[0].len(), 1, "{got:?}");
        assert!((got[0][0][0] - 2.0).abs() < 1e-5 && (got[0][0][1] - 4.0).abs() < 1e-5, "{got:?}");
        // Empty grid (all densities 0): no BVH, no intervals.
        let q = grid.query_points(&gpu, 0, 0).unwrap();
        let zeros = GpuBuffer::from_slice(&gpu, "z", &vec![0.0f32; q.count as usize]).unwrap();
        let upd = grid.update(&gpu, &q.cells, &zeros, q.count, q.decay).unwrap();
        assert_eq!((upd.occupied_cells, upd.occupied_bricks), (0, 0));
        assert!(ray_intervals(&gpu, &grid, &[ray], 16).unwrap()[0].is_empty());
    }
}

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(Params, "sampler/intervals.wgsl", "Params", [n_rays, n_nodes, max_intervals]);
    }
}
