//! Linear-blend skinning on the GPU (shaders/skin.wgsl), writing straight into a [`GpuMeshBvh`]'s
//! positions so refit and rebuild read them with no CPU round trip.

use super::buffers::{GpuBuffer, ParamSlots, bind_group};
use super::{GpuContext, GpuMeshBvh};
use crate::anim::SkinWeights;
use crate::{Error, Result};
use glam::{Mat4, Vec3};

/// A skinned mesh's rest positions, joints and weights on the GPU, plus its joint-matrix palette.
pub struct GpuSkin {
    vertices: u32,
    joints: u32,
    matrices: GpuBuffer,
    group: wgpu::BindGroup,
    _buffers: [GpuBuffer; 3],
    _params: ParamSlots,
}

impl GpuSkin {
    /// Uploads the rest pose and weights of a mesh whose tree is `target`; the palette has `joints`
    /// matrices.
    pub fn new(
        ctx: &GpuContext,
        rest: &[Vec3],
        skin: &SkinWeights,
        joints: usize,
        target: &GpuMeshBvh,
    ) -> Result<Self> {
        skin.check(rest.len(), joints)?;
        ctx.check_threads("skinned vertices", rest.len() as u64, 256)?;
        ctx.check_storage("skin weights", rest.len() as u64 * 16)?;
        let vertices = rest.len() as u32;
        let rest_buf = GpuBuffer::storage(ctx, "rest positions", vertices as u64 * 12);
        rest_buf.write(ctx, rest);
        let joint_buf = GpuBuffer::storage(ctx, "joints", vertices as u64 * 16);
        let wide: Vec<[u32; 4]> = skin.joints.iter().map(|j| j.map(u32::from)).collect();
        joint_buf.write(ctx, &wide);
        let weight_buf = GpuBuffer::storage(ctx, "weights", vertices as u64 * 16);
        weight_buf.write(ctx, &skin.weights);
        let matrices = GpuBuffer::storage(ctx, "joint matrices", joints.max(1) as u64 * 64);
        let params = ParamSlots::new(ctx, &[[vertices, 0, 0, 0]]);
        let group = bind_group(
            ctx,
            &ctx.kernels.skin.layout,
            &[
                rest_buf.binding(),
                joint_buf.binding(),
                weight_buf.binding(),
                matrices.binding(),
                target.positions().as_entire_binding(),
                params.binding(),
            ],
        );
        Ok(Self {
            vertices,
            joints: joints as u32,
            matrices,
            group,
            _buffers: [rest_buf, joint_buf, weight_buf],
            _params: params,
        })
    }

    /// Uploads this frame's joint matrices and records the skinning dispatch.
    pub fn record(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        matrices: &[Mat4],
    ) -> Result<()> {
        if matrices.len() != self.joints as usize {
            return Err(Error::InvalidOption(format!(
                "{} joint matrices for a skin of {}",
                matrices.len(),
                self.joints
            )));
        }
        self.matrices.write(ctx, matrices);
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("kinetrace skin"),
            timestamp_writes: None,
        });
        pass.set_pipeline(ctx.kernels.skin.pipeline("skin"));
        pass.set_bind_group(0, &self.group, &[ParamSlots::offset(0)]);
        let (x, y) = ctx.groups(self.vertices, 256);
        pass.dispatch_workgroups(x, y, 1);
        Ok(())
    }
}
