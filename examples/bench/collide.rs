//! Suite `collide`: discrete collision queries on animated meshes — two skinned 50k-triangle characters in
//! contact, a 64-character crowd through the ECS plugin, and a 32k-triangle cloth against itself — on one
//! thread and on all threads, with and without the BVTT front, and parry3d on the same meshes in the same
//! run: its own BVH (refitted per frame, like ours) traversed pair-wise with `leaf_pairs`, and its
//! triangle–triangle `intersection_test` on the pairs found. Refits are timed apart from queries; ratios
//! are given for queries alone and for refit + query.

use crate::record::{Records, machine};
use bevy_ecs::prelude::*;
use glam::{Affine3A, Mat4, Quat, Vec3};
use kinetrace::MeshBvh;
use kinetrace::anim::{CharacterAsset, humanoid, skin_positions};
use kinetrace::bvh::{BuildOptions, Builder};
use kinetrace::collide::{PairFront, PairQuery, PairStats, Placed};
use kinetrace::ecs::*;
use kinetrace::gpu::{GpuContext, GpuPairs};
use kinetrace::scenes::folded_sheet;
use kinetrace::{Mesh, collide::Contact};
use parry3d::bounding_volume::BoundingVolume;
use parry3d::partitioning::{Bvh, BvhBuildStrategy, BvhWorkspace};
use std::sync::Arc;
use std::time::{Duration, Instant};

const SUITE: &str = "collide";

pub fn run(rec: &mut Records) {
    println!("suite collide on {}", machine());
    two_characters(rec);
    cloth(rec);
    crowd(rec);
    let dup = DUPLICATES.load(std::sync::atomic::Ordering::Relaxed);
    rec.add(
        SUITE,
        "all",
        "parry leaf_pairs",
        "duplicate pairs",
        dup as f64,
        "pairs",
    );
}

/// Time and work of one way of running the queries, summed over frames.
#[derive(Default)]
struct Tally {
    time: Duration,
    stats: PairStats,
    contacts: usize,
}

impl Tally {
    fn add(&mut self, t: Duration, s: PairStats, contacts: usize) {
        self.time += t;
        self.stats.add(&s);
        self.contacts += contacts;
    }
}

/// Prints the rows of one scene: per frame query times, pair tests per second, the front's saving, and the
/// ratios to parry — queries alone, and with each library's refit of its trees (`refits`: ours, parry's).
fn report(
    rec: &mut Records,
    scene: &str,
    frames: usize,
    runs: &[(&str, Tally)],
    parry: &Tally,
    refits: [Duration; 2],
) {
    let per_frame = |t: Duration| t.as_secs_f64() * 1e3 / frames as f64;
    rec.add(
        SUITE,
        scene,
        "kinetrace refit",
        "time per frame",
        per_frame(refits[0]),
        "ms",
    );
    rec.add(
        SUITE,
        scene,
        "parry3d refit",
        "time per frame",
        per_frame(refits[1]),
        "ms",
    );
    for (name, t) in runs.iter().filter(|(_, t)| t.time > Duration::ZERO) {
        rec.add(
            SUITE,
            scene,
            name,
            "query per frame",
            per_frame(t.time),
            "ms",
        );
        rec.add(
            SUITE,
            scene,
            name,
            "pair tests",
            t.stats.triangle_tests as f64 / t.time.as_secs_f64() / 1e6,
            "M/s",
        );
        let ratio = |p: Duration, k: Duration| p.as_secs_f64() / k.as_secs_f64();
        rec.add(
            SUITE,
            scene,
            name,
            "parry / ours, query",
            ratio(parry.time, t.time),
            "x",
        );
        rec.add(
            SUITE,
            scene,
            name,
            "parry / ours, refit+query",
            ratio(parry.time + refits[1], t.time + refits[0]),
            "x",
        );
    }
    let (plain, front) = (&runs[0].1, &runs[1].1);
    rec.add(
        SUITE,
        scene,
        "front vs no front",
        "box tests saved",
        100.0 * (1.0 - front.stats.box_tests as f64 / plain.stats.box_tests as f64),
        "%",
    );
    rec.add(
        SUITE,
        scene,
        "parry3d 0.31",
        "query per frame",
        per_frame(parry.time),
        "ms",
    );
    rec.add(
        SUITE,
        scene,
        "contacts per frame",
        "kinetrace",
        plain.contacts as f64 / frames as f64,
        "pairs",
    );
    rec.add(
        SUITE,
        scene,
        "contacts per frame",
        "parry",
        parry.contacts as f64 / frames as f64,
        "pairs",
    );
}

/// The GPU path when an adapter exists: the trees' nodes uploaded, traversed by `GpuPairs`, the leaf
/// pairs tested on the CPU (all threads). Times include upload and read-back.
struct Gpu(Option<(GpuContext, GpuPairs)>);

impl Gpu {
    fn new(rec: &mut Records) -> Self {
        match rec.gpu() {
            Ok(ctx) => {
                let pairs = GpuPairs::new(&ctx);
                Gpu(Some((ctx, pairs)))
            }
            Err(e) => {
                println!("  (no GPU rows: {e})");
                Gpu(None)
            }
        }
    }

    fn run(
        &mut self,
        q: &mut PairQuery,
        a: Placed,
        b: Option<Placed>,
        out: &mut Vec<Contact>,
    ) -> (Duration, PairStats) {
        let Some((ctx, gp)) = &mut self.0 else {
            return (Duration::ZERO, PairStats::default());
        };
        let start = Instant::now();
        let stats = match b {
            Some(b) => {
                let b_to_a = a.to_world.inverse() * b.to_world;
                let pairs = gp
                    .leaf_pairs(
                        ctx,
                        a.mesh.bvh().nodes(),
                        Some((b.mesh.bvh().nodes(), &b_to_a)),
                    )
                    .expect("gpu");
                q.meshes_from_leaf_pairs(a, b, &pairs, out)
            }
            None => {
                let pairs = gp.leaf_pairs(ctx, a.mesh.bvh().nodes(), None).expect("gpu");
                q.itself_from_leaf_pairs(a, &pairs, out)
            }
        }
        .expect("valid pairs");
        (start.elapsed(), stats)
    }
}

/// A character's skinned positions at time `t` of its first clip.
fn pose(asset: &CharacterAsset, t: f32, mats: &mut Vec<Mat4>, out: &mut [Vec3]) {
    let mut pose = asset.skeleton.rest_pose();
    asset.clips[0].sample(t, &mut pose);
    mats.resize(pose.len(), Mat4::IDENTITY);
    asset.skeleton.skin_matrices(&pose, mats);
    skin_positions(asset.mesh.positions(), &asset.weights, mats, out).expect("valid skin");
}

/// parry's side of a scene: its BVH over one mesh's triangle boxes, refitted each frame.
struct ParryMesh {
    bvh: Bvh,
    workspace: BvhWorkspace,
    tris: Vec<parry3d::shape::Triangle>,
}

fn pv(p: Vec3) -> parry3d::math::Vector {
    parry3d::math::Vector::new(p.x, p.y, p.z)
}

impl ParryMesh {
    fn new(mesh: &Mesh, world: &[Vec3]) -> Self {
        let mut m = ParryMesh {
            bvh: Bvh::new(),
            workspace: BvhWorkspace::default(),
            tris: Vec::new(),
        };
        m.set(mesh, world);
        m.bvh = Bvh::from_leaves(
            BvhBuildStrategy::Binned,
            &m.tris.iter().map(|t| t.local_aabb()).collect::<Vec<_>>(),
        );
        m
    }

    fn set(&mut self, mesh: &Mesh, world: &[Vec3]) {
        self.tris.clear();
        self.tris.extend(mesh.indices().chunks_exact(3).map(|t| {
            parry3d::shape::Triangle::new(
                pv(world[t[0] as usize]),
                pv(world[t[1] as usize]),
                pv(world[t[2] as usize]),
            )
        }));
    }

    /// New positions, then parry's refit.
    fn refit(&mut self, mesh: &Mesh, world: &[Vec3]) {
        self.set(mesh, world);
        for (i, t) in self.tris.iter().enumerate() {
            self.bvh
                .insert_or_update_partially(t.local_aabb(), i as u32, 0.0);
        }
        self.bvh.refit(&mut self.workspace);
    }

    /// Touching triangle pairs between `self` and `other` (or within `self`, skipping neighbours), each
    /// pair once: `leaf_pairs` can yield a pair more than once, so they are collected, sorted and
    /// deduplicated (the cost is counted as parry's).
    fn touching(
        &self,
        other: Option<&ParryMesh>,
        indices: &[u32],
        found: &mut Vec<(u32, u32)>,
    ) -> usize {
        let id = parry3d::math::Pose::IDENTITY;
        let b = other.unwrap_or(self);
        found.clear();
        for (i, j) in self
            .bvh
            .leaf_pairs(&b.bvh, |x, y| x.aabb().intersects(&y.aabb()))
        {
            if other.is_none() {
                let (vi, vj) = (
                    &indices[3 * i as usize..][..3],
                    &indices[3 * j as usize..][..3],
                );
                if i >= j || vi.iter().any(|v| vj.contains(v)) {
                    continue;
                }
            }
            let (x, y) = (&self.tris[i as usize], &b.tris[j as usize]);
            if parry3d::query::intersection_test(&id, x, &id, y).is_ok_and(|r| r.intersecting) {
                found.push((i, j));
            }
        }
        let all = found.len();
        found.sort_unstable();
        found.dedup();
        if all != found.len() {
            DUPLICATES.fetch_add(all - found.len(), std::sync::atomic::Ordering::Relaxed);
        }
        found.len()
    }
}

/// Pairs parry's `leaf_pairs` yielded more than once (reported with the suite).
static DUPLICATES: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

fn world_positions(to_world: &Affine3A, object: &[Vec3], out: &mut Vec<Vec3>) {
    out.clear();
    out.extend(object.iter().map(|p| to_world.transform_point3(*p)));
}

/// A scene the suite animates, with our trees and parry's over it.
trait Scene {
    /// Moves to frame `f` (untimed) and refits our trees; returns the time of the refit.
    fn refit(&mut self, f: usize) -> Duration;
    /// The meshes to query: `b` is `None` for one mesh against itself.
    fn placed(&self) -> (Placed<'_>, Option<Placed<'_>>);
    /// parry on the current frame: refit time, query time, and the touching pairs it found.
    fn parry(&mut self, found: &mut Vec<(u32, u32)>) -> (Duration, Duration, usize);
}

/// One query of a scene's meshes, timed.
fn timed(
    (a, b): (Placed, Option<Placed>),
    q: &mut PairQuery,
    front: Option<&mut PairFront>,
    out: &mut Vec<Contact>,
) -> (Duration, PairStats) {
    let start = Instant::now();
    let stats = match (b, front) {
        (Some(b), Some(f)) => q.meshes_with_front(a, b, f, out),
        (Some(b), None) => q.meshes(a, b, out),
        (None, Some(f)) => q.itself_with_front(a, f, out),
        (None, None) => q.itself(a, out),
    }
    .expect("finite, invertible transforms");
    (start.elapsed(), stats)
}

/// Runs `frames` frames of a scene (after one warm-up frame) in every way, and reports them.
fn measure(rec: &mut Records, name: &str, frames: usize, scene: &mut impl Scene) {
    let mut runs = [
        ("kinetrace 1 thread", Tally::default()),
        ("kinetrace 1 thread + front", Tally::default()),
        ("kinetrace all threads", Tally::default()),
        ("kinetrace all threads + front", Tally::default()),
        ("kinetrace GPU traversal + CPU tests", Tally::default()),
    ];
    let mut gpu = Gpu::new(rec);
    let (mut parry, mut fronts) = (Tally::default(), [PairFront::new(), PairFront::new()]);
    let (mut serial, mut parallel) = (PairQuery::new().parallel(false), PairQuery::new());
    let (mut contacts, mut found) = (Vec::new(), Vec::new());
    let mut refits = [Duration::ZERO; 2];
    // Pass 0: the CPU rows and parry; pass 1: the GPU row alone (lavapipe's threads would otherwise compete
    // with the CPU rows' for the same cores).
    for (pass, f) in (0..2).flat_map(|p| (0..frames + 1).map(move |f| (p, f))) {
        let refit_time = scene.refit(f);
        let placed = scene.placed();
        if pass == 1 {
            let (t, s) = gpu.run(&mut parallel, placed.0, placed.1, &mut contacts);
            if f > 0 && t > Duration::ZERO {
                runs[4].1.add(t, s, contacts.len());
            }
            continue;
        }
        let r0 = timed(placed, &mut serial, None, &mut contacts);
        let n0 = contacts.len();
        let r1 = timed(placed, &mut serial, Some(&mut fronts[0]), &mut contacts);
        let r2 = timed(placed, &mut parallel, None, &mut contacts);
        let r3 = timed(placed, &mut parallel, Some(&mut fronts[1]), &mut contacts);
        let (parry_refit, parry_time, pn) = scene.parry(&mut found);
        if f == 0 {
            continue; // warm-up: fronts and caches
        }
        refits[0] += refit_time;
        refits[1] += parry_refit;
        for (run, (t, s)) in runs.iter_mut().zip([r0, r1, r2, r3]) {
            run.1.add(t, s, n0);
        }
        parry.add(parry_time, PairStats::default(), pn);
    }
    report(rec, name, frames, &runs, &parry, refits);
}

/// Two walking characters facing each other, arms and chests interpenetrating.
struct TwoCharacters {
    asset: CharacterAsset,
    place_b: Affine3A,
    mats: Vec<Mat4>,
    /// Skinned object-space positions of each, and `b`'s in world space (parry's input).
    pa: Vec<Vec3>,
    pb: Vec<Vec3>,
    wb: Vec<Vec3>,
    ta: MeshBvh,
    tb: MeshBvh,
    parry_a: ParryMesh,
    parry_b: ParryMesh,
}

impl TwoCharacters {
    fn new(triangles: usize) -> Self {
        let asset = humanoid(triangles);
        let place_b = Affine3A::from_rotation_translation(
            Quat::from_rotation_y(std::f32::consts::PI),
            Vec3::new(0.05, 0.0, 0.3),
        );
        let n = asset.mesh.positions().len();
        let (mut pa, mut pb, mut mats) = (vec![Vec3::ZERO; n], vec![Vec3::ZERO; n], Vec::new());
        pose(&asset, 0.0, &mut mats, &mut pa);
        pose(&asset, 0.5, &mut mats, &mut pb);
        let build = |p: &[Vec3]| {
            let mesh = asset.mesh.with_positions(p.to_vec()).expect("finite");
            MeshBvh::build(&mesh, &BuildOptions::new(Builder::SAH)).expect("build")
        };
        let (ta, tb) = (build(&pa), build(&pb));
        let mut wb = Vec::new();
        world_positions(&place_b, &pb, &mut wb);
        let (parry_a, parry_b) = (
            ParryMesh::new(&asset.mesh, &pa),
            ParryMesh::new(&asset.mesh, &wb),
        );
        TwoCharacters {
            asset,
            place_b,
            mats,
            pa,
            pb,
            wb,
            ta,
            tb,
            parry_a,
            parry_b,
        }
    }
}

impl Scene for TwoCharacters {
    fn refit(&mut self, f: usize) -> Duration {
        let t = f as f32 / 30.0;
        pose(&self.asset, t, &mut self.mats, &mut self.pa);
        pose(&self.asset, t + 0.5, &mut self.mats, &mut self.pb);
        let start = Instant::now();
        self.ta.refit(&self.pa).expect("finite");
        self.tb.refit(&self.pb).expect("finite");
        start.elapsed()
    }

    fn placed(&self) -> (Placed<'_>, Option<Placed<'_>>) {
        (
            Placed::new(&self.ta, Affine3A::IDENTITY),
            Some(Placed::new(&self.tb, self.place_b)),
        )
    }

    fn parry(&mut self, found: &mut Vec<(u32, u32)>) -> (Duration, Duration, usize) {
        world_positions(&self.place_b, &self.pb, &mut self.wb);
        let start = Instant::now();
        self.parry_a.refit(&self.asset.mesh, &self.pa);
        self.parry_b.refit(&self.asset.mesh, &self.wb);
        let refit = start.elapsed();
        let n = self
            .parry_a
            .touching(Some(&self.parry_b), self.asset.mesh.indices(), found);
        (refit, start.elapsed() - refit, n)
    }
}

fn two_characters(rec: &mut Records) {
    let mut scene = TwoCharacters::new(if rec.quick { 20_000 } else { 50_000 });
    let name = format!(
        "2 characters x {}k tris in contact",
        scene.asset.mesh.triangle_count() / 1000
    );
    measure(rec, &name, if rec.quick { 6 } else { 30 }, &mut scene);
}

/// A folded cloth sheet of `n × n` quads waving through itself.
struct Cloth {
    n: u32,
    mesh: Mesh,
    pos: Vec<Vec3>,
    tree: MeshBvh,
    parry: ParryMesh,
}

impl Scene for Cloth {
    fn refit(&mut self, f: usize) -> Duration {
        self.pos
            .copy_from_slice(folded_sheet(self.n, f as f32 * 0.05).positions());
        let start = Instant::now();
        self.tree.refit(&self.pos).expect("finite");
        start.elapsed()
    }

    fn placed(&self) -> (Placed<'_>, Option<Placed<'_>>) {
        (Placed::new(&self.tree, Affine3A::IDENTITY), None)
    }

    fn parry(&mut self, found: &mut Vec<(u32, u32)>) -> (Duration, Duration, usize) {
        let start = Instant::now();
        self.parry.refit(&self.mesh, &self.pos);
        let refit = start.elapsed();
        let n = self.parry.touching(None, self.mesh.indices(), found);
        (refit, start.elapsed() - refit, n)
    }
}

fn cloth(rec: &mut Records) {
    let n = if rec.quick { 64 } else { 128 };
    let mesh = folded_sheet(n, 0.0);
    let pos = mesh.positions().to_vec();
    let tree = MeshBvh::build(&mesh, &BuildOptions::new(Builder::SAH)).expect("build");
    let parry = ParryMesh::new(&mesh, &pos);
    let name = format!(
        "cloth {}k tris against itself",
        mesh.triangle_count() / 1000
    );
    let mut scene = Cloth {
        n,
        mesh,
        pos,
        tree,
        parry,
    };
    measure(rec, &name, if rec.quick { 6 } else { 30 }, &mut scene);
}

/// 64 walking 10k-triangle characters close enough to touch, as colliders in the ECS plugin (top-level
/// culling, refits by the plugin): 1 thread, all threads, and all threads with per-pair fronts.
fn crowd(rec: &mut Records) {
    let frames = if rec.quick { 5 } else { 30 };
    let asset = Arc::new(humanoid(10_000));
    let scene = "crowd of 64 x 10k tris, ECS".to_string();
    for (threads, fronts) in [(1, false), (0, false), (0, true)] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("a pool");
        let mut world = World::new();
        let mut schedule = Schedule::default();
        schedule.set_executor(bevy_ecs::schedule::SingleThreadedExecutor::new());
        KinetracePlugin::default().build(&mut world, &mut schedule);
        world.insert_resource(CollisionSettings { fronts });
        for i in 0..64 {
            let at = Vec3::new((i % 8) as f32 * 0.7, 0.0, (i / 8) as f32 * 0.7);
            world.spawn((
                AnimationPlayer::bundle(&asset, i % asset.clips.len(), i as f32 * 0.1),
                TraceTransform(Affine3A::from_translation(at)),
                Collider::default(),
            ));
        }
        let (mut time, mut pairs, mut contacts, mut stats) =
            (Duration::ZERO, 0, 0, PairStats::default());
        pool.install(|| {
            for f in 0..frames + 1 {
                schedule.run(&mut world);
                world.clear_trackers();
                if f == 0 {
                    continue;
                }
                let c = world.resource::<Contacts>();
                time += c.time;
                pairs += c.pairs().len();
                contacts += c.pairs().iter().map(|p| c.contacts(p).len()).sum::<usize>();
                stats.add(&c.stats);
            }
        });
        let name = match (threads, fronts) {
            (1, _) => "ECS collide pass, 1 thread",
            (_, false) => "ECS collide pass, all threads",
            (_, true) => "ECS collide pass, all threads + fronts",
        };
        rec.add(
            SUITE,
            &scene,
            name,
            "time per frame",
            time.as_secs_f64() * 1e3 / frames as f64,
            "ms",
        );
        rec.add(
            SUITE,
            &scene,
            name,
            "pair tests",
            stats.triangle_tests as f64 / time.as_secs_f64() / 1e6,
            "M/s",
        );
        rec.add(
            SUITE,
            &scene,
            name,
            "touching pairs",
            pairs as f64 / frames as f64,
            "entities",
        );
        rec.add(
            SUITE,
            &scene,
            name,
            "contacts",
            contacts as f64 / frames as f64,
            "tri pairs",
        );
    }
}
