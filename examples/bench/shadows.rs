//! Suite `shadows`: selective ray-traced hard shadows (thesis §6.3) on the crowd demo's scene — time per
//! image and the fraction of pixels ray traced for the shadow map alone, the selective pipeline and a
//! shadow ray per pixel, at 1024×1024 (a smaller crowd with `--quick`) with a shadow map of the image's
//! resolution (as in the thesis), on all threads, warm buffers; and selective against a ray per pixel
//! alternated pass by pass, in wall-clock and in CPU time (all threads), which a loaded machine disturbs
//! less; the selective pass with its marked pixels' rays as single rays (four walked at once,
//! interleaved) and as packets, and a ray per pixel both ways (the crowd's planner picks between them),
//! the four alternated pass by pass, and the speed-up of each mode's cheaper way over the other's, which
//! no pick of the planner's sways; the planner's picks after all the passes, hard and soft; the images'
//! times (taken after those passes, so the planners have tried both ways); and the selective pass with
//! every face of the closed characters in its map against the default (their faces away from the light
//! left out, `ShadowSettings::closed_culling`), alternated: CPU and map time, and the texels and pixels
//! that changes.
//! With a GPU, the selective pass again with its map rendered there (`GpuShadowMap`), classified on the
//! CPU and on the GPU: time, CPU time, map and classification phases, the pixels unlike the CPU-map
//! image (none), and per pass the bytes uploaded per triangle (per pixel for the classification) and
//! read back per texel (per pixel), the submissions and the blocking waits.
//!
//! For profiling, `KINETRACE_SHADOW_PROFILE=selective` (or `traced`, `map`, `gpu`: selective with the
//! map and the classification on the GPU, or `gpu-map`: the map alone there) runs only that mode's hard
//! shadows, `KINETRACE_SHADOW_REPS` times (default 60) after one warm pass, prints the median phase times
//! of those passes and nothing else: what `perf record` should see.

use crate::crowd;
use crate::record::{CpuClock, Records, best_of, cpu_seconds};
use kinetrace::gpu::GpuShadowMap;
use kinetrace::shadows::{CpuMap, GBuffer, HardShadows, Occluders, ShadowMode, ShadowSettings};
use std::time::Instant;

const SUITE: &str = "shadows";

/// The soft rows' light: a disc of 0.02 rad angular radius (about four times the sun's), 16 rays per
/// penumbra pixel.
const SOFT_ANGLE: f32 = 0.02;

/// Passes of each of selective and ray-traced hard shadows in the alternated comparison.
const ALTERNATIONS: usize = 10;

/// Consecutive frames of the moving crowd over which the selective pass's second map fits are counted.
const MOVING_FRAMES: usize = 10;

pub fn run(rec: &mut Records) {
    println!("suite shadows on {}", crate::record::machine());
    let (characters, triangles, frames, side) = if rec.quick {
        (16, 3_000, 30, 1024)
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
    let mut pass = HardShadows::new();
    if let Ok(mode) = std::env::var("KINETRACE_SHADOW_PROFILE") {
        let mut on_gpu = mode.starts_with("gpu").then(|| match rec.gpu() {
            Ok(ctx) => {
                let mut m = GpuShadowMap::new(&ctx);
                m.set_classify(mode == "gpu");
                m
            }
            Err(e) => panic!("KINETRACE_SHADOW_PROFILE={mode} needs a GPU: {e}"),
        });
        let mode = match mode.as_str() {
            "traced" => ShadowMode::RayTraced,
            "map" => ShadowMode::ShadowMap,
            _ => ShadowMode::Selective,
        };
        let reps = std::env::var("KINETRACE_SHADOW_REPS").map_or(60, |r| r.parse().unwrap_or(60));
        let settings = ShadowSettings {
            mode,
            towards_light: crowd::sun(),
            map_resolution: side as usize,
            ..Default::default()
        };
        let cpu = cpu_seconds(CpuClock::Process);
        let mut phases = Vec::with_capacity(reps + 1);
        for _ in 0..=reps {
            let vis = match &mut on_gpu {
                Some(m) => crowd::sun_visibility_with(&world, &g, &settings, &mut pass, m),
                None => crowd::sun_visibility_with(&world, &g, &settings, &mut pass, &mut CpuMap),
            };
            std::hint::black_box(vis.expect("valid settings"));
            let s = pass.stats();
            phases.push([s.map_time, s.classify_time, s.trace_time]);
        }
        let median = |k: usize| {
            let mut t: Vec<_> = phases[reps.min(1)..].iter().map(|p| p[k]).collect();
            t.sort();
            t[t.len() / 2]
        };
        let s = pass.stats();
        println!(
            "  {mode:?} x{reps}: {:.3} ms CPU a pass; median of the passes after the first: map {:?} (on the GPU: {}), classify {:?} (on the GPU: {}), rays {:?}; {} rays, refitted {}",
            (cpu_seconds(CpuClock::Process) - cpu) * 1e3 / (reps + 1) as f64,
            median(0),
            s.map_on_gpu,
            median(1),
            s.classified_on_gpu,
            median(2),
            s.rays,
            s.refitted
        );
        return;
    }
    let side_map = side as usize;
    // Selective hard shadows and a ray per pixel, alternated: each one's fastest wall-clock pass and its
    // least CPU time.
    let mut best = [[f64::INFINITY; 2]; 2];
    for _ in 0..ALTERNATIONS {
        for (b, mode) in best
            .iter_mut()
            .zip([ShadowMode::Selective, ShadowMode::RayTraced])
        {
            let settings = ShadowSettings {
                mode,
                towards_light: crowd::sun(),
                map_resolution: side_map,
                ..Default::default()
            };
            let (t, cpu) = (Instant::now(), cpu_seconds(CpuClock::Process));
            std::hint::black_box(
                crowd::sun_visibility(&world, &g, &settings, &mut pass).expect("valid settings"),
            );
            let (cpu, t) = (
                cpu_seconds(CpuClock::Process) - cpu,
                t.elapsed().as_secs_f64(),
            );
            *b = [b[0].min(t), b[1].min(cpu)];
        }
    }
    let [[sel_wall, sel_cpu], [traced_wall, traced_cpu]] = best;
    // The selective pass's and the ray-traced one's rays as single rays and as packets (the crowd's
    // planner picks between them), the four alternated pass by pass: each one's least CPU time.
    let mut ways = [[f64::INFINITY; 2]; 2];
    for _ in 0..ALTERNATIONS {
        for (mode, way) in [ShadowMode::Selective, ShadowMode::RayTraced]
            .into_iter()
            .zip(&mut ways)
        {
            let settings = ShadowSettings {
                mode,
                towards_light: crowd::sun(),
                map_resolution: side_map,
                ..Default::default()
            };
            for (as_packets, m) in [false, true].into_iter().zip(way.iter_mut()) {
                let cpu = cpu_seconds(CpuClock::Process);
                let vis = crowd::sun_visibility_rays(
                    &world,
                    &g,
                    &settings,
                    &mut pass,
                    &mut CpuMap,
                    as_packets,
                );
                std::hint::black_box(vis.expect("valid settings"));
                *m = m.min(cpu_seconds(CpuClock::Process) - cpu);
            }
        }
    }
    let [marked, every] = ways;
    // The selective pass with every face of the closed characters in its map, alternated with the
    // default (their faces away from the light left out): each one's least CPU time and map time, and
    // what changes in its map and image.
    let mut faces = [[f64::INFINITY; 2]; 2];
    let mut kept = Vec::new();
    for round in 0..ALTERNATIONS {
        for (closed_culling, f) in [true, false].into_iter().zip(&mut faces) {
            let settings = ShadowSettings {
                towards_light: crowd::sun(),
                map_resolution: side_map,
                closed_culling,
                ..Default::default()
            };
            let cpu = cpu_seconds(CpuClock::Process);
            let vis = crowd::sun_visibility(&world, &g, &settings, &mut pass);
            std::hint::black_box(vis.expect("valid settings"));
            let cpu = cpu_seconds(CpuClock::Process) - cpu;
            *f = [f[0].min(cpu), f[1].min(pass.stats().map_time.as_secs_f64())];
            if round == 0 {
                let vis = pass.visibility().to_vec();
                kept.push((vis, pass.shadow_map().clone(), pass.stats()));
            }
        }
    }
    // Each mode's image, timed now that the crowd's planners have seen the passes above (timed first,
    // the selective pass's could catch its planner trying packets, a quarter slower here).
    let mut image = |mode, map_resolution, light_angle| {
        let settings = ShadowSettings {
            mode,
            towards_light: crowd::sun(),
            map_resolution,
            light_angle,
            ..Default::default()
        };
        let (t, vis) = best_of(rec.reps(), || {
            crowd::sun_visibility(&world, &g, &settings, &mut pass)
                .expect("valid settings")
                .to_vec()
        });
        (t, vis, pass.stats())
    };
    let (t_traced, traced, _) = image(ShadowMode::RayTraced, side_map, 0.0);
    let (t_map, map, _) = image(ShadowMode::ShadowMap, side_map, 0.0);
    // A map of half the image's side: a quarter of the texels, more pixels marked.
    let (t_half, half, half_stats) = image(ShadowMode::Selective, side_map / 2, 0.0);
    let (t_sel, sel, stats) = image(ShadowMode::Selective, side_map, 0.0);
    let (t_soft_traced, soft_traced, _) = image(ShadowMode::RayTraced, side_map, SOFT_ANGLE);
    let (t_soft, soft, soft_stats) = image(ShadowMode::Selective, side_map, SOFT_ANGLE);
    let packets_now = |mode, soft| crowd::rays_as_packets(&world, mode, soft) as u8 as f64;
    for (subject, metric, value, unit) in [
        ("selective", "CPU per image", sel_cpu * 1e3, "ms"),
        ("ray traced", "CPU per image", traced_cpu * 1e3, "ms"),
        (
            "traced/selective",
            "CPU speed-up",
            traced_cpu / sel_cpu,
            "x",
        ),
        (
            "traced/selective",
            "alternated speed-up",
            traced_wall / sel_wall,
            "x",
        ),
        (
            "selective, single rays",
            "CPU per image",
            marked[0] * 1e3,
            "ms",
        ),
        (
            "selective, rays as packets",
            "CPU per image",
            marked[1] * 1e3,
            "ms",
        ),
        (
            "ray traced, single rays",
            "CPU per image",
            every[0] * 1e3,
            "ms",
        ),
        (
            "ray traced, rays as packets",
            "CPU per image",
            every[1] * 1e3,
            "ms",
        ),
        (
            "traced/selective, cheaper ways",
            "CPU speed-up",
            every[0].min(every[1]) / marked[0].min(marked[1]),
            "x",
        ),
        (
            "selective",
            "planner's rays as packets",
            packets_now(ShadowMode::Selective, false),
            "bool",
        ),
        (
            "soft selective",
            "planner's rays as packets",
            packets_now(ShadowMode::Selective, true),
            "bool",
        ),
        (
            "ray traced",
            "planner's rays as packets",
            packets_now(ShadowMode::RayTraced, false),
            "bool",
        ),
    ] {
        rec.add(SUITE, &scene, subject, metric, value, unit);
    }
    let wrong = |v: &[f32]| v.iter().zip(&traced).filter(|(a, b)| a != b).count() as f64;
    let pixels = (side * side) as f64;
    let [(culled, culled_map, culled_stats), (all, all_map, _)] =
        <[_; 2]>::try_from(kept).unwrap_or_else(|_| unreachable!("one pass each way"));
    let res = culled_map.resolution();
    let (mut unlike, mut deeper, mut most) = (0, 0, 0.0f32);
    for j in 0..res {
        for i in 0..res {
            let (c, a) = (culled_map.depth(i, j), all_map.depth(i, j));
            unlike += (c != a) as usize;
            deeper += (c > a) as usize;
            if c != a {
                most = most.max((c - a).abs());
            }
        }
    }
    let [[culled_cpu, culled_map_s], [all_cpu, all_map_s]] = faces;
    for (subject, metric, value, unit) in [
        (
            "selective",
            "closed triangles, back faces culled",
            culled_stats.closed_triangles as f64,
            "",
        ),
        ("selective, all faces", "CPU per image", all_cpu * 1e3, "ms"),
        (
            "selective, culled (alternated)",
            "CPU per image",
            culled_cpu * 1e3,
            "ms",
        ),
        ("selective, all faces", "map", all_map_s * 1e3, "ms"),
        (
            "selective, culled (alternated)",
            "map",
            culled_map_s * 1e3,
            "ms",
        ),
        (
            "all faces/culled",
            "CPU speed-up",
            all_cpu / culled_cpu,
            "x",
        ),
        (
            "culled map",
            "texels unlike all faces'",
            unlike as f64,
            "texels",
        ),
        (
            "culled map",
            "texels deeper than all faces'",
            deeper as f64,
            "texels",
        ),
        (
            "culled map",
            "largest depth difference",
            (most / culled_map.texel_size()) as f64,
            "texel sides",
        ),
        (
            "selective, culled",
            "pixels unlike all faces'",
            all.iter().zip(&culled).filter(|(a, b)| a != b).count() as f64,
            "pixels",
        ),
        (
            "selective, all faces",
            "pixels unlike traced",
            100.0 * wrong(&all) / pixels,
            "%",
        ),
    ] {
        rec.add(SUITE, &scene, subject, metric, value, unit);
    }
    for (who, t, v) in [
        ("shadow map", t_map, &map),
        ("selective", t_sel, &sel),
        ("selective, half-side map", t_half, &half),
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
        "selective, half-side map",
        "pixels ray traced",
        100.0 * half_stats.ray_fraction(),
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
        "traced/selective, half-side map",
        "speed-up",
        t_traced / t_half,
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
    let soft_wrong = soft.iter().zip(&soft_traced).filter(|(a, b)| a != b);
    for (subject, metric, value, unit) in [
        ("soft selective", "time per image", t_soft * 1e3, "ms"),
        (
            "soft ray traced",
            "time per image",
            t_soft_traced * 1e3,
            "ms",
        ),
        (
            "soft selective",
            "pixels ray traced",
            100.0 * soft_stats.ray_fraction(),
            "%",
        ),
        (
            "soft selective",
            "pixels unlike traced",
            100.0 * soft_wrong.count() as f64 / pixels,
            "%",
        ),
        (
            "soft traced/selective",
            "speed-up",
            t_soft_traced / t_soft,
            "x",
        ),
    ] {
        rec.add(SUITE, &scene, subject, metric, value, unit);
    }
    gpu_map_rows(rec, &world, &g, &scene, &sel, traced_cpu);
    // Consecutive frames of the moving crowd through one warm pass: how often the receivers' bounds
    // sampled where the last frame's extremes were missed one, so the map was fitted twice.
    let settings = ShadowSettings {
        towards_light: crowd::sun(),
        map_resolution: side_map,
        ..Default::default()
    };
    let mut refits = 0;
    for _ in 0..MOVING_FRAMES {
        crowd::step(&mut world, &mut schedule);
        let (_, g) = crowd::primary_hits(&world, side, side, &crowd::Camera::default());
        crowd::sun_visibility(&world, &g, &settings, &mut pass).expect("valid settings");
        refits += pass.stats().refitted as usize;
    }
    let moving = format!("selective, {MOVING_FRAMES} moving frames");
    rec.add(
        SUITE,
        &scene,
        &moving,
        "maps fitted twice",
        refits as f64,
        "frames",
    );
}

/// Selective hard shadows with the map rendered on the GPU (`GpuShadowMap`), classified on the CPU and
/// on the GPU: time and CPU time per image, the map's and the classification's phases, and the pixels
/// unlike the CPU-map image `cpu_image` (none: the maps and classes are the same); the bytes uploaded
/// per triangle (the map) and per pixel (the classification), read back per texel and per pixel, the
/// submissions and blocking waits; the CPU speed-up against a ray per pixel's `traced_cpu` seconds.
/// Skipped, saying so, without a GPU.
fn gpu_map_rows(
    rec: &mut Records,
    world: &bevy_ecs::world::World,
    g: &GBuffer,
    scene: &str,
    cpu_image: &[f32],
    traced_cpu: f64,
) {
    let ctx = match rec.gpu() {
        Ok(c) => c,
        Err(e) => {
            println!("  shadow map on the GPU skipped: {e}");
            return;
        }
    };
    let settings = ShadowSettings {
        towards_light: crowd::sun(),
        map_resolution: g.width,
        ..Default::default()
    };
    let triangles = (world.resource::<kinetrace::ecs::TraceWorld>())
        .occluders(&kinetrace::ecs::QueryFilter::default())
        .triangle_count() as f64;
    let (pixels, texels) = ((g.width * g.height) as f64, (g.width * g.width) as f64);
    // The map-only pass's transfers, which the classifying one's exceed by the classification's.
    let mut map_only = (0.0, 0.0);
    for classify in [false, true] {
        let mut on_gpu = GpuShadowMap::new(&ctx);
        on_gpu.set_classify(classify);
        let mut pass = HardShadows::new();
        let mut run = |pass: &mut HardShadows| {
            crowd::sun_visibility_with(world, g, &settings, pass, &mut on_gpu)
                .expect("the GPU pass")
                .to_vec()
        };
        let (t, image) = best_of(rec.reps(), || run(&mut pass));
        let stats = pass.stats();
        assert_eq!(stats.classified_on_gpu, classify);
        let mut cpu = f64::INFINITY;
        for _ in 0..rec.reps() {
            let before = cpu_seconds(CpuClock::Process);
            std::hint::black_box(run(&mut pass));
            cpu = cpu.min(cpu_seconds(CpuClock::Process) - before);
        }
        let before = ctx.counters();
        run(&mut pass);
        let d = ctx.counters().since(&before);
        let (up, back) = (d.uploaded_bytes as f64, d.read_back_bytes as f64);
        let unlike = image.iter().zip(cpu_image).filter(|(a, b)| a != b).count();
        let (subject, versus) = if classify {
            (
                "selective, map and classes on the GPU",
                "traced/selective, map and classes on the GPU",
            )
        } else {
            map_only = (up, back);
            (
                "selective, map on the GPU",
                "traced/selective, map on the GPU",
            )
        };
        let mut rows = vec![
            (subject, "time per image", t * 1e3, "ms"),
            (subject, "CPU per image", cpu * 1e3, "ms"),
            (subject, "map", stats.map_time.as_secs_f64() * 1e3, "ms"),
            (
                subject,
                "classify+compact",
                stats.classify_time.as_secs_f64() * 1e3,
                "ms",
            ),
            (subject, "pixels unlike CPU map", unlike as f64, "pixels"),
            (subject, "submissions a pass", d.submissions as f64, ""),
            (
                subject,
                "blocking waits a pass",
                d.blocking_waits as f64,
                "",
            ),
            (versus, "CPU speed-up", traced_cpu / cpu, "x"),
        ];
        if classify {
            rows.extend([
                (
                    subject,
                    "uploaded for classes",
                    (up - map_only.0) / pixels,
                    "B/pixel",
                ),
                (
                    subject,
                    "read back for classes",
                    (back - map_only.1) / pixels,
                    "B/pixel",
                ),
            ]);
        } else {
            rows.extend([
                (subject, "uploaded a pass", up / triangles, "B/triangle"),
                (subject, "read back a pass", back / texels, "B/texel"),
            ]);
        }
        for (subject, metric, value, unit) in rows {
            rec.add(SUITE, scene, subject, metric, value, unit);
        }
    }
}
