//! ECS worlds for tests, and their oracle: brute force over every triangle of every traceable entity, in
//! world space.

use bevy_ecs::prelude::*;
use glam::{Affine3A, Vec3};
use kinetrace::Ray;
use kinetrace::ecs::*;
use kinetrace::geometry::TriangleRay;

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

/// Brute force over every triangle of every accepted entity, in world space: (entity, triangle, t).
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
    let mut q = world.query_filtered::<(
        Entity,
        &TraceMesh,
        Option<&VertexPositions>,
        &QueryLayers,
    ), Without<TraceError>>();
    let tr = TriangleRay::new(ray);
    let mut best: Option<(Entity, u32, f32)> = None;
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
            let [a, b, c] = [0, 1, 2].map(|k| t.transform_point3(pos[tri[k] as usize]));
            if (b - a).cross(c - a) == Vec3::ZERO {
                continue;
            }
            if let Some(h) = tr.intersect(a, b, c, ray.tmin, ray.tmax)
                && best.is_none_or(|(_, _, bt)| h.t < bt)
            {
                best = Some((e, i as u32, h.t));
            }
        }
    }
    best
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
