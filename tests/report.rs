//! Smoke test of the evaluation harness (examples/report) in its `--quick` size: every file is written,
//! every scene and strategy is reported, and no sampled ray differs from brute force.

mod common;
#[path = "../examples/report/harness.rs"]
mod harness;
#[path = "../examples/report/output.rs"]
mod output;
#[path = "../examples/report/scenes.rs"]
mod scenes;

use std::path::Path;

#[test]
fn quick_report_writes_every_file_with_zero_mismatches() {
    let out = std::env::temp_dir().join(format!("kinetrace-report-{}", std::process::id()));
    let report = output::write_report(
        &harness::Settings::QUICK,
        &common::shared_assets_dir(),
        &out,
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
    let scenes: Vec<&String> = pngs.iter().filter(|s| !s.ends_with("-frames")).collect();
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
    let summary = std::fs::read_to_string(out.join("summary.md")).unwrap();
    assert!(summary.contains("| adaptive |") && summary.contains("Goal "));
    for r in &report.rows {
        assert_eq!(
            r.mismatches, 0,
            "{} / {}: answers differ from brute force",
            r.scene, r.strategy
        );
        assert!(
            r.sah_mean >= 0.5 && r.total_ms > 0.0,
            "{} / {}",
            r.scene,
            r.strategy
        );
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
        let e = output::write_report(&bad, assets, &out)
            .err()
            .expect("an error");
        assert_eq!(e.kind(), std::io::ErrorKind::InvalidInput);
        assert!(e.to_string().contains("at least 1"), "{e}");
    }
    assert!(!out.exists(), "nothing is written for bad settings");
}
