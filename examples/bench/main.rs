//! kinetrace benchmarks: one binary, one suite per area, peers measured in the same run.
//!
//! ```text
//! cargo run --release --example bench -- [SUITE ...] [--quick] [--json FILE]
//! ```
//! Suites: `cpu` (builders, refit, queries; obvhs and the bvh crate on the same triangles and rays),
//! `gpu` (LBVH build, refit and ray queries on the wgpu back end), `ecs` (the plugin's frame cost and
//! overhead), `skinning` (skinning throughput and crowd frame times), `collide` (collision queries on
//! animated characters and cloth, against parry3d), `grid` (per-frame uniform grid vs LBVH: build rate,
//! single-ray and packet queries).
//! With no suite named, all run. `--quick` uses small scenes and few repetitions (under a minute);
//! `--json FILE` also writes every measurement as JSON. Speed is only ever compared within one run:
//! the tables print kinetrace/peer ratios, which survive a noisy shared machine far better than times.

mod collide;
mod cpu;
mod ecs;
mod gpu;
mod grid;
mod peers;
mod rays;
mod record;
#[path = "../report/scenes.rs"]
#[allow(dead_code)]
mod report_scenes;
mod skinning;

use record::Records;
use std::process::ExitCode;

const SUITES: [&str; 6] = ["cpu", "gpu", "ecs", "skinning", "collide", "grid"];

fn main() -> ExitCode {
    let mut quick = false;
    let mut json = None;
    let mut suites = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--quick" => quick = true,
            "--json" => match args.next() {
                Some(f) => json = Some(f),
                None => return usage("--json needs a file name"),
            },
            "-h" | "--help" => return usage(""),
            s if SUITES.contains(&s) => suites.push(s.to_string()),
            s => return usage(&format!("unknown argument {s:?}")),
        }
    }
    if suites.is_empty() {
        suites = SUITES.iter().map(|s| s.to_string()).collect();
    }
    let mut rec = Records::new(quick);
    for s in &suites {
        match s.as_str() {
            "cpu" => cpu::run(&mut rec),
            "gpu" => gpu::run(&mut rec),
            "ecs" => ecs::run(&mut rec),
            "skinning" => skinning::run(&mut rec),
            "collide" => collide::run(&mut rec),
            "grid" => grid::run(&mut rec),
            _ => unreachable!("checked above"),
        }
    }
    if let Some(path) = json {
        if let Err(e) = std::fs::write(&path, rec.to_json()) {
            eprintln!("could not write {path}: {e}");
            return ExitCode::FAILURE;
        }
        println!("wrote {path}");
    }
    ExitCode::SUCCESS
}

fn usage(problem: &str) -> ExitCode {
    if !problem.is_empty() {
        eprintln!("error: {problem}");
    }
    eprintln!(
        "usage: bench [{}]... [--quick] [--json FILE]",
        SUITES.join("|")
    );
    if problem.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(2)
    }
}
