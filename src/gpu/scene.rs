//! Batched two-level queries over an ECS world on the GPU (shaders/scene.wgsl): the top-level tree over
//! entities, then each reached entity's tree in its object space.

use super::GpuContext;
use super::buffers::{GpuBuffer, Readback, bind_group, groups};
use super::trace::GpuRay;
use crate::bvh::Node;
use crate::ecs::{RayHit, TraceWorld};
use crate::geometry::Ray;
use bevy_ecs::entity::Entity;
use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// One entity as the kernel reads it (80 bytes).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct GpuInstance {
    /// World-to-object transform, columns x, y, z, translation (w unused).
    columns: [[f32; 4]; 4],
    /// Object-to-world normal matrix, columns.
    normal: [[f32; 4]; 3],
    node_offset: u32,
    slot_offset: u32,
    vertex_offset: u32,
    layers: u32,
    entity: [u32; 2],
    _pad: [u32; 2],
}

const _: () = assert!(std::mem::size_of::<GpuInstance>() == 144);

/// One ray's answer (48 bytes): `instance` is a TLAS slot; the unit world normal is computed on the GPU.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(crate) struct SceneHit {
    t: f32,
    prim: u32,
    u: f32,
    v: f32,
    instance: u32,
    _pad: [u32; 3],
    normal: [f32; 3],
    _pad2: f32,
}

/// A request the GPU can answer: layer mask and at most one excluded entity (requests with predicates or
/// longer exclusion lists stay on the CPU).
pub(crate) struct SceneRequest {
    pub ray: Ray,
    pub layers: u32,
    pub exclude: Option<Entity>,
}

/// Ray, filter and hit buffers of one kind of query.
struct Batch {
    rays: GpuBuffer,
    filters: GpuBuffer,
    hits: GpuBuffer,
    params: GpuBuffer,
    up_rays: Vec<GpuRay>,
    up_filters: Vec<[u32; 4]>,
}

impl Batch {
    fn new(ctx: &GpuContext) -> Self {
        Self {
            rays: GpuBuffer::storage(ctx, "scene rays", 80 * 1024),
            filters: GpuBuffer::storage(ctx, "scene filters", 16 * 1024),
            hits: GpuBuffer::storage(ctx, "scene hits", 48 * 1024),
            params: GpuBuffer::uniform(ctx, "scene params"),
            up_rays: Vec::new(),
            up_filters: Vec::new(),
        }
    }
}

/// A world's structures on the GPU, re-uploaded when the world changed, and the buffers of two batches
/// (closest hits and occlusion), recorded into one submission.
pub(crate) struct GpuScene {
    tlas: GpuBuffer,
    instances: GpuBuffer,
    blas: GpuBuffer,
    slot_tris: GpuBuffer,
    corners: GpuBuffer,
    /// TLAS slot → entity, for turning answers back into entities.
    entities: Vec<Entity>,
    version: Option<u64>,
    batches: [Batch; 2],
    upload: Upload,
}

/// What [`GpuScene::sync`] sends, built on the CPU.
#[derive(Default)]
struct Upload {
    nodes: Vec<Node>,
    slot_tris: Vec<[u32; 4]>,
    corners: Vec<Vec3>,
    instances: Vec<GpuInstance>,
}

/// A recorded batch on its way back.
pub(crate) struct SceneReadback {
    hits: Readback<SceneHit>,
}

impl GpuScene {
    pub fn new(ctx: &GpuContext) -> Self {
        Self {
            tlas: GpuBuffer::storage(ctx, "scene tlas", 1024),
            instances: GpuBuffer::storage(ctx, "scene instances", 1024),
            blas: GpuBuffer::storage(ctx, "scene blas", 1024),
            slot_tris: GpuBuffer::storage(ctx, "scene slot triangles", 1024),
            corners: GpuBuffer::storage(ctx, "scene corners", 1024),
            entities: Vec::new(),
            version: None,
            batches: [Batch::new(ctx), Batch::new(ctx)],
            upload: Upload::default(),
        }
    }

    /// Uploads the world's trees when they changed since the last upload. Every entity's tree is sent whole
    /// (its nodes, and its triangles' corners in slot order): simple and exact, and the place to make
    /// incremental when uploads show up in profiles.
    pub fn sync(&mut self, ctx: &GpuContext, world: &TraceWorld) {
        if self.version == Some(world.version) {
            return;
        }
        self.version = Some(world.version);
        let tlas = world.tlas();
        let n = tlas.primitive_count();
        self.entities.clear();
        // The upload arrays keep their memory from one sync to the next.
        let Upload {
            nodes,
            slot_tris,
            corners,
            instances,
        } = &mut self.upload;
        nodes.clear();
        slot_tris.clear();
        corners.clear();
        instances.clear();
        for slot in 0..n {
            let e = world.tlas_entity(tlas.prim_indices()[slot]);
            self.entities.push(e);
            let inst = &world.instances[&e];
            let bvh = &inst.bvh;
            let (node_offset, slot_offset, vertex_offset) = (
                nodes.len() as u32,
                slot_tris.len() as u32,
                corners.len() as u32,
            );
            nodes.extend_from_slice(bvh.bvh().nodes());
            for (s, (tri, &p)) in bvh
                .slot_triangles()
                .iter()
                .zip(bvh.bvh().prim_indices())
                .enumerate()
            {
                let base = 3 * s as u32;
                slot_tris.push([base, base + 1, base + 2, p]);
                corners.extend_from_slice(tri);
            }
            let m = inst.inverse;
            instances.push(GpuInstance {
                columns: [
                    m.matrix3.x_axis.extend(0.0).to_array(),
                    m.matrix3.y_axis.extend(0.0).to_array(),
                    m.matrix3.z_axis.extend(0.0).to_array(),
                    m.translation.extend(0.0).to_array(),
                ],
                normal: [0, 1, 2].map(|c| inst.normal_matrix.col(c).extend(0.0).to_array()),
                node_offset,
                slot_offset,
                vertex_offset,
                layers: inst.layers,
                entity: split(e),
                _pad: [0; 2],
            });
        }
        for (buf, bytes) in [
            (&mut self.tlas, std::mem::size_of_val(tlas.nodes())),
            (&mut self.instances, std::mem::size_of_val(&instances[..])),
            (&mut self.blas, std::mem::size_of_val(&nodes[..])),
            (&mut self.slot_tris, std::mem::size_of_val(&slot_tris[..])),
            (&mut self.corners, std::mem::size_of_val(&corners[..])),
        ] {
            buf.ensure(ctx, bytes as u64);
        }
        self.tlas.write(ctx, tlas.nodes());
        self.instances.write(ctx, instances);
        self.blas.write(ctx, nodes);
        self.slot_tris.write(ctx, slot_tris);
        self.corners.write(ctx, corners);
    }

    /// Records one batch (`any`: occlusion, else closest hits). Batch 0 and 1 have separate buffers, so one
    /// of each kind may go into the same submission.
    pub fn record(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        requests: &[SceneRequest],
        any: bool,
    ) -> SceneReadback {
        let tlas_len = self.tlas_nodes();
        let b = &mut self.batches[any as usize];
        let n = requests.len() as u32;
        b.up_rays.clear();
        b.up_rays
            .extend(requests.iter().map(|r| GpuRay::for_scene(&r.ray)));
        b.up_filters.clear();
        b.up_filters.extend(requests.iter().map(|r| {
            let [lo, hi] = r.exclude.map_or([u32::MAX; 2], split);
            [r.layers, lo, hi, 0]
        }));
        b.rays
            .ensure(ctx, std::mem::size_of_val(&b.up_rays[..]) as u64);
        b.filters
            .ensure(ctx, std::mem::size_of_val(&b.up_filters[..]) as u64);
        b.hits
            .ensure(ctx, n as u64 * std::mem::size_of::<SceneHit>() as u64);
        b.rays.write(ctx, &b.up_rays);
        b.filters.write(ctx, &b.up_filters);
        ctx.queue.write_buffer(
            b.params.buffer(),
            0,
            bytemuck::bytes_of(&[n, any as u32, tlas_len, 0]),
        );
        if n > 0 {
            let k = &ctx.kernels;
            let group = bind_group(
                ctx,
                &k.scene.layout,
                &[
                    self.tlas.binding(),
                    self.instances.binding(),
                    self.blas.binding(),
                    self.slot_tris.binding(),
                    self.corners.binding(),
                    b.rays.binding(),
                    b.filters.binding(),
                    b.hits.binding(),
                    wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer: b.params.buffer(),
                        offset: 0,
                        size: wgpu::BufferSize::new(16),
                    }),
                ],
            );
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("kinetrace scene"),
                timestamp_writes: None,
            });
            pass.set_pipeline(k.scene.pipeline("scene_trace"));
            pass.set_bind_group(0, &group, &[0]);
            let (x, y) = groups(n, 64);
            pass.dispatch_workgroups(x, y, 1);
        }
        SceneReadback {
            hits: Readback::record(ctx, encoder, b.hits.buffer(), requests.len()),
        }
    }

    /// Number of TLAS nodes uploaded (0 for an empty world).
    fn tlas_nodes(&self) -> u32 {
        if self.entities.is_empty() {
            0
        } else {
            (2 * self.entities.len() - 1) as u32
        }
    }

    /// Turns a batch's answers into world-space hits (blocking until they are there). Needs nothing of the
    /// world but the entity list of the upload the batch ran on, so it can be called a frame later.
    pub fn closest_hits(
        &self,
        ctx: &GpuContext,
        readback: SceneReadback,
        requests: &[SceneRequest],
    ) -> crate::Result<Vec<Option<RayHit>>> {
        let hits = readback.hits.wait(ctx)?;
        Ok(hits
            .iter()
            .zip(requests)
            .map(|(h, r)| {
                (h.prim != u32::MAX).then(|| RayHit {
                    entity: self.entities[h.instance as usize],
                    distance: h.t,
                    point: r.ray.at(h.t),
                    normal: Vec3::from_array(h.normal),
                    triangle: h.prim,
                    barycentrics: glam::Vec2::new(h.u, h.v),
                })
            })
            .collect())
    }

    /// Whether each occlusion request was blocked (blocking until the answers are there).
    pub fn occluded(&self, ctx: &GpuContext, readback: SceneReadback) -> crate::Result<Vec<bool>> {
        Ok(readback
            .hits
            .wait(ctx)?
            .iter()
            .map(|h| h.prim != u32::MAX)
            .collect())
    }
}

/// An entity as two u32 (its bits).
fn split(e: Entity) -> [u32; 2] {
    let b = e.to_bits();
    [b as u32, (b >> 32) as u32]
}
