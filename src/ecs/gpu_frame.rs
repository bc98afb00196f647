//! The GPU-resident frame ([`TraceConfig::resident`]): in a GPU mode that found an adapter, one
//! submission per frame skins every GPU-skinned mesh, refits or rebuilds every changed tree, builds the top
//! level, answers the batched rays and shadow rays (the GPU's resident scene) and traverses the pairs
//! of [`Collider`]s, whose exact tests run on the CPU when the answers come back (`gpu_collide`): contacts
//! arrive with the ray answers, [`GpuOnly`] colliders included.
//!
//! What moves per frame: joint matrices of changed skins (64 bytes per joint) and their blend shapes'
//! weights (4 bytes per target: the GPU skin applies the blend shapes), every instance (208 bytes:
//! transform, inverse, offsets, layers), the requests (96 bytes each) and one relative transform per
//! collider pair traversed (80 bytes; pairs whose world boxes are apart are culled on the CPU first) up;
//! the answers (48 bytes each), one degradation metric per refitted mesh (8 bytes; under the adaptive
//! policy 40 more for its SAH cost) and each collider's tree and positions (36 bytes per triangle, 12 per
//! vertex) down. Vertices (and blend shapes' displacements) go up once, when a mesh is first seen, and
//! again only for meshes deformed on the CPU ([`VertexPositions`] without a skin).
//!
//! The rebuild rule is the configured policy's, on the metric of an earlier refit read back without
//! blocking: a mesh rebuilds one frame after the refit whose metric made the policy ask for it, or later
//! when the GPU is behind. [`RebuildPolicy::Lauterbach`] compares it with its threshold;
//! [`RebuildPolicy::Custom`] is called per changed mesh per frame with a [`PolicyInput`] whose
//! degradation and `frames_since_rebuild` are those of the resident tree as last read back, whose
//! `motion_incoherence` is the mean rise per refit since its build, with no profile and `gpu` true; a
//! [`Decision::Rebuild`] with a build the frame runs in its submission (LBVH over 30-bit codes, 16-bin
//! SAH or hybrid: [`FrameBuilder`](crate::gpu::FrameBuilder)) rebuilds with it, any other rebuild it asks
//! for (a partial one included) is a whole rebuild with the configured builder.
//! [`RebuildPolicy::Adaptive`] runs its planner per resident mesh on what comes back one frame late: the
//! tree's SAH cost reduced on the GPU beside the metric, and query and rebuild work counted in a model
//! instead of measured seconds (module `gpu_policy`; the CPU mirror still runs its own planner in
//! seconds for its own trees); it chooses per mesh both when to rebuild and with which of GPU LBVH and
//! the GPU twins of its builders that the frame runs (binned SAH, hybrids). Under the other policies
//! rebuilds use [`TraceConfig::builder`] where the frame has it, GPU LBVH otherwise (PLOC's GPU build
//! needs a read-back per round). Each mesh's refit or rebuild, with its build, is listed in
//! [`TraceStats::resident_meshes`].
//!
//! **GPU phase times**: on a device with timestamp queries, [`TraceStats::gpu_phases`] holds the GPU time of
//! each phase (maintenance, top level, queries, collider pairs) of the frame whose answers were published.
//!
//! **Immediate queries and other CPU features** ([`SpatialRays`], requests with a
//! predicate or several exclusions, shape and sound queries) read the CPU's trees. By default
//! every entity keeps a CPU mirror: the CPU skins and maintains it as in [`TraceMode::Cpu`], so those
//! features see the same geometry as the GPU — at the CPU mode's cost of skinning and maintenance per
//! frame, and no saving but the bus traffic. An entity with [`GpuOnly`] drops its mirror: the CPU neither
//! skins nor maintains it (its whole CPU cost goes), and it is invisible to everything but the batched
//! requests answered on the GPU — a ray that the CPU answers passes through it. Use it for crowds that
//! only batched rays and shadow rays need to see.

#[cfg(feature = "gpu")]
use super::*;
use bevy_ecs::prelude::*;

/// Drops an entity's CPU mirror in the GPU-resident frame (see [`gpu_frame`](self)): it is skinned and
/// maintained on the GPU only and seen only by batched requests answered there (blend shapes included:
/// the GPU skin applies them). Outside the resident frame it still keeps the entity out
/// of [`TraceSystems::Skin`] and [`TraceSystems::Maintain`], so nothing sees it: do not add it there.
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct GpuOnly;

/// Whether the GPU-resident frame answers this frame.
#[cfg(feature = "gpu")]
pub(crate) fn resident_on(config: Res<TraceConfig>, gpu: Option<Res<GpuQueries>>) -> bool {
    config.resident && gpu.is_some()
}

/// Under [`Latency::NextFrame`], the frames that may be in flight before the CPU waits for the oldest
/// (as a swap chain bounds its frames): never reached while the GPU keeps up.
#[cfg(feature = "gpu")]
const IN_FLIGHT: usize = 3;

#[cfg(feature = "gpu")]
type ResidentData<'a> = (
    Entity,
    Ref<'a, TraceMesh>,
    Option<Ref<'a, TraceSkin>>,
    Option<Ref<'a, VertexPositions>>,
    &'a TraceTransform,
    &'a QueryLayers,
    Option<&'a Collider>,
    Option<&'a MotionHint>,
);

/// What the GPU-resident frame did in a frame ([`TraceStats::resident`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ResidentStats {
    /// Trees refitted on the GPU.
    pub refits: usize,
    /// Trees built or rebuilt on the GPU.
    pub rebuilds: usize,
    /// Of those, the builds with binned SAH or a hybrid (the others are LBVH); which mesh was built with
    /// what is in [`TraceStats::resident_meshes`].
    pub sah_rebuilds: usize,
    /// Trees built on the GPU only to measure their cost, each on the pose of a rebuild and overwritten by
    /// it: under the adaptive policy, an asset's first rebuilds that come due measure the builds nobody
    /// measured on it (module `gpu_policy`; [`TraceStats::calibrations`] counts the CPU's).
    pub calibrations: usize,
    /// Candidate collider pairs: colliders on interacting layers, and each self-colliding one with itself.
    pub pair_candidates: usize,
    /// Of those, the pairs traversed on the GPU; the others' world boxes were apart (module
    /// `gpu_collide`).
    pub pairs_traversed: usize,
    /// Of those, the pairs traversed for the first time: each makes its traversal's buffers and uploads
    /// their round parameters once (33 KiB); a pair's traversal is kept while both colliders exist.
    pub pairs_created: usize,
    /// Of the pair traversals published this frame (those of [`Contacts::frame`]), those that overflowed
    /// their buffers: answered by the CPU's traversal of the read-back trees, their buffers grown for the
    /// next frame.
    pub pair_overflows: usize,
    /// The largest leaf-pair buffer of the pair traversals kept, in leaf pairs.
    pub pair_capacity: u32,
    /// GPU bytes held by the resident meshes' trees and builders ([`ResidentMesh::tree_bytes`](crate::gpu::ResidentMesh::tree_bytes)),
    /// over all resident meshes, plus once what their builds share on the device
    /// ([`GpuContext::shared_tree_bytes`](crate::gpu::GpuContext::shared_tree_bytes)).
    pub tree_bytes: u64,
    /// Triangles of the resident meshes: `tree_bytes / triangles` is the bytes per triangle of issue 15's
    /// memory target.
    pub triangles: u64,
}

impl ResidentStats {
    /// GPU bytes per triangle of the resident trees and their builders (0 without resident meshes).
    pub fn bytes_per_triangle(&self) -> f64 {
        if self.triangles == 0 {
            0.0
        } else {
            self.tree_bytes as f64 / self.triangles as f64
        }
    }
}

/// What the resident frame publishes besides the ray answers: the contacts and their messages.
#[cfg(feature = "gpu")]
#[derive(bevy_ecs::system::SystemParam)]
pub(crate) struct ContactOutput<'w> {
    contacts: ResMut<'w, Contacts>,
    state: ResMut<'w, super::collide::CollisionState>,
    started: MessageWriter<'w, CollisionStarted>,
    ended: MessageWriter<'w, CollisionEnded>,
}

/// [`TraceSystems::Queries`] in the resident frame: records every mesh's update and maintenance, the top
/// level and the batches into one encoder, submits it, and publishes answers (see [`Latency`]).
#[cfg(feature = "gpu")]
#[allow(clippy::too_many_arguments)]
pub(crate) fn resident_frame_system(
    meshes: Query<ResidentData, Without<TraceError>>,
    mut world: ResMut<TraceWorld>,
    config: Res<TraceConfig>,
    mut queue: ResMut<RayQueue>,
    mut results: ResMut<RayResults>,
    mut gpu: ResMut<GpuQueries>,
    mut stats: ResMut<TraceStats>,
    mut commands: Commands,
    mut errors: MessageWriter<TraceErrorMessage>,
    mut contact_out: ContactOutput,
) {
    use super::gpu_policy::{build_of, frame_builder};
    use super::systems::{attribute, checked_transform, fail, finish};
    use crate::gpu::{FrameBuilder, FrameInstance, Maintained, MeshUpdate, ResidentMesh};
    let t = std::time::Instant::now();
    let next_frame = config.latency == Latency::NextFrame;
    stats.resident = ResidentStats::default();
    if next_frame {
        let blocking = gpu.in_flight() >= IN_FLIGHT;
        publish(
            gpu.collect_frame(blocking),
            &mut results,
            &mut contact_out,
            &mut stats,
        );
    }
    let rays_last_frame = stats.rays_last_frame;
    // The configured builder where the frame has it (LBVH, 16-bin SAH or hybrid), else LBVH; under the
    // adaptive policy, each mesh's planner's choice among the builds offered.
    let configured = FrameBuilder::of(config.builder, false).unwrap_or(FrameBuilder::Lbvh);
    let (adaptive, offered) = match config.policy {
        RebuildPolicy::Adaptive { builders } => (true, super::gpu_policy::offered(builders)),
        _ => (false, Vec::new()),
    };
    let mut mesh_stats = Vec::with_capacity(meshes.iter().len());
    let mut done_here = ResidentStats::default();
    let ctx = gpu.context().clone();
    let pending = super::gpu_queries::Pending::new(&world, &queue, stats.frame);
    let resident = gpu.resident();
    let mut enc = ctx.encoder();
    if let Some(timer) = &resident.timer {
        timer.mark(&mut enc, 0);
    }
    let mut placed = Vec::with_capacity(meshes.iter().len());
    let mut colliders = Vec::new();
    for (e, mesh, skin, positions, transform, layers, collider, hint) in &meshes {
        let fresh = mesh.is_changed() || !resident.meshes.contains_key(&e);
        let made = if fresh {
            let weights = skin
                .as_ref()
                .map(|s| (&*s.weights, s.joint_matrices.len(), s.morphs.as_deref()));
            ResidentMesh::new(&ctx, &mesh.0, weights).map(|m| {
                resident.meshes.insert(e, m);
            })
        } else {
            Ok(())
        };
        let state = resident.meshes.get_mut(&e);
        let policies = &mut resident.policies;
        let update = match (&skin, &positions) {
            (Some(s), _) if state.as_ref().is_some_and(|m| m.skinned()) => {
                (fresh || s.is_changed()).then_some(MeshUpdate::Joints {
                    matrices: &s.joint_matrices,
                    morph_weights: &s.morph_weights,
                })
            }
            (_, Some(p)) if !p.0.is_empty() => {
                (fresh || p.is_changed()).then_some(MeshUpdate::Positions(&p.0))
            }
            _ => None,
        };
        let done = made
            .and_then(|()| checked_transform(transform))
            .and_then(|tr| {
                let state = state.expect("made above");
                // From the first frame under the adaptive policy (it may be chosen at run time).
                if adaptive {
                    state.measure_costs(&ctx);
                }
                let update = update.unwrap_or(MeshUpdate::Unchanged);
                let input = |refit: &crate::gpu::RefitState| PolicyInput {
                    hint: hint.copied().unwrap_or_default(),
                    triangles: mesh.0.triangle_count(),
                    degradation: refit.degradation,
                    frames_since_rebuild: refit.frames_since_rebuild,
                    rays_last_frame,
                    profile: None,
                    motion_incoherence: refit.incoherence(),
                    gpu: true,
                };
                let mut judged = None;
                let mut calibrations = 0;
                let rule = |refit: &crate::gpu::RefitState, calibrate: &mut Vec<_>| match config
                    .policy
                {
                    RebuildPolicy::Adaptive { .. } => {
                        let asset = super::maintain::asset_of(&mesh.0);
                        let (build, why) =
                            policies.rebuild(e, asset, &offered, refit, rays_last_frame, calibrate);
                        judged = why;
                        calibrations = calibrate.len();
                        build.map(frame_builder)
                    }
                    _ if refit.first_build => Some(configured),
                    RebuildPolicy::Lauterbach { threshold } => {
                        (refit.degradation > threshold).then_some(configured)
                    }
                    RebuildPolicy::Custom(policy) => match policy(&input(refit)) {
                        Decision::Keep => None,
                        Decision::Rebuild(b) => {
                            Some(FrameBuilder::of(b.builder, false).unwrap_or(configured))
                        }
                        Decision::PartialRebuild => Some(configured),
                    },
                };
                let first = !state.built();
                let action = match state.record(&ctx, &mut enc, update, rule)? {
                    Maintained::Refit => {
                        done_here.refits += 1;
                        Some(MeshAction::Refit)
                    }
                    Maintained::Rebuilt(builder) => {
                        done_here.rebuilds += 1;
                        done_here.calibrations += calibrations;
                        done_here.sah_rebuilds += usize::from(builder != FrameBuilder::Lbvh);
                        let reason = if first {
                            RebuildReason::New
                        } else {
                            RebuildReason::Policy
                        };
                        Some(MeshAction::Rebuild {
                            build: build_of(builder),
                            reason,
                        })
                    }
                    Maintained::Kept => None,
                };
                if let Some(action) = action {
                    mesh_stats.push(MeshStats {
                        entity: e,
                        action,
                        degradation: state.degradation(),
                        time: std::time::Duration::ZERO,
                        prediction: judged,
                    });
                }
                let world = state.bound().map(|b| crate::gpu::world_bound(&b, &tr));
                Ok((tr, world))
            });
        match done {
            Ok((tr, world)) => {
                if let Some(&collider) = collider
                    && mesh.0.triangle_count() > 0
                {
                    colliders.push(super::gpu_collide::Recorded {
                        entity: e,
                        collider,
                        mesh: mesh.0.clone(),
                        transform: tr,
                        world,
                    });
                }
                placed.push((e, tr, layers.0, world));
            }
            Err(err) => {
                resident.meshes.remove(&e);
                fail(e, err, &mut world, &mut commands, &mut errors, &mut stats);
            }
        }
    }
    // Entities gone or failed since last frame.
    if resident.meshes.len() > placed.len() {
        let live: std::collections::HashSet<Entity> = placed.iter().map(|p| p.0).collect();
        resident.meshes.retain(|e, _| live.contains(e));
    }
    if adaptive {
        let boxes: Vec<_> = placed.iter().map(|p| (p.0, p.3)).collect();
        resident.policies.set_shares(&boxes);
    }
    let instances: Vec<FrameInstance> = placed
        .iter()
        .map(|&(e, transform, layers, _)| FrameInstance {
            id: e.to_bits(),
            mesh: &resident.meshes[&e],
            transform,
            layers,
        })
        .collect();
    let (closest, any) = pending.requests();
    let timer = resident.timer.as_ref();
    if let Some(timer) = timer {
        timer.mark(&mut enc, 1);
    }
    let recorded = (resident.scene).record(&ctx, &mut enc, &instances, closest, any, timer);
    if let Some(timer) = timer {
        timer.mark(&mut enc, 3);
    }
    let contacts = (!colliders.is_empty()).then(|| {
        let meshes = &resident.meshes;
        super::gpu_collide::record(
            &ctx,
            &mut enc,
            &mut resident.pairs,
            colliders,
            |e| &meshes[&e],
            &mut done_here,
        )
    });
    done_here.pair_capacity = resident.pairs.largest_capacity();
    for m in resident.meshes.values() {
        done_here.tree_bytes += m.tree_bytes();
        done_here.triangles += u64::from(m.bvh().triangle_count());
    }
    if !resident.meshes.is_empty() {
        done_here.tree_bytes += ctx.shared_tree_bytes();
    }
    let phases = timer.map(|t| t.finish(&ctx, &mut enc));
    // The meshes' work is submitted even when the scene's is refused: their trees must stay as recorded.
    ctx.submit(enc);
    let contacts = match contacts.transpose() {
        Ok(c) => c,
        Err(e) => {
            log::error!("kinetrace: GPU-resident frame's collider pairs lost: {e}");
            None
        }
    };
    stats.resident = ResidentStats {
        pair_overflows: stats.resident.pair_overflows,
        ..done_here
    };
    stats.resident_meshes = mesh_stats;
    match recorded {
        Ok(readback) => gpu.push_pending(pending, readback, contacts, phases),
        Err(e) => log::error!("kinetrace: GPU-resident frame's queries lost: {e}"),
    }
    if !next_frame {
        publish(
            gpu.collect_frame(true),
            &mut results,
            &mut contact_out,
            &mut stats,
        );
    }
    finish(&mut queue, &mut stats, t);
    attribute(&mut world, &config, &stats);
}

/// Publishes collected answers and their frame's GPU phase times; with none (nothing submitted, or not
/// back yet) the results are empty and the contacts stay as last published (their [`Contacts::frame`]
/// says which frame they are of).
#[cfg(feature = "gpu")]
fn publish(
    r: Option<crate::Result<super::gpu_queries::Answers>>,
    results: &mut RayResults,
    out: &mut ContactOutput,
    stats: &mut TraceStats,
) {
    match r {
        Some(Ok(a)) => {
            *results = a.rays;
            stats.gpu_phases = match a.phases {
                Some(Ok(p)) => Some(p),
                Some(Err(e)) => {
                    log::error!("kinetrace: GPU-resident frame's timestamps lost: {e}");
                    None
                }
                None => None,
            };
            // A frame without colliders ends the pairs of the last one that had some.
            let found = match a.contacts {
                Some(Ok(found)) => found,
                Some(Err(e)) => {
                    log::error!("kinetrace: GPU-resident frame's contacts lost: {e}");
                    return;
                }
                None => Default::default(),
            };
            stats.resident.pair_overflows = found.overflows;
            let o = &mut *out;
            let (contacts, state) = (&mut *o.contacts, &mut *o.state);
            let frame = results.frame;
            super::gpu_collide::publish(
                frame,
                &found.pairs,
                contacts,
                state,
                &mut o.started,
                &mut o.ended,
            );
        }
        Some(Err(e)) => log::error!("kinetrace: GPU batch lost: {e}"),
        None => {
            results.hits.clear();
            results.shadows.clear();
        }
    }
}
