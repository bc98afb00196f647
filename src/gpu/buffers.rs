//! Buffers that grow geometrically and are reused, uniform parameter slots, and asynchronous read-back.

use super::GpuContext;
use crate::{Error, Result};
use bytemuck::Pod;
use std::marker::PhantomData;
use std::sync::{Arc, Mutex};

/// A storage buffer reused across frames: [`ensure`](Self::ensure) grows it by doubling, never shrinks it,
/// so a mesh whose size wobbles does not reallocate every frame.
pub(crate) struct GpuBuffer {
    buffer: wgpu::Buffer,
    label: &'static str,
    usage: wgpu::BufferUsages,
}

/// Storage buffers also take copies in both directions (uploads, read-back, clears).
pub(crate) const STORAGE: wgpu::BufferUsages = wgpu::BufferUsages::STORAGE
    .union(wgpu::BufferUsages::COPY_DST)
    .union(wgpu::BufferUsages::COPY_SRC);

impl GpuBuffer {
    pub fn new(
        ctx: &GpuContext,
        label: &'static str,
        bytes: u64,
        usage: wgpu::BufferUsages,
    ) -> Self {
        Self {
            buffer: create(ctx, label, bytes, usage),
            label,
            usage,
        }
    }

    /// A storage buffer of at least `bytes`.
    pub fn storage(ctx: &GpuContext, label: &'static str, bytes: u64) -> Self {
        Self::new(ctx, label, bytes, STORAGE)
    }

    /// A uniform buffer of one parameter slot (256 bytes, the dynamic-offset alignment), written from the CPU.
    pub fn uniform(ctx: &GpuContext, label: &'static str) -> Self {
        Self::new(
            ctx,
            label,
            SLOT,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        )
    }

    /// Makes room for `bytes`; returns true when the buffer was replaced (bind groups must be rebuilt).
    pub fn ensure(&mut self, ctx: &GpuContext, bytes: u64) -> bool {
        self.ensure_within(ctx, bytes, u64::MAX)
    }

    /// [`ensure`](Self::ensure), doubling no further than `limit` bytes (a device limit `bytes` is within).
    pub fn ensure_within(&mut self, ctx: &GpuContext, bytes: u64, limit: u64) -> bool {
        if bytes <= self.buffer.size() {
            return false;
        }
        let grown = bytes.max((self.buffer.size() * 2).min(limit));
        self.buffer = create(ctx, self.label, grown, self.usage);
        true
    }

    pub fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }

    /// The whole buffer as a binding.
    pub fn binding(&self) -> wgpu::BindingResource<'_> {
        self.buffer.as_entire_binding()
    }

    /// Writes `data` at the start (queued; lands before the next submission runs).
    pub fn write<T: Pod>(&self, ctx: &GpuContext, data: &[T]) {
        if !data.is_empty() {
            ctx.write_buffer(&self.buffer, 0, bytemuck::cast_slice(data));
        }
    }
}

/// Sizes are rounded up to 256 bytes (and at least that): copy alignment, and never a zero-sized binding.
fn create(
    ctx: &GpuContext,
    label: &'static str,
    bytes: u64,
    usage: wgpu::BufferUsages,
) -> wgpu::Buffer {
    let buffer = create_on(&ctx.device, label, bytes, usage);
    ctx.count_allocated(buffer.size());
    buffer
}

/// [`create`] on a device that has no context yet (the caller counts the bytes).
fn create_on(
    device: &wgpu::Device,
    label: &'static str,
    bytes: u64,
    usage: wgpu::BufferUsages,
) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: bytes.max(256).next_multiple_of(256),
        usage,
        mapped_at_creation: false,
    })
}

/// Per-dispatch parameters (four u32 each) in one uniform buffer, 256 bytes apart, selected with dynamic
/// offsets. Written when a tree is (re)sized, not per frame.
pub(crate) struct ParamSlots {
    buffer: wgpu::Buffer,
}

/// Dynamic uniform offsets must be multiples of this (the WebGPU minimum alignment limit).
const SLOT: u64 = 256;

/// Slots of the device's [`ParamSlots::passes`]: one per pass of a radix sort of 32-bit keys.
pub(crate) const PASS_SLOTS: usize = 8;

impl ParamSlots {
    pub fn new(ctx: &GpuContext, slots: &[[u32; 4]]) -> Self {
        let (params, bytes) = Self::filled(&ctx.device, slots);
        ctx.count_allocated(params.memory_bytes());
        if !bytes.is_empty() {
            ctx.write_buffer(&params.buffer, 0, &bytes);
        }
        params
    }

    /// The device's pass slots, made once with its context: slot `p` holds `[p, 0, 0, 0]`
    /// ([`PASS_SLOTS`] of them, 2 KiB). The radix sort's kernels read their pass (which digit) from a
    /// second uniform bound here at [`offset`](Self::offset)`(p)`, and the sort's own values from its
    /// one slot: one set for every sorter of the device instead of a slot per pass per sorter. The
    /// caller counts its bytes.
    pub fn passes(device: &wgpu::Device, queue: &wgpu::Queue) -> Self {
        let levels: Vec<[u32; 4]> = (0..PASS_SLOTS as u32).map(|l| [l, 0, 0, 0]).collect();
        let (params, bytes) = Self::filled(device, &levels);
        queue.write_buffer(&params.buffer, 0, &bytes);
        params
    }

    /// An unwritten buffer for `slots` and the bytes to write into it.
    fn filled(device: &wgpu::Device, slots: &[[u32; 4]]) -> (Self, Vec<u8>) {
        let buffer = create_on(
            device,
            "kinetrace params",
            slots.len().max(1) as u64 * SLOT,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        );
        let mut bytes = vec![0u8; slots.len() * SLOT as usize];
        for (i, s) in slots.iter().enumerate() {
            bytes[i * SLOT as usize..][..16].copy_from_slice(bytemuck::bytes_of(s));
        }
        (Self { buffer }, bytes)
    }

    /// Bytes of the uniform buffer.
    pub fn memory_bytes(&self) -> u64 {
        self.buffer.size()
    }

    /// The binding (one slot wide); pick the slot with [`offset`](Self::offset).
    pub fn binding(&self) -> wgpu::BindingResource<'_> {
        wgpu::BindingResource::Buffer(wgpu::BufferBinding {
            buffer: &self.buffer,
            offset: 0,
            size: wgpu::BufferSize::new(16),
        })
    }

    /// Rewrites one slot; takes effect at the next submission, so every dispatch of that submission sees
    /// the new value.
    pub fn write(&self, ctx: &GpuContext, slot: usize, value: [u32; 4]) {
        ctx.write_buffer(&self.buffer, slot as u64 * SLOT, bytemuck::bytes_of(&value));
    }

    pub fn offset(slot: usize) -> u32 {
        (slot as u64 * SLOT) as u32
    }
}

/// A bind group over `entries` (binding indices in order) for `layout`.
pub(crate) fn bind_group(
    ctx: &GpuContext,
    layout: &wgpu::BindGroupLayout,
    entries: &[wgpu::BindingResource<'_>],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = entries
        .iter()
        .enumerate()
        .map(|(i, r)| wgpu::BindGroupEntry {
            binding: i as u32,
            resource: r.clone(),
        })
        .collect();
    ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout,
        entries: &entries,
    })
}

/// Read-back staging buffers waiting for reuse (sizes are powers of two), so that a frame's read-backs do
/// not allocate GPU memory once the pool has warmed up.
#[derive(Default)]
pub(crate) struct StagingPool(Mutex<Vec<wgpu::Buffer>>);

impl StagingPool {
    /// Most buffers kept.
    const KEEP: usize = 16;

    /// The smallest pooled buffer of at least `bytes`, or a new one.
    fn take(&self, ctx: &GpuContext, bytes: u64) -> wgpu::Buffer {
        let mut pool = self.0.lock().expect("staging pool");
        let best = pool
            .iter()
            .enumerate()
            .filter(|(_, b)| b.size() >= bytes)
            .min_by_key(|(_, b)| b.size())
            .map(|(i, _)| i);
        match best {
            Some(i) => pool.swap_remove(i),
            None => create(
                ctx,
                "kinetrace readback",
                bytes.next_power_of_two().max(256),
                wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            ),
        }
    }

    fn give_back(&self, buffer: wgpu::Buffer) {
        let mut pool = self.0.lock().expect("staging pool");
        if pool.len() < Self::KEEP {
            pool.push(buffer);
        }
    }
}

/// Results of GPU work on their way back to the CPU: recorded in the same encoder as the work, mapped when
/// that submission completes. [`try_take`](Self::try_take) never blocks, so frame N's results can be
/// collected while frame N+1 is recorded; [`wait`](Self::wait) is the blocking convenience. The staging
/// buffer comes from, and returns to, the context's pool.
pub struct Readback<T> {
    staging: Mutex<Option<wgpu::Buffer>>,
    len: usize,
    state: Arc<Mutex<Option<std::result::Result<(), String>>>>,
    _t: PhantomData<T>,
}

impl<T: Pod> Readback<T> {
    /// Records a copy of `len` elements of `src` (from byte 0) and its mapping at submission.
    pub(crate) fn record(
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        src: &wgpu::Buffer,
        len: usize,
    ) -> Self {
        Self::record_parts(ctx, encoder, &[(src, len)])
    }

    /// Records copies of the first `len` elements of each `(src, len)` part, one after the other into one
    /// staging buffer, and its mapping at submission: one read-back of results that live in several
    /// buffers. Every part but the last must be a whole number of 4-byte words.
    pub(crate) fn record_parts(
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        parts: &[(&wgpu::Buffer, usize)],
    ) -> Self {
        let bytes = |n: usize| ((n * std::mem::size_of::<T>()) as u64).next_multiple_of(4);
        let len: usize = parts.iter().map(|p| p.1).sum();
        let copy: u64 = parts.iter().map(|p| bytes(p.1)).sum();
        let state = Arc::new(Mutex::new(None));
        ctx.count_read_back(copy);
        let staging = (copy > 0).then(|| {
            let staging = ctx.staging.take(ctx, copy);
            let mut at = 0;
            for &(src, n) in parts.iter().filter(|p| p.1 > 0) {
                encoder.copy_buffer_to_buffer(src, 0, &staging, at, bytes(n));
                at += bytes(n);
            }
            let s = state.clone();
            encoder.map_buffer_on_submit(&staging, wgpu::MapMode::Read, ..copy, move |r| {
                *s.lock().expect("readback state") = Some(r.map_err(|e| e.to_string()));
            });
            staging
        });
        if staging.is_none() {
            *state.lock().expect("readback state") = Some(Ok(()));
        }
        Self {
            staging: Mutex::new(staging),
            len,
            state,
            _t: PhantomData,
        }
    }

    /// The results if the GPU has finished, without blocking.
    pub fn try_take(&self, ctx: &GpuContext) -> Option<Result<Vec<T>>> {
        let mut collect = Some(<[T]>::to_vec);
        self.try_read(ctx, &mut collect)
    }

    /// The results given to `f` (taken from it) if the GPU has finished, without blocking.
    fn try_read<R>(
        &self,
        ctx: &GpuContext,
        f: &mut Option<impl FnOnce(&[T]) -> R>,
    ) -> Option<Result<R>> {
        ctx.poll();
        if let Err(e) = ctx.take_failure() {
            return Some(Err(e));
        }
        let done = self.state.lock().expect("readback state").take()?;
        let f = f.take().expect("read once");
        Some(done.map_err(Error::Gpu).map(|()| self.read(ctx, f)))
    }

    /// Whether the results are there (a [`wait`](Self::wait) would not block), without blocking.
    pub fn ready(&self, ctx: &GpuContext) -> bool {
        ctx.poll();
        self.state.lock().expect("readback state").is_some()
    }

    /// Blocks until the results are there.
    pub fn wait(self, ctx: &GpuContext) -> Result<Vec<T>> {
        self.wait_with(ctx, <[T]>::to_vec)
    }

    /// Blocks until the results are there and gives them to `f` where they lie (the mapped staging
    /// buffer, when aligned for `T`), copied into no vector: for large results read once.
    pub(crate) fn wait_with<R>(self, ctx: &GpuContext, f: impl FnOnce(&[T]) -> R) -> Result<R> {
        let mut f = Some(f);
        loop {
            if let Some(r) = self.try_read(ctx, &mut f) {
                return r;
            }
            ctx.wait()?;
        }
    }

    fn read<R>(&self, ctx: &GpuContext, f: impl FnOnce(&[T]) -> R) -> R {
        let Some(staging) = self.staging.lock().expect("staging").take() else {
            return f(&[]);
        };
        let bytes = self.len * std::mem::size_of::<T>();
        let view = staging
            .get_mapped_range(..(bytes as u64).next_multiple_of(4))
            .expect("buffer is mapped");
        let out = match bytemuck::try_cast_slice(&view[..bytes]) {
            Ok(results) => f(results),
            Err(_) => f(&bytemuck::pod_collect_to_vec(&view[..bytes])),
        };
        drop(view);
        staging.unmap();
        ctx.staging.give_back(staging);
        out
    }
}
