//! Tests that return early (no GPU adapter, no shared assets) say so on the terminal.
//!
//! libtest captures what a test prints with `print!`/`eprint!` and shows it only for failures, so an
//! `eprintln!` skip notice vanishes from a passing run. A write to the `std::io::stderr()` handle goes to the
//! process's file descriptor 2, past the capture: a plain `cargo test` shows it.

use std::io::Write;
use std::path::PathBuf;

/// Reports on the real standard error that the current test is skipping (part of) its work, and why. The
/// test's name is its thread's, which libtest sets.
pub fn skip(reason: &str) {
    let thread = std::thread::current();
    let test = thread.name().unwrap_or("a test");
    let _ = writeln!(std::io::stderr().lock(), "*** SKIPPED {test}: {reason} ***");
}

/// The shared GPU context, or `None` after a [`skip`] notice (with `KINETRACE_REQUIRE_GPU=1` a missing
/// adapter panics instead, in `shared_for_tests`).
#[cfg(feature = "gpu")]
pub fn gpu_or_skip() -> Option<kinetrace::gpu::GpuContext> {
    let g = kinetrace::gpu::shared_for_tests();
    if g.is_none() {
        skip(
            "no GPU adapter (lavapipe: mesa-vulkan-drivers; KINETRACE_REQUIRE_GPU=1 makes this a failure)",
        );
    }
    g
}

/// The shared assets folder beside the repository (`../shared/assets`).
pub fn shared_assets_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/assets")
}

/// A file of the shared assets, or `None` after a [`skip`] notice when it is not there.
pub fn shared_asset_or_skip(name: &str) -> Option<PathBuf> {
    let p = shared_assets_dir().join(name);
    if p.exists() {
        Some(p)
    } else {
        skip(&format!(
            "{} not found (the shared assets live beside the repository)",
            p.display()
        ));
        None
    }
}
