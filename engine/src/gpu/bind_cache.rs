//! Bind groups kept across dispatches: a training step binds the same buffers to the
//! same kernels every step, so its bind groups are made once and reused.
//!
//! Owns [`BindGroupCache`], held by [`Gpu`](super::Gpu) for it and its clones. A bind
//! group is looked up by its layout and, per binding, the buffer, offset and size it
//! binds. A dispatch's parameters ([`Params`](super::Params)) are bound with a dynamic
//! offset (the layout's [`Binding::Params`](super::Binding::Params) entries), so the
//! same arena buffer at different offsets is one bind group.
//!
//! Invariants:
//! * An entry holds clones of its layout and buffers (the key) and the bind group, so a
//!   key never names a buffer that was dropped and replaced by another at the same
//!   address: while the entry lives its buffers live.
//! * Entries not used by a dispatch recorded in the last [`KEEP_SUBMISSIONS`]
//!   submissions are dropped at the next submission ([`BindGroupCache::sweep`]), so a
//!   buffer the engine dropped is released after at most that many submissions, and
//!   the cache holds only what the recent steps bound (training memory stays flat).
//! * Reusing a bind group changes no result: it binds the same buffer ranges a new
//!   one would. A bind group a recorded pass holds stays valid when its entry is
//!   dropped (wgpu keeps it alive until the submission is done).
//!
//! Why: creating a bind group per dispatch was 17 % of the main thread's time in a
//! lavapipe training step (`perf`, 2026-11-27; docs/journal.md, "Bind groups kept across
//! steps"), and the host's own work is most of a training step on an H200.

use std::collections::HashMap;
use std::hash::{Hash, Hasher};
use std::num::NonZeroU64;

use super::kernel::BindResource;

/// Submissions an unused entry survives (see the module doc). A training step is one
/// submission, and every sixteenth step adds the occupancy update's.
pub const KEEP_SUBMISSIONS: u64 = 2;

/// What a binding binds: the buffer, the offset and the size (`None`: to its end).
#[derive(Clone, PartialEq, Eq, Hash)]
struct BoundRange {
    buffer: wgpu::Buffer,
    offset: u64,
    size: Option<NonZeroU64>,
}

struct Entry {
    layout: wgpu::BindGroupLayout,
    ranges: Vec<BoundRange>,
    group: wgpu::BindGroup,
    /// The submission count when a dispatch last used it.
    used: u64,
}

impl Entry {
    fn matches(&self, layout: &wgpu::BindGroupLayout, resources: &[&dyn BindResource]) -> bool {
        self.layout == *layout
            && self.ranges.len() == resources.len()
            && self.ranges.iter().zip(resources).all(|(r, res)| {
                let (buffer, offset, size) = res.bound_range();
                r.buffer == *buffer && r.offset == offset && r.size == size
            })
    }
}

/// The bind groups of recent dispatches (module doc).
#[derive(Default)]
pub struct BindGroupCache {
    /// Entries by the hash of their key; a bucket holds the rare collisions.
    buckets: HashMap<u64, Vec<Entry>>,
    /// Bind groups created so far (what the tests count).
    created: u64,
}

fn key_hash(layout: &wgpu::BindGroupLayout, resources: &[&dyn BindResource]) -> u64 {
    let mut h = std::collections::hash_map::DefaultHasher::new();
    layout.hash(&mut h);
    for res in resources {
        let (buffer, offset, size) = res.bound_range();
        buffer.hash(&mut h);
        offset.hash(&mut h);
        size.hash(&mut h);
    }
    h.finish()
}

impl BindGroupCache {
    /// The bind group of `resources` (`resources[i]` at binding `i`) for `layout`:
    /// the cached one, or a new one made with `device`. `submissions` is the context's
    /// submission count (what [`BindGroupCache::sweep`] ages entries by).
    pub fn get(
        &mut self,
        device: &wgpu::Device,
        label: &str,
        layout: &wgpu::BindGroupLayout,
        resources: &[&dyn BindResource],
        submissions: u64,
    ) -> wgpu::BindGroup {
        let bucket = self.buckets.entry(key_hash(layout, resources)).or_default();
        if let Some(entry) = bucket.iter_mut().find(|e| e.matches(layout, resources)) {
            entry.used = submissions;
            return entry.group.clone();
        }
        let entries: Vec<_> = resources
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry { binding: i as u32, resource: b.binding() })
            .collect();
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor { label: Some(label), layout, entries: &entries });
        let ranges = resources
            .iter()
            .map(|res| {
                let (buffer, offset, size) = res.bound_range();
                BoundRange { buffer: buffer.clone(), offset, size }
            })
            .collect();
        bucket.push(Entry { layout: layout.clone(), ranges, group: group.clone(), used: submissions });
        self.created += 1;
        group
    }

    /// Drops the entries no dispatch has used since submission `submissions -
    /// KEEP_SUBMISSIONS` (called at each submission with the new count).
    pub fn sweep(&mut self, submissions: u64) {
        let oldest = submissions.saturating_sub(KEEP_SUBMISSIONS);
        self.buckets.retain(|_, bucket| {
            bucket.retain(|e| e.used >= oldest);
            !bucket.is_empty()
        });
    }

    /// Entries held.
    pub fn len(&self) -> usize {
        self.buckets.values().map(Vec::len).sum()
    }

    /// Whether no entry is held.
    pub fn is_empty(&self) -> bool {
        self.buckets.is_empty()
    }

    /// Bind groups created so far.
    pub fn created(&self) -> u64 {
        self.created
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::{test_gpu, GpuBuffer};

    /// A bind group is reused for the same buffer ranges, whatever the arena offset of
    /// the parameters; another buffer makes another; an entry unused for more than
    /// `KEEP_SUBMISSIONS` submissions is dropped at the next sweep, a used one kept.
    #[test]
    fn bind_groups_are_reused_by_range_and_dropped_when_unused() {
        let gpu = test_gpu(false);
        let storage = |binding, read_only, dynamic| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only },
                has_dynamic_offset: dynamic,
                min_binding_size: None,
            },
            count: None,
        };
        let layout = gpu.device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("bind cache test"),
            entries: &[storage(0, true, true), storage(1, false, false)],
        });
        let [b, c] = [0, 1].map(|_| GpuBuffer::<f32>::zeros(&gpu, "bound", 16).unwrap());
        let mut enc = gpu.encoder();
        let (p1, p2) = (enc.params(&[1u32; 4]), enc.params(&[2u32; 4]));
        assert_ne!(p1.dynamic_offset(), p2.dynamic_offset(), "two ranges of one arena buffer");
        let mut cache = BindGroupCache::default();
        let first = cache.get(&gpu.device, "t", &layout, &[&p1, &b.buffer], 0);
        let again = cache.get(&gpu.device, "t", &layout, &[&p2, &b.buffer], 0);
        assert_eq!(first, again, "the parameters' offset is dynamic: one bind group");
        assert_eq!(cache.created(), 1);
        let other = cache.get(&gpu.device, "t", &layout, &[&p1, &c.buffer], 0);
        assert_ne!(first, other);
        assert_eq!((cache.created(), cache.len()), (2, 2));

        // Submission 1 uses only the first; by submission KEEP + 1 the second is stale.
        cache.get(&gpu.device, "t", &layout, &[&p1, &b.buffer], 1);
        cache.sweep(KEEP_SUBMISSIONS);
        assert_eq!(cache.len(), 2, "unused for {KEEP_SUBMISSIONS} submissions: kept");
        cache.sweep(KEEP_SUBMISSIONS + 1);
        assert_eq!(cache.len(), 1, "unused for more: dropped");
        cache.get(&gpu.device, "t", &layout, &[&p2, &b.buffer], KEEP_SUBMISSIONS + 1);
        assert_eq!(cache.created(), 2, "the kept one is still reused");
        cache.sweep(3 * KEEP_SUBMISSIONS + 2);
        assert!(cache.is_empty());
        drop(enc);
    }
}
