//! Runtime self-test: a scatter-add through the float-atomic path in use, run by the
//! tests on both paths and by `edgenerf info --check` on the user's adapter.
//!
//! Owner of `kernels/gpu/roundtrip.wgsl`.

use super::{Binding, Gpu, GpuBuffer, GpuError, KernelSpec};

pub(crate) const SPEC: KernelSpec = KernelSpec {
    file: "gpu/roundtrip.wgsl",
    entry: "scatter_add",
    bindings: &[Binding::Params, Binding::ReadOnly, Binding::ReadWrite, Binding::ReadWrite],
};

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct Params {
    pub n: u32,
    pub bins: u32,
    pub scale: f32,
    pub _pad: u32,
}

/// Result of [`scatter_add`]: the GPU's outputs for comparison with a CPU reference.
pub struct ScatterAdd {
    pub scaled: Vec<f32>,
    pub sums: Vec<f32>,
}

/// Uploads `values`, writes `values * scale` and adds value `i` into bin `i % bins`
/// with float atomics, and reads both results back.
pub fn scatter_add(gpu: &Gpu, values: &[f32], bins: u32, scale: f32) -> Result<ScatterAdd, GpuError> {
    let kernel = gpu.kernel(&SPEC)?;
    let input = GpuBuffer::from_slice(gpu, "values", values)?;
    let scaled = GpuBuffer::<f32>::zeros(gpu, "scaled", values.len())?;
    // Zero bits are 0.0 on both atomic paths.
    let sums = GpuBuffer::<f32>::zeros(gpu, "sums", bins as usize)?;
    let mut enc = gpu.encoder();
    let params = enc.params(&Params { n: values.len() as u32, bins, scale, _pad: 0 });
    enc.dispatch_threads(&kernel, &[&params, &input.buffer, &scaled.buffer, &sums.buffer], values.len() as u32);
    enc.submit();
    Ok(ScatterAdd { scaled: scaled.read(gpu)?, sums: sums.read(gpu)? })
}

/// Runs [`scatter_add`] on a fixed input and checks it against the CPU; returns a
/// description of the first mismatch.
pub fn check(gpu: &Gpu) -> Result<(), String> {
    let values: Vec<f32> = (0..10_000).map(|i| ((i * 37) % 101) as f32 * 0.25 - 3.0).collect();
    let bins = 7u32;
    let out = scatter_add(gpu, &values, bins, 2.0).map_err(|e| e.to_string())?;
    for (i, (&v, &s)) in values.iter().zip(&out.scaled).enumerate() {
        if s != v * 2.0 {
            return Err(format!("element {i}: {s} != {}", v * 2.0));
        }
    }
    let mut expect = vec![0.0f64; bins as usize];
    for (i, v) in values.iter().enumerate() {
        expect[i % bins as usize] += *v as f64;
    }
    for (b, (&got, &want)) in out.sums.iter().zip(&expect).enumerate() {
        if (got as f64 - want).abs() > 1e-3 * want.abs().max(1.0) {
            return Err(format!("bin {b}: atomic sum {got} != {want}"));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(disable_float_atomics: bool) {
        let gpu = super::super::test_gpu(disable_float_atomics);
        assert_eq!(gpu.float_atomics(), !disable_float_atomics && gpu.float_atomics());
        check(&gpu).unwrap();
        // More threads than fit one grid dimension: exercises the 2-D fold.
        let n = 64 * 70_000;
        let values = vec![1.0f32; n];
        let out = scatter_add(&gpu, &values, 3, 1.0).unwrap();
        assert_eq!(out.scaled.len(), n);
        assert!(out.scaled.iter().all(|&v| v == 1.0));
        let total: f32 = out.sums.iter().sum();
        assert_eq!(total as usize, n, "every thread added exactly once");
    }

    #[test]
    fn roundtrip_native_float_atomics() {
        let gpu = super::super::test_gpu(false);
        if !gpu.float_atomics() {
            eprintln!("adapter {} lacks SHADER_FLOAT32_ATOMIC; native path not testable here", gpu.adapter().name);
        }
        run(false);
    }

    #[test]
    fn roundtrip_compare_exchange_fallback() {
        let gpu = super::super::test_gpu(true);
        assert!(!gpu.float_atomics());
        run(true);
    }
}

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(Params, "gpu/roundtrip.wgsl", "Params", [n, bins, scale]);
    }
}
