//! Batched closest-hit and any-hit queries on the GPU (shaders/trace.wgsl).

use super::buffers::{GpuBuffer, Readback, bind_group};
use super::{GpuContext, GpuMeshBvh};
use crate::Result;
use crate::geometry::{Ray, TriangleRay};
use bytemuck::{Pod, Zeroable};

/// A ray as the kernel reads it: the slab-test reciprocal and the watertight test's shear rows, computed
/// on the CPU so both devices intersect with identical edge functions. 80 bytes.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct GpuRay {
    origin: [f32; 3],
    tmin: f32,
    inv_dir: [f32; 3],
    tmax: f32,
    row_x: [f32; 3],
    /// Bit k: component k of the direction is negative (sign bit); bit 3 + k: it is zero; bit 31: the ray
    /// is invalid and misses.
    dir_bits: u32,
    row_y: [f32; 3],
    _pad0: u32,
    row_z: [f32; 3],
    _pad1: u32,
}

const _: () = assert!(std::mem::size_of::<GpuRay>() == 80);

/// The lowest `tmin` the kernels take (`-BIG` in shaders/ray_tests.wgsl): their box test marks a miss
/// with a value below it.
const TMIN_FLOOR: f32 = -3.0e38;

impl GpuRay {
    /// The GPU form of `ray`. The kernel avoids infinities (WGSL may assume none): `tmax = ∞` becomes
    /// `f32::MAX` and a `tmin` below `-3e38` (`-∞`, say) becomes `-3e38` (same answers: no hit of a
    /// finite scene lies that far out), and zero direction components get a zero reciprocal and a flag.
    /// A negative `tmin` reaches behind the origin, as on the CPU.
    pub(crate) fn new(ray: &Ray) -> Self {
        if !ray.is_valid() {
            return GpuRay {
                dir_bits: 1 << 31,
                ..Zeroable::zeroed()
            };
        }
        let [row_x, row_y, row_z] = TriangleRay::new(ray).rows();
        let mut bits = 0;
        for k in 0..3 {
            bits |= (ray.dir()[k].is_sign_negative() as u32) << k;
            bits |= ((ray.dir()[k] == 0.0) as u32) << (3 + k);
        }
        let inv = ray
            .inv_dir()
            .to_array()
            .map(|i| if i.is_finite() { i } else { 0.0 });
        GpuRay {
            origin: ray.origin.to_array(),
            tmin: ray.tmin.max(TMIN_FLOOR),
            inv_dir: inv,
            tmax: ray.tmax.min(f32::MAX),
            row_x: row_x.to_array(),
            dir_bits: bits,
            row_y: row_y.to_array(),
            _pad0: 0,
            row_z: row_z.to_array(),
            _pad1: 0,
        }
    }
}

impl GpuRay {
    /// The end of the ray's range as the kernels see it.
    pub(crate) fn tmax(&self) -> f32 {
        self.tmax
    }

    /// The form scene.wgsl takes: triangles are tested in each entity's object space, so instead of the
    /// world-space shear rows it needs the world direction, sent in `row_x`.
    pub(crate) fn for_scene(ray: &Ray) -> Self {
        let mut r = Self::new(ray);
        r.row_x = ray.dir().to_array();
        r
    }
}

/// One ray's answer from the GPU.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct GpuHit {
    /// Distance (closest hit); for a miss, the ray's `tmax`.
    pub t: f32,
    /// Triangle index, `u32::MAX` for a miss.
    pub prim: u32,
    /// Barycentric weight of the second vertex.
    pub u: f32,
    /// Barycentric weight of the third vertex.
    pub v: f32,
}

impl GpuHit {
    /// The triangle hit, if any.
    pub fn primitive(&self) -> Option<u32> {
        (self.prim != u32::MAX).then_some(self.prim)
    }
}

/// Which query to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Query {
    /// Nearest hit: smallest `t`, then lowest triangle index among those reached.
    Closest,
    /// Any hit within the ray's range (shadow rays): stops at the first.
    Any,
}

/// Ray and hit buffers for batched queries, grown as needed and reused across frames.
pub struct GpuRays {
    rays: GpuBuffer,
    hits: GpuBuffer,
    params: GpuBuffer,
    upload: Vec<GpuRay>,
}

impl GpuRays {
    /// Empty buffers; they grow with the largest batch seen.
    pub fn new(ctx: &GpuContext) -> Self {
        Self {
            rays: GpuBuffer::storage(ctx, "rays", 80 * 1024),
            hits: GpuBuffer::storage(ctx, "hits", 16 * 1024),
            params: GpuBuffer::uniform(ctx, "trace params"),
            upload: Vec::new(),
        }
    }

    /// Records `query` for every ray against `bvh` and the read-back of the answers (one per ray, in
    /// order). Record at most one batch per [`GpuRays`] per submission: the rays are uploaded at submit.
    pub fn record(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        bvh: &GpuMeshBvh,
        rays: &[Ray],
        query: Query,
    ) -> Readback<GpuHit> {
        let n = rays.len() as u32;
        self.rays.ensure(ctx, n as u64 * 80);
        self.hits.ensure(ctx, n as u64 * 16);
        self.upload.clear();
        self.upload.extend(rays.iter().map(GpuRay::new));
        self.rays.write(ctx, &self.upload);
        ctx.write_buffer(
            self.params.buffer(),
            0,
            bytemuck::bytes_of(&[n, 0u32, 0, 0]),
        );
        let k = &ctx.kernels;
        let group = bind_group(
            ctx,
            &k.trace.layout,
            &[
                bvh.nodes().as_entire_binding(),
                bvh.slot_ids().as_entire_binding(),
                bvh.indices().as_entire_binding(),
                bvh.positions().as_entire_binding(),
                self.rays.binding(),
                self.hits.binding(),
                wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                    buffer: self.params.buffer(),
                    offset: 0,
                    size: wgpu::BufferSize::new(16),
                }),
            ],
        );
        if n > 0 && bvh.triangle_count() > 0 {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("kinetrace trace"),
                timestamp_writes: None,
            });
            pass.set_pipeline(k.trace.pipeline(match query {
                Query::Closest => "closest",
                Query::Any => "any_hit",
            }));
            pass.set_bind_group(0, &group, &[0]);
            let (x, y) = ctx.groups(n, 64);
            pass.dispatch_workgroups(x, y, 1);
        } else if n > 0 {
            // An empty mesh: every ray misses.
            let miss: Vec<GpuHit> = self
                .upload
                .iter()
                .map(|r| GpuHit {
                    t: r.tmax,
                    prim: u32::MAX,
                    u: 0.0,
                    v: 0.0,
                })
                .collect();
            self.hits.write(ctx, &miss);
        }
        Readback::record(ctx, encoder, self.hits.buffer(), rays.len())
    }

    /// Runs `query` for `rays` and waits for the answers: the blocking convenience.
    pub fn run(
        &mut self,
        ctx: &GpuContext,
        bvh: &GpuMeshBvh,
        rays: &[Ray],
        query: Query,
    ) -> Result<Vec<GpuHit>> {
        ctx.check_threads("rays", rays.len() as u64, 64)?;
        ctx.check_storage("rays", (rays.len() * std::mem::size_of::<GpuRay>()) as u64)?;
        let mut enc = ctx.encoder();
        let r = self.record(ctx, &mut enc, bvh, rays, query);
        ctx.submit(enc);
        r.wait(ctx)
    }
}
