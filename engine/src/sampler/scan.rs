//! Exclusive prefix sum of `u32` on the GPU, for sample compaction.
//!
//! Owner of `kernels/sampler/scan.wgsl`. Each workgroup scans a block of
//! [`SCAN_BLOCK`] elements (4 per thread, 256 threads); the block totals are scanned
//! by the same kernel one level up (recursively, so any length works: three levels
//! cover 2^30 elements) and added back. No atomics, no subgroup operations: the
//! offsets are exact and the same on every device, unlike atomic slot allocation.
//!
//! Invariant: `output[i] = input[0] + ... + input[i - 1]` (wrapping `u32`), for
//! `i < n`; `output[0] = 0`.

use crate::gpu::{Binding, Encoder, Gpu, GpuBuffer, KernelSpec};

use super::{SamplerError, fold_groups};

/// Elements scanned per workgroup.
pub const SCAN_BLOCK: u32 = 1024;

const SCAN_BLOCKS: KernelSpec = KernelSpec {
    file: "sampler/scan.wgsl",
    entry: "scan_blocks",
    bindings: &[Binding::Params, Binding::ReadOnly, Binding::ReadWrite, Binding::ReadWrite],
};

const ADD_OFFSETS: KernelSpec = KernelSpec {
    file: "sampler/scan.wgsl",
    entry: "add_block_offsets",
    bindings: &[Binding::Params, Binding::ReadWrite, Binding::ReadOnly],
};

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    n: u32,
    n_blocks: u32,
    _pad: [u32; 2],
}

/// One level above the input: the block totals and their scan.
struct Level {
    sums: GpuBuffer<u32>,
    scanned: GpuBuffer<u32>,
}

/// A scan of up to `max_len` elements with its scratch buffers.
pub struct ExclusiveScan {
    max_len: u32,
    levels: Vec<Level>,
}

impl ExclusiveScan {
    /// Allocates the block-total buffers for inputs of up to `max_len` elements.
    pub fn new(gpu: &Gpu, max_len: u32) -> Result<Self, SamplerError> {
        let mut levels = Vec::new();
        let mut n = max_len;
        loop {
            let blocks = n.div_ceil(SCAN_BLOCK).max(1);
            levels.push(Level {
                sums: GpuBuffer::zeros(gpu, "scan block sums", blocks as usize)?,
                scanned: GpuBuffer::zeros(gpu, "scan block offsets", blocks as usize)?,
            });
            if blocks <= 1 {
                break;
            }
            n = blocks;
        }
        Ok(Self { max_len, levels })
    }

    /// Largest input this scan was allocated for.
    pub fn max_len(&self) -> u32 {
        self.max_len
    }

    /// Records the scan of `input[..n]` into `output[..n]` (`n <= max_len`).
    pub fn encode(
        &self,
        gpu: &Gpu,
        enc: &mut Encoder<'_>,
        input: &GpuBuffer<u32>,
        output: &GpuBuffer<u32>,
        n: u32,
    ) -> Result<(), SamplerError> {
        assert!(n <= self.max_len, "scan of {n} elements with room for {}", self.max_len);
        assert!(input.len() >= n as usize && output.len() >= n as usize, "scan buffers shorter than {n}");
        self.encode_level(gpu, enc, 0, &input.buffer, &output.buffer, n)
    }

    fn encode_level(
        &self,
        gpu: &Gpu,
        enc: &mut Encoder<'_>,
        level: usize,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        n: u32,
    ) -> Result<(), SamplerError> {
        if n == 0 {
            return Ok(());
        }
        let blocks = n.div_ceil(SCAN_BLOCK);
        let lv = &self.levels[level];
        let params = enc.params(&Params { n, n_blocks: blocks, _pad: [0; 2] });
        let scan = gpu.kernel(&SCAN_BLOCKS)?;
        enc.dispatch(&scan, &[&params, input, output, &lv.sums.buffer], fold_groups(gpu, blocks));
        if blocks > 1 {
            self.encode_level(gpu, enc, level + 1, &lv.sums.buffer, &lv.scanned.buffer, blocks)?;
            let add = gpu.kernel(&ADD_OFFSETS)?;
            enc.dispatch(&add, &[&params, output, &lv.scanned.buffer], fold_groups(gpu, blocks));
        }
        Ok(())
    }

    /// Uploads `values`, scans them and reads the result back (tests, tools).
    pub fn run(gpu: &Gpu, values: &[u32]) -> Result<Vec<u32>, SamplerError> {
        let n = values.len() as u32;
        let scan = Self::new(gpu, n)?;
        let input = GpuBuffer::from_slice(gpu, "scan input", values)?;
        let output = GpuBuffer::<u32>::zeros(gpu, "scan output", values.len())?;
        let mut enc = gpu.encoder();
        scan.encode(gpu, &mut enc, &input, &output, n)?;
        enc.submit();
        Ok(output.read(gpu)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cpu_exclusive(values: &[u32]) -> Vec<u32> {
        let mut s = 0u32;
        values
            .iter()
            .map(|&v| {
                let o = s;
                s = s.wrapping_add(v);
                o
            })
            .collect()
    }

    #[test]
    fn sampler_scan_matches_cpu_on_awkward_sizes() {
        let gpu = crate::gpu::test_gpu(false);
        // Around the block size, around one and two full levels, and a three-level size.
        let sizes = [0usize, 1, 2, 255, 256, 1023, 1024, 1025, 4097, 1024 * 1024, 1024 * 1024 + 3];
        for &n in &sizes {
            let values: Vec<u32> = (0..n as u32).map(|i| (i.wrapping_mul(2654435761) >> 24) % 37).collect();
            let got = ExclusiveScan::run(&gpu, &values).unwrap();
            assert_eq!(got.len(), n);
            if let Some(i) = got.iter().zip(cpu_exclusive(&values)).position(|(a, b)| *a != b) {
                panic!("size {n}: first mismatch at {i}: {} vs {}", got[i], cpu_exclusive(&values)[i]);
            }
        }
    }

    #[test]
    fn sampler_scan_reuses_buffers_for_shorter_inputs() {
        let gpu = crate::gpu::test_gpu(false);
        let scan = ExclusiveScan::new(&gpu, 5000).unwrap();
        for n in [5000u32, 3000, 1024, 7] {
            let values: Vec<u32> = (0..n).map(|i| i % 5 + 1).collect();
            let input = GpuBuffer::from_slice(&gpu, "in", &values).unwrap();
            let output = GpuBuffer::<u32>::zeros(&gpu, "out", n as usize).unwrap();
            let mut enc = gpu.encoder();
            scan.encode(&gpu, &mut enc, &input, &output, n).unwrap();
            enc.submit();
            assert_eq!(output.read(&gpu).unwrap(), cpu_exclusive(&values), "n = {n}");
        }
    }
}

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(Params, "sampler/scan.wgsl", "Params", [n, n_blocks]);
    }
}
