//! Rays cut by the batch's sample capacity, dropped from the losses. The sampler owns
//! the cut, so it owns the drop: the kernel zeroes the loss weights of those rays in
//! buffers the caller hands it (the targets' weight column, the edge regularizer's
//! per-pixel weights), before any loss runs.
//!
//! The sampler packs the samples of a batch's rays up to its capacity; a ray past the
//! cut keeps only its first samples or none ([`Sampler::wanted_counts`]) and renders
//! as if space behind were empty. Comparing such a ray with its pixel teaches the field
//! nothing true, and its depth (0 for an empty ray) would enter the edge-guided patch
//! means. [`DropTruncated`] runs after sampling and before the losses: a cut ray gets
//! target weight 0 (the photometric loss skips it) and, with patch batches, its 2x2
//! patch gets edge weight `e = 0` on all four pixels (an all-edge patch adds nothing to
//! `L_z` or `L_n`). The number of dropped rays is kept on the GPU for the step's stats.
//!
//! Invariants: only rays `0..n` (the photometric ones) are touched; a ray that kept
//! every sample it wanted is never changed; the photometric loss stays normalized by
//! the batch size, so dropping rays lowers the step's colour gradient in proportion.
//!
//! Owner of `kernels/sampler/truncated.wgsl`.
//!
//! [`Sampler::wanted_counts`]: super::Sampler::wanted_counts

use crate::gpu::{Binding, Encoder, Gpu, GpuBuffer, GpuError, KernelSpec};
use crate::layout::SampleRange;

const SPEC: KernelSpec = KernelSpec {
    file: "sampler/truncated.wgsl",
    entry: "drop_truncated",
    bindings: &[
        Binding::Params,
        Binding::ReadOnly,
        Binding::ReadOnly,
        Binding::ReadWrite,
        Binding::ReadWrite,
        Binding::ReadWrite,
    ],
};

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    n_rays: u32,
    patches: u32,
    _pad: [u32; 2],
}

/// The kernel, its dropped-ray counter and a placeholder for runs without patches.
pub struct DropTruncated {
    kernel: std::sync::Arc<crate::gpu::Kernel>,
    dropped: GpuBuffer<u32>,
    no_pixels: GpuBuffer<[f32; 2]>,
}

impl DropTruncated {
    pub fn new(gpu: &Gpu) -> Result<Self, GpuError> {
        Ok(Self {
            kernel: gpu.kernel(&SPEC)?,
            dropped: GpuBuffer::zeros(gpu, "dropped rays", 1)?,
            no_pixels: GpuBuffer::zeros(gpu, "no patch pixels", 4)?,
        })
    }

    /// Records the drop of the cut rays among `0..n`: `targets[r].w = 0` and, when
    /// `pixels` (the edge-guided losses' per-pixel `(e, z_scale)`) is given, `e = 0`
    /// on the cut ray's 2x2 patch. Resets the counter first.
    pub fn record(
        &self,
        enc: &mut Encoder,
        ranges: &GpuBuffer<SampleRange>,
        wanted: &GpuBuffer<u32>,
        targets: &GpuBuffer<[f32; 4]>,
        pixels: Option<&GpuBuffer<[f32; 2]>>,
        n: u32,
    ) {
        assert!(ranges.len() >= n as usize && wanted.len() >= n as usize && targets.len() >= n as usize);
        if let Some(p) = pixels {
            assert!(p.len() >= n as usize && n.is_multiple_of(4), "patch pixels for every ray, whole patches");
        }
        enc.clear(&self.dropped.buffer);
        let u = enc.params(&Params { n_rays: n, patches: pixels.is_some() as u32, _pad: [0; 2] });
        let pixel_buf = pixels.unwrap_or(&self.no_pixels);
        enc.dispatch_threads(
            &self.kernel,
            &[&u, &ranges.buffer, &wanted.buffer, &targets.buffer, &pixel_buf.buffer, &self.dropped.buffer],
            n,
        );
    }

    /// Rays dropped by the last [`DropTruncated::record`] (waits for the GPU).
    pub fn dropped(&self, gpu: &Gpu) -> Result<u32, GpuError> {
        Ok(self.dropped.read(gpu)?[0])
    }

    /// The one-element buffer holding that count (for a batched readback).
    pub fn dropped_count(&self) -> &GpuBuffer<u32> {
        &self.dropped
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cut_rays_and_their_patches_are_dropped_and_counted() {
        let gpu = crate::gpu::test_gpu(false);
        let n = 12u32;
        // Rays 5 (partly cut) and 9, 10 (nothing kept) were cut; ray 11 lies past n.
        let kept = [3u32, 2, 4, 1, 0, 2, 3, 3, 1, 0, 0, 2];
        let want = [3u32, 2, 4, 1, 0, 5, 3, 3, 1, 4, 2, 2, 7];
        let ranges: Vec<SampleRange> = kept.iter().map(|&c| SampleRange { start: 0, count: c }).collect();
        let ranges = GpuBuffer::from_slice(&gpu, "ranges", &ranges).unwrap();
        let wanted = GpuBuffer::from_slice(&gpu, "wanted", &want).unwrap();
        let targets_h: Vec<[f32; 4]> = (0..n).map(|r| [0.1 * r as f32, 0.2, 0.3, 1.0]).collect();
        let pixels_h: Vec<[f32; 2]> = (0..n).map(|r| [1.0, 0.5 + r as f32]).collect();
        let targets = GpuBuffer::from_slice(&gpu, "targets", &targets_h).unwrap();
        let pixels = GpuBuffer::from_slice(&gpu, "pixels", &pixels_h).unwrap();
        let drop = DropTruncated::new(&gpu).unwrap();
        let mut enc = gpu.encoder();
        drop.record(&mut enc, &ranges, &wanted, &targets, Some(&pixels), n);
        enc.submit();
        assert_eq!(drop.dropped(&gpu).unwrap(), 3);
        let t = targets.read(&gpu).unwrap();
        let p = pixels.read(&gpu).unwrap();
        for r in 0..n as usize {
            let cut = matches!(r, 5 | 9 | 10);
            let w = if cut { 0.0 } else { 1.0 };
            assert_eq!(t[r], [targets_h[r][0], 0.2, 0.3, w], "ray {r}");
            let patch_cut = matches!(r / 4, 1 | 2);
            assert_eq!(p[r], [if patch_cut { 0.0 } else { 1.0 }, pixels_h[r][1]], "pixel {r}");
        }
        // Without patches only the targets change; the counter restarts.
        let targets = GpuBuffer::from_slice(&gpu, "targets", &targets_h).unwrap();
        let mut enc = gpu.encoder();
        drop.record(&mut enc, &ranges, &wanted, &targets, None, 8);
        enc.submit();
        assert_eq!(drop.dropped(&gpu).unwrap(), 1);
        assert_eq!(targets.read(&gpu).unwrap()[5][3], 0.0);
    }
}

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(Params, "sampler/truncated.wgsl", "Params", [n_rays, patches]);
    }
}
