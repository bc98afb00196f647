//! Animated skinned characters: the trees bound the skinned triangles every frame, queries equal brute force
//! on them, and CPU and GPU skinning agree.

mod common;
use bevy_ecs::prelude::*;
use common::*;
use glam::{Mat4, Vec3};
use kinetrace::Ray;
use kinetrace::anim::{humanoid, skin_positions};
use kinetrace::ecs::*;
use rand::Rng;
use std::sync::Arc;

#[test]
fn animated_characters_stay_bounded_and_queryable() {
    let asset = Arc::new(humanoid(3_000));
    let mut world = World::new();
    let mut schedule = Schedule::default();
    KinetracePlugin::default().build(&mut world, &mut schedule);
    let ents: Vec<Entity> = (0..asset.clips.len())
        .map(|c| {
            world
                .spawn(AnimationPlayer::bundle(&asset, c, 0.1 * c as f32))
                .id()
        })
        .collect();
    let mut r = rng(4);
    for f in 0..90 {
        schedule.run(&mut world);
        world.clear_trackers();
        for (c, &e) in ents.iter().enumerate() {
            let vp = world.get::<VertexPositions>(e).unwrap().0.clone();
            let skinned = asset.mesh.with_positions(vp).unwrap();
            let tw = world.resource::<TraceWorld>();
            let blas = tw.blas(e).unwrap();
            // Every skinned vertex inside the tree's boxes.
            blas.bvh()
                .validate(Some(&skinned.triangle_bounds()))
                .unwrap_or_else(|err| panic!("frame {f} clip {c}: {err}"));
            // Queries equal brute force on the skinned triangles.
            for i in 0..10 {
                let ray = Ray::new(
                    rand_vec(&mut r, -1.0, 1.0) + Vec3::new(0.0, 1.0, -2.0),
                    Vec3::new(r.random_range(-0.3..0.3), r.random_range(-0.3..0.3), 1.0),
                );
                let got = blas.closest_hit(&ray).map(|h| (h.primitive, h.t));
                assert_brute_hit(&skinned, &ray, got, &format!("frame {f} clip {c} ray {i}"));
            }
        }
    }
    // The clips really moved the characters.
    let moved = world
        .get::<VertexPositions>(ents[0])
        .unwrap()
        .0
        .iter()
        .zip(asset.mesh.positions())
        .map(|(a, b)| (*a - *b).length())
        .fold(0.0, f32::max);
    assert!(moved > 0.1, "moved {moved}");
}

#[test]
fn rest_pose_skinning_reproduces_the_mesh() {
    let asset = humanoid(5_000);
    let mut m = vec![Mat4::IDENTITY; asset.skeleton.joints.len()];
    asset
        .skeleton
        .skin_matrices(&asset.skeleton.rest_pose(), &mut m);
    let mut out = vec![Vec3::ZERO; asset.mesh.positions().len()];
    skin_positions(asset.mesh.positions(), &asset.weights, &m, &mut out).unwrap();
    for (a, b) in out.iter().zip(asset.mesh.positions()) {
        assert!((*a - *b).length() <= 1e-4, "{a} vs {b}");
    }
}

#[cfg(feature = "gpu")]
#[test]
fn gpu_skinning_of_an_animated_character_equals_cpu_skinning() {
    use kinetrace::gpu::{GpuMeshBvh, GpuSkin};
    let Some(g) = gpu_or_skip() else { return };
    let asset = humanoid(20_000);
    let bvh = GpuMeshBvh::new(&g, &asset.mesh).unwrap();
    let skin = GpuSkin::new(
        &g,
        asset.mesh.positions(),
        &asset.weights,
        asset.skeleton.joints.len(),
        &bvh,
    )
    .unwrap();
    let mut pose = asset.skeleton.rest_pose();
    let mut m = vec![Mat4::IDENTITY; pose.len()];
    for (clip, t) in [(0usize, 0.3f32), (1, 0.1), (2, 0.55)] {
        asset.clips[clip].sample(t, &mut pose);
        asset.skeleton.skin_matrices(&pose, &mut m);
        let mut cpu = vec![Vec3::ZERO; asset.mesh.positions().len()];
        skin_positions(asset.mesh.positions(), &asset.weights, &m, &mut cpu).unwrap();
        let mut enc = g.encoder();
        skin.record(&g, &mut enc, &m).unwrap();
        g.submit(enc);
        let gpu = bvh.read_positions(&g).unwrap();
        let worst = gpu
            .iter()
            .zip(&cpu)
            .map(|(a, b)| (*a - *b).abs().max_element())
            .fold(0.0, f32::max);
        assert!(worst <= 1e-5, "clip {clip}: {worst}");
    }
}
