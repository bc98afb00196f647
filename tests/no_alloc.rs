//! Refit and queries allocate nothing: counted with a global allocator in this test binary, per thread, so
//! that rayon's pool threads (still settling after a parallel build) do not count.

mod common;
use common::*;
use glam::Vec3;
use kinetrace::bvh::{BuildOptions, Builder, TraversalStats};
use kinetrace::{MeshBvh, Ray};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;

thread_local! {
    // const-initialised: touching it never allocates.
    static ALLOCS: Cell<usize> = const { Cell::new(0) };
}

fn allocations() -> usize {
    ALLOCS.with(Cell::get)
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
}

#[global_allocator]
static A: Counting = Counting;

/// Held by every test for its whole run: the tests of this file run one at a time. Work a thread hands to
/// rayon's global pool goes through a shared queue whose blocks are allocated by whichever thread's push
/// crosses a block boundary; with another test pushing at the same time, that thread can be a test's frame
/// thread at any frame (an allocation by the test harness, not by the code under test).
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Takes [`ONE_AT_A_TIME`] (a test that failed while holding it does not poison the others).
fn alone() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

#[test]
fn refit_and_single_ray_queries_do_not_allocate() {
    let _alone = alone();
    // The counter sees this thread's allocations.
    let before = allocations();
    std::hint::black_box(vec![1u8; 64]);
    assert_eq!(allocations() - before, 1);

    let m = icosphere(3);
    let moved: Vec<Vec3> = m.positions().iter().map(|p| *p * 1.5 + Vec3::X).collect();
    let rays: Vec<Ray> = (0..64)
        .map(|i| Ray::new(Vec3::new(i as f32 * 0.01, 0.0, -5.0), Vec3::Z))
        .collect();
    for b in Builder::ALL {
        let mut bvh = MeshBvh::build(&m, &BuildOptions::new(b)).unwrap();
        let mut stats = TraversalStats::default();
        let before = allocations();
        let d = bvh.refit(&moved).unwrap();
        let mut hits = 0;
        for r in &rays {
            hits += bvh.closest_hit(r).is_some() as usize;
            hits += bvh.any_hit(r) as usize;
            hits += bvh.closest_hit_counted(r, &mut stats).is_some() as usize;
        }
        let after = allocations();
        assert_eq!(
            after - before,
            0,
            "{b:?} allocated {} times",
            after - before
        );
        assert_eq!(hits, 3 * rays.len());
        assert!(d.abs() < 1e-4);
    }
}

/// A plugin world run on the calling thread under `policy`, every mesh kept as `structure`, with a sphere
/// whose `VertexPositions` the test rewrites: the world, its schedule, the sphere's rest mesh and its entity.
fn deforming_sphere_app(
    policy: kinetrace::ecs::RebuildPolicy,
    structure: kinetrace::ecs::Structure,
) -> (
    bevy_ecs::world::World,
    bevy_ecs::schedule::Schedule,
    kinetrace::Mesh,
    bevy_ecs::entity::Entity,
) {
    use bevy_ecs::prelude::*;
    use kinetrace::ecs::*;
    let mut world = World::new();
    let mut schedule = Schedule::default();
    schedule.set_executor(bevy_ecs::schedule::SingleThreadedExecutor::new());
    KinetracePlugin {
        config: TraceConfig {
            policy,
            structure,
            ..Default::default()
        },
        ..Default::default()
    }
    .build(&mut world, &mut schedule);
    let rest = icosphere(3);
    let e = world
        .spawn((
            TraceMesh(rest.clone()),
            VertexPositions(rest.positions().to_vec()),
        ))
        .id();
    (world, schedule, rest, e)
}

/// A frame whose meshes only refit and whose rigid entities only move allocates nothing on the frame's
/// thread once warm, under a fixed policy and under the adaptive one (its SAH cost, decision and query
/// attribution included, for the meshes and for the top level), and with every mesh kept as a grid (the
/// deforming one's grid rebuilt in place every frame, closest and any hits through it).
#[test]
fn refit_only_ecs_frames_do_not_allocate() {
    let _alone = alone();
    use bevy_ecs::prelude::*;
    use kinetrace::ecs::*;
    let never = RebuildPolicy::Lauterbach {
        threshold: f32::INFINITY,
    };
    let adaptive = RebuildPolicy::Adaptive {
        builders: &[Builder::LBVH],
    };
    for (policy, structure) in [
        (never, Structure::Bvh),
        (adaptive, Structure::Bvh),
        (never, Structure::Grid),
    ] {
        let (mut world, mut schedule, rest, e) = deforming_sphere_app(policy, structure);
        // Rigid entities above the sphere, out of the rays' way, moving together: the top level refits.
        let walkers: Vec<Entity> = (0..8)
            .map(|i| {
                let at = Vec3::new(3.0 * i as f32, 10.0, 0.0);
                let place = TraceTransform(glam::Affine3A::from_translation(at));
                world
                    .spawn((TraceMesh(icosphere(1)), MotionHint::Rigid, place))
                    .id()
            })
            .collect();
        for f in 0..20 {
            for &w in &walkers {
                let mut t = world.get_mut::<TraceTransform>(w).unwrap();
                t.0.translation.z = 0.1 * f as f32;
            }
            // Uniform growth: the tree's shape and relative cost stay, so no policy rebuilds.
            let s = 1.0 + 0.01 * f as f32;
            {
                let mut vp = world.get_mut::<VertexPositions>(e).unwrap();
                for (p, q) in vp.0.iter_mut().zip(rest.positions()) {
                    *p = *q * s;
                }
                let mut queue = world.resource_mut::<RayQueue>();
                for i in 0..8 {
                    let from = Vec3::new(0.01 * i as f32, 0.0, -5.0);
                    queue.cast(i, Ray::new(from, Vec3::Z), QueryFilter::default());
                    queue.shadow(i, from, Vec3::ZERO, QueryFilter::default());
                }
            }
            let before = allocations();
            schedule.run(&mut world);
            world.clear_trackers();
            let allocated = allocations() - before;
            let stats = world.resource::<TraceStats>();
            let structure_of = |e| world.resource::<TraceWorld>().structure(e).unwrap().0;
            assert_eq!(
                structure_of(e) == StructureKind::Grid,
                structure == Structure::Grid
            );
            if f >= 2 {
                assert_eq!(allocated, 0, "{policy:?} {structure:?} frame {f}");
                assert_eq!(stats.meshes[0].action, MeshAction::Refit, "{policy:?}");
                assert_eq!(stats.moved, walkers.len(), "{policy:?}");
                assert_eq!(stats.top_level.action, TopLevelAction::Refit, "{policy:?}");
            }
            // The sphere of radius s (faceted: within 1.5% inside) is hit near z = -s, and blocks the
            // segments to its centre.
            let results = world.resource::<RayResults>();
            for (_, hit) in &results.hits {
                let depth = 5.0 - hit.as_ref().expect("aimed at the sphere").distance;
                assert!(depth <= 1.0001 * s && depth >= 0.985 * s, "{depth} vs {s}");
            }
            assert!(results.shadows.iter().all(|(_, blocked)| *blocked));
        }
    }
}

#[test]
fn warm_collision_queries_do_not_allocate() {
    let _alone = alone();
    use glam::Affine3A;
    use kinetrace::collide::{PairFront, PairQuery, Placed};
    let a = MeshBvh::build(&icosphere(3), &BuildOptions::default()).unwrap();
    let b = MeshBvh::build(
        &map_mesh(&icosphere(3), |p| p * 0.8 + Vec3::X),
        &BuildOptions::default(),
    )
    .unwrap();
    let (pa, pb) = (
        Placed::new(&a, Affine3A::IDENTITY),
        Placed::new(&b, Affine3A::from_rotation_y(0.3)),
    );
    // One thread: rayon's own bookkeeping is not ours to count.
    let mut q = PairQuery::new().parallel(false);
    let (mut front, mut self_front) = (PairFront::new(), PairFront::new());
    let mut out = Vec::new();
    let mut run = |q: &mut PairQuery| {
        q.meshes(pa, pb, &mut out).unwrap();
        let n = out.len();
        q.meshes_with_front(pa, pb, &mut front, &mut out).unwrap();
        q.itself_with_front(pa, &mut self_front, &mut out).unwrap();
        n
    };
    // Warm: the scratch grows to the scene, the fronts are recorded and restarted from.
    for _ in 0..3 {
        run(&mut q);
    }
    let before = allocations();
    let contacts = run(&mut q);
    assert_eq!(allocations() - before, 0);
    assert!(
        contacts > 0,
        "the spheres must touch for the test to mean anything"
    );
}

/// Warm batches of shape casts, closest points, overlaps and containment allocate nothing: on the frame's
/// thread through the schedule, and on every thread of a rayon pool when answered there (each pool thread's
/// count read with `broadcast`), for entities in their mesh's frame and in the world (a sheared one).
#[cfg(feature = "parallel")]
#[test]
fn warm_shape_query_batches_do_not_allocate() {
    let _alone = alone();
    use glam::{Affine3A, Mat3, Quat};
    use kinetrace::ecs::*;
    use kinetrace::queries::Shape;
    let never = RebuildPolicy::Lauterbach {
        threshold: f32::INFINITY,
    };
    let (mut world, mut schedule, rest, e) = deforming_sphere_app(never, Structure::Bvh);
    let sheared = Mat3::from_cols(Vec3::X, Vec3::new(0.5, 2.0, 0.0), Vec3::Z * 0.5);
    for (i, m) in [Mat3::from_rotation_y(0.5) * 1.5, sheared]
        .into_iter()
        .enumerate()
    {
        let at = Vec3::new(3.0 * (i as f32 * 2.0 - 1.0), 0.0, 0.0);
        world.spawn((
            TraceMesh(icosphere(2)),
            MotionHint::Rigid,
            TraceTransform(Affine3A::from_mat3_translation(m, at)),
        ));
    }
    let push = |q: &mut ShapeQueue| {
        for i in 0..16 {
            let c = Vec3::new(i as f32 * 0.5 - 4.0, 0.3, -3.0);
            let f = QueryFilter::default;
            q.cast(i, Shape::sphere(c, 0.3), Vec3::Z, 10.0, f());
            q.cast(i, Shape::capsule(c, c + Vec3::Y, 0.2), Vec3::Z, 10.0, f());
            q.cast(
                i,
                Shape::cuboid(c, Vec3::splat(0.3), Quat::IDENTITY),
                Vec3::Z,
                10.0,
                f(),
            );
            q.closest_point(i, c, f32::INFINITY, f());
            q.overlap(i, Shape::sphere(c + Vec3::Z * 3.0, 0.8), f());
            q.contains(i, c + Vec3::Z * 3.0, f());
        }
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    let pool_allocations = || pool.broadcast(|_| allocations()).iter().sum::<usize>();
    for f in 0..12 {
        let s = 1.0 + 0.01 * f as f32;
        {
            let mut vp = world.get_mut::<VertexPositions>(e).unwrap();
            for (p, q) in vp.0.iter_mut().zip(rest.positions()) {
                *p = *q * s;
            }
        }
        push(&mut world.resource_mut::<ShapeQueue>());
        let before = allocations();
        schedule.run(&mut world);
        world.clear_trackers();
        let on_frame_thread = allocations() - before;
        // The same batch again, answered on the pool.
        let mut queue = ShapeQueue::default();
        push(&mut queue);
        let mut results = std::mem::take(&mut *world.resource_mut::<ShapeResults>());
        let tw = world.resource::<TraceWorld>();
        let before = pool_allocations();
        pool.install(|| tw.answer_shapes(&queue, &mut results));
        let on_pool = pool_allocations() - before;
        if f >= 3 {
            assert_eq!(on_frame_thread, 0, "frame {f}");
            assert_eq!(on_pool, 0, "frame {f}, pool");
        }
        let hits = results.casts.iter().filter(|c| c.1.is_some()).count();
        let overlapping = results.overlaps.iter().filter(|o| !o.1.is_empty()).count();
        let inside = results.contains.iter().filter(|o| !o.1.is_empty()).count();
        assert!(
            hits > 10 && overlapping > 3 && inside > 2,
            "{hits} {overlapping} {inside}"
        );
        *world.resource_mut::<ShapeResults>() = results;
    }
}

/// A warm ray sort (its [`SortedRays`](kinetrace::raysort::SortedRays) and scratch kept from a batch as
/// large) allocates nothing on one thread, and gives the order a fresh sort gives.
#[test]
fn warm_ray_sort_does_not_allocate() {
    use kinetrace::raysort::{
        KeyLayout, RayKind, SecondaryRay, SortScratch, SortedRays, sort_rays,
    };
    let _alone = alone();
    let mut r = rng(3);
    let rays: Vec<SecondaryRay> = (0..5000u32)
        .map(|i| SecondaryRay {
            ray: if i % 101 == 0 {
                Ray::new(Vec3::ZERO, Vec3::ZERO) // trimmed
            } else {
                Ray::new(rand_vec(&mut r, -1.0, 1.0), rand_dir(&mut r))
            },
            kind: if i % 3 == 0 {
                RayKind::Reflection
            } else {
                RayKind::Shadow { light: i % 4 }
            },
            tag: i,
        })
        .collect();
    let layout = KeyLayout::default();
    let (mut sorted, mut scratch) = (SortedRays::default(), SortScratch::default());
    sorted.sort(&rays, &layout, false, &mut scratch).unwrap();
    for half in [&rays[..2500], &rays[..]] {
        let before = allocations();
        sorted.sort(half, &layout, false, &mut scratch).unwrap();
        assert_eq!(allocations() - before, 0);
        assert_eq!(sorted, sort_rays(half, &layout, false).unwrap());
    }
}

/// Warm secondary batches (reflection rays and shadow rays toward two lights, an invalid ray among them)
/// allocate nothing on the frame's thread, planned and with each fixed strategy but CRSH (which builds its
/// hierarchy per batch): the path keeps its sort and answer buffers in [`SecondaryRays`]. Answers are
/// checked against the sphere's analytic distance.
#[test]
fn warm_secondary_ray_batches_do_not_allocate() {
    let _alone = alone();
    use kinetrace::ecs::*;
    let never = RebuildPolicy::Lauterbach {
        threshold: f32::INFINITY,
    };
    for fixed in [
        None,
        Some(SecondaryStrategy::Bvh),
        Some(SecondaryStrategy::SortedBvh),
        Some(SecondaryStrategy::SortedPackets),
        Some(SecondaryStrategy::SortedRuns),
    ] {
        let (mut world, mut schedule, rest, e) = deforming_sphere_app(never, Structure::Bvh);
        let secondary = SecondaryRays::new(fixed, Default::default(), 8, 2).unwrap();
        world.insert_resource(secondary);
        for f in 0..8 {
            let s = 1.0 + 0.01 * f as f32;
            {
                let mut vp = world.get_mut::<VertexPositions>(e).unwrap();
                for (p, q) in vp.0.iter_mut().zip(rest.positions()) {
                    *p = *q * s;
                }
                let mut queue = world.resource_mut::<RayQueue>();
                let f = QueryFilter::default;
                for i in 0..150u64 {
                    // Rays from a 15 × 10 grid in the plane z = -5 toward the sphere's centre, a
                    // reflection ray each (the last one of zero direction: invalid, a miss), and a
                    // shadow segment from each start to the centre toward light 0 or 1.
                    let from =
                        Vec3::new((i % 15) as f32 * 0.05 - 0.35, (i / 15) as f32 * 0.05, -5.0);
                    let dir = if i == 149 { Vec3::ZERO } else { -from };
                    let kind = RequestKind::Reflection;
                    queue.cast_kind(i, Ray::new(from, dir), kind, f());
                    let light = RequestKind::Shadow {
                        light: i as u32 % 2,
                    };
                    queue.shadow_kind(i, from, Vec3::ZERO, light, f());
                }
            }
            let before = allocations();
            schedule.run(&mut world);
            world.clear_trackers();
            let allocated = allocations() - before;
            if f >= 3 {
                assert_eq!(allocated, 0, "{fixed:?} frame {f}");
            }
            // Aimed at the centre of the sphere of radius s (faceted: within 1.5% inside).
            let results = world.resource::<RayResults>();
            assert_eq!(results.hits.len(), 150);
            for (tag, hit) in &results.hits {
                if *tag == 149 {
                    assert!(hit.is_none(), "an invalid ray misses");
                    continue;
                }
                let from = Vec3::new(
                    (tag % 15) as f32 * 0.05 - 0.35,
                    (tag / 15) as f32 * 0.05,
                    -5.0,
                );
                let depth = from.length()
                    - hit.as_ref().expect("aimed at the sphere").distance * from.length();
                assert!(
                    depth <= 1.0001 * s && depth >= 0.985 * s,
                    "{fixed:?} {tag}: {depth} vs {s}"
                );
            }
            assert!(results.shadows.iter().all(|(_, blocked)| *blocked));
        }
    }
}
