//! Suite `skinning`: linear-blend skinning throughput (CPU one thread, all threads, GPU), and the crowd's
//! frame time for 16, 64 and 256 characters of 10k triangles, split by phase.

use crate::record::{Records, best_of};
use bevy_ecs::prelude::*;
use glam::{Affine3A, Mat4, Vec3};
use kinetrace::anim::{humanoid, skin_positions};
use kinetrace::ecs::*;
use kinetrace::gpu::{GpuMeshBvh, GpuSkin};
use kinetrace::{Ray, scenes::SceneRng};
use std::sync::Arc;
use std::time::Duration;

const SUITE: &str = "skinning";

pub fn run(rec: &mut Records) {
    println!("suite skinning on {}", crate::record::machine());
    let reps = rec.reps();
    let asset = humanoid(if rec.quick { 50_000 } else { 200_000 });
    let verts = asset.mesh.positions().len();
    let scene = format!("humanoid, {verts} vertices");
    let mut pose = asset.skeleton.rest_pose();
    asset.clips[0].sample(0.3, &mut pose);
    let mut mats = vec![Mat4::IDENTITY; pose.len()];
    asset.skeleton.skin_matrices(&pose, &mut mats);
    let mut out = vec![Vec3::ZERO; verts];
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("a pool");
    let (t1, _) = one.install(|| {
        best_of(reps, || {
            skin_positions(asset.mesh.positions(), &asset.weights, &mats, &mut out).expect("valid")
        })
    });
    let (tn, _) = best_of(reps, || {
        skin_positions(asset.mesh.positions(), &asset.weights, &mats, &mut out).expect("valid")
    });
    rec.add(
        SUITE,
        &scene,
        "cpu skinning",
        "1 thread",
        verts as f64 / t1 / 1e6,
        "Mverts/s",
    );
    rec.add(
        SUITE,
        &scene,
        "cpu skinning",
        "all threads",
        verts as f64 / tn / 1e6,
        "Mverts/s",
    );
    if let Ok(ctx) = rec.gpu() {
        let bvh = GpuMeshBvh::new(&ctx, &asset.mesh).expect("upload");
        let skin = GpuSkin::new(
            &ctx,
            asset.mesh.positions(),
            &asset.weights,
            mats.len(),
            &bvh,
        )
        .expect("valid");
        let (tg, _) = best_of(reps, || {
            let mut enc = ctx.encoder();
            skin.record(&ctx, &mut enc, &mats).expect("palette");
            ctx.submit(enc);
            ctx.wait().expect("gpu")
        });
        rec.add(
            SUITE,
            &scene,
            &format!("gpu skinning ({})", ctx.adapter_name()),
            "submit+wait",
            verts as f64 / tg / 1e6,
            "Mverts/s",
        );
    }
    let counts: &[usize] = if rec.quick { &[16] } else { &[16, 64, 256] };
    for &n in counts {
        crowd(rec, n, if rec.quick { 20 } else { 60 });
    }
}

/// `n` walking 10k-triangle characters and 10k batched rays per frame, on the CPU.
fn crowd(rec: &mut Records, n: usize, frames: usize) {
    let scene = format!("crowd of {n} x 10k tris + 10k rays");
    let asset = Arc::new(humanoid(10_000));
    let mut world = World::new();
    let mut schedule = Schedule::default();
    schedule.set_executor(bevy_ecs::schedule::SingleThreadedExecutor::new());
    KinetracePlugin::default().build(&mut world, &mut schedule);
    let side = (n as f32).sqrt().ceil() as usize;
    for i in 0..n {
        let at = Vec3::new((i % side) as f32 * 1.5, 0.0, (i / side) as f32 * 1.5);
        world.spawn((
            AnimationPlayer::bundle(&asset, i % asset.clips.len(), i as f32 * 0.1),
            TraceTransform(Affine3A::from_translation(at)),
        ));
    }
    let mut r = SceneRng::new(3);
    let extent = side as f32 * 1.5;
    let rays: Vec<Ray> = (0..10_000)
        .map(|_| {
            Ray::new(
                Vec3::new(r.range(0.0, extent), 3.0, r.range(0.0, extent)),
                Vec3::new(r.range(-0.2, 0.2), -1.0, r.range(-0.2, 0.2)),
            )
        })
        .collect();
    let mut sums = [Duration::ZERO; 5];
    for f in 0..frames + 1 {
        {
            let mut q = world.resource_mut::<RayQueue>();
            for (i, ray) in rays.iter().enumerate() {
                q.cast(i as u64, *ray, QueryFilter::default());
            }
        }
        let t = std::time::Instant::now();
        schedule.run(&mut world);
        world.clear_trackers();
        let total = t.elapsed();
        if f == 0 {
            continue;
        }
        let s = world.resource::<TraceStats>();
        for (acc, d) in sums.iter_mut().zip([
            total,
            s.animate_time + s.skin_time,
            s.maintain_time,
            s.top_level_time,
            s.query_time,
        ]) {
            *acc += d;
        }
    }
    let ms = |d: Duration| d.as_secs_f64() * 1e3 / frames as f64;
    for (label, d) in [
        "frame",
        "animate + skin",
        "maintain",
        "top level",
        "queries",
    ]
    .iter()
    .zip(sums)
    {
        rec.add(SUITE, &scene, label, "time", ms(d), "ms");
    }
}
