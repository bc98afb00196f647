//! Every bench suite's `--json` file, from its `--quick` run, parses as JSON and carries the machine and
//! the GPU adapter as top-level fields beside an array of records. The bench's own command line runs in
//! this process (its modules are compiled in, as `tests/report.rs` does with the report), one test per
//! suite.
#![cfg(all(feature = "parallel", feature = "gpu"))]

#[path = "../examples/report/camera.rs"]
mod camera;
#[path = "../examples/bench/cli.rs"]
mod cli;
#[path = "../examples/bench/collide.rs"]
mod collide;
#[path = "../examples/bench/cpu.rs"]
mod cpu;
#[path = "../examples/crowd.rs"]
#[allow(dead_code)]
mod crowd;
#[path = "../examples/bench/ecs.rs"]
mod ecs;
#[path = "../examples/bench/ecs_gpu.rs"]
mod ecs_gpu;
#[path = "../examples/bench/gpu.rs"]
mod gpu;
#[path = "../examples/bench/gpu_dacrt.rs"]
mod gpu_dacrt;
#[path = "../examples/bench/gpu_ploc.rs"]
mod gpu_ploc;
#[path = "../examples/bench/gpu_pool.rs"]
mod gpu_pool;
#[path = "../examples/bench/gpu_sah.rs"]
mod gpu_sah;
#[path = "../examples/bench/grid.rs"]
mod grid;
#[path = "../examples/bench/peers.rs"]
mod peers;
#[path = "../examples/bench/queries.rs"]
mod queries;
#[path = "../examples/bench/rays.rs"]
mod rays;
#[path = "../examples/bench/raysort.rs"]
mod raysort;
#[path = "../examples/bench/record.rs"]
mod record;
#[path = "../examples/report/scenes.rs"]
#[allow(dead_code)]
mod report_scenes;
#[path = "../examples/bench/shadows.rs"]
mod shadows;
#[path = "../examples/bench/skinning.rs"]
mod skinning;
#[path = "../examples/bench/sound.rs"]
mod sound;

use serde_json::Value;
use std::process::ExitCode;

/// Runs `bench SUITE --quick --json FILE` and returns the parsed file.
fn quick_json(suite: &str) -> Value {
    let path = std::env::temp_dir().join(format!(
        "kinetrace-bench-{suite}-{}.json",
        std::process::id()
    ));
    let args = [suite, "--quick", "--json", path.to_str().unwrap()];
    let code = cli::run(args.iter().map(|a| a.to_string()));
    assert_eq!(code, ExitCode::SUCCESS, "bench {suite} failed");
    let text = std::fs::read_to_string(&path).unwrap();
    std::fs::remove_file(&path).ok();
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{suite}: not JSON ({e}):\n{text}"))
}

fn require_gpu() -> bool {
    std::env::var("KINETRACE_REQUIRE_GPU").is_ok_and(|v| v == "1")
}

/// The checks every suite's file must pass. `uses_gpu`: whether the suite measures on the GPU when there
/// is one (then the adapter is the one `GpuContext` finds, else `null`).
fn check(suite: &str, uses_gpu: bool) {
    let doc = quick_json(suite);
    let top = doc.as_object().expect("a JSON object at the top");
    let machine = top["machine"].as_str().expect("machine: a string");
    assert!(!machine.is_empty());
    let threads = std::thread::available_parallelism().unwrap().get();
    assert_eq!(top["threads"].as_u64(), Some(threads as u64));
    assert_eq!(top["quick"], Value::Bool(true));
    let adapter = &top["gpu_adapter"];
    match kinetrace::gpu::GpuContext::new() {
        Ok(ctx) if uses_gpu => {
            assert_eq!(adapter.as_str(), Some(ctx.adapter_name()));
            assert!(top["gpu_details"].as_str().is_some_and(|d| !d.is_empty()));
        }
        Err(e) if uses_gpu => {
            assert!(!require_gpu(), "KINETRACE_REQUIRE_GPU=1 but no GPU: {e}");
            assert_eq!(adapter, &Value::Null);
            assert!(top["gpu_error"].is_string());
        }
        _ => assert_eq!(adapter, &Value::Null, "{suite} does not use the GPU"),
    }
    let records = top["records"].as_array().expect("records: an array");
    assert!(!records.is_empty(), "{suite} recorded nothing");
    for r in records {
        let r = r.as_object().expect("each record an object");
        let mut keys: Vec<&str> = r.keys().map(|k| k.as_str()).collect();
        keys.sort_unstable();
        assert_eq!(
            keys,
            ["metric", "scene", "subject", "suite", "unit", "value"],
            "{r:?}"
        );
        assert_eq!(r["suite"].as_str(), Some(suite));
        for k in ["scene", "subject", "metric"] {
            assert!(r[k].as_str().is_some_and(|s| !s.is_empty()), "{k}: {r:?}");
        }
        assert!(r["unit"].is_string(), "empty for ratios: {r:?}");
        assert!(r["value"].is_number() || r["value"].is_null(), "{r:?}");
    }
}

#[test]
fn cpu_suite_json_parses() {
    check("cpu", false);
}

#[test]
fn gpu_suite_json_parses() {
    check("gpu", true);
}

#[test]
fn ecs_suite_json_parses() {
    check("ecs", false);
}

#[test]
fn ecs_gpu_suite_json_parses() {
    check("ecs-gpu", true);
}

#[test]
fn skinning_suite_json_parses() {
    check("skinning", true);
}

#[test]
fn collide_suite_json_parses() {
    check("collide", true);
}

#[test]
fn grid_suite_json_parses() {
    check("grid", false);
}

#[test]
fn queries_suite_json_parses() {
    check("queries", false);
}

#[test]
fn raysort_suite_json_parses() {
    check("raysort", false);
}

#[test]
fn shadows_suite_json_parses() {
    check("shadows", true);
}

#[test]
fn sound_suite_json_parses() {
    check("sound", false);
}
