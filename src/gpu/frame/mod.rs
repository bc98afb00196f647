//! The GPU-resident frame: every mesh's tree stays on the GPU ([`ResidentMesh`]), and one command encoder
//! per frame takes it from joint matrices to answers — skinning, refit or rebuild per mesh (with the
//! [`FrameBuilder`] the caller's rule names: LBVH, binned SAH or the hybrid), the
//! top-level tree built on the GPU over the instances' world boxes, then the batched closest-hit and any-hit
//! queries of [`ResidentScene`] — with the answers copied to staging and mapped without blocking.
//!
//! Per frame the CPU uploads only joint matrices (64 bytes per joint of a changed skin, plus 4 per blend
//! shape for its weight), the instances (144 bytes of transforms, offsets and layers plus a 64-byte
//! transform each) and the rays (80 + 16 bytes each); positions only for meshes deformed on the CPU. The meshes' trees are copied on the GPU into the
//! scene's buffers (device bandwidth, not the bus). The top level is rebuilt every frame: an LBVH over a few
//! hundred boxes costs a handful of dispatches, less than tracking which boxes moved.

mod bound;
mod mesh;
mod pairs;
mod sah;
mod timer;

pub(crate) use bound::world as world_bound;
pub use mesh::{
    Calibrated, CostReading, FrameBuilder, Maintained, MeshUpdate, RefitState, ResidentMesh,
};
pub(crate) use pairs::{FrameCollider, FrameContacts, ReadTrees, ResidentPairs};
pub use sah::SahReading;
pub use timer::GpuPhases;
pub(crate) use timer::{FrameTimer, PhasesReadback};

use super::buffers::{GpuBuffer, bind_group};
use super::scene::{Batch, GpuInstance, SceneReadback, SceneRequest};
use super::{GpuContext, GpuMeshBvh};
use crate::{Mesh, Result};
use glam::{Affine3A, Vec3};

/// One instance of a resident mesh in this frame's scene.
pub(crate) struct FrameInstance<'a> {
    /// The caller's id, reported with hits and compared with [`SceneRequest::exclude`].
    pub id: u64,
    /// The mesh, as maintained earlier in the same encoder.
    pub mesh: &'a ResidentMesh,
    /// Object-to-world transform (must be invertible; the caller checks).
    pub transform: Affine3A,
    /// Query layers the instance is on.
    pub layers: u32,
}

/// The scene of the resident frame: the meshes' trees gathered into one set of buffers, the top-level
/// tree over the instances built on the GPU, and the buffers of the two batches.
pub(crate) struct ResidentScene {
    /// LBVH over one triangle (min, max, max) per instance: its leaf boxes are the instances' world boxes.
    tlas: Option<GpuMeshBvh>,
    blas: GpuBuffer,
    ids: GpuBuffer,
    indices: GpuBuffer,
    corners: GpuBuffer,
    /// Instances in the caller's order, then in the top-level tree's slot order.
    by_id: GpuBuffer,
    sorted: GpuBuffer,
    forward: GpuBuffer,
    params: GpuBuffer,
    batches: [Batch; 2],
    up_instances: Vec<GpuInstance>,
    up_forward: Vec<[[f32; 4]; 4]>,
}

/// A frame's answers on their way back: one per request of each batch, in request order.
pub(crate) struct FrameReadback {
    /// Closest hits.
    pub closest: SceneReadback,
    /// Any hits.
    pub any: SceneReadback,
}

impl ResidentScene {
    /// Empty buffers; they grow with the scene and the batches and are kept from frame to frame.
    pub fn new(ctx: &GpuContext) -> Self {
        Self {
            tlas: None,
            blas: GpuBuffer::storage(ctx, "frame blas", 1024),
            ids: GpuBuffer::storage(ctx, "frame slot ids", 1024),
            indices: GpuBuffer::storage(ctx, "frame indices", 1024),
            corners: GpuBuffer::storage(ctx, "frame corners", 1024),
            by_id: GpuBuffer::storage(ctx, "frame instances", 1024),
            sorted: GpuBuffer::storage(ctx, "frame sorted instances", 1024),
            forward: GpuBuffer::storage(ctx, "frame transforms", 1024),
            params: GpuBuffer::uniform(ctx, "frame params"),
            batches: [Batch::new(ctx), Batch::new(ctx)],
            up_instances: Vec::new(),
            up_forward: Vec::new(),
        }
    }

    /// Records, after the meshes' maintenance in the same `encoder`: the gathering of the instances' trees,
    /// the top-level build, and the two batches with their read-backs (with `timer`, boundary 2 between
    /// the top level and the batches). Instances of empty meshes are
    /// left out. Errors: [`Error::Gpu`](crate::Error::Gpu) for a scene past the device's limits.
    pub fn record(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        instances: &[FrameInstance<'_>],
        closest: &[SceneRequest],
        any: &[SceneRequest],
        timer: Option<&FrameTimer>,
    ) -> Result<FrameReadback> {
        let live: Vec<&FrameInstance> = instances
            .iter()
            .filter(|i| i.mesh.bvh().triangle_count() > 0)
            .collect();
        self.gather(ctx, encoder, &live)?;
        let n = live.len() as u32;
        let tlas = self.top_level(ctx, encoder, n)?;
        let tlas_len = tlas.map_or(0, |t| t.node_count());
        if let Some(timer) = timer {
            timer.mark(encoder, 2);
        }
        let Self {
            tlas,
            blas,
            ids,
            indices,
            corners,
            by_id,
            sorted,
            batches: [closest_batch, any_batch],
            ..
        } = self;
        // With no instance there is no top-level tree (and no dispatch): any bound buffer will do.
        let top = match tlas {
            Some(t) if n > 0 => t.nodes().as_entire_binding(),
            _ => by_id.binding(),
        };
        let scene = || {
            [
                top.clone(),
                sorted.binding(),
                blas.binding(),
                ids.binding(),
                indices.binding(),
                corners.binding(),
            ]
        };
        // With no instance no ray can hit: the batches record no dispatch (their hits read as misses).
        let (closest, any) = if n == 0 {
            (&[][..], &[][..])
        } else {
            (closest, any)
        };
        let closest = closest_batch.record(ctx, encoder, scene(), tlas_len, closest, false);
        let any = any_batch.record(ctx, encoder, scene(), tlas_len, any, true);
        Ok(FrameReadback { closest, any })
    }

    /// Copies every instance's nodes, slot ids, vertex indices and positions into the scene's buffers and
    /// uploads the instances.
    fn gather(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        live: &[&FrameInstance<'_>],
    ) -> Result<()> {
        let (mut nodes, mut slots, mut vertices) = (0u64, 0u64, 0u64);
        self.up_instances.clear();
        self.up_forward.clear();
        for inst in live {
            let bvh = inst.mesh.bvh();
            let inverse = inst.transform.inverse();
            let normal = inverse.matrix3.transpose();
            self.up_instances.push(GpuInstance::new(
                &inverse,
                &normal,
                [nodes as u32, slots as u32, vertices as u32],
                inst.layers,
                inst.id,
            ));
            let t = inst.transform;
            self.up_forward.push(
                [
                    t.matrix3.x_axis,
                    t.matrix3.y_axis,
                    t.matrix3.z_axis,
                    t.translation,
                ]
                .map(|c| Vec3::from(c).extend(0.0).to_array()),
            );
            nodes += bvh.node_count() as u64;
            slots += bvh.triangle_count() as u64;
            vertices += bvh.vertex_count() as u64;
        }
        for (what, buf, bytes) in [
            ("scene nodes", &mut self.blas, nodes * 32),
            ("scene slot ids", &mut self.ids, slots * 4),
            ("scene indices", &mut self.indices, slots * 12),
            ("scene corners", &mut self.corners, vertices * 12),
            ("scene instances", &mut self.by_id, live.len() as u64 * 144),
            ("scene instances", &mut self.sorted, live.len() as u64 * 144),
            (
                "scene transforms",
                &mut self.forward,
                live.len() as u64 * 64,
            ),
        ] {
            ctx.check_storage(what, bytes)?;
            buf.ensure(ctx, bytes);
        }
        self.by_id.write(ctx, &self.up_instances);
        self.forward.write(ctx, &self.up_forward);
        let (mut nodes, mut slots, mut tris, mut vertices) = (0u64, 0u64, 0u64, 0u64);
        for inst in live {
            let bvh = inst.mesh.bvh();
            let parts = [
                (
                    bvh.nodes(),
                    &self.blas,
                    &mut nodes,
                    bvh.node_count() as u64 * 32,
                ),
                (
                    bvh.slot_ids(),
                    &self.ids,
                    &mut slots,
                    bvh.triangle_count() as u64 * 4,
                ),
                (
                    bvh.indices(),
                    &self.indices,
                    &mut tris,
                    bvh.triangle_count() as u64 * 12,
                ),
                (
                    bvh.positions(),
                    &self.corners,
                    &mut vertices,
                    bvh.vertex_count() as u64 * 12,
                ),
            ];
            for (src, dst, at, bytes) in parts {
                encoder.copy_buffer_to_buffer(src, 0, dst.buffer(), *at, bytes);
                *at += bytes;
            }
        }
        Ok(())
    }

    /// Records the instances' world boxes, the top-level LBVH over them, and the instances in its slot
    /// order. The tree (and its one-time upload of 36 bytes per instance) is made again only when the
    /// number of instances changes. `None` for an empty scene.
    fn top_level(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        n: u32,
    ) -> Result<Option<&GpuMeshBvh>> {
        if n == 0 {
            return Ok(None);
        }
        if self.tlas.as_ref().is_none_or(|t| t.triangle_count() != n) {
            let indices: Vec<u32> = (0..3 * n).collect();
            let boxes = Mesh::new(vec![Vec3::ZERO; 3 * n as usize], indices)?;
            self.tlas = Some(GpuMeshBvh::new(ctx, &boxes)?);
        }
        let tlas = self.tlas.as_mut().expect("made above");
        ctx.write_buffer(self.params.buffer(), 0, bytemuck::bytes_of(&[n, 0, 0, 0]));
        let k = &ctx.kernels.frame;
        let group = bind_group(
            ctx,
            &k.layout,
            &[
                self.blas.binding(),
                self.by_id.binding(),
                self.forward.binding(),
                tlas.slot_ids().as_entire_binding(),
                tlas.positions().as_entire_binding(),
                self.sorted.binding(),
                wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                    buffer: self.params.buffer(),
                    offset: 0,
                    size: wgpu::BufferSize::new(16),
                }),
            ],
        );
        let (x, y) = ctx.groups(n, 256);
        let dispatch = |entry: &str, encoder: &mut wgpu::CommandEncoder| {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("kinetrace frame"),
                timestamp_writes: None,
            });
            pass.set_pipeline(k.pipeline(entry));
            pass.set_bind_group(0, &group, &[0]);
            pass.dispatch_workgroups(x, y, 1);
        };
        dispatch("instance_boxes", encoder);
        tlas.record_build(ctx, encoder);
        dispatch("order_instances", encoder);
        Ok(Some(tlas))
    }
}
