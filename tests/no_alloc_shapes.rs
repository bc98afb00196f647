//! Warm shape-query batches allocate nothing, counted on every thread that answers them: the plugin's
//! frame on the one thread of a pool it runs in ([`frame_allocations`]), and the same batch answered again
//! on a two-thread pool.

mod alloc_counter;
mod common;
use alloc_counter::*;
use common::*;
use glam::Vec3;

/// Warm batches of shape casts, closest points, overlaps and containment allocate nothing: on the frame's
/// pool thread through the schedule, and on every thread of a rayon pool when answered there (each pool thread's
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
            // Off the growing sphere's surface at every scale: the set of holders never changes.
            q.contains(i, c + Vec3::new(0.0, 0.2, 3.0), f());
        }
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    let pool_allocations = || pool.broadcast(|_| allocations()).iter().sum::<usize>();
    let frame = frame_pool();
    for f in 0..12 {
        let s = 1.0 + 0.01 * f as f32;
        {
            let mut vp = world.get_mut::<VertexPositions>(e).unwrap();
            for (p, q) in vp.0.iter_mut().zip(rest.positions()) {
                *p = *q * s;
            }
        }
        push(&mut world.resource_mut::<ShapeQueue>());
        let on_frame_thread = frame_allocations(&frame, &mut world, &mut schedule);
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
