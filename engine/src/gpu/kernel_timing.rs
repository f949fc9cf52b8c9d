//! Per-kernel timing, for `edgenerf speed --kernels`: which kernels a step's GPU time
//! goes to on the adapter in use.
//!
//! With timing on ([`super::Gpu::set_kernel_timing`]) every [`super::Encoder`] submits
//! what it recorded before a dispatch and waits for it (not charged), then records the
//! dispatch alone, submits it, waits, and charges the wall time since the dispatch began
//! recording to the kernel (`file:entry`). Each figure therefore includes the kernel's
//! bind group, one submit and one wait, which is what a kernel costs when nothing
//! overlaps it; the waits serialize the step, so timed steps are slower than plain ones.
//!
//! Invariant: timing changes no result, only when the host waits (the same commands run
//! in the same order, in more submissions).

use std::collections::HashMap;
use std::time::Duration;

/// Accumulated wall time and dispatch count per kernel since timing was switched on.
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
        let timed = scatter_add(&gpu, &values, 5, 0.5).unwrap();
        let times = gpu.kernel_times().expect("timing is on");
        gpu.set_kernel_timing(false);
        assert_eq!(plain.scaled, timed.scaled);
        // Small integers: the atomic sums are exact in any order.
        assert_eq!(plain.sums, timed.sums);
        let totals = times.totals();
        assert_eq!(totals.len(), 1, "{totals:?}");
        assert_eq!((totals[0].kernel.as_str(), totals[0].dispatches), ("gpu/roundtrip.wgsl:scatter_add", 1));
        assert!(totals[0].seconds > 0.0);
        assert!(gpu.kernel_times().is_none());
    }
}
