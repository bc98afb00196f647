//! Refit and queries allocate nothing: counted with a global allocator in this test binary, per thread, so
//! that rayon's pool threads (still settling after a parallel build) do not count.

mod common;
use common::*;
use glam::Vec3;
use kinetrace::bvh::{BuildOptions, Builder, TraversalStats};
use kinetrace::{MeshBvh, Ray};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;

thread_local! {
    // const-initialised: touching it never allocates.
    static ALLOCS: Cell<usize> = const { Cell::new(0) };
}

fn allocations() -> usize {
    ALLOCS.with(Cell::get)
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
}

#[global_allocator]
static A: Counting = Counting;

#[test]
fn refit_and_single_ray_queries_do_not_allocate() {
    // The counter sees this thread's allocations.
    let before = allocations();
    std::hint::black_box(vec![1u8; 64]);
    assert_eq!(allocations() - before, 1);

    let m = icosphere(3);
    let moved: Vec<Vec3> = m.positions().iter().map(|p| *p * 1.5 + Vec3::X).collect();
    let rays: Vec<Ray> = (0..64)
        .map(|i| Ray::new(Vec3::new(i as f32 * 0.01, 0.0, -5.0), Vec3::Z))
        .collect();
    for b in Builder::ALL {
        let mut bvh = MeshBvh::build(&m, &BuildOptions::new(b)).unwrap();
        let mut stats = TraversalStats::default();
        let before = allocations();
        let d = bvh.refit(&moved).unwrap();
        let mut hits = 0;
        for r in &rays {
            hits += bvh.closest_hit(r).is_some() as usize;
            hits += bvh.any_hit(r) as usize;
            hits += bvh.closest_hit_counted(r, &mut stats).is_some() as usize;
        }
        let after = allocations();
        assert_eq!(
            after - before,
            0,
            "{b:?} allocated {} times",
            after - before
        );
        assert_eq!(hits, 3 * rays.len());
        assert!(d.abs() < 1e-4);
    }
}
