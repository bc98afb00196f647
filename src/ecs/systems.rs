//! The per-frame systems of the plugin.

use super::world_interleaved::occluded_requests;
use super::*;
use crate::bvh::MAX_PACKET;
use crate::{Error, Ray, parallel};
use bevy_ecs::prelude::*;
use glam::Vec3;
use std::ops::Range;
use std::time::Instant;

/// Starts the frame's statistics.
pub(crate) fn begin_frame(mut stats: ResMut<TraceStats>) {
    let frame = stats.frame + 1;
    let mut meshes = std::mem::take(&mut stats.meshes);
    meshes.clear();
    let mut profiles = std::mem::take(&mut stats.profiles);
    profiles.clear();
    let mut structures = std::mem::take(&mut stats.structures);
    structures.clear();
    let mut options = std::mem::take(&mut stats.options);
    options.clear();
    *stats = TraceStats {
        frame,
        meshes,
        profiles,
        structures,
        options,
        rays_last_frame: stats.batched_rays,
        shapes_last_frame: stats.batched_shapes,
        ..Default::default()
    };
}

/// Marks an entity as failed: error component, message, and out of the world.
pub(super) fn fail(
    e: Entity,
    error: Error,
    world: &mut TraceWorld,
    commands: &mut Commands,
    errors: &mut MessageWriter<TraceErrorMessage>,
    stats: &mut TraceStats,
) {
    log::warn!("kinetrace: {e} left out of queries: {error}");
    world.remove(e);
    commands.entity(e).insert(TraceError(error.clone()));
    errors.write(TraceErrorMessage { entity: e, error });
    stats.meshes.push(MeshStats {
        entity: e,
        action: MeshAction::Failed,
        degradation: 0.0,
        time: Default::default(),
        prediction: None,
    });
}

type SkinData<'a> = (
    Entity,
    &'a TraceMesh,
    &'a TraceSkin,
    &'a mut VertexPositions,
);

/// Skins the CPU skins: changed, healthy, and not left to the GPU alone.
type Reskinned = (Changed<TraceSkin>, Without<TraceError>, Without<GpuOnly>);

/// [`TraceSystems::Skin`]: re-skins every mesh whose joint matrices changed into its [`VertexPositions`].
pub(crate) fn skin_system(
    mut skinned: Query<SkinData, Reskinned>,
    mut world: ResMut<TraceWorld>,
    mut stats: ResMut<TraceStats>,
    mut commands: Commands,
    mut errors: MessageWriter<TraceErrorMessage>,
    mut morphed: Local<Vec<glam::Vec3>>,
) {
    let t = Instant::now();
    for (e, mesh, skin, mut out) in &mut skinned {
        let mut rest = mesh.0.positions();
        if let Some(m) = &skin.morphs
            && skin.morph_weights.iter().any(|&w| w != 0.0)
        {
            morphed.resize(rest.len(), glam::Vec3::ZERO);
            m.apply(rest, &skin.morph_weights, &mut morphed);
            rest = &morphed;
        }
        out.0.resize(rest.len(), glam::Vec3::ZERO);
        if let Err(err) =
            crate::anim::skin_positions(rest, &skin.weights, &skin.joint_matrices, &mut out.0)
        {
            fail(e, err, &mut world, &mut commands, &mut errors, &mut stats);
        }
    }
    stats.skin_time = t.elapsed();
}

/// Traceable entities that moved or changed layers this frame.
type PlacementChanged = (
    With<TraceMesh>,
    Without<TraceError>,
    Or<(Changed<TraceTransform>, Changed<QueryLayers>)>,
);

/// The transform as an instance needs it: finite and invertible ([`Error::InvalidTransform`] otherwise).
pub(super) fn checked_transform(t: &TraceTransform) -> Result<glam::Affine3A, Error> {
    crate::geometry::checked_inverse(&t.0).map(|_| t.0)
}

/// What the top level reads of a placed entity; the mesh and positions only for whether
/// [`TraceSystems::Maintain`] already listed it this frame.
type Placement<'a> = (
    Entity,
    &'a TraceTransform,
    &'a QueryLayers,
    Ref<'a, TraceMesh>,
    Option<Ref<'a, VertexPositions>>,
    Option<Ref<'a, TraceStructure>>,
);

/// [`TraceSystems::TopLevel`]: moved or re-layered entities update their world boxes, then the TLAS follows
/// (refitted, or rebuilt by the rule of [`top_level`](super::top_level)). O(moved entities) plus the TLAS
/// update.
pub(crate) fn top_level_system(
    moved: Query<Placement, PlacementChanged>,
    mut world: ResMut<TraceWorld>,
    config: Res<TraceConfig>,
    mut stats: ResMut<TraceStats>,
    mut commands: Commands,
    mut errors: MessageWriter<TraceErrorMessage>,
) {
    let t = Instant::now();
    for (e, transform, layers, mesh, positions, structure) in &moved {
        let checked = checked_transform(transform);
        let Some(inst) = world.instances.get_mut(&e) else {
            continue;
        };
        // A finite transform can still carry finite geometry past f32's range (a 3e38 offset): such an
        // entity has no world box, and is an error like a singular transform.
        let checked = checked.and_then(|tr| {
            let b = inst.bvh.bvh().bounds();
            if b.is_empty()
                || b.corners()
                    .iter()
                    .all(|&c| tr.transform_point3(c).is_finite())
            {
                Ok(tr)
            } else {
                Err(Error::InvalidTransform(format!(
                    "the transform carries the mesh past f32's range (root box {b:?})"
                )))
            }
        });
        match checked {
            Ok(tr) => {
                if inst.transform != tr {
                    inst.set_transform(tr);
                    // Maintain listed every mesh whose geometry changed (refitted, rebuilt or failed);
                    // the meshes it rebuilt already have this transform.
                    let maintained = mesh.is_changed()
                        || positions.is_some_and(|p| p.is_changed())
                        || structure.is_some_and(|s| s.is_changed());
                    if !maintained {
                        stats.moved += 1;
                        stats.meshes.push(MeshStats {
                            entity: e,
                            action: MeshAction::Moved,
                            degradation: 0.0,
                            time: Default::default(),
                            prediction: None,
                        });
                    }
                }
                inst.layers = layers.0;
                world.tlas_dirty = true;
            }
            Err(err) => fail(e, err, &mut world, &mut commands, &mut errors, &mut stats),
        }
    }
    stats.top_level = world.update_tlas(
        &config.policy,
        stats.rays_last_frame + stats.shapes_last_frame,
    );
    stats.top_level_time = t.elapsed();
}

/// The CPU answers to every queued request, on all threads, into `out`.
fn answer_on_cpu(world: &TraceWorld, queue: &RayQueue, frame: u64, out: &mut RayResults) {
    out.frame = frame;
    let (rays, shadows) = (&queue.rays, &queue.shadows);
    out.hits.resize(rays.len(), (0, None));
    answer_units(&mut out.hits, &queue.ray_packets, |range, packet, out| {
        let rays = &rays[range];
        if packet {
            // A queued packet holds at most MAX_PACKET requests (RayQueue::cast_packet cuts them).
            let mut world_rays = [Ray::new(Vec3::ZERO, Vec3::X); MAX_PACKET];
            for (w, r) in world_rays.iter_mut().zip(rays) {
                *w = r.ray;
            }
            let mut hits = [None; MAX_PACKET];
            let (world_rays, hits) = (&world_rays[..rays.len()], &mut hits[..rays.len()]);
            world.cast_packet(world_rays, f32::INFINITY, &rays[0].filter, hits);
            for ((o, r), h) in out.iter_mut().zip(rays).zip(hits) {
                *o = (r.tag, *h);
            }
        } else {
            // Secondary kinds are their batch's ([`super::ray_kinds`]), answered after this pass.
            for (o, r) in out.iter_mut().zip(rays) {
                if r.kind == RequestKind::Primary {
                    *o = (r.tag, world.cast_ray(&r.ray, f32::INFINITY, &r.filter));
                }
            }
        }
    });
    out.shadows.resize(shadows.len(), (0, false));
    answer_units(
        &mut out.shadows,
        &queue.shadow_packets,
        |range, packet, out| {
            let shadows = &shadows[range];
            if packet {
                let mut segments = [(Vec3::ZERO, Vec3::ZERO); MAX_PACKET];
                for (g, s) in segments.iter_mut().zip(shadows) {
                    *g = (s.from, s.to);
                }
                let mut occluded = [false; MAX_PACKET];
                let n = shadows.len();
                let (segments, occluded) = (&segments[..n], &mut occluded[..n]);
                world.occluded_packet(segments, &shadows[0].filter, occluded);
                for ((o, s), b) in out.iter_mut().zip(shadows).zip(occluded) {
                    *o = (s.tag, *b);
                }
            } else {
                // The run's primary requests, walked four at a time, interleaved.
                let mut of = [0; MAX_PACKET];
                let mut n = 0;
                for (k, s) in shadows.iter().enumerate() {
                    if s.kind == RequestKind::Primary {
                        (of[n], n) = (k, n + 1);
                    }
                }
                let (of, mut occluded) = (&of[..n], [false; MAX_PACKET]);
                occluded_requests(world, |j| &shadows[of[j]], &mut occluded[..n]);
                for (&k, &b) in of.iter().zip(&occluded) {
                    out[k] = (shadows[k].tag, b);
                }
            }
        },
    );
}

/// Runs `answer(range, is_packet, out[range])` for every queued packet and every run of up to 64 single
/// requests between them, on all threads: the packets are split in halves recursively (`rayon::join`), each
/// half with its part of `out`, so nothing is allocated.
fn answer_units<T: Send>(
    out: &mut [T],
    packets: &[Range<usize>],
    answer: impl Fn(Range<usize>, bool, &mut [T]) + Sync + Send,
) {
    answer_split(out, 0, packets, &answer);
}

/// [`answer_units`] for `out` = requests `first..first + out.len()`, holding exactly `packets`.
fn answer_split<T: Send>(
    out: &mut [T],
    first: usize,
    packets: &[Range<usize>],
    answer: &(impl Fn(Range<usize>, bool, &mut [T]) + Sync + Send),
) {
    let Some(packet) = packets.get(packets.len() / 2) else {
        // Single requests only: runs of MAX_PACKET.
        let end = first + out.len();
        return parallel::fill_chunks(true, out, MAX_PACKET, |c, part| {
            let start = first + c * MAX_PACKET;
            answer(start..(start + MAX_PACKET).min(end), false, part)
        });
    };
    let mid = packets.len() / 2;
    let (before, rest) = out.split_at_mut(packet.start - first);
    let (inside, after) = rest.split_at_mut(packet.len());
    parallel::join(
        true,
        || answer_split(before, first, &packets[..mid], answer),
        || {
            answer(packet.clone(), true, inside);
            answer_split(after, packet.end, &packets[mid + 1..], answer)
        },
    );
}

/// [`TraceSystems::Queries`]: answers every queued request — on the GPU when a GPU mode found one, else on all
/// CPU threads, secondary kinds batch by batch ([`SecondaryRays`]) — and publishes them now
/// ([`Latency::SameFrame`]) or next frame ([`Latency::NextFrame`], when a GPU batch is collected without
/// having stalled the frame that submitted it).
#[allow(clippy::too_many_arguments)] // a system: each parameter is one thing it reads
pub(crate) fn queries_system(
    mut world: ResMut<TraceWorld>,
    config: Res<TraceConfig>,
    mut queue: ResMut<RayQueue>,
    mut results: ResMut<RayResults>,
    mut pending: Local<RayResults>,
    gpu: Option<ResMut<GpuQueries>>,
    mut stats: ResMut<TraceStats>,
    mut secondary: ResMut<SecondaryRays>,
) {
    let t = Instant::now();
    let frame = stats.frame;
    let next_frame = config.latency == Latency::NextFrame;
    #[cfg(feature = "gpu")]
    if let Some(mut gpu) = gpu {
        if config.resident {
            // The GPU-resident frame answers (super::gpu_frame).
            return;
        }
        let publish = |r: Option<crate::Result<RayResults>>, results: &mut RayResults| match r {
            Some(Ok(r)) => *results = r,
            Some(Err(e)) => log::error!("kinetrace: GPU batch lost: {e}"),
            None => {
                results.hits.clear();
                results.shadows.clear();
            }
        };
        if next_frame {
            let previous = gpu.collect(true);
            publish(previous, &mut results);
            gpu.submit(&world, &queue, frame);
        } else {
            gpu.submit(&world, &queue, frame);
            let now = gpu.collect(true);
            publish(now, &mut results);
        }
        finish(&mut queue, &mut stats, t);
        attribute(&mut world, &config, &stats);
        return;
    }
    #[cfg(not(feature = "gpu"))]
    let _ = gpu;
    let out = if next_frame {
        // Publish last frame's answers, compute this frame's for the next.
        std::mem::swap(&mut *results, &mut *pending);
        &mut *pending
    } else {
        &mut *results
    };
    answer_on_cpu(&world, &queue, frame, out);
    super::ray_kinds::answer_secondary(&world, &queue, &mut secondary, out, &mut stats);
    finish(&mut queue, &mut stats, t);
    attribute(&mut world, &config, &stats);
}

/// Under the adaptive policy, tells every mesh its share of the frame's batched query time, rays and
/// shape queries (answered before the rays, see [`shape_queries_system`](super::shape_batch)) apart (see
/// [`TraceWorld::attribute_queries`]); other policies pay nothing for it. Not a change of what queries
/// read, so it bypasses change detection.
pub(super) fn attribute(world: &mut ResMut<TraceWorld>, config: &TraceConfig, stats: &TraceStats) {
    if matches!(config.policy, RebuildPolicy::Adaptive { .. }) {
        world.bypass_change_detection().attribute_queries(
            stats.batched_rays,
            stats.query_time.as_secs_f64(),
            stats.batched_shapes,
            stats.shape_query_time.as_secs_f64(),
        );
    }
}

/// Empties the queue (keeping its memory) and records the phase.
pub(super) fn finish(queue: &mut RayQueue, stats: &mut TraceStats, start: Instant) {
    stats.batched_rays = queue.len();
    queue.rays.clear();
    queue.shadows.clear();
    queue.ray_packets.clear();
    queue.shadow_packets.clear();
    stats.query_time = start.elapsed();
}

/// [`TraceSystems::Characterize`]: profiles meshes that are new, were rebuilt, or whose degradation moved by
/// more than [`TraceConfig::profile_refresh`] since their last profile. Cost: a pass over the instances,
/// plus one characterisation (O(n) in triangles) per mesh that needs it.
pub(crate) fn characterize_system(
    meshes: Query<(Entity, &TraceMesh, Option<&VertexPositions>), Without<TraceError>>,
    mut world: ResMut<TraceWorld>,
    config: Res<TraceConfig>,
    mut stats: ResMut<TraceStats>,
) {
    let t = Instant::now();
    let stale: Vec<Entity> = world
        .instances
        .iter()
        .filter(|(_, i)| {
            // A rebuild makes a new instance, without a profile.
            let now = i.history.last().copied().unwrap_or(0.0);
            i.profile.is_none() || (now - i.profiled_at).abs() > config.profile_refresh
        })
        .map(|(e, _)| *e)
        .collect();
    for e in stale {
        let Ok((_, mesh, vp)) = meshes.get(e) else {
            continue;
        };
        let current = match vp {
            Some(v) if !v.0.is_empty() => mesh.0.with_positions(v.0.clone()).ok(),
            _ => Some(mesh.0.clone()),
        };
        let Some(current) = current else { continue };
        let profile = std::sync::Arc::new(crate::characterize::profile_mesh(&current));
        let inst = world.instances.get_mut(&e).expect("listed above");
        inst.profiled_at = inst.history.last().copied().unwrap_or(0.0);
        inst.profile = Some(profile.clone());
        stats.profiles.push((e, profile));
    }
    stats.characterize_time = t.elapsed();
}
