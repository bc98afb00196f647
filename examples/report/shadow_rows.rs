//! The report's shadow-map section (issue 16): per scene, its middle frame seen by the secondary section's
//! camera (`side`² pixels: 128², 32² in `--quick`), selective hard shadows of a directional light along
//! the frame's light direction, with the shadow map rendered on the CPU, on the GPU (`GpuShadowMap`,
//! where there is one: the pixels classified on the CPU, "map only", and on the GPU) and as the
//! planner's [`Choice::map_on_gpu`] picks over [`ROUNDS`] passes, each pass's map and classification
//! seconds per triangle taught as the crowd demo does; and with the map on the CPU, the
//! marked pixels' shadow rays as packets (each batch the pass gives, up to 64 rays of one 8×8 block,
//! traced together), as single rays walked four at a time interleaved (`MeshBvh::any_hits_interleaved`,
//! as the crowd demo's single rays) and as the planner's [`Choice::sparse_packets`] picks between
//! packets and interleaved single rays over [`ROUNDS`] passes, each pass's seconds per marked pixel taught as the crowd demo does;
//! and where the scene is closed ([`Mesh::is_closed`](kinetrace::Mesh::is_closed): the crowd), the
//! CPU map without the faces away from the light ([`Occluders::closed`]), the texels and pixels that
//! changes against every face's in its name (pinholes and skinning folds), its mismatches the texels
//! nearer the light than every face's map (a subset of the triangles can only leave texels deeper). All
//! on one CPU thread.
//!
//! Per row: milliseconds per pass and of its map (the GPU's with its upload and read-back), the pixels
//! marked for rays, the map's texels covered, and mismatches: texels of the map and pixels of the image unlike the CPU-map pass's
//! (the renderers give the same map, and packets the same answers as single rays, so none).

use super::camera::Orbit;
use super::harness::{Gpu, frame_light};
use super::harness::{median, planned_label};
use super::scenes::Scene;
use super::secondary_rows::ROUNDS;
use glam::Vec3;
use kinetrace::adaptive::Choice;
use kinetrace::bvh::{BuildOptions, Builder, TraversalStats};
use kinetrace::raysort::RayScene;
use kinetrace::shadows::{
    CpuMap, GBuffer, HardShadows, Interleaved, MapRenderer, Occluders, PACKET, Packets, ShadowRays,
    ShadowSettings,
};
use kinetrace::{MeshBvh, Ray};
use std::fmt::Write as _;
use std::time::Instant;

/// One renderer on one scene.
pub struct ShadowRow {
    pub scene: &'static str,
    pub renderer: String,
    pub pass_ms: f64,
    pub map_ms: f64,
    pub marked: f64,
    /// Percent of the map's texels some triangle covers.
    pub covered: f64,
    pub mismatches: u32,
}

/// The scene's rows: the CPU map (its marked pixels' rays one by one, as packets, interleaved, then as
/// the planner picks), the GPU map (with `gpu`), then the planner's map, its picks in the name.
pub fn run(
    scene: &Scene,
    settings: &super::harness::Settings,
    gpu: Option<&Gpu>,
) -> Vec<ShadowRow> {
    let mut pos = Vec::new();
    scene.positions(settings.frames / 2, &mut pos);
    let mesh = scene.mesh(&pos);
    let rs =
        RayScene::build(&mesh, &BuildOptions::new(Builder::SAH)).expect("scene meshes are valid");
    let side = if settings.frames <= super::harness::Settings::QUICK.frames {
        32
    } else {
        128
    };
    let orbit = Orbit::around(rs.bvh().bvh().bounds(), Vec3::new(0.3, 0.5, 0.8), 0.9);
    let mut g = GBuffer::new(side, side);
    orbit.hits(&rs, side, |pixel, primary, h| {
        let n = if h.normal.dot(primary.dir()) > 0.0 {
            -h.normal
        } else {
            h.normal
        };
        g.set(pixel as usize, primary.at(h.t), n);
    });
    let tris: Vec<[Vec3; 3]> = (0..mesh.triangle_count())
        .map(|i| mesh.triangle(i))
        .collect();
    let s = ShadowSettings {
        towards_light: (frame_light(&orbit.bounds) - orbit.bounds.center()).normalize(),
        map_resolution: side,
        normal_offset: 1e-4 * orbit.size,
        ray_length: 2.0 * orbit.size,
        parallel: false,
        ..Default::default()
    };
    let bvh: &MeshBvh = rs.bvh();
    let rays = |from: Vec3, to: Vec3| bvh.any_hit(&Ray::segment(from, to));
    // A batch's segments (at most `PACKET`) as rays.
    let as_rays = |segments: &[(Vec3, Vec3)]| {
        let mut r = [Ray::segment(Vec3::ZERO, Vec3::X); PACKET];
        for (r, &(from, to)) in r.iter_mut().zip(segments) {
            *r = Ray::segment(from, to);
        }
        r
    };
    // As the crowd demo's: a batch's rays together, a lone ray alone.
    let packets = |segments: &[(Vec3, Vec3)], out: &mut [bool]| {
        if let &[(from, to)] = segments {
            out[0] = rays(from, to);
            return;
        }
        let r = as_rays(segments);
        bvh.any_hits_packet(&r[..segments.len()], out, &mut TraversalStats::default());
    };
    // As the crowd demo's single rays: a batch's rays walked four at a time, interleaved.
    let interleaved = |segments: &[(Vec3, Vec3)], out: &mut [bool]| {
        bvh.any_hits_interleaved(&as_rays(segments)[..segments.len()], out);
    };
    let inputs: Inputs = (&s, &tris, &g);
    // A warm pass (its buffers grown), then the timed one.
    let pass = |renderer: &mut dyn FnMut(&mut HardShadows)| {
        let mut p = HardShadows::new();
        renderer(&mut p);
        let start = Instant::now();
        renderer(&mut p);
        (start.elapsed().as_secs_f64(), p)
    };
    let (cpu_s, cpu) = pass(&mut |p| render(p, inputs, rays, &mut CpuMap));
    let row = |renderer: String, seconds: f64, p: &HardShadows| ShadowRow {
        scene: scene.name,
        renderer,
        pass_ms: seconds * 1e3,
        map_ms: p.stats().map_time.as_secs_f64() * 1e3,
        marked: 100.0 * p.stats().ray_fraction(),
        covered: covered(p),
        mismatches: unlike(&cpu, p),
    };
    let (packets_s, p) = pass(&mut |p| render(p, inputs, Packets(&packets), &mut CpuMap));
    let (interleaved_s, i) =
        pass(&mut |p| render(p, inputs, Interleaved(&interleaved), &mut CpuMap));
    let mut rows = vec![
        row("cpu".into(), cpu_s, &cpu),
        row("cpu, rays as packets".into(), packets_s, &p),
        row("cpu, rays interleaved".into(), interleaved_s, &i),
    ];
    // A closed scene (the crowd's closed characters): its faces away from the light left out of the map
    // (`Occluders::closed`); the texels and pixels that changes against every face's map (pinholes,
    // skinning folds) in the name, its mismatches the texels nearer than every face's map.
    if mesh.is_closed() {
        let (closed_s, c) = pass(&mut |p| {
            p.run_with(&s, &Closed(&tris), &g, rays, &mut CpuMap)
                .expect("valid settings");
        });
        let [texels, pixels] = unlike_parts(&cpu, &c);
        let name = format!("cpu, faces away left out ({texels} texels, {pixels} pixels unlike)");
        rows.push(ShadowRow {
            mismatches: nearer(&cpu, &c),
            ..row(name, closed_s, &c)
        });
    }
    rows.push(planned_row(
        Choice::sparse_packets(),
        ["single rays interleaved", "packets"],
        "cpu, rays ",
        &row,
        &cpu,
        // The last pass's marked pixels: what this one likely marks.
        |p| p.stats().rays as f64,
        |p, as_packets| {
            if as_packets {
                render(p, inputs, Packets(&packets), &mut CpuMap);
            } else {
                render(p, inputs, Interleaved(&interleaved), &mut CpuMap);
            }
            let stats = p.stats();
            (stats.rays as f64, stats.trace_time.as_secs_f64())
        },
    ));
    // The GPU rows follow where the feature is on.
    #[cfg(feature = "gpu")]
    if let Some(ctx) = gpu {
        let mut on_gpu = kinetrace::gpu::GpuShadowMap::new(ctx);
        on_gpu.set_classify(false);
        let (gpu_s, p) = pass(&mut |p| render(p, inputs, rays, &mut on_gpu));
        rows.push(row("gpu, map only".into(), gpu_s, &p));
        on_gpu.set_classify(true);
        let (gpu_s, p) = pass(&mut |p| render(p, inputs, rays, &mut on_gpu));
        rows.push(row("gpu".into(), gpu_s, &p));
        let triangles = tris.len() as f64;
        rows.push(planned_row(
            Choice::map_on_gpu(),
            ["cpu", "gpu"],
            "",
            &row,
            &cpu,
            |_| triangles,
            |p, on| {
                if on {
                    render(p, inputs, rays, &mut on_gpu);
                } else {
                    render(p, inputs, rays, &mut CpuMap);
                }
                let s = p.stats();
                (triangles, (s.map_time + s.classify_time).as_secs_f64())
            },
        ));
    }
    #[cfg(not(feature = "gpu"))]
    let _ = gpu; // of an uninhabited type without the feature
    rows
}

/// The planner's row: [`ROUNDS`] passes into one pass's buffers, each run by `run(pass, option)` with
/// the option `planner` decides for `units(pass)` (the work expected, read before the pass), which
/// returns the units the pass served and their seconds, taught back. Named `prefix` and the planner's
/// label (`names[option]`) by `row`; its milliseconds a pass and of its map the passes' medians, its
/// mismatches against `cpu`'s summed over them.
fn planned_row(
    mut planner: Choice<bool>,
    names: [&str; 2],
    prefix: &str,
    row: &dyn Fn(String, f64, &HardShadows) -> ShadowRow,
    cpu: &HardShadows,
    units: impl Fn(&HardShadows) -> f64,
    mut run: impl FnMut(&mut HardShadows, bool) -> (f64, f64),
) -> ShadowRow {
    let (mut times, mut maps, mut bad, mut picks) = (Vec::new(), Vec::new(), 0, [0usize; 2]);
    let mut p = HardShadows::new();
    for _ in 0..ROUNDS {
        let option = planner.decide(units(&p));
        let start = Instant::now();
        let (served, seconds) = run(&mut p, option);
        times.push(start.elapsed().as_secs_f64());
        maps.push(p.stats().map_time.as_secs_f64());
        planner.served(option, served, seconds);
        picks[option as usize] += 1;
        bad += unlike(cpu, &p);
    }
    let label = planned_label(
        names[planner.current() as usize],
        names.into_iter().zip(picks),
    );
    let mut r = row(format!("{prefix}{label}"), median(&mut times), &p);
    r.map_ms = median(&mut maps) * 1e3;
    r.mismatches = bad;
    r
}

/// What a pass reads besides its shadow-ray query: its settings, the occluders and the G-buffer.
type Inputs<'a> = (&'a ShadowSettings, &'a [[Vec3; 3]], &'a GBuffer);

/// A selective pass over `inputs` into `pass`, its rays traced by `rays`, its map rendered by
/// `renderer`.
fn render(
    pass: &mut HardShadows,
    (s, tris, g): Inputs,
    rays: impl ShadowRays,
    renderer: &mut impl MapRenderer,
) {
    pass.run_with(s, tris, g, rays, renderer)
        .expect("valid settings");
}

/// Percent of the pass's map texels that hold a depth.
fn covered(p: &HardShadows) -> f64 {
    let map = p.shadow_map();
    let res = map.resolution();
    let held = (0..res * res)
        .filter(|&k| map.depth(k % res, k / res).is_finite())
        .count();
    100.0 * held as f64 / (res * res).max(1) as f64
}

/// Texels of `got`'s map and pixels of its image unlike `want`'s (floats compared as floats).
fn unlike(want: &HardShadows, got: &HardShadows) -> u32 {
    unlike_parts(want, got).iter().sum()
}

/// [`unlike`]'s texels and pixels.
fn unlike_parts(want: &HardShadows, got: &HardShadows) -> [u32; 2] {
    let (a, b) = (want.shadow_map(), got.shadow_map());
    let res = a.resolution();
    let texels = (0..res * res)
        .filter(|&k| a.depth(k % res, k / res) != b.depth(k % res, k / res))
        .count();
    let pixels = (want.visibility().iter().zip(got.visibility()))
        .filter(|(x, y)| x != y)
        .count();
    [texels as u32, pixels as u32]
}

/// Texels of `subset`'s map nearer the light than `all`'s: none where `subset` rendered some of `all`'s
/// triangles (each texel the nearest of fewer depths).
fn nearer(all: &HardShadows, subset: &HardShadows) -> u32 {
    let (a, b) = (all.shadow_map(), subset.shadow_map());
    let res = a.resolution();
    (0..res * res)
        .filter(|&k| b.depth(k % res, k / res) < a.depth(k % res, k / res))
        .count() as u32
}

/// A closed scene's triangles in world space: one group, closed ([`Occluders::closed`]).
struct Closed<'a>(&'a [[Vec3; 3]]);

impl Occluders for Closed<'_> {
    fn groups(&self) -> usize {
        1
    }

    fn group(&self, _: usize) -> (&[[Vec3; 3]], Option<glam::Affine3A>) {
        (self.0, None)
    }

    fn closed(&self, _: usize) -> bool {
        true
    }
}

/// The summary's section: per scene, a row per renderer.
pub fn table(rows: &[ShadowRow]) -> String {
    if rows.is_empty() {
        return String::new();
    }
    let mut s = format!(
        "\n## Shadow maps (issue 16)\n\nPer scene, its middle frame through the secondary section's camera; \
         selective hard shadows of a directional light along the frame's light, the map (as many texels a \
         side as the image) rendered on the CPU, on the GPU (the pixels classified on the CPU, \
         \"map only\", or on the GPU too), or as the planner picks over {ROUNDS} \
         passes (its milliseconds the passes' median; its picks, passes per renderer, in brackets); with \
         the CPU's map, the marked pixels' shadow rays one by one, as packets of a block's rays, as \
         single rays walked four at a time interleaved, or as the planner picks over {ROUNDS} passes; on a \
         closed scene, the CPU's map without the faces away from the light (the texels and pixels that \
         changes in pinholes and skinning folds, in brackets; its mismatches: texels nearer the light \
         than every face's map). One CPU thread; the GPU's map time includes its upload \
         and read-back (where the GPU classifies too, \"gpu\", its upload only: the map's rendering and \
         read-back share the classification's submission and wait). Mismatches: map texels and image pixels unlike the CPU-map pass's (rays one by \
         one).\n\n\
         | scene | map, rays | ms/pass | map ms | marked % | texels covered % | mismatches |\n\
         |---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {} | {:.3} | {:.3} | {:.2} | {:.1} | {} |",
            r.scene, r.renderer, r.pass_ms, r.map_ms, r.marked, r.covered, r.mismatches
        );
    }
    s
}
