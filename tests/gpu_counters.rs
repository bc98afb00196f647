//! GPU traffic in `TraceStats::gpu`: one submission per frame of batched queries, at most one blocking wait
//! per frame (none in the first frame under `Latency::NextFrame`: nothing to collect yet), and after the
//! first frame uploads that do not grow with the scene's triangles when only rays change. Runs on lavapipe
//! in CI.
//!
//! This is the plain GPU query path (`TraceMode::GpuRequired` without `TraceConfig::resident`): it collects
//! frame N's answers in frame N+1 with a blocking wait when the GPU has not finished them (the counters show
//! one on lavapipe). The GPU-resident frame, which never waits under `Latency::NextFrame`, is checked in
//! `tests/gpu_frame.rs`.
#![cfg(feature = "gpu")]

mod common;
use common::ecs::app_with;
use common::*;
use glam::{Affine3A, Vec3};
use kinetrace::Ray;
use kinetrace::ecs::*;
use kinetrace::gpu::GpuCounters;

const RAYS: usize = 200;

/// Per-frame counters of 6 frames of a static scene of `subdivisions`-icospheres queried with the same
/// number of fresh rays each frame.
fn run(latency: Latency, subdivisions: u32) -> Vec<GpuCounters> {
    let (mut world, mut schedule) = app_with(TraceConfig {
        mode: TraceMode::GpuRequired,
        latency,
        ..Default::default()
    });
    let mesh = icosphere(subdivisions);
    for k in 0..4 {
        let at = Vec3::new(k as f32 * 2.5, 0.0, 0.0);
        world.spawn((
            TraceMesh(mesh.clone()),
            TraceTransform(Affine3A::from_translation(at)),
        ));
    }
    let mut r = rng(21);
    (0..6)
        .map(|_| {
            let rays: Vec<Ray> = (0..RAYS)
                .map(|_| Ray::new(rand_vec(&mut r, -2.0, 9.0) + Vec3::Z * -6.0, Vec3::Z))
                .collect();
            let mut queue = world.resource_mut::<RayQueue>();
            for (i, ray) in rays.into_iter().enumerate() {
                queue.cast(i as u64, ray, QueryFilter::default());
            }
            schedule.run(&mut world);
            world.clear_trackers();
            world.resource::<TraceStats>().gpu
        })
        .collect()
}

#[test]
fn one_submission_and_at_most_one_wait_per_frame() {
    if gpu_or_skip().is_none() {
        return;
    }
    let next = run(Latency::NextFrame, 2);
    assert_eq!(next[0].blocking_waits, 0, "{:?}", next[0]);
    for (f, c) in next.iter().enumerate() {
        assert_eq!(c.submissions, 1, "frame {f}: {c:?}");
        assert!(c.blocking_waits <= 1, "frame {f}: {c:?}");
        assert!(c.read_back_bytes > 0, "frame {f}: {c:?}");
    }
    for (f, c) in run(Latency::SameFrame, 2).iter().enumerate() {
        assert_eq!(c.submissions, 1, "frame {f}: {c:?}");
        assert!(c.blocking_waits <= 1, "frame {f}: {c:?}");
    }
}

#[test]
fn uploads_after_the_first_frame_do_not_grow_with_triangles() {
    if gpu_or_skip().is_none() {
        return;
    }
    let small = run(Latency::NextFrame, 1);
    let big = run(Latency::NextFrame, 3);
    // The first frame uploads the trees: 16 times the triangles, more bytes.
    assert!(
        big[0].uploaded_bytes > small[0].uploaded_bytes,
        "{:?} vs {:?}",
        big[0],
        small[0]
    );
    // Later frames upload only the rays (and their parameters): the same for both scenes.
    for f in 1..small.len() {
        assert!(small[f].uploaded_bytes > 0, "frame {f}: rays were uploaded");
        assert_eq!(
            small[f].uploaded_bytes, big[f].uploaded_bytes,
            "frame {f}: {:?} vs {:?}",
            small[f], big[f]
        );
    }
}
