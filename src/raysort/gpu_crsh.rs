//! The CRSH traversal on the GPU (feature `gpu`, `shaders/raysort_crsh.wgsl`): the rays sorted and the
//! hierarchy built on the CPU as for [`Strategy::Crsh`](super::Strategy), then one workgroup per level-1
//! node culls the mesh's triangles against the mesh sphere and the node's ancestors, 64 triangle spheres
//! at a time, and each of the node's rays runs the exact watertight test on the survivors.
//!
//! When to use it: to measure the seed's GPU traversal (`bench raysort`) — like the CPU version it tests
//! every triangle sphere per level-1 node, O(rays / s · triangles · D) sphere tests, far above a BVH on
//! meshes of more than a few hundred triangles. Cost besides: uploads of 80 bytes per ray, 48 per node
//! and 64 per triangle, a read-back of 16 bytes per ray, one blocking wait. The branching `s` may be at
//! most 64 (one thread per ray of a level-1 node).
//!
//! Rays whose range reaches behind their origin (`tmin < 0`) lie outside the hierarchy's cones and are
//! answered by the scene's BVH on the CPU, as [`Strategy::Crsh`](super::Strategy) does.
//!
//! Answers equal [`RayScene::trace`](super::RayScene::trace) with [`Strategy::Crsh`](super::Strategy):
//! the same survivors reach the same exact test (both culls only drop triangles no ray of a node can
//! reach), in the same triangle order, with the same tie rule and the same rounding (division rounded as
//! the CPU's, and no contraction where [`GpuContext::contraction_free`] holds), so `t`, `u` and `v` are
//! equal too.

use super::hierarchy::{RayHierarchy, check_shape};
use super::trace::split_reaching_back;
use super::{Answer, KeyLayout, RayKind, RayScene, SecondaryRay, sort_rays};
use crate::bvh::Hit;
use crate::gpu::buffers::{GpuBuffer, bind_group};
use crate::gpu::trace::GpuRay;
use crate::gpu::{GpuContext, Readback};
use crate::{Error, Result};

/// A sphere–cone node as the kernel reads it (48 bytes): centre, radius, axis, the spread's cosine and
/// sine.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuNode {
    center: [f32; 3],
    radius: f32,
    axis: [f32; 3],
    cos_spread: f32,
    sin_spread: f32,
    _pad: [u32; 3],
}
const _: () = assert!(std::mem::size_of::<GpuNode>() == 48);

/// A triangle of non-zero area and its bounding sphere (64 bytes).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuTri {
    v0: [f32; 3],
    _p0: u32,
    v1: [f32; 3],
    _p1: u32,
    v2: [f32; 3],
    _p2: u32,
    center: [f32; 3],
    radius: f32,
}
const _: () = assert!(std::mem::size_of::<GpuTri>() == 64);

/// One ray's answer: distance, index into the scene's triangle list (`u32::MAX`: none), barycentrics.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuCrshHit {
    t: f32,
    tri: u32,
    u: f32,
    v: f32,
}

/// Answers `rays` against `scene` with CRSH of branching `branching` and depth `depth` on the GPU, in
/// request order, blocking. `Error::InvalidOption` for a layout over 32 bits, a hierarchy shape out of
/// range or `branching > 64`; `Error::Gpu` from the device.
pub fn trace_crsh_gpu(
    ctx: &GpuContext,
    scene: &RayScene,
    rays: &[SecondaryRay],
    layout: &KeyLayout,
    branching: usize,
    depth: usize,
) -> Result<Vec<Answer>> {
    check_shape(branching, depth)?;
    if branching > 64 {
        return Err(Error::InvalidOption(format!(
            "GPU CRSH branching {branching}: at most 64 (one thread per ray of a node)"
        )));
    }
    let sorted = sort_rays(rays, layout, true)?;
    let mut answers = vec![Answer::Miss; rays.len()];
    // As on the CPU, the CPU's BVH answers the rays outside the hierarchy's cones.
    let valid = sorted.order[..sorted.valid()].iter().copied();
    let (behind, order) = split_reaching_back(valid, rays);
    for i in behind {
        answers[i as usize] = scene.bvh_answer(&rays[i as usize]).0;
    }
    if order.is_empty() {
        return Ok(answers);
    }
    let ordered: Vec<_> = order.iter().map(|&i| rays[i as usize].ray).collect();
    let h = RayHierarchy::build(&ordered, branching, depth, true)?;
    let mut info = vec![
        ordered.len() as u32,
        branching as u32,
        depth as u32,
        scene.tris.len() as u32,
        h.level(1).len() as u32,
    ];
    let (c, r) = scene.sphere;
    info.extend([c.x, c.y, c.z, r].map(f32::to_bits));
    let mut nodes = Vec::new();
    for k in 1..=depth {
        info.push(nodes.len() as u32);
        nodes.extend(h.level(k).iter().map(|n| {
            let (cos_spread, sin_spread) = n.spread_cos_sin();
            GpuNode {
                center: n.center.to_array(),
                radius: n.radius,
                axis: n.axis.to_array(),
                cos_spread,
                sin_spread,
                _pad: [0; 3],
            }
        }));
    }
    let tris: Vec<GpuTri> = (scene.tris.iter())
        .map(|&(_, [a, b, c], center, radius)| GpuTri {
            v0: a.to_array(),
            v1: b.to_array(),
            v2: c.to_array(),
            center: center.to_array(),
            radius,
            _p0: 0,
            _p1: 0,
            _p2: 0,
        })
        .collect();
    let gpu_rays: Vec<GpuRay> = ordered.iter().map(GpuRay::new).collect();
    let any: Vec<u32> = (order.iter())
        .map(|&i| matches!(rays[i as usize].kind, RayKind::Shadow { .. }) as u32)
        .collect();
    let upload = |label, data: &[u8]| {
        let b = GpuBuffer::storage(ctx, label, (data.len() as u64).max(64));
        b.write(ctx, data);
        b
    };
    let ray_buf = upload("crsh rays", bytemuck::cast_slice(&gpu_rays));
    let any_buf = upload("crsh any", bytemuck::cast_slice(&any));
    let node_buf = upload("crsh nodes", bytemuck::cast_slice(&nodes));
    let tri_buf = upload("crsh triangles", bytemuck::cast_slice(&tris));
    let info_buf = upload("crsh info", bytemuck::cast_slice(&info));
    let hits = GpuBuffer::storage(ctx, "crsh hits", ordered.len() as u64 * 16);
    let module = &ctx.kernels.raysort_crsh;
    let group = bind_group(
        ctx,
        &module.layout,
        &[
            ray_buf.binding(),
            any_buf.binding(),
            node_buf.binding(),
            tri_buf.binding(),
            info_buf.binding(),
            hits.binding(),
        ],
    );
    let (x, y) = ctx.groups(h.level(1).len() as u32, 1);
    let mut enc = ctx.encoder();
    {
        let mut pass = enc.begin_compute_pass(&Default::default());
        pass.set_pipeline(module.pipeline("crsh_trace"));
        pass.set_bind_group(0, &group, &[]);
        pass.dispatch_workgroups(x, y, 1);
    }
    let back = Readback::<GpuCrshHit>::record(ctx, &mut enc, hits.buffer(), ordered.len());
    ctx.submit(enc);
    for (&i, g) in order.iter().zip(back.wait(ctx)?) {
        if g.tri == u32::MAX {
            continue;
        }
        answers[i as usize] = match rays[i as usize].kind {
            RayKind::Shadow { .. } => Answer::Occluded,
            RayKind::Reflection => {
                let (primitive, [a, b, c], ..) = scene.tris[g.tri as usize];
                Answer::Hit(Hit {
                    t: g.t,
                    primitive,
                    u: g.u,
                    v: g.v,
                    normal: (b - a).cross(c - a).normalize_or_zero(),
                })
            }
        };
    }
    Ok(answers)
}
