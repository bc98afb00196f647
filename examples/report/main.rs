//! Error-versus-run-time report: every animated scene under every refit/rebuild strategy, into
//! `target/report/` (frames.csv, summary.md with the figures embedded, overview.png across all scenes
//! and two PNGs per scene). The GPU strategies (LBVH rebuilt on the GPU every frame, and the adaptive
//! policy that may choose it) run when a hardware adapter exists, or a software one (lavapipe) with
//! `KINETRACE_ALLOW_SOFTWARE_GPU=1`; otherwise the summary and the console say they were skipped, and why.
//!
//! ```text
//! cargo run --release --example report            # 300 frames, ~20k triangles per scene
//! cargo run --release --example report -- --quick # 24 frames, ~3k triangles (what the smoke test runs)
//! options: --frames N --triangles N --rays N --runs N --out DIR --assets DIR
//!          --scenes NAME,NAME --strategies NAME,NAME
//! (--runs N: every scene N times, each strategy's median run reported; 1 by default;
//!  --scenes / --strategies: only those, by the names the summary prints; all by default; the
//!  secondary-ray, closest-point batch and shadow-map sections run unless --strategies leaves out
//!  `secondary`, `points` or `shadows`)
//! ```
//!
//! The crowd's row on a huge-page heap comes from this executable started again with `--crowd-child`
//! (see `planner::huge_page_crowd`), which runs that crowd alone and prints its row.

mod camera;
mod grid_rows;
mod harness;
mod option_rows;
mod output;
mod planner;
mod plots;
mod point_rows;
mod scale;
mod scenes;
mod secondary_rows;
mod shadow_rows;

use harness::Settings;
use std::path::PathBuf;

fn main() {
    // `KINETRACE_ALLOW_SOFTWARE_GPU=1` allows a software adapter, as for `TraceMode::GpuWhenAvailable`.
    #[cfg(feature = "gpu")]
    let software_gpu = kinetrace::gpu::software_allowed(
        false,
        std::env::var(kinetrace::gpu::ALLOW_SOFTWARE_ENV)
            .ok()
            .as_deref(),
    );
    #[cfg(not(feature = "gpu"))]
    let software_gpu = false;
    let mut settings = Settings {
        triangles: 20_000,
        frames: 300,
        rays: 4096,
        checked_rays: 16,
        runs: 1,
        software_gpu,
    };
    let mut out = PathBuf::from("target/report");
    let mut assets = PathBuf::from("../shared/assets");
    let mut only = output::Only::default();
    let mut crowd_child = false;
    let list = |v: String| v.split(',').map(str::to_owned).collect();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = |what: &str| {
            args.next()
                .unwrap_or_else(|| fail(&format!("{a} needs {what}")))
        };
        let mut number = |what: &str| -> usize {
            value(what)
                .parse()
                .unwrap_or_else(|_| fail(&format!("{a} needs {what}")))
        };
        match a.as_str() {
            "--quick" => {
                settings = Settings {
                    runs: settings.runs,
                    software_gpu: settings.software_gpu,
                    ..Settings::QUICK
                }
            }
            "--runs" => settings.runs = number("a run count").max(1) as u32,
            "--frames" => settings.frames = number("a frame count") as u32,
            "--triangles" => settings.triangles = number("a triangle count"),
            "--rays" => settings.rays = number("a ray count"),
            "--out" => out = PathBuf::from(value("a directory")),
            "--assets" => assets = PathBuf::from(value("a directory")),
            "--scenes" => only.scenes = list(value("scene names")),
            "--strategies" => only.strategies = list(value("strategy names")),
            planner::CROWD_CHILD => crowd_child = true,
            _ => fail(&format!("unknown option {a}")),
        }
    }
    if let Some(problem) = settings.problem() {
        fail(problem);
    }
    if crowd_child {
        let mut crowd = planner::instance_crowd(&settings, planner::CROWD, true);
        let (var, value) = planner::HUGE_PAGE_HEAP;
        crowd.huge_pages = std::env::var(var).is_ok_and(|v| v == value);
        println!("{}", planner::instance_crowd_row(&crowd));
        return;
    }
    only.crowd_child = std::env::current_exe().ok();
    match output::write_report(&settings, &assets, &out, &only) {
        Ok(report) => {
            for s in &report.skipped {
                eprintln!("{s}");
            }
            let bad: u32 = (report.rows.iter().map(|r| r.mismatches))
                .chain(report.secondary.iter().map(|r| r.mismatches))
                .chain(report.points.iter().map(|r| r.mismatches))
                .chain(report.shadows.iter().map(|r| r.mismatches))
                .sum();
            println!(
                "wrote {} files to {} ({} strategies per scene, {} mismatches against brute force)",
                report.files.len(),
                out.display(),
                report.strategies.len(),
                bad
            );
            if bad > 0 {
                std::process::exit(1);
            }
        }
        Err(e) => fail(&format!(
            "cannot write the report to {}: {e}",
            out.display()
        )),
    }
}

fn fail(message: &str) -> ! {
    eprintln!("report: {message}");
    std::process::exit(2)
}
