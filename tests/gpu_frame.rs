//! The GPU-resident frame (`TraceConfig::resident`) against the CPU mode, on lavapipe in CI: a few small
//! animated humanoids (4 × about 600 triangles, skinned on the GPU) on a static ground, 16 frames of closest-hit rays and
//! shadow segments. Kept small for a software adapter: it runs in seconds.
//!
//! Checked per frame: every batched answer equals the CPU mode's for the same frame (same entity,
//! triangle, distance, barycentrics and point, bit for bit — the GPU builds its own trees, so this holds
//! because no traversal culls a box at the current `tmax` exactly; the normal within 4 ulp, see
//! `assert_same_answers`); one submission; no blocking wait under
//! `Latency::NextFrame`, at most one under `SameFrame`; and after the first frame the bytes uploaded do not
//! depend on the characters' triangle counts and are exactly the joint matrices, instances and requests
//! (no vertex data). Immediate queries read the CPU's world: it holds the mirrored characters, not those
//! marked `GpuOnly`.
//!
//! Also: 300 frames of the crowd as colliders, whose contact pairs equal the CPU mode's; a custom rebuild
//! policy's decisions carried out on the resident trees; per-phase GPU times where the device has
//! timestamp queries.
#![cfg(feature = "gpu")]

mod common;
use bevy_ecs::entity::Entity;
use common::ecs::app_with;
use common::*;
use glam::{Affine3A, Vec3};
use kinetrace::Ray;
use kinetrace::anim::humanoid;
use kinetrace::ecs::*;
use kinetrace::gpu::GpuCounters;
use std::collections::BTreeMap;
use std::sync::Arc;

const CHARACTERS: usize = 4;
const FRAMES: u64 = 16;
const RAYS: usize = 48;
const SHADOWS: usize = 24;

/// Answers by the frame they answer.
type Answers = BTreeMap<u64, RayResults>;

/// Frame `f`'s `rays` rays and [`SHADOWS`] shadow segments: aimed from in front of the crowd through it.
/// Every fourth ray starts 3 further on, inside the crowd, and reaches back to where the others start
/// (`tmin = -3`): its hits may lie behind its origin.
fn requests(f: u64, rays: usize) -> (Vec<Ray>, Vec<(Vec3, Vec3)>) {
    let mut r = rng(15 + f);
    let spread = |r: &mut _, lo, hi, scale: Vec3, shift: Vec3| rand_vec(r, lo, hi) * scale + shift;
    let rays = (0..rays)
        .map(|i| {
            let from = spread(&mut r, -1.0, 3.5, Vec3::new(1.0, 0.6, 0.0), Vec3::Z * -3.0);
            let to = spread(&mut r, -0.5, 3.2, Vec3::new(1.0, 0.7, 0.3), Vec3::ZERO);
            let d = (to - from).normalize();
            if i % 4 == 0 {
                Ray::with_range(from + 3.0 * d, d, -3.0, f32::INFINITY)
            } else {
                Ray::new(from, d)
            }
        })
        .collect();
    let shadows = (0..SHADOWS)
        .map(|_| {
            let shift = |z| Vec3::new(0.0, 0.1, z);
            let from = spread(&mut r, -0.5, 3.0, Vec3::new(1.0, 0.6, 0.0), shift(-2.0));
            let to = spread(&mut r, -0.5, 3.0, Vec3::new(1.0, 0.6, 0.0), shift(2.5));
            (from, to)
        })
        .collect();
    (rays, shadows)
}

struct Run {
    answers: Answers,
    /// Batched rays requested per frame (the crowd's).
    rays: usize,
    /// Per frame the GPU traffic counted.
    counters: Vec<GpuCounters>,
    /// Per frame what the resident frame did, in all and per mesh.
    resident: Vec<ResidentStats>,
    meshes: Vec<Vec<MeshStats>>,
    /// The characters in spawn order (entity ids differ between worlds: resources are entities too).
    spawned: Vec<Entity>,
    /// Characters the CPU's world holds at the end (what immediate queries see).
    on_cpu: usize,
    /// Per frame (the frame the contacts are of), the touching pairs as spawn indices with their
    /// triangle pairs, sorted.
    contacts: BTreeMap<u64, ContactPairs>,
}

/// A frame's touching pairs: (character a, character b, triangle pairs).
type ContactPairs = Vec<(usize, usize, Vec<[u32; 2]>)>;

impl Run {
    /// Which character `e` is.
    fn character(&self, e: Entity) -> usize {
        self.spawned
            .iter()
            .position(|&s| s == e)
            .expect("a character")
    }
}

/// The crowd a run animates.
#[derive(Clone, Copy)]
struct Crowd {
    /// Triangles per character (about).
    triangles: usize,
    /// Characters without a CPU mirror.
    gpu_only: bool,
    /// Frames of requests.
    frames: u64,
    /// Distance between neighbours along x.
    spacing: f32,
    /// Characters are colliders (the first also with itself).
    colliders: bool,
    /// Starting capacity of the resident frame's pair buffers (the test hook), if forced.
    pair_capacity: Option<u32>,
    /// Characters with two blend shapes at nonzero weights.
    morphs: bool,
    /// Batched rays per frame.
    rays: usize,
    /// Animation seconds per frame.
    clock: f32,
}

impl Crowd {
    /// The queries-only crowd of the short tests.
    const fn queries(triangles: usize, gpu_only: bool) -> Self {
        Crowd {
            triangles,
            gpu_only,
            frames: FRAMES,
            spacing: 0.9,
            colliders: false,
            pair_capacity: None,
            morphs: false,
            rays: RAYS,
            clock: 1.0 / 60.0,
        }
    }

    /// The crowd of the longer tests: 60 frames under 2,000 rays, `clock` animation seconds a frame.
    const fn busy(clock: f32) -> Self {
        Crowd {
            frames: 60,
            rays: 2000,
            clock,
            ..Crowd::queries(300, false)
        }
    }
}

/// The rest of a game's frame: returns once the GPU has finished the frames submitted so far, as the
/// no-wait assertions presume ("never reached while the GPU keeps up"). This loop's frames are far
/// shorter than a game's, and a fast GPU (an H100: hundreds of small dispatches a frame) falls behind
/// them, fills the queue of batches, and the frame then waits by design.
fn keep_up(world: &bevy_ecs::world::World) {
    let Some(gpu) = world.get_resource::<GpuQueries>() else {
        return;
    };
    let start = std::time::Instant::now();
    while !gpu.caught_up() && start.elapsed() < std::time::Duration::from_secs(10) {
        std::thread::sleep(std::time::Duration::from_micros(200));
    }
}

/// `crowd` in the CPU mode, then its characters GPU-only in the resident frame under `config`.
fn cpu_and_gpu_only(config: TraceConfig, crowd: Crowd) -> (Run, Run) {
    let cpu = run(TraceConfig::default(), crowd);
    let gpu = run(
        config,
        Crowd {
            gpu_only: true,
            ..crowd
        },
    );
    (cpu, gpu)
}

/// Runs `crowd.frames` frames (then, for `NextFrame`, empty frames until the last answers are in) of the
/// crowd under `config` with the same requests every time.
fn run(config: TraceConfig, crowd: Crowd) -> Run {
    let Crowd {
        triangles,
        gpu_only,
        frames,
        ..
    } = crowd;
    let next_frame = config.latency == Latency::NextFrame;
    let (mut world, mut schedule) = app_with(config);
    world.insert_resource(kinetrace::ecs::AnimationClock { delta: crowd.clock });
    // The CPU mode has no GPU state: the capacity concerns the resident run only.
    if let (Some(c), Some(mut gpu)) = (crowd.pair_capacity, world.get_resource_mut::<GpuQueries>())
    {
        gpu.start_pair_capacity(c);
    }
    let asset = humanoid(triangles);
    let asset = Arc::new(if crowd.morphs {
        with_morphs(asset)
    } else {
        asset
    });
    // A static ground under the crowd: a mesh the resident frame uploads once and never touches again.
    let ground = kinetrace::Mesh::new(
        [(-2.0, -2.0), (5.0, -2.0), (5.0, 3.0), (-2.0, 3.0)].map(|(x, z)| Vec3::new(x, 0.0, z)),
        vec![0, 2, 1, 0, 3, 2],
    )
    .unwrap();
    let mut spawned = vec![world.spawn((TraceMesh(ground), MotionHint::Static)).id()];
    for k in 0..CHARACTERS {
        let clip = k % asset.clips.len();
        let at = Vec3::new(k as f32 * crowd.spacing, 0.0, (k % 2) as f32 * 0.7);
        let mut e = world.spawn(AnimationPlayer::bundle(&asset, clip, 0.13 * k as f32));
        e.insert(TraceTransform(Affine3A::from_translation(at)));
        if gpu_only {
            e.insert(GpuOnly);
        }
        if crowd.colliders {
            e.insert(Collider {
                self_collision: k == 0,
                ..Default::default()
            });
        }
        spawned.push(e.id());
    }
    let mut out = Run {
        answers: Answers::new(),
        rays: crowd.rays,
        counters: Vec::new(),
        resident: Vec::new(),
        meshes: Vec::new(),
        spawned,
        on_cpu: 0,
        contacts: BTreeMap::new(),
    };
    let mut frame = 0;
    while frame < frames
        || (next_frame && !out.answers.contains_key(&frames) && frame < frames + 400)
    {
        frame += 1;
        if frame <= frames {
            let (rays, shadows) = requests(frame, crowd.rays);
            let mut queue = world.resource_mut::<RayQueue>();
            for (i, ray) in rays.into_iter().enumerate() {
                queue.cast(i as u64, ray, QueryFilter::default());
            }
            for (i, (from, to)) in shadows.into_iter().enumerate() {
                queue.shadow(i as u64, from, to, QueryFilter::default());
            }
        } else {
            // Draining: give the GPU time to finish without blocking in the frame.
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        if next_frame {
            keep_up(&world);
        }
        schedule.run(&mut world);
        world.clear_trackers();
        let results = world.resource::<RayResults>().clone();
        if !results.hits.is_empty() || !results.shadows.is_empty() {
            out.answers.insert(results.frame, results);
        }
        if crowd.colliders {
            let c = world.resource::<Contacts>();
            let pairs = (c.pairs().iter())
                .map(|p| {
                    let mut tris: Vec<[u32; 2]> = (c.contacts(p).iter())
                        .map(|t| [t.triangle_a, t.triangle_b])
                        .collect();
                    tris.sort_unstable();
                    (out.character(p.a), out.character(p.b), tris)
                })
                .collect();
            out.contacts.insert(c.frame, pairs);
        }
        if frame <= frames {
            out.counters.push(world.resource::<TraceStats>().gpu);
            let stats = world.resource::<TraceStats>();
            out.resident.push(stats.resident);
            out.meshes.push(stats.resident_meshes.clone());
        }
    }
    let cpu_world = world.resource::<TraceWorld>();
    out.on_cpu = out
        .spawned
        .iter()
        .filter(|&&e| cpu_world.contains(e))
        .count();
    out
}

/// `asset` with two blend shapes (a widening and a ripple) at weights 0.8 and -0.5.
fn with_morphs(mut asset: kinetrace::anim::CharacterAsset) -> kinetrace::anim::CharacterAsset {
    let rest = asset.mesh.positions();
    let widen = rest
        .iter()
        .map(|p| Vec3::new(p.x, 0.0, p.z) * 0.1)
        .collect();
    let ripple = (rest.iter())
        .map(|p| Vec3::Y * 0.05 * (7.0 * p.x).sin())
        .collect();
    asset.morphs = Some(Arc::new(kinetrace::anim::MorphTargets {
        deltas: vec![widen, ripple],
        default_weights: vec![0.8, -0.5],
    }));
    asset
}

/// Every frame's GPU answers equal the CPU mode's, and the requests are not all misses or all hits.
fn assert_same_answers(cpu: &Run, gpu: &Run, what: &str) {
    let frames = cpu.counters.len();
    let hits: usize = (cpu.answers.values())
        .map(|a| a.hits.iter().filter(|h| h.1.is_some()).count())
        .sum();
    let blocked: usize = (cpu.answers.values())
        .map(|a| a.shadows.iter().filter(|s| s.1).count())
        .sum();
    eprintln!("{what}: {hits} hits, {blocked} blocked");
    assert_eq!(cpu.rays, gpu.rays, "{what}: the same requests");
    let (rays, shadows) = (cpu.rays * frames, SHADOWS * frames);
    assert!(hits > rays / 5 && hits < rays, "{hits} of {rays} rays hit");
    assert!(
        blocked > shadows / 10 && blocked < shadows,
        "{blocked} of {shadows} blocked"
    );
    for f in 1..=frames as u64 {
        let (c, g) = (&cpu.answers[&f], &gpu.answers[&f]);
        assert_eq!(c.hits.len(), cpu.rays, "{what} frame {f}");
        assert_eq!(g.hits.len(), cpu.rays, "{what} frame {f}");
        for ((tag, ch), (gtag, gh)) in c.hits.iter().zip(&g.hits) {
            assert_eq!(tag, gtag);
            let at = format!("{what} frame {f} ray {tag}");
            match (ch, gh) {
                (None, None) => {}
                (Some(c), Some(g)) => {
                    // The same character, triangle, distance, barycentrics and point, bit for bit. The
                    // normal is normalised twice (object space, then world space) by the kernel's
                    // `normalize`, whose inverse square root Vulkan allows 2 ulp: 4 ulp of 1 in all
                    // (lavapipe: at most 1).
                    let same = |h: &RayHit, e| {
                        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                        let (b, p) = (h.barycentrics.to_array(), h.point.to_array());
                        (e, h.triangle, h.distance.to_bits(), bits(&b), bits(&p))
                    };
                    let (ce, ge) = (cpu.character(c.entity), gpu.character(g.entity));
                    assert_eq!(same(g, ge), same(c, ce), "{at}: {g:?} vs {c:?}");
                    let n = (g.normal - c.normal).abs().max_element();
                    assert!(n <= 4.0 * f32::EPSILON, "{at}: normal {g:?} vs {c:?}");
                }
                _ => panic!("{at}: {gh:?} vs {ch:?}"),
            }
        }
        assert_eq!(c.shadows, g.shadows, "{what} frame {f}");
    }
}

/// Bytes a resident frame after the first uploads for the queries-only crowd: per character its joint
/// matrices (64 bytes each) and `per_character` more; per instance (the characters and the ground) 144
/// bytes plus a 64-byte transform; per request (`rays` rays and the shadow rays) a ray (80 bytes) and
/// its filter (16); three 16-byte parameter blocks. The humanoid's joint count does not depend on its
/// triangle count.
fn uploads_after_the_first_frame(per_character: usize, rays: usize) -> usize {
    let joints = humanoid(500).skeleton.joints.len();
    CHARACTERS * (64 * joints + per_character) + (CHARACTERS + 1) * 208 + (rays + SHADOWS) * 96 + 48
}

fn resident(latency: Latency) -> TraceConfig {
    TraceConfig {
        mode: TraceMode::GpuRequired,
        latency,
        resident: true,
        ..Default::default()
    }
}

#[test]
fn next_frame_answers_equal_the_cpu_mode_without_waiting() {
    if gpu_or_skip().is_none() {
        return;
    }
    let cpu = run(TraceConfig::default(), Crowd::queries(600, false));
    let gpu = run(resident(Latency::NextFrame), Crowd::queries(600, true));
    assert_same_answers(&cpu, &gpu, "next frame, GPU only");
    // Without their CPU mirror the characters are invisible to immediate queries; the ground has one.
    assert_eq!(gpu.on_cpu, 1);
    for (f, c) in gpu.counters.iter().enumerate() {
        assert_eq!(c.submissions, 1, "frame {}: {c:?}", f + 1);
        assert_eq!(c.blocking_waits, 0, "frame {}: {c:?}", f + 1);
    }
    // After the first frame no vertex data goes up: uploads do not depend on the triangle count.
    let big = run(resident(Latency::NextFrame), Crowd::queries(1500, true));
    assert!(big.counters[0].uploaded_bytes > gpu.counters[0].uploaded_bytes);
    // Exactly the joints, instances, requests and parameters.
    let expected = uploads_after_the_first_frame(0, RAYS);
    for f in 1..FRAMES as usize {
        let (small, big) = (gpu.counters[f], big.counters[f]);
        assert_eq!(small.uploaded_bytes, big.uploaded_bytes, "frame {}", f + 1);
        assert_eq!(small.uploaded_bytes, expected as u64, "frame {}", f + 1);
    }
}

#[test]
fn same_frame_answers_equal_the_cpu_mode_with_one_wait() {
    if gpu_or_skip().is_none() {
        return;
    }
    let cpu = run(TraceConfig::default(), Crowd::queries(600, false));
    // Threshold 0: every refit whose metric comes back rebuilds the next frame, so GPU rebuilds answer
    // about half the frames; binned SAH (the GPU's 16 bins) for them, LBVH in the other test.
    let config = TraceConfig {
        policy: RebuildPolicy::Lauterbach { threshold: 0.0 },
        builder: kinetrace::bvh::Builder::Sah { bins: 16 },
        ..resident(Latency::SameFrame)
    };
    let gpu = run(config, Crowd::queries(600, false));
    assert_same_answers(&cpu, &gpu, "same frame, mirrored, SAH rebuilds");
    // Mirrored, they are on the CPU as in the CPU mode, for immediate queries.
    assert_eq!(gpu.on_cpu, CHARACTERS + 1);
    for (f, c) in gpu.counters.iter().enumerate() {
        assert_eq!(c.submissions, 1, "frame {}: {c:?}", f + 1);
        assert!(c.blocking_waits <= 1, "frame {}: {c:?}", f + 1);
    }
}

/// The crowd at twelve times real time under 2,000 rays a frame, its trees rebuilt on the GPU with binned
/// SAH whenever a refit's metric comes back: rays meet characters' faces at an angle a short way from their
/// origins, where a triangle's computed `t` errs by ulps of its corners' depths rather than of `t` — two
/// characters' coplanar faces 0.0077 from a ray's origin came 6 ulps apart, and the GPU's trees kept the
/// farther until every traversal added [`Ray::hit_slack`] to its limit. Answers equal the CPU mode's.
#[test]
fn fast_motion_answers_equal_the_cpu_mode() {
    if gpu_or_skip().is_none() {
        return;
    }
    let config = TraceConfig {
        policy: RebuildPolicy::Lauterbach { threshold: 0.0 },
        builder: kinetrace::bvh::Builder::Sah { bins: 16 },
        ..resident(Latency::NextFrame)
    };
    let (cpu, gpu) = cpu_and_gpu_only(config, Crowd::busy(0.2));
    assert_same_answers(&cpu, &gpu, "twelve times real time");
}

/// 300 frames of the crowd as colliders (one also against itself) with batched rays and shadow rays:
/// `GpuOnly` characters in the resident frame give the CPU mode's answers and the CPU mode's contact pairs,
/// frame by frame — the same touching entity pairs, with the same triangle pairs between two characters
/// — with one submission,
/// no blocking wait, and after the first frame uploads of exactly the joints, instances, requests and
/// one 80-byte relative transform per pair traversed (pairs whose world boxes are apart are culled).
#[test]
fn colliders_and_queries_equal_the_cpu_mode_over_300_frames() {
    if gpu_or_skip().is_none() {
        return;
    }
    let cpu = run(TraceConfig::default(), COLLIDING.with_mirror());
    let gpu = run(resident(Latency::NextFrame), COLLIDING);
    assert_same_answers(&cpu, &gpu, "colliders, GPU only");
    let touching = |r: &Run| r.contacts.values().filter(|p| !p.is_empty()).count();
    let between = (cpu.contacts.values())
        .filter(|p| p.iter().any(|(a, b, _)| a != b))
        .count();
    eprintln!(
        "contacts in {} frames, between characters in {between}",
        touching(&cpu)
    );
    // The crowd brushes together in some frames and not in others.
    assert!(
        between > 0 && between < 300,
        "{between} frames with contacts between characters"
    );
    assert_same_contacts(&cpu, &gpu, 300);
    // Pairs whose world boxes are apart are culled before the traversal (the contacts above are those
    // of every candidate pair in the CPU mode): the self pair is always traversed, the others as the
    // characters sway in and out of reach.
    let pairs = CHARACTERS * (CHARACTERS - 1) / 2 + 1;
    let traversed: Vec<usize> = gpu.resident.iter().map(|s| s.pairs_traversed).collect();
    eprintln!("pairs traversed per frame: {traversed:?}");
    assert!(
        gpu.resident.iter().all(|s| s.pair_candidates == pairs),
        "{:?}",
        gpu.resident
    );
    assert!(
        traversed.iter().all(|&t| (1..=pairs).contains(&t)),
        "{traversed:?}"
    );
    let (lo, hi) = (traversed.iter().min(), traversed.iter().max());
    assert!(lo < hi, "{traversed:?}");
    // A pair traversed for the first time makes its traversal (a fixed block of round parameters goes
    // up once); otherwise uploads are exactly the joints, instances, requests and the pairs' transforms.
    let base = uploads_after_the_first_frame(0, RAYS);
    let mut per_new = std::collections::BTreeSet::new();
    for (f, c) in gpu.counters.iter().enumerate() {
        assert_eq!(c.submissions, 1, "frame {}: {c:?}", f + 1);
        assert_eq!(c.blocking_waits, 0, "frame {}: {c:?}", f + 1);
        if f > 0 {
            let extra = c.uploaded_bytes as usize - (base + traversed[f] * 80);
            match gpu.resident[f].pairs_created {
                0 => assert_eq!(extra, 0, "frame {}", f + 1),
                n => _ = per_new.insert((extra / n, extra % n)),
            }
        }
    }
    assert!(
        per_new.len() <= 1 && per_new.iter().all(|p| p.1 == 0),
        "{per_new:?}"
    );
}

/// The crowd of the collider tests: close enough to brush together.
const COLLIDING: Crowd = Crowd {
    triangles: 500,
    gpu_only: true,
    frames: 300,
    spacing: 0.45,
    colliders: true,
    pair_capacity: None,
    morphs: false,
    rays: RAYS,
    clock: 1.0 / 60.0,
};

impl Crowd {
    /// The same crowd with CPU mirrors (for the CPU mode).
    const fn with_mirror(self) -> Self {
        Crowd {
            gpu_only: false,
            ..self
        }
    }
}

/// Frames `1..=frames` have the same touching pairs in both runs; between two characters, the same
/// triangle pairs. A character against itself touches where its capsules meet at the joints, along
/// coincident surfaces whose triangle pairs touch or not by the rounding of the skinning, which differs
/// between the devices: there only the pair is compared.
fn assert_same_contacts(cpu: &Run, gpu: &Run, frames: u64) {
    let strip = |pairs: &ContactPairs| -> ContactPairs {
        (pairs.iter())
            .map(|(a, b, t)| (*a, *b, if a == b { Vec::new() } else { t.clone() }))
            .collect()
    };
    for f in 1..=frames {
        let (c, g) = (&cpu.contacts[&f], &gpu.contacts[&f]);
        assert_eq!(strip(c), strip(g), "frame {f}");
    }
}

/// With pair buffers forced tiny (room for 64 leaf pairs, the buffers' minimum), the traversals of
/// touching pairs overflow: those frames are answered by the CPU's traversal of the read-back trees, the
/// buffers grow, and the contacts still equal the CPU mode's, frame by frame.
#[test]
fn overflowing_pair_buffers_grow_and_contacts_equal_the_cpu_mode() {
    if gpu_or_skip().is_none() {
        return;
    }
    let crowd = Crowd {
        frames: 60,
        pair_capacity: Some(1),
        ..COLLIDING
    };
    let cpu = run(TraceConfig::default(), crowd.with_mirror());
    let gpu = run(resident(Latency::NextFrame), crowd);
    assert_same_contacts(&cpu, &gpu, 60);
    let overflows: usize = gpu.resident.iter().map(|s| s.pair_overflows).sum();
    let start = gpu.resident[0].pair_capacity;
    let end = gpu.resident.last().unwrap().pair_capacity;
    eprintln!("{overflows} overflows; leaf-pair capacity {start} -> {end}");
    assert!(overflows > 0, "{:?}", gpu.resident);
    assert!(end > start, "{start} -> {end}");
}

/// The adaptive policy on the resident frame: every changed mesh's planner is fed the SAH cost reduced on
/// the GPU (one frame late) and counted query work, and decides refit or rebuild and with which GPU
/// builder; the first frame builds every tree with binned SAH (the planner's first build of an asset
/// nobody measured), later frames refit and rebuild some (neither never nor always), each rebuild with
/// the build the planner named in that frame; the builds nobody measured are measured once, on the pose
/// of the asset's first rebuild that came due (binned SAH), and none is put in use before; the answers
/// still equal the CPU mode's, no frame waits, and after the first frame uploads are exactly the joints,
/// instances and requests — but in a frame where a mesh first builds with a SAH or hybrid builder (for
/// use or to measure it), which uploads that builder's parameters once. The crowd plays its clips at
/// nine times real time, under 2,000 rays a frame: at real time its trees stay as good as fresh ones and
/// no rebuild pays.
#[test]
fn the_adaptive_policy_decides_on_the_resident_trees() {
    if gpu_or_skip().is_none() {
        return;
    }
    let config = TraceConfig {
        policy: RebuildPolicy::ADAPTIVE,
        ..resident(Latency::NextFrame)
    };
    let (cpu, gpu) = cpu_and_gpu_only(config, Crowd::busy(0.15));
    assert_same_answers(&cpu, &gpu, "adaptive policy");
    eprintln!("{:?}", gpu.resident);
    assert_eq!(gpu.resident[0].rebuilds, CHARACTERS + 1);
    for m in &gpu.meshes[0] {
        let first = MeshAction::Rebuild {
            build: Build::GPU_SAH,
            reason: RebuildReason::New,
        };
        assert_eq!(m.action, first);
    }
    let later = &gpu.resident[1..];
    let rebuilds: usize = later.iter().map(|s| s.rebuilds).sum();
    let refits: usize = later.iter().map(|s| s.refits).sum();
    assert!(
        rebuilds > 0 && refits > 0,
        "{rebuilds} rebuilds, {refits} refits"
    );
    assert_eq!(rebuilds + refits, CHARACTERS * later.len());
    // Calibrated: LBVH and the hybrid, in the frame of the first rebuild that came due.
    let measuring: Vec<usize> = (0..gpu.resident.len())
        .filter(|&f| gpu.resident[f].calibrations > 0)
        .collect();
    let first_due = (1..gpu.meshes.len())
        .find(|&f| {
            gpu.meshes[f]
                .iter()
                .any(|m| matches!(m.action, MeshAction::Rebuild { .. }))
        })
        .expect("a rebuild came due");
    assert_eq!(measuring, [first_due]);
    assert_eq!(gpu.resident[first_due].calibrations, 2);
    for (f, stats) in gpu.meshes.iter().enumerate().take(first_due + 1) {
        for m in stats {
            if let MeshAction::Rebuild { build, .. } = m.action {
                assert_eq!(
                    build,
                    Build::GPU_SAH,
                    "frame {}: before the calibration",
                    f + 1
                );
            }
        }
    }
    let mut first_uses = builds_first_used(&gpu);
    first_uses.push(first_due);
    let expected = uploads_after_the_first_frame(0, gpu.rays);
    for (f, c) in gpu.counters.iter().enumerate().skip(1) {
        if !first_uses.contains(&f) {
            assert_eq!(c.uploaded_bytes, expected as u64, "frame {}", f + 1);
        }
        assert_eq!(c.blocking_waits, 0, "frame {}", f + 1);
        let stats = &gpu.meshes[f];
        assert_eq!(stats.len(), CHARACTERS, "frame {}", f + 1);
        for m in stats {
            if let MeshAction::Rebuild { build, reason } = m.action {
                assert_eq!(reason, RebuildReason::Policy);
                let why = m.prediction.expect("the planner's grounds");
                assert_ne!(why.verdict, Verdict::Keep, "frame {}", f + 1);
                assert_eq!(why.build, build, "frame {}", f + 1);
            }
        }
    }
}

/// The frames (0-based) in which some mesh first rebuilt with a SAH or hybrid build.
fn builds_first_used(run: &Run) -> Vec<usize> {
    let mut seen = std::collections::HashSet::new();
    let mut frames = Vec::new();
    for (f, stats) in run.meshes.iter().enumerate() {
        for m in stats {
            if let MeshAction::Rebuild { build, .. } = m.action
                && build != Build::GPU_LBVH
                && seen.insert((m.entity, build))
            {
                frames.push(f);
            }
        }
    }
    frames
}

/// `frames_since_rebuild` of every call of [`every_third_frame`], in call order.
static CALLS: std::sync::Mutex<Vec<(u32, f32)>> = std::sync::Mutex::new(Vec::new());

/// A custom policy that rebuilds a tree refitted twice since its build.
fn every_third_frame(input: &PolicyInput<'_>) -> Decision {
    CALLS
        .lock()
        .unwrap()
        .push((input.frames_since_rebuild, input.degradation));
    if input.frames_since_rebuild >= 2 {
        Decision::Rebuild(kinetrace::ecs::Build::GPU_LBVH)
    } else {
        Decision::Keep
    }
}

/// The resident frame consults a custom policy for every changed mesh and does what it says: trees that
/// it keeps are refitted (their refit count rises to 2), trees it rebuilds start again from 0 (never 3),
/// and a rebuilt tree's metric reads 0 until a refit's comes back; the answers still equal the CPU mode's.
#[test]
fn a_custom_policy_decides_refit_or_rebuild() {
    if gpu_or_skip().is_none() {
        return;
    }
    let cpu = run(TraceConfig::default(), Crowd::queries(600, false));
    let config = TraceConfig {
        policy: RebuildPolicy::Custom(every_third_frame),
        ..resident(Latency::NextFrame)
    };
    let gpu = run(config, Crowd::queries(600, true));
    assert_same_answers(&cpu, &gpu, "custom policy");
    let calls = CALLS.lock().unwrap().clone();
    // Every frame after the first, each character (the static ground is never asked).
    assert!(
        calls.len() >= CHARACTERS * (FRAMES as usize - 1),
        "{calls:?}"
    );
    for k in 0..=2 {
        assert!(calls.iter().any(|c| c.0 == k), "{calls:?}");
    }
    assert!(calls.iter().all(|c| c.0 <= 2), "{calls:?}");
    assert!(calls.iter().all(|c| c.0 > 0 || c.1 == 0.0), "{calls:?}");
    assert!(calls.iter().any(|c| c.1 > 0.0), "{calls:?}");
}

/// Per-phase GPU durations come with every frame's answers on a device with timestamp queries, and are
/// absent on one without (skipped cleanly); where present the timestamps were written (the frame's work
/// took some GPU time).
#[test]
fn gpu_phase_times_come_with_the_answers_where_the_device_has_them() {
    let Some(ctx) = gpu_or_skip() else {
        return;
    };
    let (mut world, mut schedule) = app_with(resident(Latency::SameFrame));
    let asset = Arc::new(humanoid(600));
    world
        .spawn(AnimationPlayer::bundle(&asset, 0, 0.0))
        .insert(Collider::default());
    world
        .spawn(AnimationPlayer::bundle(&asset, 0, 0.2))
        .insert((
            Collider::default(),
            TraceTransform(Affine3A::from_translation(Vec3::X * 0.3)),
        ));
    eprintln!("timestamps: {}", ctx.has_timestamps());
    for f in 1..=4 {
        let (rays, _) = requests(f, RAYS);
        let mut queue = world.resource_mut::<RayQueue>();
        for (i, ray) in rays.into_iter().enumerate() {
            queue.cast(i as u64, ray, QueryFilter::default());
        }
        schedule.run(&mut world);
        let phases = world.resource::<TraceStats>().gpu_phases;
        assert_eq!(phases.is_some(), ctx.has_timestamps(), "frame {f}");
        if let Some(p) = phases {
            eprintln!("frame {f}: {p:?}");
            assert!(p.maintain + p.top_level + p.queries + p.pairs > std::time::Duration::ZERO);
        }
    }
}

/// A resident mesh's SAH cost, reduced on the GPU and read back without blocking, equals the CPU's
/// `Bvh::sah_cost` and root area of the same tree read back (after builds and after refits); every
/// builder the frame offers (LBVH, binned SAH, the hybrid, then LBVH again over the SAH builder's
/// scratch) rebuilds the resident tree in place into a valid tree over the frame's vertices (every
/// triangle once, every box holding its children and its triangles); its
/// vertices, morphed by two blend shapes and skinned on the GPU, equal the CPU's morphing and skinning;
/// and its CPU-side bound from the joint matrices and blend-shape weights holds every vertex: random
/// rigid joint motions and weights in [-1, 1] on a humanoid, a fresh pose each frame. Builds asked only
/// to be measured before a rebuild (the adaptive policy's calibration) come back with the rebuild's
/// reading, each equal to the cost of that builder's tree built alone on the same vertices, and leave
/// the rebuilt tree as it is built alone.
#[test]
fn resident_costs_and_bounds_match_the_gpu_tree() {
    use glam::{Mat4, Quat};
    use kinetrace::gpu::{FrameBuilder, GpuSahOptions, Maintained, MeshUpdate, ResidentMesh};
    use rand::Rng;
    let Some(ctx) = gpu_or_skip() else {
        return;
    };
    let asset = with_morphs(humanoid(600));
    let morphs = asset.morphs.as_deref().unwrap();
    let joints = asset.skeleton.joints.len();
    let skin = Some((&*asset.weights, joints, Some(morphs)));
    let mut mesh = ResidentMesh::new(&ctx, &asset.mesh, skin).unwrap();
    // Rebuilt in frames 0, 2, 4 and 6, refitted in between.
    let builders = [
        FrameBuilder::Lbvh,
        FrameBuilder::Sah(GpuSahOptions::SAH),
        FrameBuilder::Sah(GpuSahOptions::hybrid(6)),
        FrameBuilder::Lbvh,
    ];
    // Measured before the rebuilds of frames 2, 4 and 6.
    let calibrations = [
        vec![],
        vec![],
        vec![builders[0], builders[2]],
        vec![],
        vec![builders[1]],
        vec![],
        vec![builders[1], builders[2]],
        vec![],
    ];
    // The costs of `builder`'s tree built alone on `posed`, read back; and the tree.
    let alone = |posed: &kinetrace::Mesh, builder: FrameBuilder| {
        let mut twin = ResidentMesh::new(&ctx, posed, None).unwrap();
        let mut enc = ctx.encoder();
        let done = twin.record(&ctx, &mut enc, MeshUpdate::Unchanged, |_, _| Some(builder));
        assert_eq!(done.unwrap(), Maintained::Rebuilt(builder));
        ctx.submit(enc);
        ctx.wait().unwrap();
        twin.bvh().read_tree(&ctx).unwrap()
    };
    // What the last frame's calibrations cost, built alone.
    let mut expected_calibrated = vec![];
    let mut calibrated_readings = 0;
    mesh.measure_costs(&ctx);
    let mut r = rng(1519);
    let mut readings = 0;
    // The CPU's SAH cost and root area of the tree as the last frame left it.
    let mut last: Option<(f64, f64)> = None;
    for frame in 0..8 {
        let matrices: Vec<Mat4> = (0..joints)
            .map(|_| {
                let axis = rand_vec(&mut r, -1.0, 1.0).normalize_or(Vec3::Y);
                let turn = Quat::from_axis_angle(axis, 0.4 * frame as f32);
                Mat4::from_rotation_translation(turn, rand_vec(&mut r, -0.3, 0.3))
            })
            .collect();
        let weights = [r.random_range(-1.0..1.0), r.random_range(-1.0..1.0)];
        let update = MeshUpdate::Joints {
            matrices: &matrices,
            morph_weights: &weights,
        };
        let mut enc = ctx.encoder();
        let mut seen = None;
        let mut seen_calibrated = vec![];
        let asked = (frame % 2 == 0).then(|| builders[frame / 2]);
        let done = mesh
            .record(&ctx, &mut enc, update, |s, calibrate| {
                assert_eq!(s.first_build, frame == 0);
                seen = s.cost;
                seen_calibrated = s.calibrated.to_vec();
                calibrate.extend_from_slice(&calibrations[frame]);
                asked
            })
            .unwrap();
        let expected_done = asked.map_or(Maintained::Refit, Maintained::Rebuilt);
        assert_eq!(done, expected_done, "frame {frame}");
        ctx.submit(enc);
        ctx.wait().unwrap();
        // The GPU morphed and skinned as the CPU does (to the rounding of a few dozen operations on
        // coordinates of a few metres), and the bound holds every vertex.
        let positions = mesh.bvh().read_positions(&ctx).unwrap();
        let mut morphed = vec![Vec3::ZERO; positions.len()];
        morphs.apply(asset.mesh.positions(), &weights, &mut morphed);
        let mut expected = vec![Vec3::ZERO; positions.len()];
        kinetrace::anim::skin_positions(&morphed, &asset.weights, &matrices, &mut expected)
            .unwrap();
        let bound = mesh.bound().expect("weights in [0, 1]");
        for (i, (p, q)) in positions.iter().zip(&expected).enumerate() {
            let tol = 64.0 * f32::EPSILON * (1.0 + q.abs().max_element());
            let at = format!("frame {frame} vertex {i}");
            assert!((*p - *q).abs().max_element() <= tol, "{at}: {p} vs {q}");
            assert!(bound.contains_point(*p), "{at}: {p} outside {bound:?}");
        }
        // A frame's reading (a build's, then refits') arrives with the next frame's record: compare it
        // with the tree read back right after its own frame.
        if let Some(c) = seen {
            let (sah, area) = last.take().expect("a tree was recorded before");
            assert_eq!(c.rebuilt, frame % 2 == 1, "frame {frame}");
            let rel = |a: f64, b: f64| (a - b).abs() / b;
            assert!(
                rel(c.reading.sah, sah) <= 1e-5,
                "frame {frame}: {} vs {sah}",
                c.reading.sah
            );
            assert!(rel(c.reading.root_half_area, area) <= 1e-6, "frame {frame}");
            readings += 1;
            let got: Vec<_> = seen_calibrated.iter().map(|c| c.builder).collect();
            assert_eq!(got, calibrations[frame - 1], "frame {frame}");
            for (c, (sah, area)) in seen_calibrated.iter().zip(&expected_calibrated) {
                let at = format!("frame {frame}, {:?}", c.builder);
                assert!(rel(c.reading.sah, *sah) <= 1e-5, "{at}: {c:?} vs {sah}");
                assert!(rel(c.reading.root_half_area, *area) <= 1e-6, "{at}");
                calibrated_readings += 1;
            }
        } else {
            assert!(seen_calibrated.is_empty(), "frame {frame}");
        }
        let tree = mesh.bvh().read_tree(&ctx).unwrap();
        let posed = kinetrace::Mesh::new(positions, asset.mesh.indices().to_vec()).unwrap();
        tree.validate(Some(&posed.triangle_bounds()))
            .unwrap_or_else(|e| panic!("frame {frame}: {e}"));
        last = Some((tree.sah_cost(), tree.bounds().half_area_f64()));
        expected_calibrated = (calibrations[frame].iter())
            .map(|&b| {
                let t = alone(&posed, b);
                (t.sah_cost(), t.bounds().half_area_f64())
            })
            .collect();
        if let (Some(b), false) = (asked, calibrations[frame].is_empty()) {
            assert_eq!(
                alone(&posed, b),
                tree,
                "frame {frame}: the rebuilt tree, built alone"
            );
        }
    }
    assert_eq!(readings, 7);
    assert_eq!(calibrated_readings, 5);
}

/// Blend shapes on the GPU: characters with two blend shapes at nonzero weights, skinned on the GPU
/// (`GpuOnly`: no CPU mirror), give the CPU mode's answers, where the CPU morphs and skins; after the
/// first frame only the weights go up besides the joints (4 bytes per target), never vertex data.
#[test]
fn blend_shapes_on_the_gpu_equal_the_cpu_mode() {
    if gpu_or_skip().is_none() {
        return;
    }
    let crowd = Crowd {
        morphs: true,
        ..Crowd::queries(600, false)
    };
    let cpu = run(TraceConfig::default(), crowd);
    let gpu = run(
        resident(Latency::NextFrame),
        Crowd {
            gpu_only: true,
            ..crowd
        },
    );
    assert_same_answers(&cpu, &gpu, "blend shapes");
    // Two blend-shape weights per character.
    let expected = uploads_after_the_first_frame(2 * 4, RAYS);
    for (f, c) in gpu.counters.iter().enumerate().skip(1) {
        assert_eq!(c.uploaded_bytes, expected as u64, "frame {}", f + 1);
    }
}
