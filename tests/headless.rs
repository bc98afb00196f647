//! Headless runs print only their own output: creating the GPU context on a machine with no display
//! writes nothing to stderr. (Mesa's device-select layer, seeing wgpu's Wayland surface extension, used to
//! make libwayland print `error: XDG_RUNTIME_DIR is invalid or not set in the environment.` on every
//! adapter listing.) The context is created in a child process, this test binary run again, so that its
//! stderr can be read whole.
#![cfg(feature = "gpu")]

use std::process::Command;

const CHILD: &str = "child_creates_a_gpu_context";

/// Run only by the test below, in a child process with no display in its environment.
#[test]
#[ignore = "run in a child process by creating_a_gpu_context_without_a_display_prints_nothing_to_stderr"]
fn child_creates_a_gpu_context() {
    match kinetrace::gpu::GpuContext::new() {
        Ok(ctx) => println!("adapter: {}", ctx.adapter_name()),
        Err(e) => println!("no adapter: {e}"),
    }
}

#[test]
fn creating_a_gpu_context_without_a_display_prints_nothing_to_stderr() {
    let out = Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            CHILD,
            "--ignored",
            "--nocapture",
            "--test-threads=1",
        ])
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("WAYLAND_DISPLAY")
        .env_remove("DISPLAY")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "child failed:\n{stdout}\n{stderr}");
    assert!(stdout.contains("1 passed"), "the child test ran:\n{stdout}");
    if std::env::var("KINETRACE_REQUIRE_GPU").is_ok_and(|v| v == "1") {
        assert!(
            stdout.contains("adapter: "),
            "KINETRACE_REQUIRE_GPU=1 but no adapter:\n{stdout}"
        );
    }
    assert_eq!(stderr, "", "creating a GPU context printed to stderr");
}
