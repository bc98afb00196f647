//! Batched queries on the GPU for [`TraceMode::GpuWhenAvailable`](super::TraceMode) and
//! [`TraceMode::GpuRequired`](super::TraceMode).

use bevy_ecs::prelude::*;

/// The GPU state of batched queries, present when a GPU mode found an adapter.
#[derive(Resource)]
pub struct GpuQueries {
    #[cfg(feature = "gpu")]
    inner: imp::Inner,
    /// Without the `gpu` feature there is never one.
    #[cfg(not(feature = "gpu"))]
    never: std::convert::Infallible,
}

impl GpuQueries {
    /// The adapter answering the queries.
    pub fn adapter_name(&self) -> &str {
        #[cfg(feature = "gpu")]
        return self.inner.ctx.adapter_name();
        #[cfg(not(feature = "gpu"))]
        match self.never {}
    }
}

#[cfg(feature = "gpu")]
mod imp {
    use super::*;
    use crate::ecs::{RayHit, RayQueue, RayResults, TraceWorld};
    use crate::geometry::Ray;
    use crate::gpu::GpuContext;
    use crate::gpu::scene::{GpuScene, SceneInstance, SceneReadback, SceneRequest};

    /// A batch submitted but not yet collected: the CPU-answered part is in `fresh`, the GPU answers
    /// arrive through the read-backs and go to the recorded indices.
    pub(crate) struct Pending {
        fresh: RayResults,
        ray_at: Vec<usize>,
        ray_requests: Vec<SceneRequest>,
        closest: SceneReadback,
        shadow_at: Vec<usize>,
        shadows: SceneReadback,
    }

    pub(crate) struct Inner {
        pub(super) ctx: GpuContext,
        scene: GpuScene,
        pending: Option<Pending>,
        /// The context's totals when the last frame's traffic was counted.
        pub(super) counted: crate::gpu::GpuCounters,
    }

    impl GpuQueries {
        /// The device, for the GPU rebuilds of [`RebuildPolicy::Adaptive`](crate::ecs::RebuildPolicy).
        pub(crate) fn context(&self) -> &GpuContext {
            &self.inner.ctx
        }

        pub(crate) fn new(ctx: GpuContext) -> Self {
            let scene = GpuScene::new(&ctx);
            let counted = ctx.counters();
            GpuQueries {
                inner: Inner {
                    ctx,
                    scene,
                    pending: None,
                    counted,
                },
            }
        }

        /// Answers `queue` (requests the GPU cannot take — predicates, several exclusions — on the CPU) and
        /// submits; the answers come back through [`collect`](Self::collect).
        pub(crate) fn submit(&mut self, world: &TraceWorld, queue: &RayQueue, frame: u64) {
            let inner = &mut self.inner;
            let tlas = world.tlas();
            let instances = tlas.prim_indices().iter().map(|&p| {
                let entity = world.tlas_entity(p);
                let inst = &world.instances[&entity];
                SceneInstance {
                    id: entity.to_bits(),
                    bvh: &inst.bvh,
                    inverse: inst.inverse,
                    normal_matrix: inst.normal_matrix,
                    layers: inst.layers,
                }
            });
            inner.scene.sync(&inner.ctx, world.version, tlas, instances);
            let mut fresh = RayResults {
                frame,
                hits: Vec::with_capacity(queue.rays.len()),
                shadows: Vec::with_capacity(queue.shadows.len()),
            };
            let gpu_ok =
                |f: &super::super::QueryFilter| f.predicate.is_none() && f.excluded.len() <= 1;
            let (mut ray_at, mut ray_requests, mut shadow_at, mut shadow_requests) =
                (vec![], vec![], vec![], vec![]);
            for (i, r) in queue.rays.iter().enumerate() {
                if gpu_ok(&r.filter) {
                    ray_at.push(i);
                    ray_requests.push(SceneRequest {
                        ray: r.ray,
                        layers: r.filter.layers,
                        exclude: r.filter.excluded.first().map(|e| e.to_bits()),
                    });
                    fresh.hits.push((r.tag, None));
                } else {
                    fresh
                        .hits
                        .push((r.tag, world.cast_ray(&r.ray, f32::INFINITY, &r.filter)));
                }
            }
            for (i, s) in queue.shadows.iter().enumerate() {
                if gpu_ok(&s.filter) {
                    shadow_at.push(i);
                    shadow_requests.push(SceneRequest {
                        ray: Ray::segment(s.from, s.to),
                        layers: s.filter.layers,
                        exclude: s.filter.excluded.first().map(|e| e.to_bits()),
                    });
                    fresh.shadows.push((s.tag, false));
                } else {
                    fresh
                        .shadows
                        .push((s.tag, world.occluded(s.from, s.to, &s.filter)));
                }
            }
            let mut enc = inner.ctx.encoder();
            let closest = inner
                .scene
                .record(&inner.ctx, &mut enc, &ray_requests, false);
            let shadows = inner
                .scene
                .record(&inner.ctx, &mut enc, &shadow_requests, true);
            inner.ctx.submit(enc);
            inner.pending = Some(Pending {
                fresh,
                ray_at,
                ray_requests,
                closest,
                shadow_at,
                shadows,
            });
        }

        /// The answers of the last submitted batch (blocking until the GPU is done), or `None` when there is
        /// none.
        pub(crate) fn collect(&mut self) -> Option<crate::Result<RayResults>> {
            let inner = &mut self.inner;
            let p = inner.pending.take()?;
            let mut fresh = p.fresh;
            let run = || -> crate::Result<RayResults> {
                let hits = inner.scene.closest_hits(&inner.ctx, p.closest)?;
                for ((at, r), h) in p.ray_at.iter().zip(&p.ray_requests).zip(hits) {
                    fresh.hits[*at].1 = h.map(|(id, h)| RayHit {
                        entity: Entity::from_bits(id),
                        distance: h.t,
                        point: r.ray.at(h.t),
                        normal: h.normal,
                        triangle: h.primitive,
                        barycentrics: glam::Vec2::new(h.u, h.v),
                    });
                }
                let blocked = inner.scene.occluded(&inner.ctx, p.shadows)?;
                for (at, b) in p.shadow_at.iter().zip(blocked) {
                    fresh.shadows[*at].1 = b;
                }
                Ok(fresh)
            };
            Some(run())
        }
    }
}

/// After the queries: this frame's GPU traffic into [`TraceStats::gpu`](super::TraceStats) — what the
/// context counted since the same point of the last frame (clones of one context share their totals).
#[cfg(feature = "gpu")]
pub(crate) fn gpu_counters_system(
    gpu: Option<ResMut<GpuQueries>>,
    mut stats: ResMut<super::TraceStats>,
) {
    let Some(mut gpu) = gpu else { return };
    let now = gpu.inner.ctx.counters();
    stats.gpu = now.since(&gpu.inner.counted);
    gpu.inner.counted = now;
}
