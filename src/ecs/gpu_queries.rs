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
pub(crate) use imp::{Answers, Pending};

#[cfg(feature = "gpu")]
mod imp {
    use super::*;
    use crate::ecs::{RayHit, RayQueue, RayResults, TraceWorld};
    use crate::geometry::Ray;
    use crate::gpu::scene::{GpuScene, SceneInstance, SceneReadback, SceneRequest};
    use crate::gpu::{FrameTimer, GpuContext, ResidentMesh, ResidentPairs, ResidentScene};
    use std::collections::{HashMap, VecDeque};

    /// A batch submitted but not yet collected: the CPU-answered part is in `fresh`, the GPU answers
    /// arrive through the read-backs and go to the recorded indices.
    pub(crate) struct Pending {
        fresh: RayResults,
        ray_at: Vec<usize>,
        ray_requests: Vec<SceneRequest>,
        closest: Option<SceneReadback>,
        shadow_at: Vec<usize>,
        shadow_requests: Vec<SceneRequest>,
        shadows: Option<SceneReadback>,
        /// The resident frame's collider pairs.
        contacts: Option<crate::ecs::gpu_collide::PendingContacts>,
        /// The resident frame's timestamps.
        phases: Option<crate::gpu::PhasesReadback>,
    }

    /// A collected frame: the batch's answers and, from the resident frame with colliders, its contact
    /// pairs.
    pub(crate) struct Answers {
        pub(crate) rays: RayResults,
        pub(crate) contacts: Option<crate::Result<crate::ecs::gpu_collide::Found>>,
        pub(crate) phases: Option<crate::Result<crate::gpu::GpuPhases>>,
    }

    /// The state of the GPU-resident frame (see [`TraceConfig::resident`](crate::ecs::TraceConfig)).
    pub(crate) struct Resident {
        pub(crate) meshes: HashMap<Entity, ResidentMesh>,
        pub(crate) scene: ResidentScene,
        pub(crate) pairs: ResidentPairs,
        /// `None` where the device has no timestamp queries.
        pub(crate) timer: Option<FrameTimer>,
        /// The meshes' planners under the adaptive policy.
        pub(crate) policies: crate::ecs::gpu_policy::ResidentPolicies,
    }

    pub(crate) struct Inner {
        pub(super) ctx: GpuContext,
        scene: GpuScene,
        /// Submitted batches, oldest first.
        pending: VecDeque<Pending>,
        resident: Option<Resident>,
        /// The context's totals when the last frame's traffic was counted.
        pub(super) counted: crate::gpu::GpuCounters,
    }

    impl Pending {
        /// Splits `queue` into what the GPU answers (requests with a layer mask and at most one exclusion)
        /// and what `world` answers now on the CPU (predicates, longer exclusion lists).
        pub(crate) fn new(world: &TraceWorld, queue: &RayQueue, frame: u64) -> Self {
            let mut p = Pending {
                fresh: RayResults {
                    frame,
                    hits: Vec::with_capacity(queue.rays.len()),
                    shadows: Vec::with_capacity(queue.shadows.len()),
                },
                ray_at: vec![],
                ray_requests: vec![],
                closest: None,
                shadow_at: vec![],
                shadow_requests: vec![],
                shadows: None,
                contacts: None,
                phases: None,
            };
            let gpu_ok =
                |f: &super::super::QueryFilter| f.predicate.is_none() && f.excluded.len() <= 1;
            let request = |ray, f: &super::super::QueryFilter| SceneRequest {
                ray,
                layers: f.layers,
                exclude: f.excluded.first().map(|e| e.to_bits()),
            };
            for (i, r) in queue.rays.iter().enumerate() {
                if gpu_ok(&r.filter) {
                    p.ray_at.push(i);
                    p.ray_requests.push(request(r.ray, &r.filter));
                    p.fresh.hits.push((r.tag, None));
                } else {
                    let hit = world.cast_ray(&r.ray, f32::INFINITY, &r.filter);
                    p.fresh.hits.push((r.tag, hit));
                }
            }
            for (i, s) in queue.shadows.iter().enumerate() {
                if gpu_ok(&s.filter) {
                    p.shadow_at.push(i);
                    p.shadow_requests
                        .push(request(Ray::segment(s.from, s.to), &s.filter));
                    p.fresh.shadows.push((s.tag, false));
                } else {
                    let blocked = world.occluded(s.from, s.to, &s.filter);
                    p.fresh.shadows.push((s.tag, blocked));
                }
            }
            p
        }

        /// The GPU's requests: closest hits, occlusion.
        pub(crate) fn requests(&self) -> (&[SceneRequest], &[SceneRequest]) {
            (&self.ray_requests, &self.shadow_requests)
        }

        /// Whether every read-back of the batch is there (polls, never blocks).
        fn ready(&self, ctx: &GpuContext) -> bool {
            let (Some(closest), Some(shadows)) = (&self.closest, &self.shadows) else {
                return false;
            };
            closest.ready(ctx)
                && shadows.ready(ctx)
                && self.contacts.as_ref().is_none_or(|c| c.ready(ctx))
                && self.phases.as_ref().is_none_or(|p| p.ready(ctx))
        }

        /// The answers, if both read-backs are there (or `blocking`, after waiting for them).
        fn answers(&mut self, ctx: &GpuContext, blocking: bool) -> Option<crate::Result<Answers>> {
            if !(blocking || self.ready(ctx)) {
                return None;
            }
            let (closest, shadows) = (self.closest.take()?, self.shadows.take()?);
            let (hits, blocked) = (closest.wait(ctx), shadows.wait(ctx));
            let run = || -> crate::Result<RayResults> {
                let mut fresh = std::mem::take(&mut self.fresh);
                for ((at, r), h) in self.ray_at.iter().zip(&self.ray_requests).zip(hits?) {
                    fresh.hits[*at].1 = h.closest().map(|(id, h)| RayHit {
                        entity: Entity::from_bits(id),
                        distance: h.t,
                        point: r.ray.at(h.t),
                        normal: h.normal,
                        triangle: h.primitive,
                        barycentrics: glam::Vec2::new(h.u, h.v),
                    });
                }
                for (at, b) in self.shadow_at.iter().zip(blocked?) {
                    fresh.shadows[*at].1 = b.blocked();
                }
                Ok(fresh)
            };
            let contacts = self.contacts.take().map(|c| c.finish(ctx));
            let phases = self.phases.take().map(|p| p.wait(ctx));
            Some(run().map(|rays| Answers {
                rays,
                contacts,
                phases,
            }))
        }
    }

    impl GpuQueries {
        /// The device the queries run on: for the GPU rebuilds of
        /// [`RebuildPolicy::Adaptive`](crate::ecs::RebuildPolicy), and for a frame's other GPU work on
        /// the same device (a [`GpuShadowMap`](crate::gpu::GpuShadowMap), say).
        pub fn context(&self) -> &GpuContext {
            &self.inner.ctx
        }

        pub(crate) fn new(ctx: GpuContext) -> Self {
            let scene = GpuScene::new(&ctx);
            let counted = ctx.counters();
            GpuQueries {
                inner: Inner {
                    ctx,
                    scene,
                    pending: VecDeque::new(),
                    resident: None,
                    counted,
                },
            }
        }

        /// Answers `queue` (requests the GPU cannot take — predicates, several exclusions — on the CPU) and
        /// submits; the answers come back through [`collect`](Self::collect). Uploads the world's trees
        /// whenever it changed.
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
            let mut p = Pending::new(world, queue, frame);
            let mut enc = inner.ctx.encoder();
            p.closest = Some((inner.scene).record(&inner.ctx, &mut enc, &p.ray_requests, false));
            p.shadows = Some((inner.scene).record(&inner.ctx, &mut enc, &p.shadow_requests, true));
            inner.ctx.submit(enc);
            inner.pending.push_back(p);
        }

        /// Queues a batch recorded by the resident frame.
        pub(crate) fn push_pending(
            &mut self,
            mut p: Pending,
            readback: crate::gpu::FrameReadback,
            contacts: Option<crate::ecs::gpu_collide::PendingContacts>,
            phases: Option<crate::gpu::PhasesReadback>,
        ) {
            p.closest = Some(readback.closest);
            p.shadows = Some(readback.any);
            p.contacts = contacts;
            p.phases = phases;
            self.inner.pending.push_back(p);
        }

        /// Test hook (feature `testing`): the resident frame's new collider pairs start with buffers for
        /// `capacity` queued pairs and leaf pairs, so that tests reach the overflow path.
        #[cfg(feature = "testing")]
        pub fn start_pair_capacity(&mut self, capacity: u32) {
            self.resident().pairs.start_capacity(capacity);
        }

        /// The resident frame's state, made at its first frame.
        pub(crate) fn resident(&mut self) -> &mut Resident {
            let ctx = &self.inner.ctx;
            self.inner.resident.get_or_insert_with(|| Resident {
                meshes: Default::default(),
                scene: ResidentScene::new(ctx),
                pairs: ResidentPairs::default(),
                timer: FrameTimer::new(ctx),
                policies: Default::default(),
            })
        }

        /// Whether the GPU has finished every batch submitted so far (polls, never blocks). Under
        /// [`Latency::NextFrame`](crate::ecs::Latency) a frame that starts while this holds publishes the
        /// last frame's answers without waiting; a game that finds it false at the start of its frames
        /// is GPU-bound, and the frame that meets a full queue of batches waits (counted in
        /// `TraceStats::gpu.blocking_waits`).
        pub fn caught_up(&self) -> bool {
            let ctx = &self.inner.ctx;
            self.inner.pending.iter().all(|p| p.ready(ctx))
        }

        /// Batches submitted and not collected yet.
        pub(crate) fn in_flight(&self) -> usize {
            self.inner.pending.len()
        }

        /// The answers of the oldest submitted batch, or `None` when there is none or (not `blocking`) when
        /// the GPU has not finished it; `blocking` waits for it.
        pub(crate) fn collect(&mut self, blocking: bool) -> Option<crate::Result<RayResults>> {
            self.collect_frame(blocking).map(|r| r.map(|a| a.rays))
        }

        /// Like [`collect`](Self::collect), with the frame's contact pairs.
        pub(crate) fn collect_frame(&mut self, blocking: bool) -> Option<crate::Result<Answers>> {
            let inner = &mut self.inner;
            let answers = inner.pending.front_mut()?.answers(&inner.ctx, blocking);
            if answers.is_some() {
                inner.pending.pop_front();
            }
            answers
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
