//! The command line: which suites run, how big, and where the JSON goes.

use crate::record::Records;
use std::process::ExitCode;

const SUITES: [&str; 11] = [
    "cpu", "gpu", "ecs", "ecs-gpu", "skinning", "collide", "grid", "queries", "raysort", "shadows",
    "sound",
];

/// Runs the suites the arguments name (all when none is named) and writes the JSON file if asked.
pub fn run(mut args: impl Iterator<Item = String>) -> ExitCode {
    let mut quick = false;
    let mut json = None;
    let mut suites = Vec::new();
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
            "cpu" => crate::cpu::run(&mut rec),
            "gpu" => crate::gpu::run(&mut rec),
            "ecs" => crate::ecs::run(&mut rec),
            "ecs-gpu" => crate::ecs_gpu::run(&mut rec),
            "skinning" => crate::skinning::run(&mut rec),
            "collide" => crate::collide::run(&mut rec),
            "grid" => crate::grid::run(&mut rec),
            "queries" => crate::queries::run(&mut rec),
            "raysort" => crate::raysort::run(&mut rec),
            "shadows" => crate::shadows::run(&mut rec),
            "sound" => crate::sound::run(&mut rec),
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
