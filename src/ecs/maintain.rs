//! [`TraceSystems::Maintain`]: per changed mesh, refit and ask the policy, or rebuild — with the chosen builder
//! on the chosen device — and feed the adaptive policy what it measured. The refits of meshes that keep
//! their topology run first, in parallel across meshes ([`refit_ahead`]); everything else goes mesh by
//! mesh.

use super::config::lauterbach;
use super::planned::{CostScript, plan_overlap, plan_structure, scripted, structure_for};
use super::systems::{checked_transform, fail};
use super::world::{Instance, Kept, Prefit, topology_id};
use super::*;
use crate::adaptive::{
    AdaptivePolicy, Asset, Build, Choice, CostTable, Device, Prediction, TreeCost, Verdict,
};
use crate::bvh::{BuildOptions, MeshBvh, PartialOptions};
use crate::grid::{GridOptions, StructureKind, UniformGrid};
use crate::{Error, Mesh};
use bevy_ecs::prelude::*;
use std::time::Instant;

type MeshData<'a> = (
    Entity,
    &'a TraceMesh,
    Option<&'a VertexPositions>,
    Option<&'a MotionHint>,
    &'a TraceTransform,
    &'a QueryLayers,
);
/// Meshes whose geometry changed this frame.
type GeometryChanged = (
    Without<TraceError>,
    Without<GpuOnly>,
    Or<(
        Changed<TraceMesh>,
        Changed<VertexPositions>,
        Changed<TraceStructure>,
    )>,
);

/// GPU rebuilds asked for that ran on the CPU, each said once in the log.
#[derive(Default)]
pub(crate) struct Fallbacks {
    no_gpu: bool,
    #[cfg(feature = "gpu")]
    not_lbvh: bool,
}

impl Fallbacks {
    fn no_gpu(&mut self) {
        if !std::mem::replace(&mut self.no_gpu, true) {
            log::warn!(
                "kinetrace: a GPU rebuild was asked for but the world has no GPU context (TraceMode::Cpu, \
                 no adapter, or no `gpu` feature); rebuilds run on the CPU"
            );
        }
    }

    #[cfg(feature = "gpu")]
    fn not_lbvh(&mut self, build: Build) {
        if !std::mem::replace(&mut self.not_lbvh, true) {
            log::warn!(
                "kinetrace: the GPU builds LBVH over 30-bit codes, 16-bin SAH, their hybrid and PLOC only; GPU rebuilds with {} run on the CPU",
                build.builder.name()
            );
        }
    }
}

/// Refits or rebuilds every changed mesh; forgets removed ones.
#[allow(clippy::too_many_arguments)]
pub(crate) fn maintain_system(
    changed: Query<MeshData, GeometryChanged>,
    all: Query<MeshData, (Without<TraceError>, Without<GpuOnly>)>,
    mut removed: RemovedComponents<TraceMesh>,
    mut recovered: RemovedComponents<TraceError>,
    mut world: ResMut<TraceWorld>,
    config: Res<TraceConfig>,
    mut stats: ResMut<TraceStats>,
    mut commands: Commands,
    mut errors: MessageWriter<TraceErrorMessage>,
    gpu: Option<Res<GpuQueries>>,
    mut fallbacks: Local<Fallbacks>,
    structures: Query<&TraceStructure>,
    costs: Local<CostTable>,
    mut ahead: Local<Vec<(Entity, bool, Instance)>>,
) {
    let start = Instant::now();
    // Topologies whose mesh went away this frame: the planner forgets them once no mesh has them.
    let mut gone: Vec<u64> = Vec::new();
    for e in removed.read() {
        if let Some(topology) = world.instances.get(&e).map(|i| i.topology()) {
            gone.push(topology);
        }
        world.remove(e);
    }
    let script = world.script.clone();
    stats.refits_ahead = refit_ahead(&mut world, &changed, &config, &mut ahead);
    let retry: Vec<Entity> = recovered.read().filter(|e| !changed.contains(*e)).collect();
    let mut rebuilder = Rebuilder {
        config: &config,
        gpu: gpu.as_deref(),
        fallbacks: &mut fallbacks,
        costs: &costs,
        calibrations: 0,
    };
    for data in changed
        .iter()
        .chain(retry.iter().filter_map(|&e| all.get(e).ok()))
    {
        let (e, mesh, vp, hint, ..) = data;
        let mut t = Instant::now();
        let positions = positions_of(mesh, vp);
        let mut degradation = 0.0;
        let mut prediction = None;
        let mut decision = None;
        let wanted = structures.get(e).map_or(config.structure, |s| s.0);
        if !world.contains(e) && hint != Some(&MotionHint::Static) {
            match start_from_sibling(&mut world, &config, data) {
                Ok(started) => stats.siblings += started as usize,
                Err(err) => {
                    fail(e, err, &mut world, &mut commands, &mut errors, &mut stats);
                    continue;
                }
            }
        }
        let planned =
            wanted == Structure::Auto && matches!(config.policy, RebuildPolicy::Adaptive { .. });
        let grid_rate = world.grid_rate.mean();
        let (structure, why) = match world.instances.get_mut(&e) {
            Some(inst) if planned => plan_structure(inst, grid_rate),
            inst => structure_for(wanted, inst.map(|i| &*i)),
        };
        if let Some(inst) = world
            .instances
            .get_mut(&e)
            .filter(|i| i.topology() == topology_id(&mesh.0))
        {
            // The planner weighs the refitted tree (its SAH cost measured in the refit's pass); a
            // motion that outpaces refitting is rebuilt without a refit.
            let planned = structure == StructureKind::Bvh
                && matches!(config.policy, RebuildPolicy::Adaptive { .. });
            let outpaced =
                planned && (inst.kept.adaptive.as_mut()).is_some_and(AdaptivePolicy::outpaced);
            if outpaced {
                prediction = inst.kept.adaptive.as_ref().map(AdaptivePolicy::prediction);
                decision = prediction.map(|p| Decision::Rebuild(p.build));
            } else {
                let refit = match inst.prefit.take() {
                    // Refitted ahead: its time counts as this mesh's, as if refitted here.
                    Some(Prefit { result, took }) => {
                        t = t.checked_sub(took).unwrap_or(t);
                        result.map(|(d, s)| (d, s.filter(|_| planned)))
                    }
                    None => refit_tree(inst, positions, planned),
                };
                match refit {
                    Ok((d, sah)) => {
                        degradation = d;
                        inst.frames_since_rebuild += 1;
                        inst.remember(d);
                        // A grid answers the rays: its BVH is only refitted, for what the grid does not answer.
                        let asked = (structure == StructureKind::Bvh).then_some(Asked {
                            policy: config.policy,
                            hint: hint.copied().unwrap_or_default(),
                            triangles: mesh.0.triangle_count(),
                            degradation: d,
                            rays_last_frame: stats.rays_last_frame,
                            gpu: rebuilder.gpu.is_some(),
                            costs: &costs,
                            asset: asset_of(&mesh.0),
                            sah,
                        });
                        (decision, prediction) = match asked {
                            Some(asked) => {
                                let (d, p) = asked.decide(inst, &mut stats.partial_checks);
                                (Some(d), p)
                            }
                            None => (Some(Decision::Keep), None),
                        };
                    }
                    Err(err) => {
                        fail(e, err, &mut world, &mut commands, &mut errors, &mut stats);
                        continue;
                    }
                }
            }
        }
        let partial = decision == Some(Decision::PartialRebuild);
        let rebuild = match decision {
            Some(Decision::Keep | Decision::PartialRebuild) => None,
            Some(Decision::Rebuild(build)) => Some((Some(build), RebuildReason::Policy)),
            None if world.contains(e) => {
                gone.extend(world.instances.get(&e).map(|i| i.topology()));
                Some((None, RebuildReason::Topology))
            }
            None => Some((None, RebuildReason::New)),
        };
        let action = match rebuild {
            None => {
                stats.refits += 1;
                let inst = world.instances.get_mut(&e).expect("refitted");
                let done = if partial {
                    partial_rebuild(inst, positions).map(Some)
                } else {
                    Ok(None)
                };
                inst.update_world_bounds();
                match done {
                    // Asked, but no subtree had degraded: a plain refit.
                    Ok(None | Some(0)) => MeshAction::Refit,
                    Ok(Some(triangles)) => {
                        stats.partial_rebuilds += 1;
                        stats.partial_triangles += triangles;
                        MeshAction::PartialRebuild { triangles }
                    }
                    Err(err) => {
                        fail(e, err, &mut world, &mut commands, &mut errors, &mut stats);
                        continue;
                    }
                }
            }
            Some((asked, reason)) => {
                match rebuilder.rebuild(&mut world, data, positions, asked, reason) {
                    Ok(build) => {
                        stats.rebuilds += 1;
                        MeshAction::Rebuild { build, reason }
                    }
                    Err(err) => {
                        fail(e, err, &mut world, &mut commands, &mut errors, &mut stats);
                        continue;
                    }
                }
            }
        };
        let inst = world.instances.get_mut(&e).expect("refitted or rebuilt");
        // A switch's frame pays a catch-up (a BVH only refitted under the grid may be rebuilt now): not
        // what the structure costs per frame, so its overhead is not learned.
        let switched = inst.structure != structure;
        // A structure being tried is measured with its sub-options as settled (`Choice::hold`).
        let hold = inst.kept.structure.as_ref().is_some_and(Choice::explored);
        let grid = match structure {
            StructureKind::Grid => plan_overlap(inst, &config.grid, hold),
            StructureKind::Bvh => config.grid,
        };
        let built = Instant::now();
        if let Err(err) = inst.keep_structure(structure, why, &grid, mesh, positions) {
            fail(e, err, &mut world, &mut commands, &mut errors, &mut stats);
            continue;
        }
        let measured = t.elapsed().as_secs_f64();
        if let Some(overlap) = inst.kept.overlap.as_mut()
            && structure == StructureKind::Grid
        {
            let option = PlannedOption::Overlap(grid.overlap_test);
            let seconds = built.elapsed().as_secs_f64();
            overlap.kept(
                grid.overlap_test,
                scripted(script.as_ref(), e, option, seconds, |c| c.overhead_s),
            );
            stats.options.push(OptionStats {
                entity: e,
                option,
                tried: overlap.explored(),
            });
        }
        if structure == StructureKind::Bvh && inst.kept.adaptive.is_some() {
            let wide = plan_wide(inst, t, script.as_ref(), e, hold);
            stats.options.push(OptionStats {
                entity: e,
                option: PlannedOption::Wide(wide.current()),
                tried: wide.explored(),
            });
            let packets = plan_packets(inst, hold);
            stats.options.push(OptionStats {
                entity: e,
                option: PlannedOption::Packets(packets.current()),
                tried: packets.explored(),
            });
        }
        // A frame in which the wide tree or packets are tried measures that try: it teaches the
        // structure nothing.
        let sub_try = structure == StructureKind::Bvh && inst.sub_option_tried();
        let mut grid_frame = None;
        if let Some(choice) = inst.kept.structure.as_mut() {
            let option = PlannedOption::Structure(structure);
            if !switched && !sub_try {
                let seconds = scripted(script.as_ref(), e, option, measured, |c| c.overhead_s);
                choice.kept(structure, seconds);
                grid_frame = (structure == StructureKind::Grid).then_some(seconds);
            }
            stats.options.push(OptionStats {
                entity: e,
                option,
                tried: choice.explored(),
            });
        }
        stats.structures.push(StructureStats {
            entity: e,
            structure,
            why,
        });
        if let Some(seconds) = grid_frame {
            let triangles = mesh.0.triangle_count().max(1) as f64;
            world.grid_rate.add(seconds / triangles);
        }
        world.tlas_dirty = true;
        stats.meshes.push(MeshStats {
            entity: e,
            action,
            degradation,
            time: t.elapsed(),
            prediction,
        });
    }
    stats.calibrations = rebuilder.calibrations;
    forget_orphans(&world, &costs, gone);
    stats.maintain_time = start.elapsed();
}

/// Rebuilds the degraded subtrees of the refitted `inst` at the default [`PartialOptions`] and tells its
/// adaptive policy, if any, what that cost; returns the triangles rebuilt. The wide tree is collapsed
/// again by [`MeshBvh::rebuild_degraded`](crate::bvh::MeshBvh::rebuild_degraded) itself; the grid and the
/// world bounds follow as after a refit. Allocates (the subtree selection's scratch and the rebuilt
/// subtrees' build), so a frame that rebuilds partially is not allocation-free.
fn partial_rebuild(inst: &mut Instance, positions: &[glam::Vec3]) -> Result<usize, Error> {
    let t = Instant::now();
    let done = inst
        .bvh
        .rebuild_degraded(positions, &PartialOptions::default())?;
    let seconds = t.elapsed().as_secs_f64();
    if done.subtrees > 0 {
        inst.frames_since_rebuild = 0;
    }
    if let Some(policy) = inst.kept.adaptive.as_mut() {
        inst.sah = inst.bvh.bvh().sah_cost();
        policy.partially_rebuilt(done.primitives, seconds, inst.sah);
    }
    Ok(done.primitives)
}

/// The positions a mesh is maintained at: its `VertexPositions` where it has some, else its own.
fn positions_of<'a>(mesh: &'a TraceMesh, vp: Option<&'a VertexPositions>) -> &'a [glam::Vec3] {
    match vp {
        Some(v) if !v.0.is_empty() => &v.0[..],
        _ => mesh.0.positions(),
    }
}

/// Refits `inst` to `positions`, measuring its SAH cost in the same pass when `with_sah`: the
/// degradation and that cost.
fn refit_tree(
    inst: &mut Instance,
    positions: &[glam::Vec3],
    with_sah: bool,
) -> Result<(f32, Option<f64>), Error> {
    match with_sah {
        true => (inst.bvh)
            .refit_with_sah(positions)
            .map(|(d, s)| (d, Some(s))),
        false => inst.bvh.refit(positions).map(|d| (d, None)),
    }
}

/// Runs this frame's refits ahead of the maintenance loop, in parallel across meshes (the `parallel`
/// feature): the O(n) step of every kept mesh, independent of every other mesh, which the loop would
/// run one mesh after another. A mesh is refitted ahead when it changed, keeps its topology and the
/// adaptive policy does not skip its refit this frame ([`AdaptivePolicy::skips_next_refit`]); the loop
/// takes the result ([`Prefit`]) at the mesh's turn and charges the mesh its time, so decisions,
/// answers and the planner's measurements are the loop's own. Others (new meshes, which may start from
/// a sibling refitted here; a topology change; a retried mesh) are refitted in the loop as before. The
/// SAH cost is measured in the pass for a mesh the adaptive policy answers with its BVH last frame; a
/// mesh that switches structure this frame has it measured by the loop where needed.
///
/// The meshes refitted ahead leave the world's map for the pass (into `ahead`, with whether to measure
/// the SAH cost; its capacity is kept from frame to frame) and go back after it: a slice splits over
/// threads without allocating, the map's entries would not. Returns the meshes refitted. Allocates
/// nothing once warm.
fn refit_ahead(
    world: &mut TraceWorld,
    changed: &Query<MeshData, GeometryChanged>,
    config: &TraceConfig,
    ahead: &mut Vec<(Entity, bool, Instance)>,
) -> usize {
    let adaptive = matches!(config.policy, RebuildPolicy::Adaptive { .. });
    ahead.clear();
    for (e, mesh, ..) in changed.iter() {
        let Some(inst) = world.instances.get_mut(&e) else {
            continue;
        };
        let outpaced = (inst.kept.adaptive.as_ref()).is_some_and(AdaptivePolicy::skips_next_refit);
        // Cleared for every changed mesh: no earlier frame's refit is ever taken for this one's.
        inst.prefit = None;
        if inst.topology() == topology_id(&mesh.0) && !outpaced {
            let with_sah = adaptive && inst.structure == StructureKind::Bvh;
            let inst = world.instances.remove(&e).expect("looked up above");
            ahead.push((e, with_sah, inst));
        }
    }
    // One mesh gains nothing from other threads (a large one's refit is not split).
    let parallel = ahead.len() > 1;
    crate::parallel::for_each_mut_one_by_one(parallel, ahead, |_, (e, with_sah, inst)| {
        // Every entity here came from `changed` this run; one it no longer yields is refitted in turn.
        if let Ok((_, mesh, vp, ..)) = changed.get(*e) {
            let t = Instant::now();
            let result = refit_tree(inst, positions_of(mesh, vp), *with_sah);
            let took = t.elapsed();
            inst.prefit = Some(Prefit { result, took });
        }
    });
    let due = ahead.len();
    for (e, _, inst) in ahead.drain(..) {
        world.instances.insert(e, inst);
    }
    due
}

/// Prunes the shared cost table of the assets among `gone` that no mesh has any more. O(gone · meshes),
/// only in frames where meshes were removed or changed topology.
fn forget_orphans(world: &TraceWorld, costs: &CostTable, mut gone: Vec<u64>) {
    gone.retain(|t| !world.instances.values().any(|i| i.topology() == *t));
    if !gone.is_empty() {
        costs.retain_assets(|a| !gone.contains(&a.id));
    }
}

/// Under [`RebuildPolicy::Adaptive`], gives a new entity a copy of the tree of another entity of the same
/// mesh (a sibling: same topology, a tree and a planner of its own) with the sibling's planner
/// ([`AdaptivePolicy::sibling`]), so that the refit that follows judges the copy like any refitted tree
/// instead of building from scratch: a crowd of one character pays one build and then a copy and a refit
/// per instance (O(n) each instead of O(n log n)), and explores nothing the first instance measured. The
/// sibling's expected queries stand in for the new entity's until its own are attributed.
/// True if it did; errors only for an unusable transform.
fn start_from_sibling(
    world: &mut TraceWorld,
    config: &TraceConfig,
    data: MeshData,
) -> Result<bool, Error> {
    let (e, mesh, _, _, transform, layers) = data;
    if !matches!(config.policy, RebuildPolicy::Adaptive { .. }) {
        return Ok(false);
    }
    let topology = topology_id(&mesh.0);
    let Some((bvh, policy, wide, packets, structure, overlap, load)) =
        world.instances.values().find_map(|i| {
            let policy = (i.kept.adaptive.as_ref()).filter(|_| i.topology() == topology)?;
            Some((
                i.bvh.clone(),
                policy.sibling(),
                i.kept.wide.clone(),
                i.kept.packets.clone(),
                i.kept.structure.clone(),
                i.kept.overlap.clone(),
                i.load,
            ))
        })
    else {
        return Ok(false);
    };
    checked_transform(transform)?;
    let kept = Kept {
        adaptive: Some(policy),
        wide,
        packets,
        structure,
        overlap,
        ..Kept::default()
    };
    let mut inst = Instance::new(bvh, &mesh.0, kept);
    // Until its first frame is attributed, the sibling's queries are the best guess of its own: planned
    // for none, its first frame dropped the wide tree the sibling's planner had settled on.
    inst.load = load;
    inst.layers = layers.0;
    inst.set_transform(transform.0);
    world.instances.insert(e, inst);
    world.membership_changed = true;
    Ok(true)
}

/// Whether the mesh keeps its wide query tree from this frame on, decided by its [`Choice`] (made at its
/// first call, [`Choice::wide`]; with `hold`, the settled option, no try): the option is applied (a
/// collapse when the tree comes back, a refit when it comes back from a try of the binary tree, whose
/// frames keep it aside) and charged this frame's maintenance of the mesh since `start`, its rays and
/// shape queries are charged by [`TraceWorld::attribute_queries`]. O(1) beyond the collapse or refit.
fn plan_wide<'a>(
    inst: &'a mut Instance,
    start: Instant,
    script: Option<&CostScript>,
    e: Entity,
    hold: bool,
) -> &'a Choice<bool> {
    let queries = inst.load.tree_queries();
    let wide = (inst.kept.wide).get_or_insert_with(Choice::wide);
    let on = if hold {
        wide.hold()
    } else {
        wide.decide(queries)
    };
    if on || !wide.settled() {
        inst.bvh.set_wide(on);
    } else {
        // A try of the binary tree: the wide one is likely back in a frame or three.
        inst.bvh.suspend_wide();
    }
    let measured = start.elapsed().as_secs_f64();
    wide.kept(
        on,
        scripted(script, e, PlannedOption::Wide(on), measured, |c| {
            c.overhead_s
        }),
    );
    wide
}

/// Whether packet requests meet the mesh as packets from this frame on, decided by its [`Choice`] (made
/// at its first call, [`Choice::packets`]; with `hold`, the settled option, no try). Its rays are
/// charged by [`TraceWorld::attribute_queries`] to the option in use. O(1).
fn plan_packets(inst: &mut Instance, hold: bool) -> &Choice<bool> {
    let packets = (inst.kept.packets).get_or_insert_with(Choice::packets);
    if hold {
        packets.hold();
    } else {
        packets.decide(inst.load.rays());
    }
    packets
}

impl Instance {
    /// Records the structure that answers the mesh's rays and, for a grid, rebuilds it over `positions`
    /// (its buffers kept from frame to frame: no allocation once warm; a new grid when the options
    /// changed). Errors: [`Error::InvalidOption`] for bad grid options.
    fn keep_structure(
        &mut self,
        structure: StructureKind,
        why: StructureWhy,
        options: &GridOptions,
        mesh: &TraceMesh,
        positions: &[glam::Vec3],
    ) -> Result<(), Error> {
        if structure == StructureKind::Grid {
            let same = |g: &UniformGrid| {
                let o = GridOptions {
                    overlap_test: options.overlap_test,
                    ..*g.options()
                };
                o == *options
            };
            let grid = match &mut self.kept.grid {
                // The overlap test (a planned option) switches without new buffers.
                Some(g) if same(g) => {
                    g.set_overlap_test(options.overlap_test);
                    g
                }
                slot => slot.insert(UniformGrid::new(*options)?),
            };
            grid.rebuild_deformed(&mesh.0, positions)?;
        }
        self.structure = structure;
        self.why = why;
        Ok(())
    }
}

/// What rebuilds need beyond the mesh.
struct Rebuilder<'a> {
    config: &'a TraceConfig,
    /// The world's GPU, when a GPU mode found one.
    gpu: Option<&'a GpuQueries>,
    fallbacks: &'a mut Fallbacks,
    /// The costs every mesh's adaptive policy learns into and from.
    costs: &'a CostTable,
    /// Builds run this frame only to measure them (see [`Rebuilder::calibrate`]).
    calibrations: usize,
}

impl Rebuilder<'_> {
    /// A fresh tree for the entity of `data` at `positions`, with the `asked` build (else the configured or
    /// the adaptive policy's first), replacing its instance and carrying over what outlives a rebuild; the
    /// adaptive policy is told what the build cost. Returns the build that really ran.
    fn rebuild(
        &mut self,
        world: &mut TraceWorld,
        data: MeshData,
        positions: &[glam::Vec3],
        asked: Option<Build>,
        reason: RebuildReason,
    ) -> Result<Build, Error> {
        let (e, mesh, _, hint, transform, layers) = data;
        let current = current_mesh(mesh, positions, transform)?;
        // The characteriser's verdict on the old tree's mesh lowers a GPU hybrid's LBVH levels.
        let clustered = world
            .instances
            .get(&e)
            .and_then(|i| i.profile.as_deref())
            .is_some_and(|p| !p.uniform);
        // What the old tree leaves to the new one: the learned model always, GPU buffers if still the size,
        // and the queries expected per frame — not the tree's but the scene's: a new instance counting none
        // made this frame's planners choose for a frame without work (the wide tree dropped on every
        // rebuild frame, since without queries its collapse is all it costs).
        let (mut kept, load) = world
            .instances
            .get_mut(&e)
            .map(|i| (std::mem::take(&mut i.kept), i.load))
            .unwrap_or_default();
        #[cfg(feature = "gpu")]
        if reason == RebuildReason::Topology {
            kept.gpu = None;
            kept.gpu_sah = None;
            kept.gpu_ploc = None;
        }
        if let RebuildPolicy::Adaptive { builders } = self.config.policy
            && kept.adaptive.is_none()
        {
            kept.adaptive = Some(adaptive_policy(
                builders,
                self.gpu.is_some(),
                self.costs,
                asset_of(&mesh.0),
            ));
        }
        let build =
            asked.unwrap_or_else(
                || match (hint.copied().unwrap_or_default(), &kept.adaptive) {
                    (MotionHint::Static, _) => Build::cpu(self.config.static_builder),
                    (_, Some(policy)) => policy.next_build(),
                    (_, None) => Build::cpu(self.config.builder),
                },
            );
        let (bvh, build, seconds) = self.build_tree(&current, build, clustered, &mut kept)?;
        let triangles = current.triangle_count();
        log::debug!(
            "kinetrace: rebuilt {e} with {build} ({reason:?}), {triangles} triangles in {:.3} ms",
            seconds * 1e3
        );
        let mut inst = Instance::new(bvh, &mesh.0, kept);
        inst.load = load;
        if let Some(policy) = inst.kept.adaptive.as_mut() {
            inst.sah = inst.bvh.bvh().sah_cost();
            policy.built(
                build,
                triangles,
                seconds,
                TreeCost {
                    sah: inst.sah,
                    root_area: Some(inst.bvh.bvh().bounds().half_area_f64()),
                },
            );
        }
        self.calibrate(&current, clustered, &mut inst.kept)?;
        inst.layers = layers.0;
        inst.set_transform(transform.0);
        if world.instances.insert(e, inst).is_none() {
            world.membership_changed = true;
        }
        Ok(build)
    }

    /// Builds on `current` each build the adaptive policy in `kept` asks to calibrate
    /// ([`AdaptivePolicy::calibration`]: at an asset's rebuilds, its unmeasured builds that may pay) and
    /// reports them; the trees are dropped. A build that ran as another (a GPU build fallen back to the
    /// CPU) is reported unmeasured.
    fn calibrate(&mut self, current: &Mesh, clustered: bool, kept: &mut Kept) -> Result<(), Error> {
        while let Some(asked) = kept.adaptive.as_ref().and_then(AdaptivePolicy::calibration) {
            let (tree, ran, seconds) = self.build_tree(current, asked, clustered, kept)?;
            let (seconds, cost) = match ran == asked {
                true => (seconds, tree.bvh().sah_cost()),
                false => (f64::NAN, f64::NAN),
            };
            if let Some(policy) = kept.adaptive.as_mut() {
                policy.calibrated(asked, current.triangle_count(), seconds, cost);
            }
            self.calibrations += 1;
        }
        Ok(())
    }

    /// Builds the tree of `current` with `build`: on the GPU when asked for and possible, else on the CPU.
    /// Returns the tree, the build that really ran, and the seconds the build itself took (not the one-time
    /// allocation of GPU buffers, which would make a first GPU measurement look worse than the device is).
    fn build_tree(
        &mut self,
        current: &Mesh,
        build: Build,
        clustered: bool,
        kept: &mut Kept,
    ) -> Result<(MeshBvh, Build, f64), Error> {
        if build.device == Device::Gpu
            && let Some(done) = self.on_gpu(current, build, clustered, kept)
        {
            return Ok(done);
        }
        let t = Instant::now();
        // The wide query tree only where the mesh's planner keeps it (always without one).
        let wide = kept.wide.as_ref().is_none_or(Choice::current);
        let bvh = MeshBvh::build(current, &BuildOptions::new(build.builder).wide(wide))?;
        Ok((bvh, Build::cpu(build.builder), t.elapsed().as_secs_f64()))
    }

    /// LBVH, binned SAH, the hybrid, PLOC or the spatial median (the task pool's build) on the GPU
    /// ([`Build::GPU_LBVH`], [`Build::GPU_SAH`], [`Build::gpu_hybrid`], [`Build::GPU_PLOC`],
    /// [`Build::GPU_MEDIAN`]), read back for CPU queries; `None` (said once in the log) where it cannot
    /// run. A clustered mesh's hybrid gets fewer LBVH levels ([`crate::gpu::hybrid_levels`]). The mesh's
    /// GPU buffers (and a SAH builder's scratch) are made at its first GPU build of that kind.
    #[cfg(feature = "gpu")]
    fn on_gpu(
        &mut self,
        current: &Mesh,
        build: Build,
        clustered: bool,
        kept: &mut Kept,
    ) -> Option<(MeshBvh, Build, f64)> {
        let Some(gpu) = self.gpu else {
            self.fallbacks.no_gpu();
            return None;
        };
        let sah = crate::gpu::GpuSahOptions::for_builder(build.builder, clustered);
        if sah.is_none()
            && !matches!(
                build.builder,
                crate::bvh::Builder::Ploc { .. } | crate::bvh::Builder::Median
            )
        {
            self.fallbacks.not_lbvh(build);
            return None;
        }
        if kept.gpu.is_none() {
            // A SAH builder's scratch is bound to the tree buffers it was made with.
            kept.gpu_sah = None;
        }
        let ctx = gpu.context();
        let mut run = || -> crate::Result<(MeshBvh, Build, f64)> {
            if build.builder == crate::bvh::Builder::Median {
                // The task pool's build makes its buffers per build: nothing to keep.
                let t = Instant::now();
                let bvh = crate::gpu::taskpool::build_bvh(ctx, current)?.bvh;
                return Ok((bvh, build, t.elapsed().as_secs_f64()));
            }
            if let crate::bvh::Builder::Ploc { radius } = build.builder {
                let tree = match &mut kept.gpu_ploc {
                    Some(tree) if tree.radius() == radius => tree,
                    other => other.insert(crate::gpu::GpuPloc::new(ctx, current, radius)?),
                };
                let t = Instant::now();
                let bvh = tree.build_for_cpu(ctx, current)?;
                return Ok((bvh, build, t.elapsed().as_secs_f64()));
            }
            let tree = match &mut kept.gpu {
                Some(tree) => tree,
                empty => empty.insert(crate::gpu::GpuMeshBvh::new(ctx, current)?),
            };
            let Some(options) = sah.flatten() else {
                let t = Instant::now();
                let bvh = tree.build_for_cpu(ctx, current)?;
                return Ok((bvh, build, t.elapsed().as_secs_f64()));
            };
            let builder = match &mut kept.gpu_sah {
                Some(b) if b.options() == options => b,
                slot => slot.insert(crate::gpu::GpuSahBuilder::new(ctx, tree, options)?),
            };
            let t = Instant::now();
            let bvh = builder.build_for_cpu(ctx, tree, current)?;
            Ok((bvh, build, t.elapsed().as_secs_f64()))
        };
        run()
            .inspect_err(|err| {
                log::error!("kinetrace: GPU rebuild failed ({err}); rebuilt on the CPU")
            })
            .ok()
    }

    #[cfg(not(feature = "gpu"))]
    fn on_gpu(
        &mut self,
        _: &Mesh,
        _: Build,
        _: bool,
        _: &mut Kept,
    ) -> Option<(MeshBvh, Build, f64)> {
        self.fallbacks.no_gpu();
        None
    }
}

/// A new mesh's adaptive policy: `builders` on the CPU, plus GPU LBVH when a GPU context exists (second,
/// after the cheapest CPU build) and the GPU twins of the SAH, hybrid, PLOC and median builders among them (last),
/// learning into the world's shared `costs` under the mesh's `asset`.
fn adaptive_policy(
    builders: &[crate::bvh::Builder],
    gpu: bool,
    costs: &CostTable,
    asset: Asset,
) -> AdaptivePolicy {
    let mut builds: Vec<Build> = builders.iter().map(|&b| Build::cpu(b)).collect();
    if gpu {
        builds.insert(builds.len().min(1), Build::GPU_LBVH);
        // The GPU twins of the configured SAH, hybrid and PLOC builders the GPU runs, last.
        #[cfg(feature = "gpu")]
        builds.extend(
            builders
                .iter()
                .filter(|&&b| {
                    matches!(
                        b,
                        crate::bvh::Builder::Ploc { .. } | crate::bvh::Builder::Median
                    ) || matches!(
                        crate::gpu::GpuSahOptions::for_builder(b, false),
                        Some(Some(_))
                    )
                })
                .map(|&builder| Build {
                    builder,
                    device: Device::Gpu,
                }),
        );
    }
    // Unmeasured builds are measured on the pose of the first rebuild's binned-SAH tree
    // (`Rebuilder::calibrate`), not tried on frames of their own.
    let mut policy = AdaptivePolicy::shared(&builds, costs, asset);
    policy.calibrates = true;
    policy
}

/// A mesh's asset for the shared costs: its topology, which every entity spawned from the same [`Mesh`]
/// shares (another [`Mesh::new`] of the same triangles counts as another asset and is measured again).
pub(super) fn asset_of(mesh: &Mesh) -> Asset {
    Asset {
        triangles: mesh.triangle_count(),
        id: topology_id(mesh),
    }
}

/// What a policy is asked about a refitted mesh.
struct Asked<'a> {
    policy: RebuildPolicy,
    hint: MotionHint,
    triangles: usize,
    degradation: f32,
    rays_last_frame: usize,
    gpu: bool,
    costs: &'a CostTable,
    asset: Asset,
    /// The refitted tree's SAH cost, where the refit measured it.
    sah: Option<f64>,
}

impl Asked<'_> {
    /// The policy's decision for the refitted `inst`, with the adaptive policy's grounds. Under the
    /// adaptive policy a rebuild due by the rent may become a partial rebuild; `checks` counts the
    /// passes that weighed one ([`crate::bvh::Bvh::degraded_primitives`]).
    fn decide(&self, inst: &mut Instance, checks: &mut usize) -> (Decision, Option<Prediction>) {
        let d = self.degradation;
        match self.policy {
            RebuildPolicy::Lauterbach { threshold } => (lauterbach(d, threshold), None),
            RebuildPolicy::Custom(policy) => {
                let input = PolicyInput {
                    hint: self.hint,
                    triangles: self.triangles,
                    degradation: d,
                    frames_since_rebuild: inst.frames_since_rebuild,
                    rays_last_frame: self.rays_last_frame,
                    profile: inst.profile.as_deref(),
                    motion_incoherence: inst.motion_incoherence(),
                    gpu: self.gpu,
                };
                (policy(&input), None)
            }
            RebuildPolicy::Adaptive { builders } => {
                let queries = inst.tree_queries();
                let Some(policy) = inst.kept.adaptive.as_mut() else {
                    // The policy became adaptive at run time: rebuild once to start measuring.
                    let policy = inst
                        .kept
                        .adaptive
                        .insert(adaptive_policy(builders, self.gpu, self.costs, self.asset));
                    return (Decision::Rebuild(policy.next_build()), None);
                };
                if let Some(profile) = inst.profile.as_deref() {
                    policy.set_profile(profile);
                }
                let cost = match self.sah {
                    Some(sah) => TreeCost::measured(inst.bvh.bvh(), sah),
                    None => TreeCost::of(inst.bvh.bvh()),
                };
                inst.sah = cost.sah;
                let rebuild = policy.after_refit(cost, queries);
                // Only a rebuild due by the rent weighs the partial one: a mesh that is kept pays no
                // pass over its nodes for it.
                let partial = policy.prediction().verdict == Verdict::Rent && {
                    *checks += 1;
                    let options = PartialOptions::default();
                    let degraded = inst.bvh.bvh().degraded_primitives(&options);
                    policy.prefer_partial(degraded.unwrap_or(0))
                };
                let why = policy.prediction();
                let decision = match rebuild {
                    _ if partial => Decision::PartialRebuild,
                    true => Decision::Rebuild(why.build),
                    false => Decision::Keep,
                };
                (decision, Some(why))
            }
        }
    }
}

/// The mesh at its current positions, once its transform is known to be usable.
fn current_mesh(
    mesh: &TraceMesh,
    positions: &[glam::Vec3],
    transform: &TraceTransform,
) -> Result<Mesh, Error> {
    checked_transform(transform)?;
    if std::ptr::eq(positions, mesh.0.positions()) {
        Ok(mesh.0.clone())
    } else {
        mesh.0.with_positions(positions.to_vec())
    }
}
