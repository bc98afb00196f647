//! Refit and queries allocate nothing: counted with a global allocator in this test binary, per thread —
//! direct calls on the test's thread, plugin frames on the thread of a one-thread pool they run in
//! ([`frame_allocations`]), so that their parallel work is counted too.

mod common;
use common::*;
use glam::Vec3;
use kinetrace::bvh::{BuildOptions, Builder, TraversalStats};
use kinetrace::{MeshBvh, Ray};

mod alloc_counter;
use alloc_counter::*;

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

/// A frame whose meshes only refit and whose rigid entities only move allocates nothing on the threads of
/// the pool it runs in once warm (its queued rays and shadow rays single and as packets, and a packet asked of the
/// world directly), under a fixed policy and under the adaptive one (its SAH cost, decision and query
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
        // Two more deforming spheres, out of the rays' way: three meshes refit ahead, in parallel.
        let others: Vec<Entity> = (0..2)
            .map(|i| {
                let at = Vec3::new(-4.0 - 3.0 * i as f32, 10.0, 0.0);
                world
                    .spawn((
                        TraceMesh(rest.clone()),
                        VertexPositions(rest.positions().to_vec()),
                        TraceTransform(glam::Affine3A::from_translation(at)),
                    ))
                    .id()
            })
            .collect();
        // Under the adaptive policy the option planners learn scripted costs (measured ones made this
        // test flaky: which options a sphere tried depended on the machine's noise): the wide tree, packets
        // and the BVH are the cheap options, so each sphere tries the binary tree and comes back to the
        // wide one — without a collapse, which would allocate.
        let adaptive = matches!(policy, RebuildPolicy::Adaptive { .. });
        if adaptive {
            let cheap = [
                PlannedOption::Wide(true),
                PlannedOption::Packets(true),
                PlannedOption::Structure(StructureKind::Bvh),
            ];
            world
                .resource_mut::<TraceWorld>()
                .script_costs(Some(std::sync::Arc::new(move |_, option| {
                    Some(common::ecs::scripted_cost(option, cheap.contains(&option)))
                })));
        }
        let mut binary_tried = false;
        let from = |i: u64| Vec3::new(0.01 * i as f32, 0.0, -5.0);
        let pool = frame_pool();
        for f in 0..20 {
            for &w in &walkers {
                let mut t = world.get_mut::<TraceTransform>(w).unwrap();
                t.0.translation.z = 0.1 * f as f32;
            }
            // Uniform growth: the tree's shape and relative cost stay, so no policy rebuilds.
            let s = 1.0 + 0.01 * f as f32;
            for &d in others.iter().chain([&e]) {
                let mut vp = world.get_mut::<VertexPositions>(d).unwrap();
                for (p, q) in vp.0.iter_mut().zip(rest.positions()) {
                    *p = *q * s;
                }
            }
            {
                let mut queue = world.resource_mut::<RayQueue>();
                for i in 0..8 {
                    queue.cast(i, Ray::new(from(i), Vec3::Z), QueryFilter::default());
                    queue.shadow(i, from(i), Vec3::ZERO, QueryFilter::default());
                }
                // The same rays again as packets, between single requests.
                let tile: Vec<Ray> = (0..8).map(|i| Ray::new(from(i), Vec3::Z)).collect();
                let points: Vec<Vec3> = (0..8).map(from).collect();
                queue.cast_packet(100, &tile, QueryFilter::default());
                queue.shadow_packet(100, &points, Vec3::ZERO, QueryFilter::default());
                queue.cast(200, tile[0], QueryFilter::default());
                queue.shadow(200, points[0], Vec3::ZERO, QueryFilter::default());
            }
            let mut allocated = frame_allocations(&pool, &mut world, &mut schedule);
            // A packet asked of the world directly, on this thread.
            let before = allocations();
            let tile: [Ray; 8] = std::array::from_fn(|i| Ray::new(from(i as u64), Vec3::Z));
            let segments: [(Vec3, Vec3); 8] = std::array::from_fn(|i| (from(i as u64), Vec3::ZERO));
            let (mut hits, mut blocked) = ([None; 8], [false; 8]);
            let trace_world = world.resource::<TraceWorld>();
            trace_world.cast_packet(&tile, f32::INFINITY, &QueryFilter::default(), &mut hits);
            trace_world.occluded_packet(&segments, &QueryFilter::default(), &mut blocked);
            let mut interleaved = [false; 8];
            trace_world.occluded_interleaved(&segments, &QueryFilter::default(), &mut interleaved);
            allocated += allocations() - before;
            assert!(hits.iter().all(Option::is_some) && blocked.iter().all(|b| *b));
            assert_eq!(interleaved, blocked);
            let stats = world.resource::<TraceStats>();
            binary_tried |= (stats.options.iter())
                .any(|o| o.entity == e && o.option == PlannedOption::Wide(false) && o.tried);
            let structure_of = |e| world.resource::<TraceWorld>().structure(e).unwrap().0;
            assert_eq!(
                structure_of(e) == StructureKind::Grid,
                structure == Structure::Grid
            );
            if f >= 2 {
                assert_eq!(allocated, 0, "{policy:?} {structure:?} frame {f}");
                let deformed = (stats.meshes.iter()).filter(|m| m.action != MeshAction::Moved);
                assert_eq!(deformed.clone().count(), 1 + others.len());
                for m in deformed {
                    assert_eq!(m.action, MeshAction::Refit, "{policy:?}");
                }
                assert_eq!(stats.refits_ahead, 1 + others.len(), "{policy:?}");
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
        assert_eq!(binary_tried, adaptive, "{policy:?} {structure:?}");
        if adaptive {
            let stats = world.resource::<TraceStats>();
            let wide = (stats.options.iter())
                .find(|o| o.entity == e && matches!(o.option, PlannedOption::Wide(_)));
            assert_eq!(
                wide.map(|o| (o.option, o.tried)),
                Some((PlannedOption::Wide(true), false))
            );
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
/// allocate nothing on the frame's pool threads, planned and with each fixed strategy but CRSH (which builds its
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
        let pool = frame_pool();
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
            let allocated = frame_allocations(&pool, &mut world, &mut schedule);
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
