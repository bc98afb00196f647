//! ECS worlds for tests, and their oracle: brute force over every triangle of every traceable entity, in
//! world space.

use super::RayOracle;
use bevy_ecs::prelude::*;
use glam::{Affine3A, Vec3};
use kinetrace::Ray;
use kinetrace::ecs::*;

/// A world and schedule with the plugin installed with `config` (whose GPU, in a GPU mode, must exist).
pub fn app_with(config: TraceConfig) -> (World, Schedule) {
    let mut world = World::new();
    let mut schedule = Schedule::default();
    KinetracePlugin {
        config,
        ..Default::default()
    }
    .try_build(&mut world, &mut schedule)
    .expect("the mode's device is there");
    (world, schedule)
}

/// Brute force over every triangle of every accepted entity, in world space, by the independent oracle
/// ([`RayOracle`]'s exact closest hit): (entity, triangle, t).
pub fn brute(world: &mut World, ray: &Ray, filter: &QueryFilter) -> Option<(Entity, u32, f32)> {
    brute_placed(world, ray, filter, |e| {
        e.get::<TraceTransform>().expect("required by TraceMesh").0
    })
}

/// [`brute`] with every entity placed where `place` says rather than by its `TraceTransform`: the oracle
/// for code that is meant to write that transform.
pub fn brute_placed(
    world: &mut World,
    ray: &Ray,
    filter: &QueryFilter,
    place: impl Fn(EntityRef) -> Affine3A,
) -> Option<(Entity, u32, f32)> {
    let (keys, tris) = placed_triangles(world, filter, place);
    RayOracle::new(ray, tris).closest().map(|(k, t)| {
        let (e, i) = keys[k as usize];
        (e, i, t as f32)
    })
}

/// Every triangle of every accepted, healthy entity in world space (its current positions placed by
/// `place`), with its `(entity, triangle index)`.
pub fn placed_triangles(
    world: &mut World,
    filter: &QueryFilter,
    place: impl Fn(EntityRef) -> Affine3A,
) -> (Vec<(Entity, u32)>, Vec<[Vec3; 3]>) {
    let mut q = world.query_filtered::<(
        Entity,
        &TraceMesh,
        Option<&VertexPositions>,
        &QueryLayers,
    ), Without<TraceError>>();
    let mut keys = Vec::new();
    let mut tris = Vec::new();
    for (e, m, vp, l) in q.iter(world) {
        if !filter.accepts(e, l.0) {
            continue;
        }
        let t = place(world.entity(e));
        let pos = match vp {
            Some(v) if !v.0.is_empty() => &v.0[..],
            _ => m.0.positions(),
        };
        for (i, tri) in m.0.indices().chunks(3).enumerate() {
            keys.push((e, i as u32));
            tris.push([0, 1, 2].map(|k| t.transform_point3(pos[tri[k] as usize])));
        }
    }
    (keys, tris)
}

/// [`placed_triangles`] placed by each entity's `TraceTransform`.
pub fn world_triangles(
    world: &mut World,
    filter: &QueryFilter,
) -> (Vec<(Entity, u32)>, Vec<[Vec3; 3]>) {
    placed_triangles(world, filter, |e| {
        e.get::<TraceTransform>().expect("required by TraceMesh").0
    })
}

/// The world and brute force agree: same entity and triangle at the same distance (1e-4 relative: the
/// world traces in object space), or an equally near hit elsewhere (a tie).
pub fn agree(got: Option<&RayHit>, expect: Option<(Entity, u32, f32)>, what: &str) {
    match (got, expect) {
        (None, None) => {}
        (Some(h), Some((e, tri, t))) => {
            let close = (h.distance - t).abs() <= 1e-4 * t.abs().max(1.0);
            assert!(close, "{what}: t {} vs {t}", h.distance);
            if (h.entity, h.triangle) != (e, tri) {
                assert!(
                    (h.distance - t).abs() <= 1e-5 * t.abs().max(1.0),
                    "{what}: {h:?} vs {expect:?}"
                );
            }
        }
        _ => panic!("{what}: {got:?} vs {expect:?}"),
    }
}

/// The scripted cost (`TraceWorld::script_costs`) of a planned option that is the `cheap` one of its kind
/// or not: the cheaper wide mode costs a hundredth of the other's upkeep (a wide tree's collapse and
/// refit), the cheaper structure or packet mode half per ray. Both stay within reach of each option's
/// prior, so that the planner tries the other option whatever the machine's load.
pub fn scripted_cost(option: PlannedOption, cheap: bool) -> ScriptedCost {
    match option {
        PlannedOption::Wide(_) => ScriptedCost {
            overhead_s: if cheap { 1e-6 } else { 1e-4 },
            per_ray_s: 1e-6,
        },
        _ => ScriptedCost {
            overhead_s: 1e-6,
            per_ray_s: if cheap { 0.5e-6 } else { 1e-6 },
        },
    }
}
