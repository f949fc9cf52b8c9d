//! Typed storage buffers: upload, zero-fill, overwrite and read back `Pod` data.
//!
//! Invariant: a [`GpuBuffer<T>`] holds exactly `len` elements of `T`, its usage always
//! includes `STORAGE | COPY_SRC | COPY_DST`, and its size is checked against the
//! device's storage binding limit at creation (a clear error instead of a
//! validation panic deep inside a dispatch).

use std::marker::PhantomData;

use bytemuck::Pod;
use wgpu::util::DeviceExt;

use super::{Gpu, GpuError};

/// A storage buffer of `len` elements of `T`.
pub struct GpuBuffer<T: Pod> {
    pub buffer: wgpu::Buffer,
    len: usize,
    _marker: PhantomData<T>,
}

const USAGE: wgpu::BufferUsages = wgpu::BufferUsages::STORAGE
    .union(wgpu::BufferUsages::COPY_SRC)
    .union(wgpu::BufferUsages::COPY_DST);

impl<T: Pod> GpuBuffer<T> {
    fn check_size(gpu: &Gpu, label: &str, len: usize) -> Result<u64, GpuError> {
        let bytes = (len.max(1) * std::mem::size_of::<T>()) as u64;
        let limit = gpu.limits().max_storage_buffer_binding_size as u64;
        if bytes > limit {
            return Err(GpuError::BufferTooLarge { label: label.to_string(), bytes, limit });
        }
        Ok(bytes)
    }

    /// Uploads `data` into a new buffer.
    pub fn from_slice(gpu: &Gpu, label: &str, data: &[T]) -> Result<Self, GpuError> {
        Self::check_size(gpu, label, data.len())?;
        // Zero-length bindings are invalid: keep at least one element of storage.
        let placeholder = [T::zeroed()];
        let contents: &[T] = if data.is_empty() { &placeholder } else { data };
        let buffer = gpu.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytemuck::cast_slice(contents),
            usage: USAGE,
        });
        Ok(Self { buffer, len: data.len(), _marker: PhantomData })
    }

    /// A new buffer of `len` zeroed elements.
    pub fn zeros(gpu: &Gpu, label: &str, len: usize) -> Result<Self, GpuError> {
        let bytes = Self::check_size(gpu, label, len)?;
        let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes,
            usage: USAGE,
            mapped_at_creation: false,
        });
        Ok(Self { buffer, len, _marker: PhantomData })
    }

    /// Number of elements.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Overwrites the start of the buffer with `data` (queued; ordered before later submits).
    pub fn write(&self, gpu: &Gpu, data: &[T]) {
        assert!(data.len() <= self.len, "write of {} elements into a buffer of {}", data.len(), self.len);
        if !data.is_empty() {
            gpu.queue.write_buffer(&self.buffer, 0, bytemuck::cast_slice(data));
        }
    }

    /// Sets every byte to zero (queued).
    pub fn clear(&self, gpu: &Gpu) {
        let mut enc = gpu.encoder();
        enc.clear(&self.buffer);
        enc.submit();
    }

    /// Copies the buffer back to the host, waiting for all submitted work first (a
    /// [`ReadBatch`](super::ReadBatch) of one).
    pub fn read(&self, gpu: &Gpu) -> Result<Vec<T>, GpuError> {
        self.read_prefix(gpu, self.len)
    }

    /// [`GpuBuffer::read`] of the first `len` elements only (at most the length).
    pub fn read_prefix(&self, gpu: &Gpu, len: usize) -> Result<Vec<T>, GpuError> {
        let mut batch = super::ReadBatch::new();
        let slot = batch.add(self, len);
        Ok(batch.read(gpu)?.get(&slot))
    }
}
