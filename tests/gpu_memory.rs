//! The GPU builders' memory figures (`memory_bytes`, reported as bytes per triangle by `bench gpu`) against
//! the device bytes actually allocated, as the context counts them at every buffer creation; and the
//! aliased scratch keeps the LBVH tree within the per-buffer budget its docs state. One test in this
//! binary, so no other test allocates on the shared device while it counts. On lavapipe in CI
//! (`KINETRACE_REQUIRE_GPU=1`); without an adapter it skips and says so.
#![cfg(feature = "gpu")]

mod common;
use common::*;
use kinetrace::gpu::{
    GpuContext, GpuMeshBvh, GpuPloc, GpuSahBuilder, GpuSahOptions, HYBRID_LEVELS,
};

/// Device bytes allocated while `make` runs, and what it made.
fn allocated<T>(g: &GpuContext, make: impl FnOnce() -> T) -> (u64, T) {
    let before = g.counters().allocated_bytes;
    let made = make();
    (g.counters().allocated_bytes - before, made)
}

#[test]
fn memory_bytes_are_the_allocated_buffers() {
    let Some(g) = gpu_or_skip() else { return };
    for (name, m) in [
        ("one triangle", soup(1, 1)),
        ("soup of 1025", soup(2, 1025)),
        ("bumpy torus", kinetrace::scenes::bumpy_torus(20_000)),
    ] {
        let (n, v) = (m.triangle_count() as u64, m.positions().len() as u64);
        let (bytes, bvh) = allocated(&g, || GpuMeshBvh::new(&g, &m).unwrap());
        assert_eq!(bvh.memory_bytes(), bytes, "{name}: LBVH");
        // The documented budget (src/gpu/bvh.rs): mesh 12 per vertex + 12, tree 64 + 4 + 4, schedule 4,
        // scratch 16 + 8 + 8 per triangle; plus per-buffer rounding to 256 bytes (at most 32
        // buffers), per-block partial bounds, degradation sums, the sort's histogram and scans (under 160
        // bytes per 256 triangles) and at most 40 KiB of parameter slots.
        let budget = 12 * v + 120 * n + n.div_ceil(256) * 160 + 32 * 256 + (40 << 10);
        assert!(bytes <= budget, "{name}: {bytes} > {budget}");
        for options in [
            GpuSahOptions::SAH,
            GpuSahOptions::hybrid(HYBRID_LEVELS),
            GpuSahOptions::SAH.small_split(false),
        ] {
            let (bytes, sah) = allocated(&g, || GpuSahBuilder::new(&g, &bvh, options).unwrap());
            assert_eq!(sah.memory_bytes(), bytes, "{name}: {options:?}");
            if options.small_split {
                // The documented scratch (src/gpu/build_sah.rs): primitives 20 per triangle, bins and
                // level queues 1,432 bytes per queued node (at most n / 65 + 1), the scan's block sums,
                // and under 17 KiB of parameters plus at most 16 buffers' rounding to 256 bytes.
                let scratch =
                    20 * n + 1432 * (n / 65 + 1) + n.div_ceil(256) * 8 + 16 * 256 + (17 << 10);
                assert!(bytes <= scratch, "{name}: {options:?} {bytes} > {scratch}");
            }
        }
        let (bytes, ploc) = allocated(&g, || GpuPloc::new(&g, &m, 16).unwrap());
        assert_eq!(ploc.memory_bytes(), bytes, "{name}: PLOC");
        // PLOC clusters in its LBVH tree's buffers: beyond them only the scan's block sums and five
        // small buffers (state, arguments, stand-in, parameters, sums) of at least 256 bytes each.
        let own = n.div_ceil(256) * 4 + 5 * 256;
        assert!(
            bytes <= budget + own,
            "{name}: PLOC {bytes} > {}",
            budget + own
        );
    }
}
