//! Suite `shadows`: selective ray-traced hard shadows (thesis §6.3) on the crowd demo's scene — time per
//! image and the fraction of pixels ray traced for the shadow map alone, the selective pipeline and a
//! shadow ray per pixel, at 1024×1024 (512×512 with `--quick`) with a shadow map of the image's
//! resolution (as in the thesis), on all threads, warm buffers.

use crate::crowd;
use crate::record::{Records, best_of};
use kinetrace::shadows::{HardShadows, ShadowMode, ShadowSettings};

const SUITE: &str = "shadows";

pub fn run(rec: &mut Records) {
    println!("suite shadows on {}", crate::record::machine());
    let (characters, triangles, frames, side) = if rec.quick {
        (16, 3_000, 30, 512)
    } else {
        (64, 10_000, 60, 1024)
    };
    let opt = crowd::Options {
        characters,
        triangles,
        gpu: false,
        ..Default::default()
    };
    let (mut world, mut schedule) = crowd::setup(&opt).expect("the crowd sets up");
    for _ in 0..frames {
        crowd::step(&mut world, &mut schedule);
    }
    let scene = format!("crowd {characters}x{triangles}, {side}x{side}");
    println!("\n{scene}");
    let (_, g) = crowd::primary_hits(&world, side, side, &crowd::Camera::default());
    let (mut pass, mut tris) = (HardShadows::new(), Vec::new());
    let mut image = |mode| {
        let settings = ShadowSettings {
            mode,
            towards_light: crowd::sun(),
            map_resolution: side as usize,
            ..Default::default()
        };
        let (t, vis) = best_of(rec.reps(), || {
            crowd::sun_visibility(&world, &g, &settings, &mut pass, &mut tris)
                .expect("valid settings")
                .to_vec()
        });
        (t, vis, pass.stats())
    };
    let (t_traced, traced, _) = image(ShadowMode::RayTraced);
    let (t_map, map, _) = image(ShadowMode::ShadowMap);
    let (t_sel, sel, stats) = image(ShadowMode::Selective);
    let wrong = |v: &[f32]| v.iter().zip(&traced).filter(|(a, b)| a != b).count() as f64;
    let pixels = (side * side) as f64;
    for (who, t, v) in [
        ("shadow map", t_map, &map),
        ("selective", t_sel, &sel),
        ("ray traced", t_traced, &traced),
    ] {
        rec.add(SUITE, &scene, who, "time per image", t * 1e3, "ms");
        rec.add(
            SUITE,
            &scene,
            who,
            "pixels unlike traced",
            100.0 * wrong(v) / pixels,
            "%",
        );
    }
    rec.add(
        SUITE,
        &scene,
        "selective",
        "pixels ray traced",
        100.0 * stats.ray_fraction(),
        "%",
    );
    rec.add(
        SUITE,
        &scene,
        "selective",
        "map",
        stats.map_time.as_secs_f64() * 1e3,
        "ms",
    );
    let classify = stats.classify_time.as_secs_f64() * 1e3;
    rec.add(
        SUITE,
        &scene,
        "selective",
        "classify+compact",
        classify,
        "ms",
    );
    let trace = stats.trace_time.as_secs_f64() * 1e3;
    rec.add(SUITE, &scene, "selective", "rays+composite", trace, "ms");
    rec.add(
        SUITE,
        &scene,
        "traced/selective",
        "speed-up",
        t_traced / t_sel,
        "x",
    );
    rec.add(
        SUITE,
        &scene,
        "selective/map",
        "slow-down",
        t_sel / t_map,
        "x",
    );
}
