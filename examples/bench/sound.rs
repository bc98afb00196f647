//! Suite `sound`: frustum-traced sound propagation, order 3, one source and one listener. In an empty
//! 10 × 8 × 3.5 m shoebox, at 4², 8² and 16² samples per frustum (4² and 8² with `--quick`), the paths
//! found are counted against the image-source method's (every image source up to order 3 is a valid path
//! in a closed convex room: what the sampling misses), with the frusta traced, the time per update on
//! all threads and on one, and the frusta per second per thread both ways. In the same room with 16
//! walking characters (23k triangles, the `sound` example's scene), the time per ECS update, its frusta
//! and paths, on all threads and on one, at the same samplings: how cost grows with the sampling rate
//! (the thesis found it about logarithmic; here the frusta grow several times with each doubling) and
//! with threads.

use crate::record::{Records, best_of};
use bevy_ecs::prelude::*;
use glam::{Affine3A, Quat, Vec3};
use kinetrace::bvh::BuildOptions;
use kinetrace::ecs::{
    KinetracePlugin, Listener, SoundPaths, SoundSettings, SoundSource, TraceMesh, TraceTransform,
};
use kinetrace::sound::{AcousticMaterial, SoundConfig, SoundScene, propagate};
use kinetrace::{MeshBvh, scenes};

const SUITE: &str = "sound";
const ROOM: Vec3 = Vec3::new(10.0, 8.0, 3.5);
const ORDER: i32 = 3;

pub fn run(rec: &mut Records) {
    println!("suite sound on {}", crate::record::machine());
    let (source, listener) = (Vec3::new(0.8, 0.7, 1.7), Vec3::new(9.1, 7.2, 1.6));
    let samplings: &[usize] = if rec.quick { &[4, 8] } else { &[4, 8, 16] };
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    // Image sources of a box up to ORDER: one per (nx, ny, nz) with |nx| + |ny| + |nz| <= ORDER.
    let oracle = (-ORDER..=ORDER)
        .flat_map(|x| (-ORDER..=ORDER).flat_map(move |y| (-ORDER..=ORDER).map(move |z| (x, y, z))))
        .filter(|(x, y, z)| x.abs() + y.abs() + z.abs() <= ORDER)
        .count();
    let room = scenes::shoebox(Vec3::ZERO, ROOM);
    let bvh = MeshBvh::build(&room, &BuildOptions::default()).expect("room builds");
    let wall = AcousticMaterial::uniform(0.1).expect("valid absorption");
    let materials = vec![0; room.triangle_count()];
    let scene = SoundScene::new(&bvh, &materials, vec![wall]).expect("valid materials");
    for &sampling in samplings {
        let name = format!("shoebox, {sampling}x{sampling} samples");
        // On all threads, then on one.
        let [(t, found), (t_one, _)] = [true, false].map(|parallel| {
            let config = SoundConfig {
                sampling,
                parallel,
                ..Default::default()
            };
            best_of(rec.reps(), || {
                propagate(&scene, source, listener, &config).expect("valid config")
            })
        });
        let frusta = found.frusta as f64;
        for (subject, metric, value, unit) in [
            ("frusta", "time per update", t * 1e3, "ms"),
            ("frusta, 1 thread", "time per update", t_one * 1e3, "ms"),
            ("frusta", "paths found", found.paths.len() as f64, ""),
            ("image sources", "paths", oracle as f64, ""),
            ("frusta", "frusta", frusta, ""),
            ("frusta", "frusta per second", frusta / t, "1/s"),
            (
                "frusta",
                "frusta per second per thread",
                frusta / t / threads as f64,
                "1/s",
            ),
            (
                "frusta, 1 thread",
                "frusta per second per thread",
                frusta / t_one,
                "1/s",
            ),
            ("1 thread/all", "speed-up", t_one / t, "x"),
        ] {
            rec.add(SUITE, &name, subject, metric, value, unit);
        }
    }
    for &sampling in samplings {
        let name = format!("room + 16 characters, {sampling}x{sampling} samples");
        let [(t, (frusta, paths)), (t_one, _)] = [true, false].map(|parallel| {
            let (mut world, mut schedule, characters) =
                crowd_room(sampling, parallel, source, listener);
            let body_at = |k: usize, t: f32| {
                let phase = k as f32 * 0.7;
                let home = Vec3::new(1.5 + (k % 4) as f32 * 2.3, 1.3 + (k / 4) as f32 * 1.8, 0.9);
                let at = home + 0.6 * Vec3::new((t + phase).cos(), (1.3 * t + phase).sin(), 0.0);
                Affine3A::from_scale_rotation_translation(
                    Vec3::new(0.25, 0.15, 0.9),
                    Quat::IDENTITY,
                    at,
                )
            };
            // Every run of the schedule moves the characters on; both thread counts see the same frames.
            let mut frame = 0;
            best_of(rec.reps(), || {
                frame += 1;
                for (k, &e) in characters.iter().enumerate() {
                    world.get_mut::<TraceTransform>(e).expect("character").0 =
                        body_at(k, frame as f32 * 0.1);
                }
                schedule.run(&mut world);
                world.clear_trackers();
                let pair = &world.resource::<SoundPaths>().pairs[0];
                (pair.frusta, pair.paths.len())
            })
        });
        let frusta = frusta as f64;
        for (subject, metric, value, unit) in [
            ("ecs update", "time per update", t * 1e3, "ms"),
            (
                "ecs update, sound on 1 thread",
                "time per update",
                t_one * 1e3,
                "ms",
            ),
            ("ecs update", "frusta", frusta, ""),
            ("ecs update", "paths found", paths as f64, ""),
            (
                "ecs update",
                "frusta per second per thread",
                frusta / t / threads as f64,
                "1/s",
            ),
            ("1 thread/all", "speed-up", t_one / t, "x"),
        ] {
            rec.add(SUITE, &name, subject, metric, value, unit);
        }
    }
}

/// The `sound` example's room with 16 characters as entities, a source and a listener, propagated at
/// `sampling`² samples on all threads or (`parallel` false) on one.
fn crowd_room(
    sampling: usize,
    parallel: bool,
    source: Vec3,
    listener: Vec3,
) -> (World, Schedule, Vec<Entity>) {
    let mut world = World::new();
    let mut schedule = Schedule::default();
    schedule.set_executor(bevy_ecs::schedule::SingleThreadedExecutor::new());
    KinetracePlugin::default()
        .try_build(&mut world, &mut schedule)
        .expect("cpu plugin");
    world.insert_resource(SoundSettings {
        config: SoundConfig {
            sampling,
            parallel,
            ..Default::default()
        },
        ..Default::default()
    });
    world.spawn(TraceMesh(scenes::shoebox(Vec3::ZERO, ROOM)));
    let body = scenes::cube_sphere(11);
    let characters = (0..16)
        .map(|_| world.spawn(TraceMesh(body.clone())).id())
        .collect();
    world.spawn(SoundSource(source));
    world.spawn(Listener(listener));
    (world, schedule, characters)
}
