//! Per-kernel timing, for `edgenerf speed --kernels`: which kernels a step's GPU time
//! goes to on the adapter in use.
//!
//! With timing on ([`super::Gpu::set_kernel_timing`]) every [`super::Encoder`] submits
//! what it recorded before a dispatch and waits for it (not charged), then records the
//! dispatch alone in a compute pass of its own, submits it and waits. What is charged
//! to the kernel (`file:entry`):
//! * where the adapter has `TIMESTAMP_QUERY` (NVIDIA, lavapipe): the GPU time between
//!   the pass's beginning and end timestamps ([`GpuTimer`]), the kernel's execution
//!   alone. On an H200 a submission and its wait cost 70-100 us, more than most of the
//!   step's kernels run, so wall time there measured launches (docs/journal.md, "On an H200: the
//!   weight gradients in one launch").
//! * otherwise: the wall time since the dispatch began recording, which includes its
//!   bind group, one submit and one wait.
//!
//! The waits serialize the step, so timed steps are slower than plain ones.
//!
//! Invariant: timing changes no result, only when the host waits (the same commands run
//! in the same order, in more submissions).

use std::collections::HashMap;
use std::time::Duration;

use super::{Gpu, GpuBuffer, GpuError};

/// Two timestamp queries (a timed pass's beginning and end), the buffer they resolve
/// into (`QUERY_RESOLVE`, which a [`GpuBuffer`] has not) and a [`GpuBuffer`] copy of it
/// that the ordinary readback reads.
pub(crate) struct GpuTimer {
    pub(crate) queries: wgpu::QuerySet,
    resolved: wgpu::Buffer,
    ticks: GpuBuffer<u64>,
}

impl GpuTimer {
    pub(crate) fn new(gpu: &Gpu) -> Result<Self, GpuError> {
        let device = &gpu.device;
        Ok(GpuTimer {
            queries: device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("kernel timer"),
                ty: wgpu::QueryType::Timestamp,
                count: 2,
            }),
            resolved: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("kernel timer resolved"),
                size: 16,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            }),
            ticks: GpuBuffer::zeros(gpu, "kernel timer ticks", 2)?,
        })
    }

    /// The timestamps a timed pass writes into `queries`: 0 at its beginning, 1 at its end.
    pub(crate) fn pass_writes(queries: &wgpu::QuerySet) -> wgpu::ComputePassTimestampWrites<'_> {
        wgpu::ComputePassTimestampWrites {
            query_set: queries,
            beginning_of_pass_write_index: Some(0),
            end_of_pass_write_index: Some(1),
        }
    }

    /// Records the resolve of both queries and their copy into `ticks`.
    pub(crate) fn record_resolve(&self, encoder: &mut wgpu::CommandEncoder) {
        encoder.resolve_query_set(&self.queries, 0..2, &self.resolved, 0);
        encoder.copy_buffer_to_buffer(&self.resolved, 0, &self.ticks.buffer, 0, 16);
    }

    /// The time between the two timestamps, read back after the submission holding
    /// [`Self::record_resolve`].
    pub(crate) fn elapsed(&self, gpu: &Gpu) -> Result<Duration, GpuError> {
        let ticks = self.ticks.read(gpu)?;
        let ns = ticks[1].saturating_sub(ticks[0]) as f64 * gpu.queue.get_timestamp_period() as f64;
        Ok(Duration::from_nanos(ns as u64))
    }
}

/// Accumulated time and dispatch count per kernel since timing was switched on.
#[derive(Clone, Debug, Default)]
pub struct KernelTimes {
    by_kernel: HashMap<String, (Duration, u64)>,
}

/// One kernel's total: `file:entry`, seconds and dispatches.
#[derive(Clone, Debug, PartialEq)]
pub struct KernelTotal {
    pub kernel: String,
    pub seconds: f64,
    pub dispatches: u64,
}

impl KernelTimes {
    /// Adds one dispatch of `kernel` that took `elapsed`.
    pub(super) fn charge(&mut self, kernel: &str, elapsed: Duration) {
        let entry = self.by_kernel.entry(kernel.to_string()).or_default();
        entry.0 += elapsed;
        entry.1 += 1;
    }

    /// Every kernel timed, the slowest first (ties by name).
    pub fn totals(&self) -> Vec<KernelTotal> {
        let mut v: Vec<KernelTotal> = self
            .by_kernel
            .iter()
            .map(|(k, &(d, n))| KernelTotal { kernel: k.clone(), seconds: d.as_secs_f64(), dispatches: n })
            .collect();
        v.sort_by(|a, b| b.seconds.total_cmp(&a.seconds).then_with(|| a.kernel.cmp(&b.kernel)));
        v
    }

    /// The sum over every kernel, in seconds.
    pub fn total_seconds(&self) -> f64 {
        self.by_kernel.values().map(|(d, _)| d.as_secs_f64()).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn totals_add_up_per_kernel_slowest_first() {
        let mut t = KernelTimes::default();
        t.charge("a.wgsl:x", Duration::from_millis(2));
        t.charge("b.wgsl:y", Duration::from_millis(5));
        t.charge("a.wgsl:x", Duration::from_millis(4));
        let totals = t.totals();
        assert_eq!(totals.iter().map(|k| k.kernel.as_str()).collect::<Vec<_>>(), ["a.wgsl:x", "b.wgsl:y"]);
        assert_eq!(totals[0].dispatches, 2);
        assert!((totals[0].seconds - 0.006).abs() < 1e-9);
        assert!((t.total_seconds() - 0.011).abs() < 1e-9);
    }

    #[test]
    fn timing_changes_no_result_and_counts_each_dispatch() {
        use crate::gpu::{Gpu, GpuOptions, selftest::scatter_add};
        // A context of its own: timing is per context, and the shared test context
        // serves tests running beside this one.
        let gpu = Gpu::new(&GpuOptions::default()).expect("tests need a Vulkan device");
        let values: Vec<f32> = (0..5000).map(|i| (i % 13) as f32 - 6.0).collect();
        let plain = scatter_add(&gpu, &values, 5, 0.5).unwrap();
        assert!(gpu.kernel_times().is_none());
        gpu.set_kernel_timing(true);
        let started = std::time::Instant::now();
        let timed = scatter_add(&gpu, &values, 5, 0.5).unwrap();
        let wall = started.elapsed().as_secs_f64();
        let times = gpu.kernel_times().expect("timing is on");
        gpu.set_kernel_timing(false);
        assert_eq!(plain.scaled, timed.scaled);
        // Small integers: the atomic sums are exact in any order.
        assert_eq!(plain.sums, timed.sums);
        let totals = times.totals();
        assert_eq!(totals.len(), 1, "{totals:?}");
        assert_eq!((totals[0].kernel.as_str(), totals[0].dispatches), ("gpu/roundtrip.wgsl:scatter_add", 1));
        // With timestamps the kernel's GPU time, inside the call's wall time.
        assert!(totals[0].seconds > 0.0 && totals[0].seconds < wall, "{} s of {wall} s", totals[0].seconds);
        assert!(gpu.kernel_times().is_none());
    }
}
