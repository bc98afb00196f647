//! Bevy conventions: an app's own transform component places traceable entities with no copy system of
//! the app's (checked against world-space brute force that reads the app's component, not the crate's
//! copy), and the deprecated `TraceSet` name still schedules systems.

mod common;
use bevy_ecs::prelude::*;
use common::ecs::{agree, app_with, brute_placed};
use common::*;
use glam::{Affine3A, Quat, Vec3};
use kinetrace::Ray;
use kinetrace::ecs::*;
use rand::Rng;
use rand::rngs::SmallRng;

/// The app's transform: translation, rotation and a non-uniform scale.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
struct Place {
    at: Vec3,
    rotation: Quat,
    scale: Vec3,
}

impl Place {
    fn affine(&self) -> Affine3A {
        Affine3A::from_scale_rotation_translation(self.scale, self.rotation, self.at)
    }

    fn random(r: &mut SmallRng) -> Self {
        Place {
            at: rand_vec(r, -6.0, 6.0),
            rotation: Quat::from_axis_angle(rand_dir(r), r.random_range(0.0..6.0)),
            scale: rand_vec(r, 0.5, 1.5),
        }
    }
}

/// Entities that the app's gameplay system moves every frame.
#[derive(Component)]
struct Mover;

/// Gameplay: moves every [`Mover`]'s own transform, nothing else — ordered before the top level, as the
/// plugin asks of transform writes.
fn wander(mut q: Query<&mut Place, With<Mover>>, stats: Res<TraceStats>) {
    for (i, mut p) in q.iter_mut().enumerate() {
        let s = (stats.frame as f32 + i as f32) * 0.37;
        p.at += Vec3::new(s.sin(), s.cos(), (2.0 * s).sin()) * 0.4;
        p.rotation *= Quat::from_rotation_x(0.2);
    }
}

/// Where the app means the entity to be: its `Place`, or the identity without one.
fn intended(e: EntityRef) -> Affine3A {
    e.get::<Place>().map_or(Affine3A::IDENTITY, Place::affine)
}

/// Rays at every traceable entity's intended centre plus random ones; each answer must match the
/// brute force over the app's placement. Returns how many rays hit something.
fn check(world: &mut World, r: &mut SmallRng, what: &str) -> usize {
    let targets: Vec<Vec3> = world
        .query_filtered::<EntityRef, With<TraceMesh>>()
        .iter(world)
        .map(|e| intended(e).translation.into())
        .collect();
    let mut rays: Vec<Ray> = targets
        .iter()
        .map(|&c| {
            let from = c + rand_dir(r) * 20.0;
            Ray::new(from, (c + rand_vec(r, -0.2, 0.2) - from).normalize())
        })
        .collect();
    rays.extend((0..20).map(|_| Ray::new(rand_vec(r, -8.0, 8.0), rand_dir(r))));
    let filter = QueryFilter::default();
    let mut hits = 0;
    for (i, ray) in rays.iter().enumerate() {
        let got = world
            .resource::<TraceWorld>()
            .cast_ray(ray, f32::INFINITY, &filter);
        let expect = brute_placed(world, ray, &filter, intended);
        hits += usize::from(expect.is_some());
        agree(got.as_ref(), expect, &format!("{what}, ray {i}"));
    }
    hits
}

fn frame(world: &mut World, schedule: &mut Schedule) {
    schedule.run(world);
    world.clear_trackers();
}

/// Whether the top level recorded `e` as moved this frame.
fn moved(world: &World, e: Entity) -> bool {
    let stats = world.resource::<TraceStats>();
    stats
        .meshes
        .iter()
        .any(|m| m.entity == e && m.action == MeshAction::Moved)
}

#[test]
fn own_transform_component_places_entities_through_insert_change_and_removal() {
    let mut world = World::new();
    let mut schedule = Schedule::default();
    KinetracePlugin::default()
        .sync_transforms(Place::affine)
        .try_build(&mut world, &mut schedule)
        .expect("CPU mode needs no device");
    schedule.add_systems(wander.before(TraceSystems::TopLevel));
    let mut r = rng(11);

    // Spawned with their own transform; some of them wander every frame.
    let placed: Vec<Entity> = (0..8)
        .map(|i| {
            let mut e = world.spawn((
                TraceMesh(icosphere(2)),
                MotionHint::Rigid,
                Place::random(&mut r),
            ));
            if i % 2 == 0 {
                e.insert(Mover);
            }
            e.id()
        })
        .collect();
    // Traceable with no transform of the app's yet (at the identity), and a transform not yet traceable.
    let bare = world
        .spawn((TraceMesh(cube_sphere(2)), MotionHint::Rigid))
        .id();
    let untraced = world.spawn(Place::random(&mut r)).id();

    let mut hits = 0;
    for f in 0..16 {
        match f {
            // Insertion of the app's component on a traceable entity, and of a mesh on a placed one.
            3 => {
                world
                    .entity_mut(bare)
                    .insert((Place::random(&mut r), Mover));
                world
                    .entity_mut(untraced)
                    .insert((TraceMesh(icosphere(1)), MotionHint::Rigid));
            }
            // A plain change outside the schedule.
            5 => world.get_mut::<Place>(placed[1]).unwrap().at = Vec3::new(0.0, 7.0, 0.0),
            // Removal: back to the identity, mover or not.
            7 => {
                world.entity_mut(placed[0]).remove::<Place>();
                world.entity_mut(placed[3]).remove::<Place>();
            }
            // Re-insertion, and removal with re-insertion in the same frame.
            10 => {
                world.entity_mut(placed[0]).insert(Place::random(&mut r));
                let p = Place::random(&mut r);
                world.entity_mut(placed[5]).remove::<Place>().insert(p);
            }
            // Despawning a placed entity.
            12 => {
                world.despawn(placed[7]);
            }
            _ => {}
        }
        frame(&mut world, &mut schedule);
        hits += check(&mut world, &mut r, &format!("frame {f}"));
        assert!(
            world.query::<&TraceError>().iter(&world).next().is_none(),
            "frame {f}: no entity failed"
        );
        if f == 5 {
            assert!(moved(&world, placed[1]), "a changed Place moves the entity");
        }
        if f == 7 {
            assert!(moved(&world, placed[3]), "a removed Place moves it home");
        }
    }
    // The rays at the entities' centres hit far more often than not: the checks compared hits, not misses.
    assert!(hits > 16 * 8, "only {hits} hits");

    // A write that leaves the matrix as it was costs the top level nothing.
    let still = placed[1]; // not a mover
    let p = *world.get::<Place>(still).unwrap();
    *world.get_mut::<Place>(still).unwrap() = p;
    frame(&mut world, &mut schedule);
    assert!(!moved(&world, still), "same matrix, no top-level work");
}

#[test]
fn without_sync_the_apps_component_is_ignored() {
    // The control for the test above: the same world without `sync_transforms` leaves entities at the
    // identity, so the oracle that reads `Place` disagrees — the sync is what places them.
    let (mut world, mut schedule) = app_with(TraceConfig::default());
    let p = Place {
        at: Vec3::new(0.0, 0.0, 10.0),
        rotation: Quat::IDENTITY,
        scale: Vec3::ONE,
    };
    world.spawn((TraceMesh(icosphere(2)), p));
    frame(&mut world, &mut schedule);
    let ray = Ray::new(Vec3::new(0.0, 0.0, 20.0), -Vec3::Z);
    let filter = QueryFilter::default();
    let got = world
        .resource::<TraceWorld>()
        .cast_ray(&ray, f32::INFINITY, &filter)
        .expect("the sphere at the origin");
    let intended_hit =
        brute_placed(&mut world, &ray, &filter, intended).expect("the sphere at z = 10");
    assert!(got.distance > intended_hit.2 + 9.0);
}

#[test]
#[allow(deprecated)]
fn deprecated_trace_set_alias_names_the_same_sets() {
    use kinetrace::ecs::TraceSet;

    // The alias names variants, in expressions and in patterns.
    assert_eq!(TraceSet::TopLevel, TraceSystems::TopLevel);
    assert!(matches!(TraceSystems::Queries, TraceSet::Queries));

    // A system ordered with the old name still runs before the top level: its move is seen this frame.
    let (mut world, mut schedule) = app_with(TraceConfig::default());
    let e = world
        .spawn((TraceMesh(icosphere(2)), MotionHint::Rigid))
        .id();
    frame(&mut world, &mut schedule);
    fn lift(mut q: Query<&mut TraceTransform>) {
        for mut t in &mut q {
            t.0 = Affine3A::from_translation(Vec3::new(0.0, 5.0, 0.0));
        }
    }
    schedule.add_systems(lift.before(TraceSet::TopLevel).in_set(TraceSet::Animate));
    frame(&mut world, &mut schedule);
    let ray = Ray::new(Vec3::new(0.0, 5.0, -10.0), Vec3::Z);
    let got = world
        .resource::<TraceWorld>()
        .cast_ray(&ray, f32::INFINITY, &QueryFilter::default());
    let expect = common::ecs::brute(&mut world, &ray, &QueryFilter::default());
    assert!(expect.is_some_and(|(hit, _, _)| hit == e));
    agree(got.as_ref(), expect, "moved under the old set name");
}
