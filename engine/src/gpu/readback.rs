//! Batched readbacks: several buffers copied to the host with one submission, one map
//! and one wait, instead of one of each per buffer.
//!
//! A training step reads its losses, the sampler's counts and the dropped-ray count
//! together ([`ReadBatch`]); on a GPU each separate readback is a round trip that
//! drains the queue, so the step waits once instead of once per value.
//!
//! A batch can also go out at the end of a caller's encoder ([`ReadBatch::read_after`],
//! a training step's one submission) or be waited for later
//! ([`ReadBatch::submit_after`] -> [`PendingRead::wait`]): a run submits step N, then
//! waits for step N-1's values while the GPU runs step N.
//!
//! Invariants: a batch reads what every earlier submission, and what its encoder
//! recorded before it, wrote (its copies are queued after them), exactly as
//! [`GpuBuffer::read`], which is a batch of one; the values come back bit for bit, in
//! the order of [`ReadBatch::add`]. [`PendingRead::wait`] waits for the batch's own
//! submission only (and so for the earlier ones), not for later ones.

use std::marker::PhantomData;

use super::{Encoder, Gpu, GpuBuffer, GpuError};

/// Buffers (their first elements) to read back together.
#[derive(Default)]
pub struct ReadBatch<'a> {
    parts: Vec<(&'a wgpu::Buffer, u64)>,
}

/// Where one buffer's values are in a [`ReadBack`]: `len` elements of type `T`.
#[derive(Debug)]
pub struct ReadSlot<T> {
    index: usize,
    len: usize,
    _values: PhantomData<T>,
}

/// The host copy of a [`ReadBatch`].
pub struct ReadBack {
    bytes: Vec<u8>,
    /// Byte range of each part in `bytes`.
    ranges: Vec<std::ops::Range<usize>>,
}

impl<'a> ReadBatch<'a> {
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds the first `len` elements of `buffer` (at most its length) to the batch.
    pub fn add<T: bytemuck::Pod>(&mut self, buffer: &'a GpuBuffer<T>, len: usize) -> ReadSlot<T> {
        assert!(len <= buffer.len(), "readback of {len} elements from a buffer of {}", buffer.len());
        self.parts.push((&buffer.buffer, (len * std::mem::size_of::<T>()) as u64));
        ReadSlot { index: self.parts.len() - 1, len, _values: PhantomData }
    }

    /// Copies every part into one staging buffer, submits, and waits for the GPU.
    pub fn read(self, gpu: &Gpu) -> Result<ReadBack, GpuError> {
        self.read_after(gpu.encoder())
    }

    /// [`ReadBatch::read`] at the end of `enc`: the copies are recorded after what
    /// `enc` holds and go out in its one submission (a training step's only one).
    pub fn read_after(self, enc: Encoder) -> Result<ReadBack, GpuError> {
        let gpu = enc.gpu();
        self.submit_after(enc).wait(gpu)
    }

    /// Records the copies at the end of `enc` and submits it, without waiting: the
    /// values are read by [`PendingRead::wait`], e.g. after the host has recorded and
    /// submitted the next training step (a readback deferred by a step).
    pub fn submit_after(self, mut enc: Encoder) -> PendingRead {
        let gpu = enc.gpu();
        let mut ranges = Vec::with_capacity(self.parts.len());
        let mut total = 0u64;
        for (_, bytes) in &self.parts {
            // Every element type is a whole number of 4-byte words (the copy alignment).
            debug_assert_eq!(bytes % wgpu::COPY_BUFFER_ALIGNMENT, 0);
            ranges.push(total as usize..(total + bytes) as usize);
            total += bytes;
        }
        if total == 0 {
            enc.submit();
            return PendingRead { staging: None, ranges };
        }
        let staging = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: total,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        for ((buffer, bytes), range) in self.parts.iter().zip(&ranges) {
            if *bytes > 0 {
                enc.copy_at(buffer, &staging, range.start as u64, *bytes);
            }
        }
        let submission = enc.submit();
        let (tx, rx) = std::sync::mpsc::channel();
        staging.slice(..).map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        PendingRead { staging: Some((staging, submission, rx)), ranges }
    }
}

/// A [`ReadBatch`] submitted and not yet read ([`ReadBatch::submit_after`]).
pub struct PendingRead {
    /// The staging buffer, the submission that fills it, and its map's result (`None`:
    /// nothing to read).
    staging: Option<(wgpu::Buffer, wgpu::SubmissionIndex, MapResult)>,
    ranges: Vec<std::ops::Range<usize>>,
}

type MapResult = std::sync::mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>;

impl PendingRead {
    /// Waits for the submission that holds the copies (and so for every earlier one;
    /// later submissions may still run) and returns the values.
    pub fn wait(self, gpu: &Gpu) -> Result<ReadBack, GpuError> {
        let Some((staging, submission, mapped)) = self.staging else {
            return Ok(ReadBack { bytes: Vec::new(), ranges: self.ranges });
        };
        gpu.wait_for(submission)?;
        mapped
            .recv()
            .map_err(|e| GpuError::Readback(e.to_string()))?
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        let slice = staging.slice(..);
        let view = slice.get_mapped_range().map_err(|e| GpuError::Readback(e.to_string()))?;
        let bytes = view.to_vec();
        drop(view);
        staging.unmap();
        Ok(ReadBack { bytes, ranges: self.ranges })
    }
}

impl ReadBack {
    /// The values of `slot`'s part.
    pub fn get<T: bytemuck::Pod>(&self, slot: &ReadSlot<T>) -> Vec<T> {
        let bytes = &self.bytes[self.ranges[slot.index].clone()];
        let values: Vec<T> = bytes.chunks_exact(std::mem::size_of::<T>()).map(bytemuck::pod_read_unaligned).collect();
        debug_assert_eq!(values.len(), slot.len);
        values
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::test_gpu;

    /// Parts of different types and lengths (a prefix, an empty one, a whole buffer)
    /// come back in order, bit for bit, after the writes submitted before the batch.
    #[test]
    fn a_batch_reads_every_part_after_earlier_writes() {
        let gpu = test_gpu(false);
        let floats = GpuBuffer::from_slice(&gpu, "floats", &[1.5f32, -2.0, f32::MIN_POSITIVE, 7.0]).unwrap();
        let words = GpuBuffer::<u32>::zeros(&gpu, "words", 3).unwrap();
        words.write(&gpu, &[9, u32::MAX, 4]);
        let pairs = GpuBuffer::from_slice(&gpu, "pairs", &[[0.25f32, 0.5], [3.0, -0.0]]).unwrap();
        let mut batch = ReadBatch::new();
        let a = batch.add(&floats, 3);
        let none = batch.add(&words, 0);
        let b = batch.add(&words, 3);
        let c = batch.add(&pairs, 2);
        let back = batch.read(&gpu).unwrap();
        assert_eq!(back.get(&a), vec![1.5, -2.0, f32::MIN_POSITIVE]);
        assert!(back.get(&none).is_empty());
        assert_eq!(back.get(&b), vec![9, u32::MAX, 4]);
        let p = back.get(&c);
        assert_eq!(p[0], [0.25, 0.5]);
        assert_eq!(p[1][0], 3.0);
        assert!(p[1][1] == 0.0 && p[1][1].is_sign_negative());
        assert!(ReadBatch::new().read(&gpu).unwrap().bytes.is_empty());
    }

    /// A batch submitted at the end of an encoder and waited for later returns the
    /// values as of its place in the queue: what its encoder wrote before it, not what
    /// a later submission (already queued when it is waited for) overwrites.
    #[test]
    fn a_pending_read_returns_the_values_at_its_place_in_the_queue() {
        let gpu = test_gpu(false);
        let values = GpuBuffer::from_slice(&gpu, "values", &[1u32, 2, 3, 4]).unwrap();
        let copy = GpuBuffer::<u32>::zeros(&gpu, "copy", 4).unwrap();
        let mut enc = gpu.encoder();
        enc.copy(&values.buffer, &copy.buffer, 16);
        let mut batch = ReadBatch::new();
        let slot = batch.add(&copy, 4);
        let pending = batch.submit_after(enc);
        let mut later = gpu.encoder();
        later.clear(&copy.buffer);
        later.submit();
        assert_eq!(pending.wait(&gpu).unwrap().get(&slot), vec![1, 2, 3, 4]);
        assert_eq!(copy.read(&gpu).unwrap(), vec![0; 4], "the later clear ran too");
    }
}
