//! Occupied bricks and the BVH over them (CPU side, rebuilt when the bitfield changes).
//!
//! A brick is a cube of `brick_size`^3 occupancy cells (clipped at the grid's far
//! faces when the resolution is not a multiple); it is occupied when any of its cells
//! is. The BVH is an `obvhs` BVH2 built over the world AABBs of the occupied bricks
//! with [`obvhs::BvhBuildParams::medium_build`]: PLOC with a medium search radius,
//! reinsertion optimisation and leaf collapsing by SAH (up to 8 bricks per leaf), the
//! preset that builds about as fast as Embree with better traversal; for at most
//! 32^3 primitives that is a few milliseconds.
//!
//! For the GPU the BVH is flattened into [`GpuBvhNode`]s (the layout of `BvhNode` in
//! `kernels/sampler/intervals.wgsl`) and the brick boxes are reordered by obvhs's
//! `primitive_indices`, so leaves index the brick array directly. Invariants: node 0
//! is the root; an inner node's children are `first_index` and `first_index + 1`; a
//! leaf (`prim_count > 0`) owns `prims[first_index ..][.. prim_count]`; the tree depth
//! plus one fits the kernel's traversal stack ([`STACK_CAP`]).

use std::time::Duration;

use bytemuck::{Pod, Zeroable};
use glam::{Vec3, Vec3A};
use obvhs::{BvhBuildParams, aabb::Aabb, bvh2::Bvh2, bvh2::builder::build_bvh2};

use super::SamplerError;

/// Entries of the interval kernel's traversal stack (`STACK_CAP` in the WGSL).
pub const STACK_CAP: u32 = 64;

/// A BVH node or brick box as the interval kernel reads it.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuBvhNode {
    pub min: [f32; 3],
    /// Leaf: number of bricks (> 0); inner node: 0.
    pub prim_count: u32,
    pub max: [f32; 3],
    /// Leaf: first brick in the reordered brick array; inner node: first child;
    /// brick box (in `prims`): the brick's index in [`BrickBvh::bricks`] (unused by
    /// the kernel).
    pub first_index: u32,
}

/// Geometry of the brick partition of an occupancy grid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BrickLayout {
    pub aabb: [Vec3; 2],
    pub resolution: u32,
    pub brick_size: u32,
}

impl BrickLayout {
    /// Bricks per axis.
    pub fn bricks_per_axis(&self) -> u32 {
        self.resolution.div_ceil(self.brick_size)
    }

    /// World position of grid-corner coordinate `c` (in cells, `0..=resolution`).
    fn corner(&self, c: [u32; 3]) -> Vec3 {
        let ext = self.aabb[1] - self.aabb[0];
        let r = self.resolution as f32;
        self.aabb[0] + ext * Vec3::new(c[0] as f32 / r, c[1] as f32 / r, c[2] as f32 / r)
    }

    /// World AABB of brick `b` (brick coordinates).
    pub fn brick_aabb(&self, b: [u32; 3]) -> Aabb {
        let lo = b.map(|x| x * self.brick_size);
        let hi = b.map(|x| ((x + 1) * self.brick_size).min(self.resolution));
        Aabb::new(Vec3A::from(self.corner(lo)), Vec3A::from(self.corner(hi)))
    }

    /// AABBs of the bricks holding an occupied cell of `bits` (bit `c & 31` of word
    /// `c >> 5` for cell `c = x + res * (y + res * z)`), in brick index order.
    pub fn occupied_bricks(&self, bits: &[u32]) -> Vec<Aabb> {
        let res = self.resolution as usize;
        let bs = self.brick_size as usize;
        let nb = self.bricks_per_axis() as usize;
        let mut occupied = vec![false; nb * nb * nb];
        for (w, &word) in bits.iter().enumerate() {
            let mut word = word;
            while word != 0 {
                let c = w * 32 + word.trailing_zeros() as usize;
                word &= word - 1;
                if c >= res * res * res {
                    break;
                }
                let (x, y, z) = (c % res, (c / res) % res, c / (res * res));
                occupied[x / bs + nb * (y / bs + nb * (z / bs))] = true;
            }
        }
        let mut out = Vec::new();
        for (i, _) in occupied.iter().enumerate().filter(|(_, o)| **o) {
            let b = [(i % nb) as u32, ((i / nb) % nb) as u32, (i / (nb * nb)) as u32];
            out.push(self.brick_aabb(b));
        }
        out
    }
}

/// The BVH over occupied bricks, on the host, flattened for the GPU.
#[derive(Clone, Default)]
pub struct BrickBvh {
    /// Brick AABBs in input order (what the BVH was built from).
    pub bricks: Vec<Aabb>,
    /// The obvhs BVH (`None` without bricks).
    pub bvh: Option<Bvh2>,
    /// Flattened nodes (empty without bricks).
    pub nodes: Vec<GpuBvhNode>,
    /// Brick boxes in leaf order.
    pub prims: Vec<GpuBvhNode>,
    /// Levels of the tree (0 when empty, 1 for a lone leaf).
    pub depth: u32,
}

fn gpu_box(a: &Aabb, prim_count: u32, first_index: u32) -> GpuBvhNode {
    GpuBvhNode { min: a.min.to_array(), prim_count, max: a.max.to_array(), first_index }
}

impl BrickBvh {
    /// Builds the BVH over `bricks` and flattens it.
    pub fn build(bricks: Vec<Aabb>) -> Result<Self, SamplerError> {
        if bricks.is_empty() {
            return Ok(Self::default());
        }
        let bvh = build_bvh2(&bricks, BvhBuildParams::medium_build(), &mut Duration::default());
        let nodes: Vec<GpuBvhNode> = bvh.nodes.iter().map(|n| gpu_box(n.aabb(), n.prim_count, n.first_index)).collect();
        let prims: Vec<GpuBvhNode> =
            bvh.primitive_indices.iter().map(|&i| gpu_box(&bricks[i as usize], 0, i)).collect();
        let depth = tree_depth(&nodes);
        if depth + 1 > STACK_CAP {
            return Err(SamplerError::BvhTooDeep { depth, limit: STACK_CAP - 1 });
        }
        Ok(Self { bricks, bvh: Some(bvh), nodes, prims, depth })
    }
}

/// Number of levels of a flattened tree rooted at node 0.
fn tree_depth(nodes: &[GpuBvhNode]) -> u32 {
    if nodes.is_empty() {
        return 0;
    }
    let mut max = 0;
    let mut stack = vec![(0u32, 1u32)];
    while let Some((i, d)) = stack.pop() {
        max = max.max(d);
        let n = nodes[i as usize];
        if n.prim_count == 0 {
            stack.push((n.first_index, d + 1));
            stack.push((n.first_index + 1, d + 1));
        }
    }
    max
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sampler_bricks_cover_occupied_cells_and_bvh_is_consistent() {
        let layout = BrickLayout { aabb: [Vec3::splat(-1.0), Vec3::new(3.0, 1.0, 1.0)], resolution: 20, brick_size: 8 };
        assert_eq!(layout.bricks_per_axis(), 3);
        let res = 20usize;
        let mut bits = vec![0u32; (res * res * res).div_ceil(32)];
        let mut set = |x: usize, y: usize, z: usize| {
            let c = x + res * (y + res * z);
            bits[c >> 5] |= 1 << (c & 31);
        };
        set(0, 0, 0);
        set(7, 7, 7); // same brick
        set(19, 19, 19); // the clipped far brick
        set(8, 0, 0);
        let bricks = layout.occupied_bricks(&bits);
        assert_eq!(bricks.len(), 3);
        assert_eq!(bricks[0].min, Vec3A::new(-1.0, -1.0, -1.0));
        assert!((bricks[0].max - Vec3A::new(0.6, -0.2, -0.2)).abs().max_element() < 1e-6);
        assert_eq!(bricks[2].max, Vec3A::new(3.0, 1.0, 1.0), "far brick clipped to the AABB");
        let bvh = BrickBvh::build(bricks.clone()).unwrap();
        // Every brick appears exactly once among the leaves, inside every ancestor.
        let mut seen = vec![0; bricks.len()];
        let mut stack = vec![0u32];
        while let Some(i) = stack.pop() {
            let n = bvh.nodes[i as usize];
            if n.prim_count == 0 {
                for c in [n.first_index, n.first_index + 1] {
                    let ch = bvh.nodes[c as usize];
                    assert!((0..3).all(|k| ch.min[k] >= n.min[k] && ch.max[k] <= n.max[k]));
                    stack.push(c);
                }
            } else {
                for p in &bvh.prims[n.first_index as usize..(n.first_index + n.prim_count) as usize] {
                    seen[p.first_index as usize] += 1;
                    assert!((0..3).all(|k| p.min[k] >= n.min[k] && p.max[k] <= n.max[k]));
                }
            }
        }
        assert!(seen.iter().all(|&s| s == 1), "{seen:?}");
        assert!(BrickBvh::build(Vec::new()).unwrap().nodes.is_empty());
    }
}

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(GpuBvhNode, "sampler/intervals.wgsl", "BvhNode", [min, prim_count, max, first_index]);
    }
}
