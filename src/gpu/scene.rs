//! Batched two-level queries on the GPU (shaders/scene.wgsl): the top-level tree over instances, then each
//! reached instance's tree in its object space. Instances are named by the caller's 64-bit ids (the ECS
//! passes entity bits); nothing here knows where they come from.

use super::GpuContext;
use super::buffers::{GpuBuffer, Readback, bind_group};
use super::trace::GpuRay;
use crate::bvh::{Bvh, Hit, MeshBvh, Node};
use crate::geometry::Ray;
use bytemuck::{Pod, Zeroable};
use glam::{Affine3A, Mat3A, Vec3};

/// One instance as the kernel reads it (144 bytes).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct GpuInstance {
    /// World-to-object transform, columns x, y, z, translation (w unused).
    columns: [[f32; 4]; 4],
    /// Object-to-world normal matrix, columns.
    normal: [[f32; 4]; 3],
    /// The instance's root in the BLAS node buffer.
    node_offset: u32,
    /// Its first entry in the slot-triangle buffer.
    slot_offset: u32,
    /// Its first corner in the corner buffer (slot-triangle corners are relative to it).
    vertex_offset: u32,
    /// Query layers it is on.
    layers: u32,
    /// The instance id, low word first (compared with a request's exclusion).
    entity: [u32; 2],
    _pad: [u32; 2],
}

const _: () = assert!(std::mem::size_of::<GpuInstance>() == 144);

impl GpuInstance {
    /// An instance with world-to-object transform `inverse`, object-to-world `normal` matrix, its tree's
    /// root, first slot and first corner (`offsets`) in the scene's buffers, on `layers`, named `id`.
    pub(crate) fn new(
        inverse: &Affine3A,
        normal: &Mat3A,
        offsets: [u32; 3],
        layers: u32,
        id: u64,
    ) -> Self {
        let m = inverse;
        let [node_offset, slot_offset, vertex_offset] = offsets;
        Self {
            columns: [
                m.matrix3.x_axis.extend(0.0).to_array(),
                m.matrix3.y_axis.extend(0.0).to_array(),
                m.matrix3.z_axis.extend(0.0).to_array(),
                m.translation.extend(0.0).to_array(),
            ],
            normal: [0, 1, 2].map(|c| normal.col(c).extend(0.0).to_array()),
            node_offset,
            slot_offset,
            vertex_offset,
            layers,
            entity: split(id),
            _pad: [0; 2],
        }
    }
}

/// One ray's answer (48 bytes): `instance` is a TLAS slot; the unit world normal is computed on the GPU.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(crate) struct SceneHit {
    t: f32,
    prim: u32,
    u: f32,
    v: f32,
    instance: u32,
    /// The id of the instance hit, low word first.
    entity: [u32; 2],
    _pad: u32,
    normal: [f32; 3],
    _pad2: f32,
}

/// A request the GPU can answer: layer mask and at most one excluded instance id (requests with predicates
/// or longer exclusion lists stay on the CPU).
pub(crate) struct SceneRequest {
    pub ray: Ray,
    pub layers: u32,
    pub exclude: Option<u64>,
}

/// One instance as [`GpuScene::sync`] uploads it.
pub(crate) struct SceneInstance<'a> {
    /// The caller's id, reported with hits and compared with [`SceneRequest::exclude`].
    pub id: u64,
    /// The instance's tree, in object space.
    pub bvh: &'a MeshBvh,
    /// World-to-object transform.
    pub inverse: Affine3A,
    /// Object-to-world normal matrix (inverse transpose of the linear part).
    pub normal_matrix: Mat3A,
    /// Query layers the instance is on.
    pub layers: u32,
}

/// Ray, filter and hit buffers of one kind of query.
pub(crate) struct Batch {
    rays: GpuBuffer,
    filters: GpuBuffer,
    hits: GpuBuffer,
    params: GpuBuffer,
    up_rays: Vec<GpuRay>,
    up_filters: Vec<[u32; 4]>,
}

impl Batch {
    pub(crate) fn new(ctx: &GpuContext) -> Self {
        Self {
            rays: GpuBuffer::storage(ctx, "scene rays", 80 * 1024),
            filters: GpuBuffer::storage(ctx, "scene filters", 16 * 1024),
            hits: GpuBuffer::storage(ctx, "scene hits", 48 * 1024),
            params: GpuBuffer::uniform(ctx, "scene params"),
            up_rays: Vec::new(),
            up_filters: Vec::new(),
        }
    }

    /// Uploads `requests` and records their traversal of `scene` (its top-level nodes, instances in
    /// top-level slot order, meshes' nodes, slot ids, vertex indices and corners; `tlas_len` top-level
    /// nodes) and the answers' read-back.
    pub(crate) fn record(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        scene: [wgpu::BindingResource<'_>; 6],
        tlas_len: u32,
        requests: &[SceneRequest],
        any: bool,
    ) -> SceneReadback {
        let b = self;
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
        ctx.write_buffer(
            b.params.buffer(),
            0,
            bytemuck::bytes_of(&[n, any as u32, tlas_len, 0]),
        );
        if n > 0 {
            let k = &ctx.kernels;
            let [tlas, instances, blas, ids, indices, corners] = scene;
            let group = bind_group(
                ctx,
                &k.scene.layout,
                &[
                    tlas,
                    instances,
                    blas,
                    ids,
                    indices,
                    corners,
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
            let (x, y) = ctx.groups(n, 64);
            pass.dispatch_workgroups(x, y, 1);
        }
        SceneReadback {
            hits: Readback::record(ctx, encoder, b.hits.buffer(), requests.len()),
        }
    }
}

/// A world's structures on the GPU, re-uploaded when the world changed, and the buffers of two batches
/// (closest hits and occlusion), recorded into one submission.
pub(crate) struct GpuScene {
    tlas: GpuBuffer,
    instances: GpuBuffer,
    blas: GpuBuffer,
    ids: GpuBuffer,
    indices: GpuBuffer,
    corners: GpuBuffer,
    /// Instances uploaded.
    count: usize,
    version: Option<u64>,
    batches: [Batch; 2],
    upload: Upload,
}

/// What [`GpuScene::sync`] sends, built on the CPU.
#[derive(Default)]
struct Upload {
    nodes: Vec<Node>,
    /// Per slot its triangle's id.
    ids: Vec<u32>,
    /// Per triangle (by id, from the instance's slot offset) its corners' indices from the instance's
    /// vertex offset.
    indices: Vec<[u32; 3]>,
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
            ids: GpuBuffer::storage(ctx, "scene slot ids", 1024),
            indices: GpuBuffer::storage(ctx, "scene indices", 1024),
            corners: GpuBuffer::storage(ctx, "scene corners", 1024),
            count: 0,
            version: None,
            batches: [Batch::new(ctx), Batch::new(ctx)],
            upload: Upload::default(),
        }
    }

    /// Uploads a scene — its top-level tree over instance boxes, and per TLAS slot in order the instance
    /// there — unless `version` is the one of the last upload (then `instances` is not iterated). Every
    /// instance's tree is sent whole (its nodes, and its triangles' corners in slot order): simple and
    /// exact, and the place to make incremental when uploads show up in profiles.
    pub fn sync<'a>(
        &mut self,
        ctx: &GpuContext,
        version: u64,
        tlas: &Bvh,
        instances: impl IntoIterator<Item = SceneInstance<'a>>,
    ) {
        if self.version == Some(version) {
            return;
        }
        self.version = Some(version);
        self.count = 0;
        // The upload arrays keep their memory from one sync to the next.
        let Upload {
            nodes,
            ids,
            indices,
            corners,
            instances: uploads,
        } = &mut self.upload;
        nodes.clear();
        ids.clear();
        indices.clear();
        corners.clear();
        uploads.clear();
        for inst in instances {
            self.count += 1;
            let bvh = inst.bvh;
            let (node_offset, slot_offset, vertex_offset) =
                (nodes.len() as u32, ids.len() as u32, corners.len() as u32);
            nodes.extend_from_slice(bvh.bvh().nodes());
            let prims = bvh.bvh().prim_indices();
            ids.extend_from_slice(prims);
            indices.resize(ids.len(), [0; 3]);
            let by_id = &mut indices[slot_offset as usize..];
            for (s, (tri, &p)) in bvh.slot_triangles().iter().zip(prims).enumerate() {
                let base = 3 * s as u32;
                by_id[p as usize] = [base, base + 1, base + 2];
                corners.extend_from_slice(tri);
            }
            uploads.push(GpuInstance::new(
                &inst.inverse,
                &inst.normal_matrix,
                [node_offset, slot_offset, vertex_offset],
                inst.layers,
                inst.id,
            ));
        }
        for (buf, bytes) in [
            (&mut self.tlas, std::mem::size_of_val(tlas.nodes())),
            (&mut self.instances, std::mem::size_of_val(&uploads[..])),
            (&mut self.blas, std::mem::size_of_val(&nodes[..])),
            (&mut self.ids, std::mem::size_of_val(&ids[..])),
            (&mut self.indices, std::mem::size_of_val(&indices[..])),
            (&mut self.corners, std::mem::size_of_val(&corners[..])),
        ] {
            buf.ensure(ctx, bytes as u64);
        }
        self.tlas.write(ctx, tlas.nodes());
        self.instances.write(ctx, uploads);
        self.blas.write(ctx, nodes);
        self.ids.write(ctx, ids);
        self.indices.write(ctx, indices);
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
        let scene = [
            self.tlas.binding(),
            self.instances.binding(),
            self.blas.binding(),
            self.ids.binding(),
            self.indices.binding(),
            self.corners.binding(),
        ];
        self.batches[any as usize].record(ctx, encoder, scene, tlas_len, requests, any)
    }

    /// Number of TLAS nodes uploaded (0 for an empty scene).
    fn tlas_nodes(&self) -> u32 {
        if self.count == 0 {
            0
        } else {
            (2 * self.count - 1) as u32
        }
    }
}

impl SceneReadback {
    /// Whether the GPU has finished the answers (then [`wait`](Self::wait) does not block); never blocks.
    pub fn ready(&self, ctx: &GpuContext) -> bool {
        self.hits.ready(ctx)
    }

    /// The answers, one per request, blocking until they are there.
    pub fn wait(self, ctx: &GpuContext) -> crate::Result<Vec<SceneHit>> {
        self.hits.wait(ctx)
    }
}

impl SceneHit {
    /// A closest-hit answer: the id of the instance hit and the hit, its normal in world space. Needs
    /// nothing of the scene, so it can be read a frame later.
    pub fn closest(&self) -> Option<(u64, Hit)> {
        (self.prim != u32::MAX).then(|| {
            let hit = Hit {
                t: self.t,
                primitive: self.prim,
                u: self.u,
                v: self.v,
                normal: Vec3::from_array(self.normal),
            };
            (self.entity[0] as u64 | (self.entity[1] as u64) << 32, hit)
        })
    }

    /// An occlusion answer: whether the segment was blocked.
    pub fn blocked(&self) -> bool {
        self.prim != u32::MAX
    }
}

/// An id as two u32, low word first.
pub(crate) fn split(id: u64) -> [u32; 2] {
    [id as u32, (id >> 32) as u32]
}
