//! Suite `queries`: gameplay queries on a deforming mesh, against parry3d in the same run — sphere casts,
//! capsule casts, closest points, containment and sphere, capsule and box overlaps, each frame after the
//! mesh moved, on one thread. Both sides pay their cheapest honest update every frame: our refit, parry's
//! `TriMesh::set_vertices` (a refit of its BVH; for containment also its pseudo-normals, which its
//! inside test needs). Throughput counts refit + queries. The `ecs batch` rows ask the same closest points
//! and sphere overlaps through a `bevy_ecs` world ([`ShapeQueue`] answered in the plugin's schedule, which
//! also maintains the mesh from its new `VertexPositions`), against the same parry rows. The plugin runs
//! with its default settings, what a user gets: Lauterbach's rule and `TraceConfig::builder`'s LBVH tree
//! (the direct rows build binned SAH). Under `RebuildPolicy::ADAPTIVE` the planner would choose the tree
//! from the measured query time (docs/BENCHMARKS.md, issue 18, for what it chose here).
//!
//! For profiling (callgrind counts instructions, not time, so a loaded machine does not matter),
//! `KINETRACE_QUERY_ROWS` keeps only the rows named in it (comma-separated, e.g. `closest point,ecs batch
//! closest point`) and runs only our side of them, once, printing a fingerprint of every answer (a hash of
//! their `Debug` forms, to check that a change leaves them bit for bit as they were) unless
//! `KINETRACE_QUERY_FINGERPRINT=0` (the hashing costs about as much as the queries);
//! `KINETRACE_QUERY_REPS=n` repeats them `n` times and prints the least thread CPU time of the timed frames
//! (refit + queries; time slices lost to other processes do not count, so builds compare on a loaded
//! machine); `KINETRACE_QUERY_SIDE=parry` runs parry3d's side of the direct rows instead.

use crate::cpu::one_thread;
use crate::record::{CpuClock, Records, cpu_seconds, machine};
use bevy_ecs::prelude::*;
use glam::Quat;
use glam::Vec3;
use kinetrace::bvh::BuildOptions;
use kinetrace::ecs::{
    KinetracePlugin, Plugin, QueryFilter, ShapeQueue, ShapeResults, TraceMesh, VertexPositions,
};
use kinetrace::queries::Shape;
use kinetrace::scenes::bumpy_torus;
use kinetrace::{Mesh, MeshBvh};
use parry3d::math::{Pose, Vector};
use parry3d::query::{PointQuery, ShapeCastOptions, cast_shapes, intersection_test};
use parry3d::shape::{Ball, Capsule, Cuboid, TriMesh, TriMeshFlags};
use std::hash::{Hash, Hasher};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

const SUITE: &str = "queries";

#[derive(Clone, Copy, Debug, PartialEq)]
enum Kind {
    SphereCast,
    CapsuleCast,
    ClosestPoint,
    Containment,
    SphereOverlap,
    CapsuleOverlap,
    BoxOverlap,
    /// Closest points through the ECS batch.
    EcsClosestPoint,
    /// Sphere overlaps through the ECS batch.
    EcsSphereOverlap,
}

const KINDS: [Kind; 9] = [
    Kind::SphereCast,
    Kind::CapsuleCast,
    Kind::ClosestPoint,
    Kind::Containment,
    Kind::SphereOverlap,
    Kind::CapsuleOverlap,
    Kind::BoxOverlap,
    Kind::EcsClosestPoint,
    Kind::EcsSphereOverlap,
];

impl Kind {
    fn name(self) -> &'static str {
        match self {
            Kind::SphereCast => "sphere cast",
            Kind::CapsuleCast => "capsule cast",
            Kind::ClosestPoint => "closest point",
            Kind::Containment => "containment",
            Kind::SphereOverlap => "sphere overlap",
            Kind::CapsuleOverlap => "capsule overlap",
            Kind::BoxOverlap => "box overlap",
            Kind::EcsClosestPoint => "ecs batch closest point",
            Kind::EcsSphereOverlap => "ecs batch sphere overlap",
        }
    }

    /// The immediate query a batched kind asks (parry answers that one).
    fn immediate(self) -> Kind {
        match self {
            Kind::EcsClosestPoint => Kind::ClosestPoint,
            Kind::EcsSphereOverlap => Kind::SphereOverlap,
            k => k,
        }
    }
}

/// One query's input: a point (the cast's start, the overlap's centre), a second point (the cast's
/// target or the capsule's other end) and a radius.
struct Query {
    p: Vec3,
    q: Vec3,
    r: f32,
}

impl Query {
    /// The overlap shape of an overlap kind: centred on the target vertex, a capsule or box across the
    /// direction towards it.
    fn overlap_shape(&self, kind: Kind) -> Shape {
        let dir = (self.q - self.p).normalize();
        match kind {
            Kind::CapsuleOverlap => Shape::capsule(
                self.q,
                self.q + dir.any_orthonormal_vector() * self.r * 3.0,
                self.r,
            ),
            Kind::BoxOverlap => Shape::cuboid(
                self.q,
                Vec3::new(1.4, 0.6, 1.0) * self.r,
                Quat::from_rotation_arc(Vec3::Z, dir),
            ),
            _ => Shape::sphere(self.q, self.r),
        }
    }
}

pub fn run(rec: &mut Records) {
    println!("suite queries on {}", machine());
    let (tris, frames, n) = if rec.quick {
        (20_000, 4, 2_000)
    } else {
        (200_000, 10, 20_000)
    };
    let rest = bumpy_torus(tris);
    let poses: Vec<Vec<Vec3>> = (0..frames).map(|f| deform(&rest, f as f32)).collect();
    let queries = sample(&rest, n);
    let scene = format!("deforming torus {}k", rest.triangle_count() / 1000);
    let only = std::env::var("KINETRACE_QUERY_ROWS").ok();
    let hashing = std::env::var("KINETRACE_QUERY_FINGERPRINT").map_or(true, |v| v != "0");
    PROFILING.store(only.is_some() && hashing, Ordering::Relaxed);
    THREAD_CLOCK.store(only.is_some(), Ordering::Relaxed);
    let parry_side =
        only.is_some() && std::env::var("KINETRACE_QUERY_SIDE").is_ok_and(|s| s == "parry");
    for kind in KINDS {
        let count = (frames * n) as f64;
        let reps = match &only {
            Some(rows) if !rows.split(',').any(|r| r.trim() == kind.name()) => continue,
            Some(_) => std::env::var("KINETRACE_QUERY_REPS").map_or(1, |r| r.parse().unwrap_or(1)),
            None => rec.reps(),
        };
        let ours = one_thread(|| {
            best(reps, || match kind {
                Kind::EcsClosestPoint | Kind::EcsSphereOverlap => {
                    ecs_frames(kind, &rest, &poses, &queries)
                }
                _ if parry_side => parry_frames(kind.immediate(), &rest, &poses, &queries),
                _ => kinetrace_frames(kind, &rest, &poses, &queries),
            })
        });
        if only.is_some() {
            println!(
                "  {} {}: {} answers, fingerprint {:016x}, best of {reps}: {:.2} ms thread CPU time",
                if parry_side { "parry3d" } else { "kinetrace" },
                kind.name(),
                ours.1,
                FINGERPRINT.swap(0, Ordering::Relaxed),
                ours.0.as_secs_f64() * 1e3
            );
            continue;
        }
        let theirs = best(rec.reps(), || {
            parry_frames(kind.immediate(), &rest, &poses, &queries)
        });
        let per_s = |t: Duration| count / t.as_secs_f64() / 1e3;
        rec.add(
            SUITE,
            &scene,
            "kinetrace",
            kind.name(),
            per_s(ours.0),
            "k/s",
        );
        rec.add(
            SUITE,
            &scene,
            "parry3d 0.31",
            kind.name(),
            per_s(theirs.0),
            "k/s",
        );
        rec.add(
            SUITE,
            &scene,
            "kinetrace / parry3d",
            kind.name(),
            theirs.0.as_secs_f64() / ours.0.as_secs_f64(),
            "x",
        );
        if ours.1 != theirs.1 {
            println!(
                "  ({}: {} answers vs parry's {})",
                kind.name(),
                ours.1,
                theirs.1
            );
        }
    }
}

/// Whether the run profiles (`KINETRACE_QUERY_ROWS`): answers are then folded into [`FINGERPRINT`].
static PROFILING: AtomicBool = AtomicBool::new(false);

/// A hash of every answer of the profiled row (its `Debug` form: point, distance, triangle,
/// barycentrics, feature, entity), to check that a change leaves the answers bit for bit as they were.
static FINGERPRINT: AtomicU64 = AtomicU64::new(0);

/// Folds `answer` into [`FINGERPRINT`] when profiling; one relaxed load otherwise.
fn fingerprint(answer: &impl std::fmt::Debug) {
    if PROFILING.load(Ordering::Relaxed) {
        let mut h = std::hash::DefaultHasher::new();
        FINGERPRINT.load(Ordering::Relaxed).hash(&mut h);
        format!("{answer:?}").hash(&mut h);
        FINGERPRINT.store(h.finish(), Ordering::Relaxed);
    }
}

/// Whether the frames are timed in this thread's CPU time (when profiling: time slices lost to other
/// processes do not count, so two builds compare on a loaded machine) rather than wall time.
static THREAD_CLOCK: AtomicBool = AtomicBool::new(false);

/// The time of a row's frames: wall time, or this thread's CPU time under [`THREAD_CLOCK`].
struct Timer(Instant, f64);

impl Timer {
    fn start() -> Timer {
        let cpu = THREAD_CLOCK.load(Ordering::Relaxed);
        Timer(
            Instant::now(),
            if cpu {
                cpu_seconds(CpuClock::Thread)
            } else {
                0.0
            },
        )
    }

    fn elapsed(&self) -> Duration {
        if THREAD_CLOCK.load(Ordering::Relaxed) {
            Duration::from_secs_f64(cpu_seconds(CpuClock::Thread) - self.1)
        } else {
            self.0.elapsed()
        }
    }
}

/// The least time of `reps` runs of `f`, and its answer count.
fn best(reps: usize, mut f: impl FnMut() -> (Duration, usize)) -> (Duration, usize) {
    (0..reps.max(1))
        .map(|_| f())
        .min_by_key(|r| r.0)
        .expect("one run")
}

/// The torus twisted about its axis and rippled, by an amount that changes with `f`.
fn deform(rest: &Mesh, f: f32) -> Vec<Vec3> {
    rest.positions()
        .iter()
        .map(|p| {
            let a = 0.3 * p.y * (0.7 * f).sin();
            let (s, c) = a.sin_cos();
            Vec3::new(p.x * c - p.z * s, p.y, p.x * s + p.z * c)
                + Vec3::Y * 0.03 * (4.0 * p.x + f).sin()
        })
        .collect()
}

/// Queries around the mesh: points uniform in its box grown by a fifth, targets on its vertices, radii a
/// few hundredths of its size.
fn sample(m: &Mesh, n: usize) -> Vec<Query> {
    let mut rng = kinetrace::scenes::SceneRng::new(11);
    let b = m
        .positions()
        .iter()
        .fold(kinetrace::Aabb::EMPTY, |mut b, p| {
            b.grow(*p);
            b
        });
    let size = b.extent().length();
    let (lo, hi) = (b.min - b.extent() * 0.2, b.max + b.extent() * 0.2);
    (0..n)
        .map(|_| {
            let p = lo + (hi - lo) * Vec3::new(rng.unit(), rng.unit(), rng.unit());
            let target = m.positions()[(rng.next_u64() % m.positions().len() as u64) as usize];
            Query {
                p,
                q: target,
                r: size * rng.range(0.005, 0.03),
            }
        })
        .collect()
}

/// Refit + the queries, every frame, on our tree; the time and the number of hits (or inside points,
/// or overlapped triangles).
fn kinetrace_frames(
    kind: Kind,
    rest: &Mesh,
    poses: &[Vec<Vec3>],
    queries: &[Query],
) -> (Duration, usize) {
    let mut bvh = MeshBvh::build(rest, &BuildOptions::default()).expect("a valid mesh");
    let mut found = Vec::new();
    let mut answers = 0;
    let t = Timer::start();
    for pos in poses {
        bvh.refit(pos).expect("same vertex count");
        for q in queries {
            answers += match kind {
                Kind::SphereCast => {
                    let dir = (q.q - q.p).normalize();
                    bvh.cast_sphere(q.p, dir, q.r, f32::INFINITY).is_some() as usize
                }
                Kind::CapsuleCast => {
                    let dir = (q.q - q.p).normalize();
                    let b = q.p + dir.any_orthonormal_vector() * q.r * 3.0;
                    bvh.cast_capsule(q.p, b, dir, q.r, f32::INFINITY).is_some() as usize
                }
                Kind::ClosestPoint => {
                    let hit = bvh.closest_point(q.p, f32::INFINITY);
                    fingerprint(&hit);
                    hit.is_some() as usize
                }
                Kind::Containment => bvh.contains_point(q.p) as usize,
                Kind::SphereOverlap | Kind::CapsuleOverlap | Kind::BoxOverlap => {
                    bvh.overlapping(&q.overlap_shape(kind), &mut found);
                    fingerprint(&found);
                    found.len()
                }
                Kind::EcsClosestPoint | Kind::EcsSphereOverlap => {
                    unreachable!("batched kinds run in ecs_frames")
                }
            };
        }
    }
    (t.elapsed(), answers)
}

/// The batched kinds through a `bevy_ecs` world: each frame the new positions go in, the queries are
/// queued, and the plugin's schedule maintains the mesh and answers them. The answer count as in
/// [`kinetrace_frames`].
fn ecs_frames(
    kind: Kind,
    rest: &Mesh,
    poses: &[Vec<Vec3>],
    queries: &[Query],
) -> (Duration, usize) {
    let mut world = World::new();
    let mut schedule = Schedule::default();
    schedule.set_executor(bevy_ecs::schedule::SingleThreadedExecutor::new());
    KinetracePlugin::default().build(&mut world, &mut schedule);
    let e = world
        .spawn((
            TraceMesh(rest.clone()),
            VertexPositions(rest.positions().to_vec()),
        ))
        .id();
    // The first frame builds the tree and the second profiles the new mesh (the characteriser runs
    // before maintenance), as the immediate side's build before its clock starts: once per mesh.
    for _ in 0..2 {
        schedule.run(&mut world);
        world.clear_trackers();
    }
    let mut answers = 0;
    let t = Timer::start();
    for pos in poses {
        world
            .get_mut::<VertexPositions>(e)
            .expect("spawned")
            .0
            .copy_from_slice(pos);
        let mut queue = world.resource_mut::<ShapeQueue>();
        for (tag, q) in queries.iter().enumerate() {
            let filter = QueryFilter::default();
            match kind {
                Kind::EcsClosestPoint => {
                    queue.closest_point(tag as u64, q.p, f32::INFINITY, filter)
                }
                _ => queue.overlap(tag as u64, Shape::sphere(q.q, q.r), filter),
            }
        }
        schedule.run(&mut world);
        world.clear_trackers();
        let res = world.resource::<ShapeResults>();
        fingerprint(&res.closest);
        fingerprint(&res.overlaps);
        answers += match kind {
            Kind::EcsClosestPoint => res.closest.iter().filter(|c| c.1.is_some()).count(),
            _ => res.overlaps.iter().map(|o| o.1.len()).sum(),
        };
    }
    (t.elapsed(), answers)
}

/// The same on parry3d's `TriMesh`, updated with `set_vertices` each frame.
fn parry_frames(
    kind: Kind,
    rest: &Mesh,
    poses: &[Vec<Vec3>],
    queries: &[Query],
) -> (Duration, usize) {
    let v = |x: Vec3| Vector::new(x.x, x.y, x.z);
    // parry's inside test reads the winding (outward counter-clockwise faces); ours does not.
    let p = rest.positions();
    let volume: f64 = rest
        .indices()
        .chunks(3)
        .map(|t| {
            let [a, b, c] = [0, 1, 2].map(|k| p[t[k] as usize].as_dvec3());
            a.dot(b.cross(c))
        })
        .sum();
    let idx: Vec<[u32; 3]> = rest
        .indices()
        .chunks(3)
        .map(|t| {
            if volume >= 0.0 {
                [t[0], t[1], t[2]]
            } else {
                [t[0], t[2], t[1]]
            }
        })
        .collect();
    let flags = if kind == Kind::Containment {
        TriMeshFlags::DEFORMABLE | TriMeshFlags::ORIENTED
    } else {
        TriMeshFlags::DEFORMABLE
    };
    let verts: Vec<Vector> = rest.positions().iter().map(|&p| v(p)).collect();
    let mut mesh = TriMesh::with_flags(verts, idx, flags).expect("a valid parry mesh");
    let frames: Vec<Vec<Vector>> = poses
        .iter()
        .map(|p| p.iter().map(|&x| v(x)).collect())
        .collect();
    let mut found = Vec::new();
    let mut answers = 0;
    let t = Timer::start();
    for pos in &frames {
        mesh.set_vertices(pos);
        for q in queries {
            let dir = (q.q - q.p).normalize();
            let cast = |pose: Pose, shape: &dyn parry3d::shape::Shape| {
                let options = ShapeCastOptions::with_max_time_of_impact(f32::MAX);
                cast_shapes(
                    &pose,
                    v(dir),
                    shape,
                    &Pose::IDENTITY,
                    Vector::ZERO,
                    &mesh,
                    options,
                )
                .expect("supported shapes")
                .is_some() as usize
            };
            answers += match kind {
                Kind::SphereCast => cast(Pose::from_translation(v(q.p)), &Ball::new(q.r)),
                Kind::CapsuleCast => {
                    let b = q.p + dir.any_orthonormal_vector() * q.r * 3.0;
                    cast(Pose::IDENTITY, &Capsule::new(v(q.p), v(b), q.r))
                }
                Kind::ClosestPoint => {
                    std::hint::black_box(mesh.project_point(&Pose::IDENTITY, v(q.p), false));
                    1
                }
                Kind::Containment => mesh.contains_point(&Pose::IDENTITY, v(q.p)) as usize,
                Kind::SphereOverlap | Kind::CapsuleOverlap | Kind::BoxOverlap => {
                    let shape = q.overlap_shape(kind);
                    let (at, parry_shape): (Pose, Box<dyn parry3d::shape::Shape>) = match shape {
                        Shape::Sphere { center, radius } => (
                            Pose::from_translation(v(center)),
                            Box::new(Ball::new(radius)),
                        ),
                        Shape::Capsule { a, b, radius } => {
                            (Pose::IDENTITY, Box::new(Capsule::new(v(a), v(b), radius)))
                        }
                        Shape::Box {
                            center,
                            half,
                            rotation,
                        } => (
                            Pose::from_parts(
                                v(center),
                                parry3d::glamx::Quat::from_array(rotation.to_array()),
                            ),
                            Box::new(Cuboid::new(v(half))),
                        ),
                    };
                    let aabb = parry_shape.compute_aabb(&at);
                    found.clear();
                    for leaf in mesh.bvh().intersect_aabb(&aabb) {
                        let tri = mesh.triangle(leaf);
                        if intersection_test(&at, parry_shape.as_ref(), &Pose::IDENTITY, &tri)
                            .expect("supported")
                            .intersecting
                        {
                            found.push(leaf);
                        }
                    }
                    found.sort_unstable();
                    found.len()
                }
                Kind::EcsClosestPoint | Kind::EcsSphereOverlap => {
                    unreachable!("parry answers the immediate kind")
                }
            };
        }
    }
    (t.elapsed(), answers)
}
