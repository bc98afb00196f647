//! Linear-blend skinning on the GPU (shaders/skin.wgsl), writing straight into a [`GpuMeshBvh`]'s
//! positions so refit and rebuild read them with no CPU round trip. The positions equal the CPU's
//! [`skin_positions`](crate::anim::skin_positions) where the kernels are contraction-free
//! ([`GpuContext::contraction_free`]): each joint's transform is written out in glam's operation order.

use super::buffers::{GpuBuffer, ParamSlots, bind_group};
use super::{GpuContext, GpuMeshBvh};
use crate::anim::{MorphTargets, SkinWeights};
use crate::{Error, Result};
use glam::{Mat4, Vec3};

/// A skinned mesh's rest positions, joints and weights on the GPU, plus its joint-matrix palette, and
/// optionally its blend shapes ([`new_morphed`](Self::new_morphed)) with their per-frame weights.
pub struct GpuSkin {
    vertices: u32,
    joints: u32,
    targets: u32,
    matrices: GpuBuffer,
    morph_weights: GpuBuffer,
    group: wgpu::BindGroup,
    _buffers: [GpuBuffer; 4],
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
        Self::new_morphed(ctx, rest, skin, joints, None, target)
    }

    /// [`new`](Self::new), with `morphs`' blend shapes applied to the rest pose before skinning, in the
    /// same pass, at the weights of [`set_morph_weights`](Self::set_morph_weights) (0 until set). Costs
    /// the upload of 12 bytes per vertex per target once and 4 bytes per target per frame the weights
    /// change; the pass reads 12 bytes per vertex per target with a nonzero weight. Errors for a target
    /// whose vertex count differs from the rest pose's.
    pub fn new_morphed(
        ctx: &GpuContext,
        rest: &[Vec3],
        skin: &SkinWeights,
        joints: usize,
        morphs: Option<&MorphTargets>,
        target: &GpuMeshBvh,
    ) -> Result<Self> {
        skin.check(rest.len(), joints)?;
        let deltas = morphs.map_or(&[][..], |m| &m.deltas[..]);
        if let Some(d) = deltas.iter().find(|d| d.len() != rest.len()) {
            return Err(Error::VertexCountMismatch {
                expected: rest.len(),
                got: d.len(),
            });
        }
        let targets = deltas.len() as u32;
        ctx.check_storage("morph targets", rest.len() as u64 * 12 * targets as u64)?;
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
        let delta_buf =
            GpuBuffer::storage(ctx, "morph targets", vertices as u64 * 12 * targets as u64);
        for (t, d) in deltas.iter().enumerate() {
            let at = t as u64 * vertices as u64 * 12;
            if !d.is_empty() {
                ctx.write_buffer(delta_buf.buffer(), at, bytemuck::cast_slice(d));
            }
        }
        let morph_weights = GpuBuffer::storage(ctx, "morph weights", targets as u64 * 4);
        morph_weights.write(ctx, &vec![0.0f32; targets as usize]);
        let params = ParamSlots::new(ctx, &[[vertices, targets, 0, 0]]);
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
                delta_buf.binding(),
                morph_weights.binding(),
            ],
        );
        Ok(Self {
            vertices,
            joints: joints as u32,
            targets,
            matrices,
            morph_weights,
            group,
            _buffers: [rest_buf, joint_buf, weight_buf, delta_buf],
            _params: params,
        })
    }

    /// Uploads the blend shapes' weights for the next skinning passes (4 bytes per target; nothing for a
    /// skin without blend shapes). Missing weights count as 0 and extra ones are ignored, as in
    /// [`MorphTargets::apply`].
    pub fn set_morph_weights(&self, ctx: &GpuContext, weights: &[f32]) {
        let mut all = vec![0.0f32; self.targets as usize];
        for (w, v) in all.iter_mut().zip(weights) {
            *w = *v;
        }
        self.morph_weights.write(ctx, &all);
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
