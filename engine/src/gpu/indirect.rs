//! Dispatch sizes from GPU-side counts: indirect dispatch arguments written by a kernel
//! (`kernels/gpu/indirect.wgsl`) from a count buffer, so a kernel over "the first
//! `count[0]` items" launches only the workgroups those items need, without a readback.
//!
//! Why: a kernel dispatched over a buffer's capacity that returns early past the count
//! runs its whole body under an execution mask on lavapipe (its storage and weight reads
//! become per-lane gathers), and launches idle workgroups everywhere. With these
//! arguments the kernel has no early return: the threads of the last workgroup past the
//! count recompute a valid item and write nothing.
//!
//! Invariant: chunk `k` covers items `[k chunk, min((k + 1) chunk, min(count[0], cap)))`
//! and its workgroup grid is `grid_1d` of that many threads (zero workgroups past the
//! count); the arguments are written in the same command buffer before the dispatches
//! that read them.

use super::kernel::{Binding, Encoder, Kernel, KernelSpec};
use super::{BindResource, Gpu, GpuError};

const INDIRECT: KernelSpec = KernelSpec {
    file: "gpu/indirect.wgsl",
    entry: "indirect_args",
    bindings: &[Binding::Params, Binding::ReadOnly, Binding::ReadWrite],
};

/// Mirror of `IndirectParams` in `kernels/gpu/indirect.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct IndirectParams {
    cap: u32,
    chunk: u32,
    n_chunks: u32,
    max_per_dim: u32,
}

/// Indirect dispatch arguments for up to `n_chunks` chunks (module doc).
pub struct IndirectArgs {
    buffer: wgpu::Buffer,
    n_chunks: u32,
}

impl IndirectArgs {
    pub fn new(gpu: &Gpu, n_chunks: u32) -> Self {
        let n_chunks = n_chunks.max(1);
        let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("indirect dispatch arguments"),
            size: 12 * n_chunks as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::INDIRECT | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        Self { buffer, n_chunks }
    }

    /// Chunks these arguments have room for.
    pub fn capacity(&self) -> u32 {
        self.n_chunks
    }

    /// Records the kernel writing the arguments of `n_chunks` chunks of `chunk` threads
    /// over the first `min(count[0], cap)` items (`count`: a `u32` storage buffer).
    pub fn record(&self, enc: &mut Encoder, count: &wgpu::Buffer, cap: u32, chunk: u32, n_chunks: u32)
    -> Result<(), GpuError> {
        assert!(n_chunks <= self.n_chunks && chunk > 0, "indirect arguments: {n_chunks} chunks of room {}", self.n_chunks);
        let gpu = enc.gpu();
        let kernel = gpu.kernel(&INDIRECT)?;
        let p = IndirectParams { cap, chunk, n_chunks, max_per_dim: gpu.limits().max_compute_workgroups_per_dimension };
        let params = enc.params(&p);
        enc.dispatch_threads(&kernel, &[&params, count, &self.buffer], n_chunks);
        Ok(())
    }

    /// Dispatches `kernel` with the arguments of chunk `k` (written by [`Self::record`]
    /// earlier in the same encoder).
    pub fn dispatch(&self, enc: &mut Encoder, kernel: &Kernel, resources: &[&dyn BindResource], k: u32) {
        assert!(k < self.n_chunks, "indirect arguments: chunk {k} of {}", self.n_chunks);
        enc.dispatch_indirect(kernel, resources, &self.buffer, 12 * k as u64);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::{test_gpu, GpuBuffer};

    #[test]
    fn arguments_cover_the_counted_items_of_each_chunk() {
        let gpu = test_gpu(false);
        let max = gpu.limits().max_compute_workgroups_per_dimension;
        for (count, cap, chunk, n_chunks) in [(1000u32, 5000u32, 300u32, 4u32), (0, 100, 64, 2), (70_000, 60_000, 1 << 16, 1), (u32::MAX, 64 * max + 65, u32::MAX, 1)] {
            let count_buf = GpuBuffer::from_slice(&gpu, "count", &[count, 0]).unwrap();
            let args = IndirectArgs::new(&gpu, n_chunks);
            let mut enc = gpu.encoder();
            args.record(&mut enc, &count_buf.buffer, cap, chunk, n_chunks).unwrap();
            let out = GpuBuffer::<u32>::zeros(&gpu, "out", 3 * n_chunks as usize).unwrap();
            enc.copy(&args.buffer, &out.buffer, 12 * n_chunks as u64);
            enc.submit();
            let got = out.read(&gpu).unwrap();
            let total = count.min(cap);
            for k in 0..n_chunks {
                let start = (k as u64 * chunk as u64).min(total as u64) as u32;
                let threads = (total - start).min(chunk);
                let want = crate::gpu::kernel::grid_1d(threads, max);
                let want = if threads == 0 { [0, 1, 1] } else { want };
                assert_eq!(&got[3 * k as usize..3 * k as usize + 3], &want, "count {count} cap {cap} chunk {chunk} k {k}");
            }
        }
    }
}

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(IndirectParams, "gpu/indirect.wgsl", "IndirectParams", [cap, chunk, n_chunks, max_per_dim]);
    }
}
