//! The SAH cost of a resident tree, reduced on the GPU after a refit or a rebuild and read back without
//! blocking: what the adaptive policy needs of the tree on the GPU-resident frame, where the tree itself
//! never comes back.

use crate::Result;
use crate::bvh::Node;
use crate::gpu::buffers::{GpuBuffer, ParamSlots, Readback, bind_group};
use crate::gpu::{GpuContext, GpuMeshBvh};

/// The reduction's buffers for one tree: one double-float pair per 256 nodes and two parameter slots
/// (nodes, blocks). Made once per tree: 8 bytes per 256 nodes plus 512 bytes of parameters.
pub(crate) struct SahReduction {
    pairs: GpuBuffer,
    /// Holds the parameters and `pairs` (wgpu keeps them alive while it exists).
    group: wgpu::BindGroup,
    nodes: u32,
}

/// A tree's SAH cost as read back: [`Bvh::sah_cost`](crate::bvh::Bvh::sah_cost) of the GPU's tree, and
/// half the area of its root box (the planner's [`TreeCost`](crate::adaptive::TreeCost)).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SahReading {
    /// The SAH cost (`C_TRAV = C_ISECT = 1`).
    pub sah: f64,
    /// Half the surface area of the root box (object space).
    pub root_half_area: f64,
}

/// A reduction on its way back: the sum (two words) and the root node (eight).
pub(crate) struct SahReadback(Readback<u32>);

impl SahReduction {
    /// The reduction's buffers for `bvh` (its node count is fixed for its topology).
    pub fn new(ctx: &GpuContext, bvh: &GpuMeshBvh) -> Self {
        let nodes = bvh.node_count();
        let blocks = nodes.div_ceil(256).max(1);
        let pairs = GpuBuffer::storage(ctx, "frame sah pairs", blocks as u64 * 8);
        let params = ParamSlots::new(ctx, &[[nodes, 0, 0, 0], [blocks, 0, 0, 0]]);
        let group = bind_group(
            ctx,
            &ctx.kernels.frame_sah.layout,
            &[
                bvh.nodes().as_entire_binding(),
                pairs.binding(),
                params.binding(),
                bvh.nodes().as_entire_binding(),
            ],
        );
        Self {
            pairs,
            group,
            nodes,
        }
    }

    /// Records the reduction over the tree as it stands at this point of `encoder` and its read-back (40
    /// bytes): two dispatches, one pass over the nodes.
    pub fn record(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        bvh: &GpuMeshBvh,
    ) -> SahReadback {
        let k = &ctx.kernels.frame_sah;
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("kinetrace frame sah"),
                timestamp_writes: None,
            });
            let (x, y) = ctx.groups(self.nodes, 256);
            pass.set_pipeline(k.pipeline("sah_blocks"));
            pass.set_bind_group(0, &self.group, &[ParamSlots::offset(0)]);
            pass.dispatch_workgroups(x, y, 1);
            pass.set_pipeline(k.pipeline("sum_pairs"));
            pass.set_bind_group(0, &self.group, &[ParamSlots::offset(1)]);
            pass.dispatch_workgroups(1, 1, 1);
        }
        SahReadback(Readback::record_parts(
            ctx,
            encoder,
            &[(self.pairs.buffer(), 2), (bvh.nodes(), 8)],
        ))
    }
}

impl SahReadback {
    /// Whether the GPU has finished the reading.
    pub fn ready(&self, ctx: &GpuContext) -> bool {
        self.0.ready(ctx)
    }

    /// The reading if the GPU has finished it, without blocking.
    pub fn try_take(&self, ctx: &GpuContext) -> Option<Result<SahReading>> {
        self.0.try_take(ctx).map(|r| {
            r.map(|w| {
                let sum = f32::from_bits(w[0]) as f64 + f32::from_bits(w[1]) as f64;
                let root: Node = bytemuck::pod_read_unaligned(bytemuck::cast_slice(&w[2..10]));
                SahReading {
                    sah: sum,
                    root_half_area: root.aabb().half_area_f64(),
                }
            })
        })
    }
}
