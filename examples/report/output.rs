//! The report's files: `frames.csv` (every frame of every strategy on every scene), `summary.md` (the
//! table and the goal check) and per scene `SCENE.png` (error against run time, one point per strategy
//! with the per-frame spread as bars) and `SCENE-frames.png` (per-frame curves of time and error).

use super::harness::{FrameRecord, Settings, Strategy, find_gpu, run_scene};
use super::scenes::Scene;
use image::{Rgb, RgbImage};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// One strategy's totals on one scene.
pub struct Row {
    pub scene: &'static str,
    pub strategy: String,
    pub fixed: bool,
    /// Mean update + query milliseconds per frame.
    pub total_ms: f64,
    pub update_ms: f64,
    pub query_ms: f64,
    pub rebuilds: usize,
    pub sah_mean: f64,
    pub sah_max: f64,
    pub steps_mean: f64,
    pub mismatches: u32,
    /// Per-frame (total ms, SAH ratio) extremes for the plot's bars.
    spread: [(f64, f64); 2],
}

fn row(scene: &'static str, strategy: &Strategy, recs: &[FrameRecord]) -> Row {
    let n = recs.len().max(1) as f64;
    let ms = |r: &FrameRecord| 1e3 * (r.update_s + r.query_s);
    let fold = |f: fn(f64, f64) -> f64, init: f64, g: &dyn Fn(&FrameRecord) -> f64| {
        recs.iter().map(g).fold(init, f)
    };
    Row {
        scene,
        strategy: strategy.name(),
        fixed: strategy.is_fixed(),
        total_ms: recs.iter().map(ms).sum::<f64>() / n,
        update_ms: recs.iter().map(|r| 1e3 * r.update_s).sum::<f64>() / n,
        query_ms: recs.iter().map(|r| 1e3 * r.query_s).sum::<f64>() / n,
        rebuilds: recs.iter().filter(|r| r.rebuilt).count(),
        sah_mean: recs.iter().map(|r| r.sah_ratio).sum::<f64>() / n,
        sah_max: fold(f64::max, 0.0, &|r| r.sah_ratio),
        steps_mean: recs.iter().map(|r| r.steps_ratio).sum::<f64>() / n,
        mismatches: recs.iter().map(|r| r.mismatches).sum(),
        spread: [
            (
                fold(f64::min, f64::MAX, &ms),
                fold(f64::min, f64::MAX, &|r| r.sah_ratio),
            ),
            (
                fold(f64::max, 0.0, &ms),
                fold(f64::max, 0.0, &|r| r.sah_ratio),
            ),
        ],
    }
}

/// What the report found; the files are written under `out`.
pub struct Report {
    pub rows: Vec<Row>,
    pub files: Vec<PathBuf>,
    pub skipped: Vec<String>,
    /// The strategies run, in the order of each scene's rows.
    pub strategies: Vec<Strategy>,
}

/// Runs every scene and strategy and writes the files.
/// Errors: `InvalidInput` for settings with a zero count (see [`Settings::problem`]), or the I/O error.
pub fn write_report(settings: &Settings, assets: &Path, out: &Path) -> std::io::Result<Report> {
    if let Some(problem) = settings.problem() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            problem,
        ));
    }
    std::fs::create_dir_all(out)?;
    let (scenes, mut skipped) = Scene::all(settings.triangles, assets);
    let gpu = find_gpu()
        .inspect_err(|e| skipped.push(format!("GPU strategies SKIPPED: {e}")))
        .ok();
    let strategies = Strategy::all(gpu.is_some());
    let mut csv = String::from(
        "scene,strategy,frame,update_ms,query_ms,rebuilt,sah_ratio,steps_ratio,mismatches\n",
    );
    let (mut rows, mut files) = (Vec::new(), Vec::new());
    for scene in &scenes {
        let per_strategy = run_scene(scene, settings, &strategies, gpu.as_ref());
        let first = rows.len();
        for (s, recs) in strategies.iter().zip(&per_strategy) {
            for r in recs {
                let _ = writeln!(
                    csv,
                    "{},{},{},{:.4},{:.4},{},{:.4},{:.4},{}",
                    scene.name,
                    s.name(),
                    r.frame,
                    1e3 * r.update_s,
                    1e3 * r.query_s,
                    r.rebuilt as u8,
                    r.sah_ratio,
                    r.steps_ratio,
                    r.mismatches
                );
            }
            rows.push(row(scene.name, s, recs));
        }
        for (suffix, img) in [
            ("", plot(&rows[first..])),
            ("-frames", curves(&per_strategy)),
        ] {
            let png = out.join(format!("{}{suffix}.png", scene.name));
            img.save(&png).map_err(std::io::Error::other)?;
            files.push(png);
        }
    }
    for (name, text) in [
        ("frames.csv", csv),
        (
            "summary.md",
            summary(&rows, settings, &skipped, &strategies),
        ),
    ] {
        let path = out.join(name);
        std::fs::write(&path, text)?;
        files.push(path);
    }
    Ok(Report {
        rows,
        files,
        skipped,
        strategies,
    })
}

/// Colours of the strategies in the plots, in [`Strategy::all`] order.
const COLOURS: [[u8; 3]; 11] = [
    [230, 25, 75],
    [60, 180, 75],
    [0, 130, 200],
    [245, 130, 48],
    [145, 30, 180],
    [70, 240, 240],
    [240, 50, 230],
    [128, 128, 0],
    [0, 0, 0],
    [170, 110, 40],
    [128, 128, 128],
];

/// Error (SAH ratio, up) against time per frame (right), the per-frame spread as bars.
fn plot(rows: &[Row]) -> RgbImage {
    let (w, h, m) = (640u32, 480u32, 40u32);
    let mut img = RgbImage::from_pixel(w, h, Rgb([255, 255, 255]));
    let t_max = rows.iter().map(|r| r.spread[1].0).fold(1e-9, f64::max);
    let e_max = rows.iter().map(|r| r.spread[1].1).fold(1.0, f64::max);
    let e_min = rows.iter().map(|r| r.spread[0].1).fold(1.0, f64::min);
    let x = |t: f64| m + ((t / t_max) * (w - 2 * m) as f64) as u32;
    let y =
        |e: f64| h - m - (((e - e_min) / (e_max - e_min).max(1e-9)) * (h - 2 * m) as f64) as u32;
    for i in m..=w - m {
        img.put_pixel(i, h - m, Rgb([0, 0, 0]));
    }
    for j in m..=h - m {
        img.put_pixel(m, j, Rgb([0, 0, 0]));
    }
    for (r, c) in rows.iter().zip(COLOURS) {
        let (cx, cy) = (x(r.total_ms), y(r.sah_mean));
        for i in x(r.spread[0].0)..=x(r.spread[1].0) {
            img.put_pixel(i, cy, Rgb(c));
        }
        for j in y(r.spread[1].1)..=y(r.spread[0].1) {
            img.put_pixel(cx, j, Rgb(c));
        }
        for dx in 0..7 {
            for dy in 0..7 {
                img.put_pixel(
                    (cx + dx).saturating_sub(3),
                    (cy + dy).saturating_sub(3),
                    Rgb(c),
                );
            }
        }
    }
    img
}

/// Per-frame curves, one colour per strategy: update + query ms on a log scale (top half), SAH ratio
/// (bottom half; ratios above 3 are drawn at 3).
fn curves(per_strategy: &[Vec<FrameRecord>]) -> RgbImage {
    let (w, h, m) = (640u32, 480u32, 20u32);
    let mut img = RgbImage::from_pixel(w, h, Rgb([255, 255, 255]));
    let frames = per_strategy.iter().map(Vec::len).max().unwrap_or(0).max(2);
    let ms = |r: &FrameRecord| (1e3 * (r.update_s + r.query_s)).max(1e-4).log10();
    let error = |r: &FrameRecord| r.sah_ratio.min(3.0);
    let half = h / 2;
    for (top, value) in [(0u32, &ms as &dyn Fn(&FrameRecord) -> f64), (half, &error)] {
        let all = per_strategy.iter().flatten().map(value);
        let (lo, hi) = all.fold((f64::MAX, f64::MIN), |(l, u), v| (l.min(v), u.max(v)));
        let span = (hi - lo).max(1e-9);
        let (y0, y1) = (top + m, top + half - m);
        for i in m..w - m {
            img.put_pixel(i, y1, Rgb([0, 0, 0]));
        }
        for (recs, c) in per_strategy.iter().zip(COLOURS) {
            let mut last: Option<(u32, f64)> = None;
            for (f, r) in recs.iter().enumerate() {
                let x = m + (f as u64 * (w - 2 * m - 1) as u64 / (frames - 1) as u64) as u32;
                let y = y1 as f64 - (value(r) - lo) / span * (y1 - y0) as f64;
                // A segment from the previous point: one pixel per column, joined vertically.
                let (x0, ya) = last.unwrap_or((x, y));
                let mut prev = ya;
                for i in x0..=x {
                    let t = if x > x0 {
                        (i - x0) as f64 / (x - x0) as f64
                    } else {
                        1.0
                    };
                    let yi = ya + (y - ya) * t;
                    for j in prev.min(yi).round() as u32..=prev.max(yi).round() as u32 {
                        img.put_pixel(i, j, Rgb(c));
                    }
                    prev = yi;
                }
                last = Some((x, y));
            }
        }
    }
    img
}

fn summary(
    rows: &[Row],
    settings: &Settings,
    skipped: &[String],
    strategies: &[Strategy],
) -> String {
    let mut s = format!(
        "# kinetrace error-versus-run-time report\n\n{} frames, about {} triangles per scene, {} primary \
         rays per frame plus a shadow ray per hit; {} rays per frame checked against brute force. Times are \
         mean milliseconds per frame on this machine (queries on one CPU thread; CPU builds on all threads; \
         `-gpu` builds on the GPU, read back for the CPU's queries, their update time including the round \
         trip); error is the tree's SAH cost and \
         traversal steps per ray over a fresh binned-SAH build of the same frame.\n\n",
        settings.frames, settings.triangles, settings.rays, settings.checked_rays
    );
    for line in skipped {
        let _ = writeln!(s, "- {line}");
    }
    s.push_str(
        "\n| scene | strategy | total ms | update ms | query ms | rebuilds | SAH ratio mean | SAH ratio max \
         | steps ratio | mismatches |\n|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {} | {:.3} | {:.3} | {:.3} | {} | {:.3} | {:.3} | {:.3} | {} |",
            r.scene,
            r.strategy,
            r.total_ms,
            r.update_ms,
            r.query_ms,
            r.rebuilds,
            r.sah_mean,
            r.sah_max,
            r.steps_mean,
            r.mismatches
        );
    }
    s.push_str(
        "\n## Goal: adaptive within 5% of the best fixed strategy, ≥ 10% faster than lauterbach-0.4 on three \
         scenes, SAH ratio never above 1.5\n\n| scene | best fixed | adaptive / best | adaptive / \
         lauterbach-0.4 | adaptive SAH max | within 5% |\n|---|---|---|---|---|---|\n",
    );
    let mut beats = 0;
    let mut all_within = true;
    let mut error_ok = true;
    let mut scenes: Vec<&str> = rows.iter().map(|r| r.scene).collect();
    scenes.dedup();
    for scene in scenes {
        let of = |name: &str| rows.iter().find(|r| r.scene == scene && r.strategy == name);
        let best = rows
            .iter()
            .filter(|r| r.scene == scene && r.fixed)
            .min_by(|a, b| a.total_ms.total_cmp(&b.total_ms));
        let (Some(best), Some(ad), Some(la)) = (best, of("adaptive"), of("lauterbach-0.4")) else {
            continue;
        };
        let vs_best = ad.total_ms / best.total_ms;
        let vs_la = ad.total_ms / la.total_ms;
        beats += (vs_la <= 0.9) as usize;
        all_within &= vs_best <= 1.05;
        error_ok &= ad.sah_max <= 1.5;
        let _ = writeln!(
            s,
            "| {scene} | {} | {vs_best:.3} | {vs_la:.3} | {:.3} | {} |",
            best.strategy,
            ad.sah_max,
            if vs_best <= 1.05 { "yes" } else { "NO" }
        );
    }
    let met = all_within && beats >= 3 && error_ok;
    let _ = writeln!(
        s,
        "\nGoal {}: within 5% on every scene: {all_within}; scenes where adaptive beats lauterbach-0.4 by \
         10% or more: {beats}; adaptive SAH ratio ≤ 1.5 throughout: {error_ok}.\n\nPlots: one PNG per \
         scene, x = total ms per frame, y = SAH ratio; dot = mean, bars = per-frame range; SCENE-frames.png: \
         per-frame curves, top = total ms (log scale), bottom = SAH ratio (capped at 3). Colours in \
         strategy order: {}.",
        if met { "MET" } else { "NOT MET" },
        strategies
            .iter()
            .zip(COLOURS)
            .map(|(st, c)| format!("{} #{:02x}{:02x}{:02x}", st.name(), c[0], c[1], c[2]))
            .collect::<Vec<_>>()
            .join(", ")
    );
    s
}
