//! Per-phase GPU durations of the resident frame from timestamp queries: an empty compute pass that writes
//! a timestamp at each phase boundary, resolved and read back with the frame's answers. Only where the
//! device has [`wgpu::Features::TIMESTAMP_QUERY`] ([`GpuContext::has_timestamps`]); elsewhere nothing is
//! recorded. Costs per frame one empty pass per boundary and 8 bytes per boundary read back.
//!
//! The GPU may overlap the end of one phase with the start of the next (no barrier is implied between
//! passes that do not depend on each other), so a phase's duration is the time between its boundaries as
//! the GPU reached them, not an isolated measurement.

use crate::Result;
use crate::gpu::GpuContext;
use crate::gpu::buffers::{GpuBuffer, Readback};
use std::time::Duration;

/// The phases of a resident frame, in recording order ([`GpuPhases`]' fields).
const PHASES: [&str; 4] = ["maintain", "top level", "queries", "collider pairs"];

/// GPU durations of one resident frame's phases.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GpuPhases {
    /// Skinning and every mesh's refit or rebuild.
    pub maintain: Duration,
    /// Gathering the instances' trees and the top-level build.
    pub top_level: Duration,
    /// The batched closest-hit and any-hit queries.
    pub queries: Duration,
    /// The collider pairs' traversals and the trees' read-back copies.
    pub pairs: Duration,
}

/// The timestamp query set of the resident frame, kept from frame to frame.
pub(crate) struct FrameTimer {
    set: wgpu::QuerySet,
    resolved: GpuBuffer,
    /// Nanoseconds per tick.
    period: f64,
}

/// A frame's timestamps on their way back.
pub(crate) struct PhasesReadback {
    ticks: Readback<u64>,
    period: f64,
}

impl FrameTimer {
    /// A timer for `ctx`, `None` where the device has no timestamp queries.
    pub fn new(ctx: &GpuContext) -> Option<Self> {
        if !ctx.has_timestamps() {
            return None;
        }
        let count = PHASES.len() as u32 + 1;
        let set = ctx.device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("kinetrace frame phases"),
            ty: wgpu::QueryType::Timestamp,
            count,
        });
        let resolved = GpuBuffer::new(
            ctx,
            "frame phase timestamps",
            count as u64 * 8,
            wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
        );
        Some(Self {
            set,
            resolved,
            period: ctx.queue.get_timestamp_period() as f64,
        })
    }

    /// Records boundary `i` (0 before the first phase, `i` after phase `i - 1`).
    pub fn mark(&self, encoder: &mut wgpu::CommandEncoder, i: u32) {
        encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("kinetrace frame phase boundary"),
            timestamp_writes: Some(wgpu::ComputePassTimestampWrites {
                query_set: &self.set,
                beginning_of_pass_write_index: Some(i),
                end_of_pass_write_index: None,
            }),
        });
    }

    /// Records the last boundary, the resolution of the timestamps and their read-back.
    pub fn finish(&self, ctx: &GpuContext, encoder: &mut wgpu::CommandEncoder) -> PhasesReadback {
        let count = PHASES.len() as u32 + 1;
        self.mark(encoder, PHASES.len() as u32);
        encoder.resolve_query_set(&self.set, 0..count, self.resolved.buffer(), 0);
        PhasesReadback {
            ticks: Readback::record(ctx, encoder, self.resolved.buffer(), count as usize),
            period: self.period,
        }
    }
}

impl PhasesReadback {
    /// Whether the timestamps are back.
    pub fn ready(&self, ctx: &GpuContext) -> bool {
        self.ticks.ready(ctx)
    }

    /// The phases' durations (waiting if they are not back). A boundary the GPU reports earlier than
    /// the one before it (a device whose timestamps are not ordered across passes) counts as no time.
    pub fn wait(self, ctx: &GpuContext) -> Result<GpuPhases> {
        let ticks = self.ticks.wait(ctx)?;
        let span = |i: usize| {
            let ns = ticks[i + 1].saturating_sub(ticks[i]) as f64 * self.period;
            Duration::from_nanos(ns as u64)
        };
        Ok(GpuPhases {
            maintain: span(0),
            top_level: span(1),
            queries: span(2),
            pairs: span(3),
        })
    }
}
