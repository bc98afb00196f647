//! The counting global allocator shared by the no-allocation test binaries (`tests/no_alloc.rs`,
//! `tests/no_alloc_shapes.rs`), and the deforming-sphere plugin world they run frames of.

use crate::common::*;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;

thread_local! {
    // const-initialised: touching it never allocates.
    static ALLOCS: Cell<usize> = const { Cell::new(0) };
}

pub fn allocations() -> usize {
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

/// Held by every test for its whole run: the tests of this file run one at a time. Work a thread hands to
/// rayon's global pool goes through a shared queue whose blocks are allocated by whichever thread's push
/// crosses a block boundary; with another test pushing at the same time, that thread can be a test's frame
/// thread at any frame (an allocation by the test harness, not by the code under test).
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Takes [`ONE_AT_A_TIME`] (a test that failed while holding it does not poison the others).
pub fn alone() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

/// Runs one frame of `schedule` on `world` inside `pool` and returns the allocations made on the pool's
/// threads meanwhile (each one's count read with `broadcast`). The frame runs on a pool thread, so the
/// parallel work it hands out goes to the pool's own deques; a frame run from outside a pool enters it
/// through the pool's shared injector queue, which allocates a block on whichever push crosses a block
/// boundary (every 63 jobs) — rayon's bookkeeping, amortised, not the code under test.
#[cfg(feature = "parallel")]
pub fn frame_allocations(
    pool: &rayon::ThreadPool,
    world: &mut bevy_ecs::world::World,
    schedule: &mut bevy_ecs::schedule::Schedule,
) -> usize {
    let count = || pool.broadcast(|_| allocations()).iter().sum::<usize>();
    let before = count();
    pool.install(|| {
        schedule.run(world);
        world.clear_trackers();
    });
    count() - before
}

/// Without the `parallel` feature the frame runs on the calling thread, and its allocations are that
/// thread's.
#[cfg(not(feature = "parallel"))]
pub fn frame_allocations(
    _pool: &(),
    world: &mut bevy_ecs::world::World,
    schedule: &mut bevy_ecs::schedule::Schedule,
) -> usize {
    let before = allocations();
    schedule.run(world);
    world.clear_trackers();
    allocations() - before
}

/// The pool [`frame_allocations`] runs frames in: one thread, so that the per-thread scratch a frame's
/// parallel work keeps (e.g. each thread's list of the entities a ray packet reaches) is warm on every
/// thread of it after the first frames, whichever thread the work lands on.
#[cfg(feature = "parallel")]
pub fn frame_pool() -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
}

/// No pool without the `parallel` feature.
#[cfg(not(feature = "parallel"))]
pub fn frame_pool() {}

/// A plugin world run on the calling thread under `policy`, every mesh kept as `structure`, with a sphere
/// whose `VertexPositions` the test rewrites: the world, its schedule, the sphere's rest mesh and its entity.
pub fn deforming_sphere_app(
    policy: kinetrace::ecs::RebuildPolicy,
    structure: kinetrace::ecs::Structure,
) -> (
    bevy_ecs::world::World,
    bevy_ecs::schedule::Schedule,
    kinetrace::Mesh,
    bevy_ecs::entity::Entity,
) {
    use bevy_ecs::prelude::*;
    use kinetrace::ecs::*;
    let mut world = World::new();
    let mut schedule = Schedule::default();
    schedule.set_executor(bevy_ecs::schedule::SingleThreadedExecutor::new());
    KinetracePlugin {
        config: TraceConfig {
            policy,
            structure,
            ..Default::default()
        },
        ..Default::default()
    }
    .build(&mut world, &mut schedule);
    let rest = icosphere(3);
    let e = world
        .spawn((
            TraceMesh(rest.clone()),
            VertexPositions(rest.positions().to_vec()),
        ))
        .id();
    (world, schedule, rest, e)
}
