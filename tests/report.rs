//! Smoke test of the evaluation harness (examples/report) in its `--quick` size: every file is written,
//! every scene and strategy is reported, no sampled ray differs from brute force, and every figure is a
//! PNG of its size with text, a legend entry per strategy and data drawn.

#[path = "../examples/report/camera.rs"]
mod camera;
mod common;
#[path = "../examples/report/grid_rows.rs"]
mod grid_rows;
#[path = "../examples/report/harness.rs"]
mod harness;
#[path = "../examples/report/option_rows.rs"]
mod option_rows;
#[path = "../examples/report/output.rs"]
mod output;
#[path = "../examples/report/planner.rs"]
mod planner;
#[path = "../examples/report/plots.rs"]
mod plots;
#[path = "../examples/report/point_rows.rs"]
mod point_rows;
#[path = "../examples/report/scale.rs"]
mod scale;
#[path = "../examples/report/scenes.rs"]
mod scenes;
#[path = "../examples/report/secondary_rows.rs"]
mod secondary_rows;
#[path = "../examples/report/shadow_rows.rs"]
mod shadow_rows;

use plotters::coord::ranged1d::Ranged;
use std::path::{Path, PathBuf};

#[test]
fn quick_report_writes_every_file_with_zero_mismatches() {
    let out = std::env::temp_dir().join(format!("kinetrace-report-{}", std::process::id()));
    // The GPU rows too where only lavapipe runs them (CI).
    let settings = harness::Settings {
        software_gpu: true,
        ..harness::Settings::QUICK
    };
    let report = output::write_report(
        &settings,
        &common::shared_assets_dir(),
        &out,
        &output::Only::default(),
    )
    .unwrap();
    for s in &report.skipped {
        common::skip(s);
    }
    let pngs: Vec<String> = report
        .files
        .iter()
        .filter(|f| f.extension().is_some_and(|e| e == "png"))
        .map(|f| f.file_stem().unwrap().to_string_lossy().into_owned())
        .collect();
    assert!(pngs.contains(&"overview".to_string()), "{pngs:?}");
    let scenes: Vec<&String> = pngs
        .iter()
        .filter(|s| !s.ends_with("-frames") && *s != "overview")
        .collect();
    assert!(scenes.len() >= 6, "a plot per scene: {pngs:?}");
    for s in &scenes {
        assert!(
            pngs.contains(&format!("{s}-frames")),
            "per-frame curves of {s}"
        );
    }
    assert_eq!(report.rows.len(), scenes.len() * report.strategies.len());
    let gpu_rows = report.rows.iter().filter(|r| r.strategy.contains("gpu"));
    if std::env::var("KINETRACE_REQUIRE_GPU").is_ok_and(|v| v == "1") && cfg!(feature = "gpu") {
        assert_eq!(
            gpu_rows.count(),
            scenes.len() * harness::Strategy::GPU.len(),
            "KINETRACE_REQUIRE_GPU=1: the GPU strategies must run ({:?})",
            report.skipped
        );
    }
    // The shadow-map section: per scene the CPU map's rows (its marked pixels' rays one by one, as
    // packets, interleaved and as the planner picks), and the GPU's (classified on the CPU and on the
    // GPU) and the planner's maps where a GPU runs; every renderer's map and image are the CPU map's
    // with rays one by one.
    let rows = |label: &str| {
        let n = |r: &&shadow_rows::ShadowRow| r.renderer.starts_with(label);
        report.shadows.iter().filter(n).count()
    };
    let cpu_maps = report
        .shadows
        .iter()
        .filter(|r| r.renderer == "cpu")
        .count();
    assert_eq!(cpu_maps, scenes.len(), "a CPU shadow-map row per scene");
    for label in [
        "cpu, rays as packets",
        "cpu, rays interleaved",
        "cpu, rays planned → ",
    ] {
        assert_eq!(rows(label), scenes.len(), "a {label} row per scene");
    }
    // A row of the CPU map without the faces away from the light per closed scene (its middle frame's
    // mesh), the crowd's among them.
    let (all, _) = scenes::Scene::all(settings.triangles, &common::shared_assets_dir());
    let closed: Vec<&str> = (all.iter())
        .filter(|s| {
            let mut p = Vec::new();
            s.positions(settings.frames / 2, &mut p);
            s.mesh(&p).is_closed()
        })
        .map(|s| s.name)
        .collect();
    assert!(closed.contains(&"crowd"), "closed scenes: {closed:?}");
    let culled: Vec<&str> = (report.shadows.iter())
        .filter(|r| r.renderer.starts_with("cpu, faces away left out"))
        .map(|r| r.scene)
        .collect();
    assert_eq!(culled, closed, "a culled row per closed scene");
    if std::env::var("KINETRACE_REQUIRE_GPU").is_ok_and(|v| v == "1") && cfg!(feature = "gpu") {
        assert_eq!(
            report.shadows.len(),
            7 * scenes.len() + closed.len(),
            "CPU maps (four ways of tracing rays, and without the faces away from the light where \
             closed), GPU maps (classified on the CPU and the GPU) and planned maps"
        );
    }
    for r in &report.shadows {
        assert_eq!(
            r.mismatches, 0,
            "{} {}: texels or pixels unlike the CPU map's",
            r.scene, r.renderer
        );
        assert!(
            r.covered > 1.0,
            "{} {}: an empty map compares trivially",
            r.scene,
            r.renderer
        );
    }
    // The GPU's LBVH is the CPU's, node for node: the same error, frame for frame.
    for gpu in report
        .rows
        .iter()
        .filter(|r| r.strategy == "rebuild-lbvh-gpu")
    {
        let cpu = report
            .rows
            .iter()
            .find(|r| r.scene == gpu.scene && r.strategy == "rebuild-lbvh")
            .unwrap();
        assert!(
            (gpu.sah_mean - cpu.sah_mean).abs() <= 1e-3 * cpu.sah_mean,
            "{}: GPU LBVH {} vs CPU LBVH {}",
            gpu.scene,
            gpu.sah_mean,
            cpu.sah_mean
        );
    }
    for f in &report.files {
        assert!(
            std::fs::metadata(f).unwrap().len() > 0,
            "{} is empty",
            f.display()
        );
    }
    let csv = std::fs::read_to_string(out.join("frames.csv")).unwrap();
    assert_eq!(
        csv.lines().count(),
        1 + report.rows.len() * harness::Settings::QUICK.frames as usize,
        "a CSV line per frame per strategy per scene"
    );
    // Only the adaptive policy's guard estimates the SAH ratio, and it does once it has a fresh cost.
    assert!(csv.lines().next().unwrap().ends_with(",guard_ratio"));
    let mut guarded = 0;
    for line in csv.lines().skip(1) {
        let fields: Vec<&str> = line.split(',').collect();
        assert_eq!(fields.len(), 10, "{line}");
        let guard: f64 = fields[9].parse().unwrap();
        assert!(
            guard.is_nan() || fields[1].starts_with("adaptive"),
            "{line}"
        );
        guarded += guard.is_finite() as usize;
    }
    assert!(
        guarded > 0,
        "no adaptive frame carries the guard's estimate"
    );
    let summary = std::fs::read_to_string(out.join("summary.md")).unwrap();
    assert!(summary.contains("| adaptive |") && summary.contains("Goal "));
    for png in &pngs {
        assert!(
            summary.contains(&format!("]({png}.png)")),
            "summary.md embeds {png}.png"
        );
    }
    let figures = report
        .files
        .iter()
        .filter(|f| f.extension().is_some_and(|e| e == "png"));
    for f in figures {
        check_figure(f, &report.strategies);
    }
    for r in &report.rows {
        assert_eq!(
            r.mismatches, 0,
            "{} / {}: answers differ from brute force",
            r.scene, r.strategy
        );
        // A grid has no SAH cost (NaN, see grid_rows): only the structure rows and the planned options
        // (whose frames on the grid have none) may lack one.
        let structure_row = grid_rows::STRATEGIES.iter().any(|s| s.name() == r.strategy)
            || (option_rows::STRATEGIES.iter()).any(|s| !s.is_fixed() && s.name() == r.strategy);
        let sah_ok = r.sah_mean >= 0.5 || (structure_row && r.sah_mean.is_nan());
        assert!(
            sah_ok && r.steps_mean > 0.0 && r.total_ms > 0.0,
            "{} / {}",
            r.scene,
            r.strategy
        );
    }
    // Secondary rays: per scene two batches of rays, each with every fixed strategy and the planner; every
    // strategy's answers equal the BVH's, whose sample equals brute force; the section is in the summary.
    assert_eq!(
        report.secondary.len(),
        scenes.len() * 2 * (secondary_rows::FIXED.len() + 1)
    );
    assert!(summary.contains("## Secondary rays"));
    for r in &report.secondary {
        assert_eq!(
            r.mismatches, 0,
            "{} / {} / {}: answers differ from the BVH's or brute force",
            r.scene, r.batch, r.strategy
        );
        assert!(
            r.rays > 0 && r.mrays > 0.0 && r.tests_per_ray > 0.0,
            "{} / {}",
            r.scene,
            r.batch
        );
        assert!(summary.contains(&format!("| {} | {} | {} |", r.scene, r.batch, r.strategy)));
    }
    // Closest-point batches: per scene every fixed order and the planner; every order's answers equal
    // the as-queued ones; the section is in the summary.
    assert_eq!(
        report.points.len(),
        scenes.len() * (point_rows::FIXED.len() + 1)
    );
    assert!(summary.contains("## Closest-point batches"));
    for r in &report.points {
        assert_eq!(r.mismatches, 0, "{} / {}", r.scene, r.order);
        assert!(
            r.points > 0 && r.us_per_query > 0.0,
            "{} / {}",
            r.scene,
            r.order
        );
        assert!(summary.contains(&format!("| {} | {} | {} |", r.scene, r.order, r.points)));
    }
    // Rebuilding with binned SAH every frame is the reference itself.
    for r in report.rows.iter().filter(|r| r.strategy == "rebuild-sah") {
        assert!(
            (r.sah_mean - 1.0).abs() < 1e-9,
            "{}: {}",
            r.scene,
            r.sah_mean
        );
    }
    std::fs::remove_dir_all(&out).ok();
}

/// `path` decodes as a PNG of its figure's size; its title band holds text (dark pixels, so the embedded
/// font drew); the legend column holds a marker in every strategy's colour; the plots hold data (pixels
/// in strategy colours, beyond the legend).
fn check_figure(path: &PathBuf, strategies: &[harness::Strategy]) {
    let name = path.file_stem().unwrap().to_string_lossy();
    let img = image::open(path)
        .unwrap_or_else(|e| panic!("{name}.png does not decode: {e}"))
        .to_rgb8();
    let size = match name.as_ref() {
        "overview" => plots::OVERVIEW,
        n if n.ends_with("-frames") => plots::PER_FRAME,
        _ => plots::ERROR_VS_TIME,
    };
    assert_eq!(img.dimensions(), size, "{name}.png");
    let (w, _) = size;
    let dark = |p: &image::Rgb<u8>| p.0.iter().all(|&c| c < 96);
    let title_ink = (0..w)
        .flat_map(|x| (0..40).map(move |y| (x, y)))
        .filter(|&(x, y)| dark(img.get_pixel(x, y)))
        .count();
    assert!(
        title_ink > 200,
        "{name}.png: no title text ({title_ink} dark pixels)"
    );
    let legend_x = w - 260;
    let mut in_plots = 0;
    for look in plots::looks(strategies) {
        let colour = image::Rgb([look.colour.0, look.colour.1, look.colour.2]);
        let (mut legend, mut plot) = (0, 0);
        for (x, _, _) in img.enumerate_pixels().filter(|(_, _, p)| **p == colour) {
            if x >= legend_x {
                legend += 1
            } else {
                plot += 1
            }
        }
        // A legend marker of radius 6 covers about 110 pixels.
        assert!(
            legend >= 60,
            "{name}.png: legend marker {colour:?}: {legend} pixels"
        );
        in_plots += plot;
    }
    assert!(
        in_plots >= 100 * strategies.len(),
        "{name}.png: {in_plots} data pixels"
    );
}

#[test]
fn axes_turn_logarithmic_only_where_values_span_a_decade() {
    let wide = scale::Scale::fit([0.04, 0.3, 7.5], true);
    assert!(wide.is_log());
    let r = wide.range();
    assert!(r.start <= 0.04 && r.end >= 7.5, "{r:?}");
    let ticks = wide.key_points(10usize);
    assert!(!ticks.is_empty() && ticks.len() <= 10, "{ticks:?}");
    for t in &ticks {
        // Every tick is 1, 2 or 5 times a power of ten, inside the axis.
        let mantissa = t / 10f64.powf(t.log10().floor());
        assert!(
            [1.0, 2.0, 5.0].iter().any(|m| (mantissa - m).abs() < 1e-9),
            "tick {t}"
        );
        assert!(r.contains(t), "tick {t} outside {r:?}");
    }
    for narrow in [&[1.0, 1.3, 9.9][..], &[2.0, 2.0], &[-1.0, 0.5, 50.0]] {
        let s = scale::Scale::fit(narrow.iter().copied(), true);
        let r = s.range();
        assert!(!s.is_log(), "{narrow:?}");
        assert!(
            narrow.iter().all(|v| r.start < *v && *v < r.end),
            "{narrow:?} in {r:?}"
        );
    }
    assert!(!scale::Scale::fit([0.01, 100.0], false).is_log());
    for (v, label) in [
        (0.05, "0.05"),
        (1.25, "1.25"),
        (200.0, "200"),
        (0.0001, "0.0001"),
    ] {
        assert_eq!(scale::tick(v), label);
    }
}

#[test]
fn zero_counts_are_errors_not_panics() {
    let out = std::env::temp_dir().join(format!("kinetrace-report-bad-{}", std::process::id()));
    let assets = Path::new("/nonexistent");
    let q = harness::Settings::QUICK;
    for bad in [
        harness::Settings { frames: 0, ..q },
        harness::Settings { triangles: 0, ..q },
        harness::Settings { rays: 0, ..q },
    ] {
        let e = output::write_report(&bad, assets, &out, &output::Only::default())
            .err()
            .expect("an error");
        assert_eq!(e.kind(), std::io::ErrorKind::InvalidInput);
        assert!(e.to_string().contains("at least 1"), "{e}");
    }
    assert!(!out.exists(), "nothing is written for bad settings");
}
