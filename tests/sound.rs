//! Sound propagation against the image-source method in a shoebox room (an analytic oracle written here),
//! closed walls, a moving occluder against an analytic segment–box test, and thread-count independence;
//! through the ECS: the same answer as the direct call on the same world geometry, a walking character
//! blocking the direct path, updates every n frames.

use bevy_ecs::prelude::*;
use glam::{Affine3A, DVec3, Quat, Vec3};
use kinetrace::bvh::BuildOptions;
use kinetrace::bvh::Bvh;
use kinetrace::ecs::{
    AcousticSurface, KinetracePlugin, Listener, Plugin, SoundPaths, SoundSettings, SoundSource,
    TraceMesh, TraceStats, TraceTransform, VertexPositions,
};
use kinetrace::sound::{
    AcousticMaterial, BANDS, Propagation, SoundConfig, SoundInstance, SoundScene, propagate,
};
use kinetrace::{Aabb, Mesh, MeshBvh, scenes};

const ROOM: Vec3 = Vec3::new(5.0, 3.7, 2.9);

/// Wall index of a face of an axis-aligned box: `2·axis + (1 on the max side)`, from the triangle itself.
fn wall_of(mesh: &Mesh, i: usize, lo: Vec3, hi: Vec3) -> usize {
    let [a, b, c] = mesh.triangle(i);
    let n = (b - a).cross(c - a);
    let axis = n.abs().max_position();
    2 * axis + usize::from((a[axis] - hi[axis]).abs() < (a[axis] - lo[axis]).abs())
}

/// A different absorption spectrum per wall.
fn wall_material(w: usize) -> AcousticMaterial {
    AcousticMaterial::new(std::array::from_fn(|b| {
        0.05 + 0.07 * w as f32 + 0.03 * b as f32
    }))
    .unwrap()
}

fn concat(meshes: &[Mesh]) -> Mesh {
    let mut pos = Vec::new();
    let mut idx = Vec::new();
    for m in meshes {
        let base = pos.len() as u32;
        pos.extend_from_slice(m.positions());
        idx.extend(m.indices().iter().map(|i| i + base));
    }
    Mesh::new(pos, idx).unwrap()
}

fn config(parallel: bool) -> SoundConfig {
    SoundConfig {
        primary: 4,
        sampling: 8,
        max_order: 3,
        speed_of_sound: 343.0,
        parallel,
    }
}

/// One image source of the shoebox: its unfolded position and, per reflection, the wall, the path length
/// from the source to the reflection point, the reflection point's distance to its wall's border and the
/// cosine of the incidence angle.
struct Image {
    pos: DVec3,
    order: u32,
    reflections: Vec<(usize, f64, f64, f64)>,
}

/// Allen & Berkley's image sources of a box `[0, room]` up to `max_order`, in f64.
fn image_sources(room: DVec3, s: DVec3, l: DVec3, max_order: i32) -> Vec<Image> {
    let image = |n: i32, len: f64, x: f64| {
        if n % 2 == 0 {
            n as f64 * len + x
        } else {
            (n + 1) as f64 * len - x
        }
    };
    let fold = |x: f64, len: f64| {
        let m = x.rem_euclid(2.0 * len);
        if m > len { 2.0 * len - m } else { m }
    };
    let mut out = Vec::new();
    for nx in -max_order..=max_order {
        for ny in -max_order..=max_order {
            for nz in -max_order..=max_order {
                let order = nx.abs() + ny.abs() + nz.abs();
                if order > max_order {
                    continue;
                }
                let n = [nx, ny, nz];
                let pos = DVec3::from_array(std::array::from_fn(|a| image(n[a], room[a], s[a])));
                let d = pos - l;
                let mut reflections = Vec::new();
                for a in 0..3 {
                    // Planes x_a = m · room_a crossed on the way from the listener's cell to the image's.
                    let planes: Vec<i32> = if n[a] > 0 {
                        (1..=n[a]).collect()
                    } else {
                        (n[a] + 1..=0).rev().collect()
                    };
                    for m in planes {
                        let t = (m as f64 * room[a] - l[a]) / d[a];
                        let q = l + d * t;
                        let border = (0..3)
                            .filter(|&b| b != a)
                            .map(|b| {
                                let f = fold(q[b], room[b]);
                                f.min(room[b] - f)
                            })
                            .fold(f64::INFINITY, f64::min);
                        // Which wall: the unfolded plane's parity says min or max side.
                        let max_side = m.rem_euclid(2) == 1;
                        let wall = 2 * a + usize::from(max_side);
                        reflections.push((wall, pos.distance(q), border, d[a].abs() / d.length()));
                    }
                }
                out.push(Image {
                    pos,
                    order: order as u32,
                    reflections,
                });
            }
        }
    }
    out
}

/// Footprint of a sub-frustum's centre ray error at path length `r` and incidence cosine `cos`: the bound
/// the module documents, `r · sin ρ / cos(θ + ρ)` with `ρ = √2 / (primary · sampling)`.
fn footprint(cfg: &SoundConfig, r: f64, cos: f64) -> f64 {
    let rho = 2f64.sqrt() / (cfg.primary * cfg.sampling) as f64;
    let theta = cos.clamp(-1.0, 1.0).acos();
    if theta + rho >= std::f64::consts::FRAC_PI_2 {
        f64::INFINITY
    } else {
        r * rho.sin() / (theta + rho).cos()
    }
}

fn shoebox_scene() -> (Mesh, Vec<u32>) {
    let room = scenes::shoebox(Vec3::ZERO, ROOM);
    let mats = (0..room.triangle_count())
        .map(|i| wall_of(&room, i, Vec3::ZERO, ROOM) as u32)
        .collect();
    (room, mats)
}

#[test]
fn specular_paths_match_image_sources_up_to_order_3() {
    let (room, mats) = shoebox_scene();
    let bvh = MeshBvh::build(&room, &BuildOptions::default()).unwrap();
    let scene = SoundScene::new(&bvh, &mats, (0..6).map(wall_material).collect()).unwrap();
    // The default sampling (4²) and a finer one (8²): each with its own footprint.
    for sampling in [4, 8] {
        let cfg = SoundConfig {
            sampling,
            ..config(true)
        };
        match_image_sources(&scene, &cfg);
    }
}

/// [`specular_paths_match_image_sources_up_to_order_3`] at one configuration.
fn match_image_sources(scene: &SoundScene, cfg: &SoundConfig) {
    let cases = [
        (Vec3::new(1.3, 1.1, 1.7), Vec3::new(3.9, 2.5, 0.8)),
        (Vec3::new(4.2, 0.6, 0.5), Vec3::new(0.9, 3.1, 2.3)),
        (Vec3::new(2.5, 1.85, 1.45), Vec3::new(2.6, 1.7, 1.2)),
    ];
    let (mut required, mut unsafe_missed, mut unsafe_found) = (0, 0, 0);
    for (s, l) in cases {
        let found = propagate(scene, s, l, cfg).unwrap();
        let oracle = image_sources(ROOM.as_dvec3(), s.as_dvec3(), l.as_dvec3(), 3);
        let mut matched = vec![false; oracle.len()];
        for p in &found.paths {
            // Every path found is an image source: same order, length and direction of arrival.
            let hit = oracle.iter().position(|im| {
                let d = im.pos - l.as_dvec3();
                im.order == p.order
                    && (d.length() - p.length as f64).abs() <= 1e-5 * d.length()
                    && (d.normalize() - p.direction.as_dvec3()).length() <= 1e-5
            });
            let k = hit.unwrap_or_else(|| panic!("path {p:?} is no image source of {s} → {l}"));
            assert!(!matched[k], "image source {:?} found twice", oracle[k].pos);
            matched[k] = true;
            let im = &oracle[k];
            assert_eq!(p.delay, p.length / cfg.speed_of_sound);
            // Energy: the walls' reflectances over the squared length.
            let walls: Vec<usize> = im.reflections.iter().map(|r| r.0).collect();
            for b in 0..BANDS {
                let keep: f64 = walls
                    .iter()
                    .map(|&w| 1.0 - wall_material(w).absorption[b] as f64)
                    .product();
                let want = keep / (p.length as f64).powi(2);
                assert!(
                    (p.attenuation[b] as f64 - want).abs() <= 1e-5 * want,
                    "band {b} of {p:?}"
                );
            }
        }
        // Every image source whose reflection points all lie farther from their walls' borders than the
        // sampling footprint is found.
        for (im, &m) in oracle.iter().zip(&matched) {
            let safe = im
                .reflections
                .iter()
                .all(|&(_, r, border, cos)| border > footprint(cfg, r, cos));
            match (safe, m) {
                (true, false) => panic!("missed image source {:?} (order {})", im.pos, im.order),
                (true, true) => required += 1,
                (false, false) => unsafe_missed += 1,
                (false, true) => unsafe_found += 1,
            }
        }
    }
    println!(
        "{}² samples: image sources {required} required and found; near a border: {unsafe_found} found, {unsafe_missed} missed",
        cfg.sampling
    );
    // A third of the image sources, at least, lie clear of their borders (86 and 128 of 189 at 4² and 8²).
    assert!(
        required * 3 > required + unsafe_found + unsafe_missed,
        "{}² samples: the footprint bound left too few paths to check",
        cfg.sampling
    );
}

#[test]
fn no_path_leaks_through_closed_walls() {
    // The source shut in a closed box inside the room; the listener in the room, then outside it.
    let inner_lo = Vec3::new(0.5, 0.5, 0.5);
    let inner_hi = Vec3::new(1.5, 1.5, 1.5);
    let mesh = concat(&[
        scenes::shoebox(Vec3::ZERO, ROOM),
        scenes::shoebox(inner_lo, inner_hi),
    ]);
    let bvh = MeshBvh::build(&mesh, &BuildOptions::default()).unwrap();
    let mats = vec![0; mesh.triangle_count()];
    let scene =
        SoundScene::new(&bvh, &mats, vec![AcousticMaterial::uniform(0.1).unwrap()]).unwrap();
    let cfg = config(true);
    let source = Vec3::new(1.0, 0.9, 1.1);
    for listener in [
        Vec3::new(3.5, 2.0, 1.0),
        Vec3::new(7.0, 1.0, 1.0),
        Vec3::new(1.0, 1.0, 2.0),
    ] {
        let found = propagate(&scene, source, listener, &cfg).unwrap();
        assert!(found.frusta > 0);
        assert!(found.paths.is_empty(), "{listener}: {:?}", found.paths);
    }
    // Inside the same closed box the listener hears the source, directly and by reflections.
    let found = propagate(&scene, source, Vec3::new(1.3, 1.2, 0.7), &cfg).unwrap();
    assert_eq!(found.paths.iter().filter(|p| p.order == 0).count(), 1);
    assert_eq!(found.paths.iter().filter(|p| p.order == 1).count(), 6);
}

/// Whether the segment `a → b` passes through the box, by the slab method in f64; `None` when it passes
/// within `margin` of the box's surface (too close to call for f32 geometry).
fn segment_blocked(a: DVec3, b: DVec3, lo: DVec3, hi: DVec3, margin: f64) -> Option<bool> {
    let through = |lo: DVec3, hi: DVec3| {
        let d = b - a;
        let (mut t0, mut t1) = (0.0f64, 1.0f64);
        for k in 0..3 {
            if d[k] == 0.0 {
                if a[k] < lo[k] || a[k] > hi[k] {
                    return false;
                }
                continue;
            }
            let (x, y) = ((lo[k] - a[k]) / d[k], (hi[k] - a[k]) / d[k]);
            t0 = t0.max(x.min(y));
            t1 = t1.min(x.max(y));
        }
        t0 <= t1
    };
    let m = DVec3::splat(margin);
    let (inner, outer) = (through(lo + m, hi - m), through(lo - m, hi + m));
    (inner == outer).then_some(inner)
}

#[test]
fn moving_occluder_removes_the_direct_path_exactly_while_it_blocks() {
    let (room, room_mats) = shoebox_scene();
    let cfg = SoundConfig {
        max_order: 1,
        ..config(true)
    };
    walk_across_the_line_of_sight(|source, listener, lo, hi| {
        let mesh = concat(&[room.clone(), scenes::shoebox(lo, hi)]);
        let mut mats = room_mats.clone();
        mats.resize(mesh.triangle_count(), 6);
        let bvh = MeshBvh::build(&mesh, &BuildOptions::default()).unwrap();
        let materials = (0..7).map(wall_material).collect();
        let scene = SoundScene::new(&bvh, &mats, materials).unwrap();
        let found = propagate(&scene, source, listener, &cfg).unwrap();
        found.paths.iter().filter(|p| p.order == 0).count()
    });
}

/// Walks a character-sized box `[lo, hi]` across the line of sight from a source to a listener in 61
/// steps; `direct(source, listener, lo, hi)` gives the number of direct paths found with the box there,
/// which must be 1 exactly while the analytic segment–box test says the line is clear.
fn walk_across_the_line_of_sight(mut direct: impl FnMut(Vec3, Vec3, Vec3, Vec3) -> usize) {
    let source = Vec3::new(1.0, 1.5, 1.2);
    let listener = Vec3::new(4.0, 2.1, 1.4);
    let half = Vec3::new(0.15, 0.3, 0.5);
    let (mut blocked, mut clear) = (0, 0);
    for step in 0..=60 {
        let centre = Vec3::new(2.4, 0.4 + 0.05 * step as f32, 1.2);
        let (lo, hi) = (centre - half, centre + half);
        let found = direct(source, listener, lo, hi);
        let Some(oracle) = segment_blocked(
            source.as_dvec3(),
            listener.as_dvec3(),
            lo.as_dvec3(),
            hi.as_dvec3(),
            1e-4,
        ) else {
            continue;
        };
        assert_eq!(found, usize::from(!oracle), "occluder at {centre}");
        if oracle { blocked += 1 } else { clear += 1 }
    }
    assert!(
        blocked >= 5 && clear >= 5,
        "{blocked} blocked, {clear} clear positions"
    );
}

/// The same paths, in the same order, single-threaded and in pools of several threads.
#[test]
fn results_do_not_depend_on_the_thread_count() {
    // The room with two bumpy tori standing in for characters: many small triangles, partial coverage.
    let torus = |c: Vec3| {
        let t = scenes::bumpy_torus(2000);
        let pos: Vec<Vec3> = t.positions().iter().map(|p| *p * 0.5 + c).collect();
        t.with_positions(pos).unwrap()
    };
    let mesh = concat(&[
        scenes::shoebox(Vec3::ZERO, ROOM),
        torus(Vec3::new(2.0, 1.5, 1.0)),
        torus(Vec3::new(3.5, 2.5, 1.8)),
    ]);
    let bvh = MeshBvh::build(&mesh, &BuildOptions::default()).unwrap();
    let mats: Vec<u32> = (0..mesh.triangle_count()).map(|i| (i % 3) as u32).collect();
    let materials = (0..3).map(wall_material).collect();
    let scene = SoundScene::new(&bvh, &mats, materials).unwrap();
    let (s, l) = (Vec3::new(0.7, 0.8, 1.5), Vec3::new(4.4, 3.1, 0.9));
    let one: Propagation = propagate(&scene, s, l, &config(false)).unwrap();
    assert!(!one.paths.is_empty());
    // In pools of 2, 3 and 7 threads, whatever the machine's cores.
    for threads in [2, 3, 7] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let all = pool.install(|| {
            assert_eq!(rayon::current_num_threads(), threads);
            propagate(&scene, s, l, &config(true)).unwrap()
        });
        assert_eq!(one, all, "{threads} threads");
    }
}

#[test]
fn bad_input_is_an_error() {
    let (room, mats) = shoebox_scene();
    let bvh = MeshBvh::build(&room, &BuildOptions::default()).unwrap();
    assert!(AcousticMaterial::uniform(1.5).is_err());
    assert!(AcousticMaterial::uniform(f32::NAN).is_err());
    assert!(SoundScene::new(&bvh, &mats[1..], vec![wall_material(0); 6]).is_err());
    assert!(SoundScene::new(&bvh, &mats, vec![wall_material(0); 5]).is_err());
    let scene = SoundScene::new(&bvh, &mats, vec![wall_material(0); 6]).unwrap();
    let ok = Vec3::ONE;
    assert!(propagate(&scene, Vec3::NAN, ok, &config(true)).is_err());
    let bad_configs = [
        SoundConfig {
            sampling: 6,
            ..config(true)
        },
        SoundConfig {
            primary: 0,
            ..config(true)
        },
        // Past the bound: 6 · primary² frusta would overflow a capacity instead of failing cleanly.
        SoundConfig {
            primary: kinetrace::sound::MAX_PRIMARY + 1,
            ..config(true)
        },
        SoundConfig {
            primary: usize::MAX,
            ..config(true)
        },
        SoundConfig {
            speed_of_sound: 0.0,
            ..config(true)
        },
    ];
    for bad in bad_configs {
        assert!(propagate(&scene, ok, ok, &bad).is_err(), "{bad:?}");
    }
}

// ---- Through the ECS: `SoundSource`, `Listener`, `AcousticSurface` → `SoundPaths`. ----

/// A plugin world with these sound settings, run on the calling thread.
fn sound_app(settings: SoundSettings) -> (World, Schedule) {
    let mut world = World::new();
    let mut schedule = Schedule::default();
    schedule.set_executor(bevy_ecs::schedule::SingleThreadedExecutor::new());
    KinetracePlugin::default().build(&mut world, &mut schedule);
    world.insert_resource(settings);
    (world, schedule)
}

fn run_frame(world: &mut World, schedule: &mut Schedule) {
    schedule.run(world);
    world.clear_trackers();
}

fn moved(mesh: &Mesh, t: Affine3A) -> Vec<Vec3> {
    mesh.positions()
        .iter()
        .map(|p| t.transform_point3(*p))
        .collect()
}

#[test]
fn ecs_paths_equal_the_direct_call_on_the_same_world_geometry() {
    let cfg = config(true);
    let default_material = wall_material(5);
    let (mut world, mut schedule) = sound_app(SoundSettings {
        config: cfg,
        default_material,
        ..Default::default()
    });
    let room = scenes::shoebox(Vec3::ZERO, ROOM);
    let body = scenes::cube_sphere(6);
    let blob = scenes::bumpy_torus(600);
    world.spawn((TraceMesh(room.clone()), AcousticSurface(wall_material(0))));
    let walker = world
        .spawn((TraceMesh(body.clone()), AcousticSurface(wall_material(3))))
        .id();
    let deformer = world
        .spawn((
            TraceMesh(blob.clone()),
            VertexPositions(blob.positions().to_vec()),
        ))
        .id();
    let (s, l) = (Vec3::new(0.6, 0.7, 1.6), Vec3::new(4.3, 3.0, 1.1));
    let source = world.spawn(SoundSource(s)).id();
    let listener = world.spawn(Listener(l)).id();
    for frame in 0..3 {
        // A rigid character walking (scaled and turned), a blob deforming in place.
        let t = frame as f32 * 0.4;
        let walk = Affine3A::from_scale_rotation_translation(
            Vec3::new(0.3, 0.2, 0.8),
            Quat::from_rotation_z(t),
            Vec3::new(2.0 + t, 1.4, 0.9),
        );
        let wobble: Vec<Vec3> = blob
            .positions()
            .iter()
            .map(|p| *p * (0.5 + 0.05 * (3.0 * p.x + t).sin()) + Vec3::new(3.2, 2.4, 1.5))
            .collect();
        world.get_mut::<TraceTransform>(walker).unwrap().0 = walk;
        world.get_mut::<VertexPositions>(deformer).unwrap().0 = wobble.clone();
        run_frame(&mut world, &mut schedule);

        // The oracle: the same world-space triangles, put together here, traced by the direct call.
        let mesh = concat(&[
            room.clone(),
            body.with_positions(moved(&body, walk)).unwrap(),
            blob.with_positions(wobble).unwrap(),
        ]);
        let mut mats = vec![0u32; room.triangle_count()];
        mats.resize(room.triangle_count() + body.triangle_count(), 1);
        mats.resize(mesh.triangle_count(), 2);
        let bvh = MeshBvh::build(&mesh, &BuildOptions::default()).unwrap();
        let palette = vec![wall_material(0), wall_material(3), default_material];
        let scene = SoundScene::new(&bvh, &mats, palette).unwrap();
        let direct = propagate(&scene, s, l, &cfg).unwrap();

        let sound = world.resource::<SoundPaths>();
        assert_eq!(sound.frame, world.resource::<TraceStats>().frame);
        assert_eq!(sound.triangles, mesh.triangle_count());
        let ecs = sound.between(source, listener).expect("one pair");
        assert!(direct.paths.iter().any(|p| p.order == 3), "frame {frame}");
        assert_same_paths(ecs, &direct.paths, &format!("frame {frame}"));
    }
}

/// The same paths in both lists: equal counts, and each path of `found` has one in `oracle` of its order
/// with the same length, direction and attenuation to float rounding. Surface ids depend on the trees'
/// leaf order, and a merged surface's plane on which of its triangles came first (rounding), so they are
/// not compared.
fn assert_same_paths(
    found: &[kinetrace::sound::SoundPath],
    oracle: &[kinetrace::sound::SoundPath],
    what: &str,
) {
    assert_eq!(found.len(), oracle.len(), "{what}");
    for p in found {
        let q = oracle
            .iter()
            .find(|q| {
                q.order == p.order
                    && (q.length - p.length).abs() <= 1e-5 * q.length
                    && (q.direction - p.direction).length() <= 1e-5
            })
            .unwrap_or_else(|| panic!("{what}: {p:?} not in the oracle"));
        for b in 0..BANDS {
            assert!(
                (q.attenuation[b] - p.attenuation[b]).abs() <= 1e-5 * q.attenuation[b],
                "{what}: band {b} of {p:?}"
            );
        }
    }
}

#[test]
fn two_level_scene_equals_one_copied_tree() {
    // A room, a scaled and turned body, a mirrored one (negative determinant) and a sheared blob, each with
    // its own tree and transform, against one tree over the same triangles transformed to world space.
    let room = scenes::shoebox(Vec3::ZERO, ROOM);
    let body = scenes::cube_sphere(6);
    let blob = scenes::bumpy_torus(600);
    let placed = [
        (&room, Affine3A::IDENTITY, 0u32),
        (
            &body,
            Affine3A::from_scale_rotation_translation(
                Vec3::new(0.3, 0.2, 0.8),
                Quat::from_rotation_z(0.7),
                Vec3::new(2.2, 1.4, 0.9),
            ),
            1,
        ),
        (
            &body,
            Affine3A::from_scale_rotation_translation(
                Vec3::new(-0.25, 0.3, 0.6),
                Quat::from_rotation_y(0.3),
                Vec3::new(1.2, 2.6, 1.5),
            ),
            2,
        ),
        (
            &blob,
            Affine3A::from_cols(
                Vec3::new(0.5, 0.1, 0.0).into(),
                Vec3::new(0.0, 0.4, 0.2).into(),
                Vec3::new(0.1, 0.0, 0.5).into(),
                Vec3::new(3.6, 2.3, 1.6).into(),
            ),
            1,
        ),
    ];
    let palette: Vec<_> = (0..3).map(wall_material).collect();
    let trees: Vec<MeshBvh> = placed
        .iter()
        .map(|(m, _, _)| MeshBvh::build(m, &BuildOptions::default()).unwrap())
        .collect();
    let boxes: Vec<Aabb> = placed
        .iter()
        .map(|(m, t, _)| {
            moved(m, *t).iter().fold(Aabb::EMPTY, |mut b, p| {
                b.grow(*p);
                b
            })
        })
        .collect();
    let top = Bvh::build(&boxes, &BuildOptions::default()).unwrap();
    let instances: Vec<_> = placed
        .iter()
        .zip(&trees)
        .map(|((_, t, m), bvh)| {
            Some(SoundInstance {
                bvh,
                transform: *t,
                material: *m,
            })
        })
        .collect();
    let two_level = SoundScene::instanced(&top, &instances, palette.clone()).unwrap();

    let world: Vec<Mesh> = placed
        .iter()
        .map(|(m, t, _)| m.with_positions(moved(m, *t)).unwrap())
        .collect();
    let mesh = concat(&world);
    let mats: Vec<u32> = placed
        .iter()
        .flat_map(|(m, _, k)| std::iter::repeat_n(*k, m.triangle_count()))
        .collect();
    let bvh = MeshBvh::build(&mesh, &BuildOptions::default()).unwrap();
    let copied = SoundScene::new(&bvh, &mats, palette).unwrap();
    assert_eq!(two_level.triangle_count(), mesh.triangle_count());
    assert_eq!(two_level.surface_count(), copied.surface_count());

    let cfg = config(true);
    for (s, l) in [
        (Vec3::new(0.6, 0.7, 1.6), Vec3::new(4.3, 3.0, 1.1)),
        (Vec3::new(4.1, 0.5, 0.4), Vec3::new(0.4, 3.1, 2.3)),
    ] {
        let a = propagate(&two_level, s, l, &cfg).unwrap();
        let b = propagate(&copied, s, l, &cfg).unwrap();
        assert!(
            b.paths
                .iter()
                .any(|p| p.order == 3 && !p.surfaces.is_empty())
        );
        assert_eq!(a.frusta, b.frusta, "{s} → {l}");
        assert_same_paths(&a.paths, &b.paths, &format!("{s} → {l}"));
    }
    // One instance left out: it neither reflects nor occludes, as if it were not there.
    let mut without = instances.clone();
    without[1] = None;
    let partial =
        SoundScene::instanced(&top, &without, (0..3).map(wall_material).collect()).unwrap();
    assert_eq!(
        partial.triangle_count(),
        mesh.triangle_count() - body.triangle_count()
    );
    // A material that does not exist, a transform that cannot be inverted.
    let first = instances[0].unwrap();
    for wrong in [
        SoundInstance {
            material: 3,
            ..first
        },
        SoundInstance {
            transform: Affine3A::from_scale(Vec3::new(1.0, 0.0, 1.0)),
            ..first
        },
    ] {
        let listed = [Some(wrong), None, None, None];
        assert!(SoundScene::instanced(&top, &listed, vec![wall_material(0); 3]).is_err());
    }
    assert!(SoundScene::instanced(&top, &instances[1..], vec![wall_material(0); 3]).is_err());
}

#[test]
fn ecs_character_stepping_between_removes_the_direct_path() {
    let cfg = SoundConfig {
        max_order: 1,
        ..config(true)
    };
    let (mut world, mut schedule) = sound_app(SoundSettings {
        config: cfg,
        ..Default::default()
    });
    // The character is a unit-centred box its transform walks (its size is the walk's box).
    world.spawn(TraceMesh(scenes::shoebox(Vec3::ZERO, ROOM)));
    let (source, listener) = (world.spawn_empty().id(), world.spawn_empty().id());
    let mut character = None;
    walk_across_the_line_of_sight(|s, l, lo, hi| {
        let half = (hi - lo) / 2.0;
        let e = *character.get_or_insert_with(|| {
            world.entity_mut(source).insert(SoundSource(s));
            world.entity_mut(listener).insert(Listener(l));
            world.spawn(TraceMesh(scenes::shoebox(-half, half))).id()
        });
        world.get_mut::<TraceTransform>(e).unwrap().0 = Affine3A::from_translation(lo + half);
        run_frame(&mut world, &mut schedule);
        let paths = world
            .resource::<SoundPaths>()
            .between(source, listener)
            .unwrap();
        paths.iter().filter(|p| p.order == 0).count()
    });
}

#[test]
fn ecs_updates_every_n_frames() {
    let cfg = SoundConfig {
        max_order: 1,
        ..config(true)
    };
    let (mut world, mut schedule) = sound_app(SoundSettings {
        config: cfg,
        every: 3,
        ..Default::default()
    });
    world.spawn(TraceMesh(scenes::shoebox(Vec3::ZERO, ROOM)));
    let at = |frame: u64| Vec3::new(0.5 + 0.3 * frame as f32, 1.2, 1.4);
    let l = Vec3::new(4.4, 2.9, 1.0);
    let source = world.spawn(SoundSource(at(1))).id();
    let listener = world.spawn(Listener(l)).id();
    for frame in 1..=10u64 {
        world.get_mut::<SoundSource>(source).unwrap().0 = at(frame);
        run_frame(&mut world, &mut schedule);
        assert_eq!(world.resource::<TraceStats>().frame, frame);
        // Updates on frames 1, 4, 7, 10; in between, the last update's paths stay.
        let updated = 1 + 3 * ((frame - 1) / 3);
        let sound = world.resource::<SoundPaths>();
        assert_eq!(sound.frame, updated);
        assert_eq!(sound.updates, 1 + (frame - 1) / 3);
        let paths = sound.between(source, listener).unwrap();
        let direct = paths.iter().find(|p| p.order == 0).expect("line of sight");
        assert_eq!(direct.length, at(updated).distance(l), "frame {frame}");
    }
}
