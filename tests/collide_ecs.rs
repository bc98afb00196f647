//! Collision queries through the ECS plugin: contacts against brute force in world space, layer filters,
//! self-collision, continuous colliders, and the started/ended messages once per contact episode.

mod common;

use bevy_ecs::message::Messages;
use bevy_ecs::prelude::*;
use common::icosphere;
use glam::{Affine3A, Vec3};
use kinetrace::Mesh;
use kinetrace::collide::tri_tri::triangles_intersect;
use kinetrace::ecs::*;
use std::time::Duration;

fn app() -> (World, Schedule) {
    let mut world = World::new();
    let mut schedule = Schedule::default();
    KinetracePlugin::default().build(&mut world, &mut schedule);
    (world, schedule)
}

type Pairs = Vec<(Entity, Entity)>;

/// Runs a frame and returns the messages it sent: (started, ended).
fn frame(world: &mut World, schedule: &mut Schedule) -> (Pairs, Pairs) {
    schedule.run(world);
    world.clear_trackers();
    let started = world.resource::<Messages<CollisionStarted>>();
    let ended = world.resource::<Messages<CollisionEnded>>();
    (
        started
            .iter_current_update_messages()
            .map(|m| (m.a, m.b))
            .collect(),
        ended
            .iter_current_update_messages()
            .map(|m| (m.a, m.b))
            .collect(),
    )
}

/// Every pair of triangles of two meshes in world space through the exact test: (triangle a, triangle b).
fn brute(a: &Mesh, ta: &Affine3A, b: &Mesh, tb: &Affine3A) -> Vec<(u32, u32)> {
    let mut out = Vec::new();
    for i in 0..a.triangle_count() {
        let x = a.triangle(i).map(|p| ta.transform_point3(p));
        for j in 0..b.triangle_count() {
            let y = b.triangle(j).map(|p| tb.transform_point3(p));
            if triangles_intersect(&x, &y) {
                out.push((i as u32, j as u32));
            }
        }
    }
    out
}

#[test]
fn contact_episodes_start_and_end_once() {
    for fronts in [false, true] {
        contact_episodes(fronts);
    }
}

fn contact_episodes(fronts: bool) {
    let (mut world, mut schedule) = app();
    world.insert_resource(CollisionSettings { fronts });
    let sphere = icosphere(2);
    let a = world
        .spawn((TraceMesh(sphere.clone()), Collider::default()))
        .id();
    let b = world
        .spawn((
            TraceMesh(sphere.clone()),
            Collider::default(),
            TraceTransform::default(),
        ))
        .id();
    let (lo, hi) = (a.min(b), a.max(b));
    // b approaches a, passes through it, leaves, and comes back: two episodes.
    let xs: Vec<f32> = (0..=40)
        .map(|i| 3.0 - i as f32 * 0.15)
        .chain((0..=40).map(|i| -3.0 + i as f32 * 0.15))
        .collect();
    let (mut starts, mut ends) = (0, 0);
    let mut touching = false;
    for (f, &x) in xs.iter().enumerate() {
        let tb = Affine3A::from_translation(Vec3::new(x, 0.05, 0.02));
        world.entity_mut(b).insert(TraceTransform(tb));
        let (s, e) = frame(&mut world, &mut schedule);
        let want = brute(&sphere, &Affine3A::IDENTITY, &sphere, &tb);
        let contacts = world.resource::<Contacts>();
        let got: Vec<(u32, u32)> = match contacts.between(a, b) {
            Some(p) => {
                assert_eq!((p.a, p.b), (lo, hi));
                // Triangle a belongs to the smaller entity; both spheres are the same mesh here.
                contacts
                    .contacts(p)
                    .iter()
                    .map(|c| (c.triangle_a, c.triangle_b))
                    .collect()
            }
            None => Vec::new(),
        };
        let want = if lo == a {
            want
        } else {
            want.into_iter().map(|(i, j)| (j, i)).collect::<Vec<_>>()
        };
        let mut want = want;
        want.sort_unstable();
        assert_eq!(got, want, "frame {f}, x = {x}, fronts {fronts}");
        let now = !got.is_empty();
        assert_eq!(
            s,
            if now && !touching {
                vec![(lo, hi)]
            } else {
                vec![]
            },
            "frame {f}"
        );
        assert_eq!(
            e,
            if touching && !now {
                vec![(lo, hi)]
            } else {
                vec![]
            },
            "frame {f}"
        );
        starts += s.len();
        ends += e.len();
        touching = now;
    }
    assert_eq!((starts, ends), (2, 2));
}

#[test]
fn layers_filter_pairs_and_removal_ends_contact() {
    let (mut world, mut schedule) = app();
    let sphere = icosphere(1);
    let near = Affine3A::from_translation(Vec3::X * 0.5);
    let a = world
        .spawn((
            TraceMesh(sphere.clone()),
            Collider {
                layers: CollisionLayers::new(0b01, 0b01),
                ..Default::default()
            },
        ))
        .id();
    let b = world
        .spawn((
            TraceMesh(sphere.clone()),
            TraceTransform(near),
            Collider {
                layers: CollisionLayers::new(0b10, 0b10),
                ..Default::default()
            },
        ))
        .id();
    let c = world
        .spawn((
            TraceMesh(sphere.clone()),
            TraceTransform(near),
            Collider {
                layers: CollisionLayers::new(0b01, 0b11),
                ..Default::default()
            },
        ))
        .id();
    let (s, _) = frame(&mut world, &mut schedule);
    // a–c interact; b is on a layer that a does not collide with, and does not collide with c's layer.
    assert_eq!(s, vec![(a.min(c), a.max(c))]);
    assert!(world.resource::<Contacts>().between(a, b).is_none());
    assert!(world.resource::<Contacts>().between(b, c).is_none());
    world.entity_mut(c).remove::<Collider>();
    let (s, e) = frame(&mut world, &mut schedule);
    assert_eq!((s, e), (vec![], vec![(a.min(c), a.max(c))]));
    assert!(world.resource::<Contacts>().is_empty());
}

#[test]
fn no_collider_no_pass() {
    let (mut world, mut schedule) = app();
    world.spawn(TraceMesh(icosphere(1)));
    world.spawn((
        TraceMesh(icosphere(1)),
        TraceTransform(Affine3A::from_translation(Vec3::X * 0.3)),
    ));
    frame(&mut world, &mut schedule);
    frame(&mut world, &mut schedule);
    assert_eq!(world.resource::<Contacts>().time, Duration::ZERO);
}

#[test]
fn self_collision_in_world_space() {
    let (mut world, mut schedule) = app();
    let sheet = kinetrace::scenes::folded_sheet(16, 0.0);
    let to_world = Affine3A::from_scale_rotation_translation(
        Vec3::splat(2.0),
        glam::Quat::from_rotation_x(0.7),
        Vec3::new(5.0, 1.0, -2.0),
    );
    let e = world
        .spawn((
            TraceMesh(sheet.clone()),
            TraceTransform(to_world),
            Collider {
                self_collision: true,
                ..Default::default()
            },
        ))
        .id();
    let (s, _) = frame(&mut world, &mut schedule);
    assert_eq!(s, vec![(e, e)]);
    let contacts = world.resource::<Contacts>();
    let pair = contacts.between(e, e).unwrap();
    let idx = sheet.indices();
    let mut want = Vec::new();
    for i in 0..sheet.triangle_count() {
        for j in i + 1..sheet.triangle_count() {
            let shared = idx[3 * j..3 * j + 3]
                .iter()
                .any(|v| idx[3 * i..3 * i + 3].contains(v));
            if !shared && triangles_intersect(&sheet.triangle(i), &sheet.triangle(j)) {
                want.push((i as u32, j as u32));
            }
        }
    }
    let got: Vec<_> = contacts
        .contacts(pair)
        .iter()
        .map(|c| (c.triangle_a, c.triangle_b))
        .collect();
    assert_eq!(got, want);
    for c in contacts.contacts(pair) {
        // World-space points: on the scaled, rotated, moved sheet, within its world box.
        let local = to_world.inverse().transform_point3(c.point);
        assert!(
            local.x > -1e-4 && local.x < 0.5 + 1e-4 && local.y > -1e-4 && local.y < 1.0 + 1e-4,
            "{local}"
        );
        assert!((c.normal.length() - 1.0).abs() < 1e-5);
    }
}

#[test]
fn continuous_colliders_catch_tunnelling() {
    // A small ball crosses a thin plate between two frames: discrete tests never see them touch.
    let plate = Mesh::new(
        vec![
            Vec3::new(-1.0, -1.0, 0.0),
            Vec3::new(1.0, -1.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(-1.0, 1.0, 0.0),
        ],
        vec![0, 1, 2, 0, 2, 3],
    )
    .unwrap();
    let ball = common::map_mesh(&icosphere(1), |p| p * 0.1);
    for continuous in [false, true] {
        let (mut world, mut schedule) = app();
        let collider = Collider {
            continuous,
            ..Default::default()
        };
        let p = world.spawn((TraceMesh(plate.clone()), collider)).id();
        let b = world
            .spawn((
                TraceMesh(ball.clone()),
                TraceTransform(Affine3A::from_translation(Vec3::Z * 1.0)),
                collider,
            ))
            .id();
        frame(&mut world, &mut schedule);
        assert!(world.resource::<Contacts>().is_empty());
        // From 1 above the plate to 1 below in one frame: the ball's lowest vertex, at height 1 + z_min,
        // reaches the plate when 1 + z_min - 2t = 0.
        let z_min = ball
            .positions()
            .iter()
            .map(|p| p.z)
            .fold(f32::INFINITY, f32::min);
        let t_hit = (1.0 + z_min) / 2.0;
        world
            .entity_mut(b)
            .insert(TraceTransform(Affine3A::from_translation(-Vec3::Z * 1.0)));
        let (s, _) = frame(&mut world, &mut schedule);
        let contacts = world.resource::<Contacts>();
        if !continuous {
            assert!(contacts.is_empty() && s.is_empty());
            continue;
        }
        assert_eq!(s, vec![(p.min(b), p.max(b))]);
        let pair = contacts.between(p, b).unwrap();
        let first = contacts
            .impacts(pair)
            .iter()
            .map(|i| i.t)
            .fold(f32::INFINITY, f32::min);
        assert!(
            (first - t_hit).abs() < 1e-5,
            "first impact at {first}, not {t_hit}"
        );
        for i in contacts.impacts(pair) {
            assert!(i.point.z.abs() < 1e-4, "{:?}", i.point);
        }
    }
}
