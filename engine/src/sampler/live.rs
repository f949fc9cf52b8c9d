//! The samples of a batch that carry gradient, listed for the field's backward.
//!
//! After the renderer's backward, a sample's output gradient is exactly zero when no
//! loss reaches it: past its ray's early termination (the renderer zeroes those), or
//! in a ray every loss skipped. Late in a run that is a fifth to a quarter of a batch
//! (demo and 3-view presets, 400 and 800 steps), and the field's backward is most of a
//! step. [`LiveCompaction`] lists the others, in increasing order, into a
//! [`LiveSamples`]: a flag per sample slot (`mark_live`), the exclusive scan of the
//! flags ([`ExclusiveScan`]), and the scatter of the flagged indices with the total
//! (`write_live`). Order is kept, so a chunk of the backward still holds the samples of
//! a few neighbouring rays, and the list is the same on every device.
//!
//! Invariants: a sample is listed iff it lies below `count[0]` and its `dL/drgb`,
//! `dL/dsigma` or (when asked) `dL/dn` has a non-zero component (NaN included: a
//! non-finite gradient must reach the optimizer's check); GPU work is queued, never
//! waited for.
//!
//! Owner of `kernels/sampler/live.wgsl`.

use std::sync::Arc;

use super::{ExclusiveScan, SamplerError};
use crate::gpu::{Binding, Encoder, Gpu, GpuBuffer, Kernel, KernelSpec};
use crate::layout::{FieldGrads, LiveSamples, SampleBatch};

const MARK: KernelSpec = KernelSpec {
    file: "sampler/live.wgsl",
    entry: "mark_live",
    bindings: &[Binding::Params, Binding::ReadOnly, Binding::ReadOnly, Binding::ReadOnly, Binding::ReadWrite],
};

const WRITE: KernelSpec = KernelSpec {
    file: "sampler/live.wgsl",
    entry: "write_live",
    bindings: &[Binding::Params, Binding::ReadOnly, Binding::ReadOnly, Binding::ReadWrite],
};

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    capacity: u32,
    normals: u32,
    _pad: [u32; 2],
}

/// The kernels and scratch of the compaction, for batches of up to `capacity` samples.
pub struct LiveCompaction {
    mark: Arc<Kernel>,
    write: Arc<Kernel>,
    flags: GpuBuffer<u32>,
    offsets: GpuBuffer<u32>,
    scan: ExclusiveScan,
}

impl LiveCompaction {
    pub fn new(gpu: &Gpu, capacity: u32) -> Result<Self, SamplerError> {
        let n = capacity.max(1);
        Ok(Self {
            mark: gpu.kernel(&MARK)?,
            write: gpu.kernel(&WRITE)?,
            flags: GpuBuffer::zeros(gpu, "live flags", n as usize)?,
            offsets: GpuBuffer::zeros(gpu, "live offsets", n as usize)?,
            scan: ExclusiveScan::new(gpu, n)?,
        })
    }

    /// Records the listing of the samples of `batch` whose `grads` are not all zero
    /// (`dL/dn` looked at only when `normals`) into `live`.
    pub fn record(
        &self,
        gpu: &Gpu,
        enc: &mut Encoder<'_>,
        batch: &SampleBatch,
        grads: &FieldGrads,
        normals: bool,
        live: &LiveSamples,
    ) -> Result<(), SamplerError> {
        let cap = batch.capacity.max(1);
        let room = self.flags.len() as u32;
        assert!(cap <= room && cap <= live.capacity(), "live compaction of {cap} samples, room for {room} / {}", live.capacity());
        grads.assert_capacity(batch.capacity, "live compaction: FieldGrads");
        let params = enc.params(&Params { capacity: cap, normals: normals as u32, _pad: [0; 2] });
        enc.dispatch_threads(
            &self.mark,
            &[&params, &batch.count.buffer, &grads.rgb_density.buffer, &grads.normal.buffer, &self.flags.buffer],
            cap,
        );
        self.scan.encode(gpu, enc, &self.flags, &self.offsets, cap)?;
        enc.dispatch_threads(&self.write, &[&params, &self.flags.buffer, &self.offsets.buffer, &live.list.buffer], cap);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::test_gpu;
    use crate::layout::FieldOutputs;
    use crate::rng::SplitMix64;

    /// The listing a host would make.
    fn expected(count: u32, d: &[[f32; 4]], n: &[[f32; 4]], normals: bool) -> Vec<u32> {
        (0..count.min(d.len() as u32))
            .filter(|&i| {
                let i = i as usize;
                d[i].iter().any(|&v| v != 0.0 || v.is_nan()) || (normals && n[i][..3].iter().any(|&v| v != 0.0 || v.is_nan()))
            })
            .collect()
    }

    #[test]
    fn lists_exactly_the_samples_with_gradient_in_order() {
        let gpu = test_gpu(false);
        let mut rng = SplitMix64::new(5);
        // Over one scan block and a partial one; count below the capacity.
        for (cap, count) in [(1u32, 1u32), (7, 0), (300, 300), (2500, 2311)] {
            let mut d = vec![[0.0f32; 4]; cap as usize];
            let mut n = vec![[0.0f32; 4]; cap as usize];
            for i in 0..cap as usize {
                match rng.next_u64() % 6 {
                    0 => d[i][(rng.next_u64() % 4) as usize] = 0.5,
                    1 => n[i][(rng.next_u64() % 3) as usize] = -1.0,
                    // The unused w of the normal gradient is not a gradient.
                    2 => n[i][3] = 1.0,
                    3 if i % 50 == 0 => d[i][3] = f32::NAN,
                    _ => {}
                }
            }
            // A live-looking sample past the count is not listed.
            if count < cap {
                d[count as usize] = [1.0; 4];
            }
            let batch = SampleBatch::new(&gpu, 1, cap).unwrap();
            batch.count.write(&gpu, &[count, count]);
            let grads = FieldOutputs::new(&gpu, cap).unwrap();
            grads.rgb_density.write(&gpu, &d);
            grads.normal.write(&gpu, &n);
            let compaction = LiveCompaction::new(&gpu, cap).unwrap();
            let live = LiveSamples::new(&gpu, cap).unwrap();
            for normals in [false, true] {
                // Stale entries from an earlier listing must not leak into the count.
                live.write(&gpu, &vec![cap - 1; cap as usize]);
                let mut enc = gpu.encoder();
                compaction.record(&gpu, &mut enc, &batch, &grads, normals, &live).unwrap();
                enc.submit();
                assert_eq!(live.read(&gpu).unwrap(), expected(count, &d, &n, normals), "cap {cap} count {count} normals {normals}");
            }
        }
    }
}
