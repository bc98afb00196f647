//! The per-mesh options the planner picks in the ECS (structure under `Structure::Auto`, wide tree,
//! packets, the grid's overlap test), with scripted costs (`TraceWorld::script_costs`, the test hook): whichever option is picked,
//! batched answers equal world-space brute force; the cheaper scripted option is taken and shows in
//! `TraceStats::options`, also against the profile rule's prior; with ±10% noise around equal costs no
//! option changes more often than `Choice` documents (a try and a return per other option). No timing is
//! asserted: every cost the planners learn here is scripted.

mod common;
use bevy_ecs::prelude::*;
use common::ecs::{agree, app_with, brute, scripted_cost};
use common::*;
use glam::{Affine3A, Vec3};
use kinetrace::adaptive::Choice;
use kinetrace::ecs::*;
use kinetrace::grid::StructureChoice;
use kinetrace::scenes::bumpy_torus;
use kinetrace::{Mesh, Ray};
use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

/// The option kinds a mesh can report.
const KINDS: usize = 4;

/// The option kinds a mesh reports, as indices.
fn kind(o: PlannedOption) -> usize {
    match o {
        PlannedOption::Structure(_) => 0,
        PlannedOption::Wide(_) => 1,
        PlannedOption::Packets(_) => 2,
        PlannedOption::Overlap(_) => 3,
        PlannedOption::Secondary(..) | PlannedOption::PointOrder(_) => {
            panic!("only primary rays are queued: no secondary or point batch to plan")
        }
    }
}

/// A world under the adaptive policy and `Structure::Auto` with deforming meshes at 3 units apart: a
/// bumpy torus (the rule's prior: the BVH) and an even soup of mixed sizes (the prior: the grid), each
/// twice.
fn scene() -> (World, Schedule, Vec<(Entity, Mesh)>) {
    let (mut world, schedule) = app_with(TraceConfig {
        structure: Structure::Auto,
        policy: RebuildPolicy::ADAPTIVE,
        ..Default::default()
    });
    let meshes = [
        bumpy_torus(1200),
        even_soup(1500, 0.002, 2.5),
        bumpy_torus(1200),
        even_soup(1500, 0.002, 2.5),
    ];
    let entities = (meshes.iter().enumerate())
        .map(|(i, m)| {
            let at = Vec3::new(3.0 * i as f32 - 4.5, 0.0, 0.0);
            let e = world
                .spawn((
                    TraceMesh(m.clone()),
                    VertexPositions(m.positions().to_vec()),
                    TraceTransform(Affine3A::from_translation(at)),
                ))
                .id();
            (e, m.clone())
        })
        .collect();
    (world, schedule, entities)
}

/// Deforms every mesh for frame `f`, queues single rays and camera packets, runs the frame, checks
/// every answer against brute force, and returns each mesh's options from `TraceStats::options`.
fn frame(
    world: &mut World,
    schedule: &mut Schedule,
    meshes: &[(Entity, Mesh)],
    f: u32,
    check: bool,
) -> HashMap<Entity, [Option<PlannedOption>; KINDS]> {
    for (e, m) in meshes {
        let mut vp = world.get_mut::<VertexPositions>(*e).unwrap();
        for (p, q) in vp.0.iter_mut().zip(m.positions()) {
            *p = *q * (1.0 + 0.05 * (f as f32 * 0.3 + q.y * 3.0).sin());
        }
    }
    let mut r = rng(100 + f as u64);
    // Toward points in and around the meshes.
    let singles: Vec<Ray> = (0..64)
        .map(|i| {
            let to = Vec3::new(3.0 * (i % 4) as f32 - 4.5, 0.0, 0.0) + rand_vec(&mut r, -0.8, 0.8);
            let from = Vec3::new(0.0, 2.0, -8.0) + rand_vec(&mut r, -1.0, 1.0);
            Ray::new(from, to - from)
        })
        .collect();
    let tiles = camera(Vec3::new(0.0, 1.5, -9.0), Vec3::ZERO, 16, 4, 1.0);
    {
        let mut q = world.resource_mut::<RayQueue>();
        for (i, ray) in singles.iter().enumerate() {
            q.cast(i as u64, *ray, QueryFilter::default());
        }
        q.cast_packet(1000, &tiles, QueryFilter::default());
    }
    schedule.run(world);
    world.clear_trackers();
    let results = world.resource::<RayResults>().clone();
    let expect: Vec<&Ray> = singles.iter().chain(&tiles).collect();
    assert_eq!(results.hits.len(), expect.len());
    let mut hits = 0;
    for (k, ((_, got), ray)) in results.hits.iter().zip(expect).enumerate() {
        if !check {
            hits = usize::MAX;
            break;
        }
        let b = brute(world, ray, &QueryFilter::default());
        agree(got.as_ref(), b, &format!("frame {f} request {k}"));
        hits += got.is_some() as usize;
    }
    assert!(hits > 40, "frame {f}: {hits} hits");
    let stats = world.resource::<TraceStats>();
    let mut picks: HashMap<Entity, [Option<PlannedOption>; KINDS]> = HashMap::new();
    for o in &stats.options {
        let slot = &mut picks.entry(o.entity).or_default()[kind(o.option)];
        assert!(slot.is_none(), "frame {f}: {:?} reported twice", o.option);
        *slot = Some(o.option);
    }
    picks
}

/// A deterministic number in [−1, 1] per call.
fn noise(counter: &AtomicU64) -> f64 {
    let mut x = counter
        .fetch_add(1, Ordering::Relaxed)
        .wrapping_add(0x9e37_79b9_7f4a_7c15);
    x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^= x >> 31;
    (x >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
}

#[test]
fn scripted_costs_pick_the_cheaper_option_and_answers_stay_exact() {
    let (mut world, mut schedule, meshes) = scene();
    // Mesh i prefers: the structure its prior did *not* pick for i < 2 (the planner must overturn the
    // rule), the prior's for the others; the wide tree off for odd i; single rays for i ≥ 2.
    let cheap: Vec<(Entity, [PlannedOption; 3])> = (meshes.iter().enumerate())
        .map(|(i, (e, _))| {
            let torus = i % 2 == 0;
            let grid = torus == (i < 2);
            let structure = if grid {
                StructureKind::Grid
            } else {
                StructureKind::Bvh
            };
            (
                *e,
                [
                    PlannedOption::Structure(structure),
                    PlannedOption::Wide(i % 2 == 0),
                    PlannedOption::Packets(i < 2),
                ],
            )
        })
        .collect();
    let table = cheap.clone();
    world
        .resource_mut::<TraceWorld>()
        .script_costs(Some(Arc::new(move |e, option| {
            let (_, cheap) = table.iter().find(|(c, _)| *c == e)?;
            Some(scripted_cost(option, cheap.contains(&option)))
        })));
    let mut used = [[false; 2]; 4];
    let mut last = HashMap::new();
    for f in 0..24 {
        last = frame(&mut world, &mut schedule, &meshes, f, true);
        let stats = world.resource::<TraceStats>();
        for (i, (e, _)) in meshes.iter().enumerate() {
            if let Some(s) = stats.structures.iter().find(|s| s.entity == *e) {
                used[i][(s.structure == StructureKind::Grid) as usize] = true;
            }
        }
    }
    for (i, (e, options)) in cheap.iter().enumerate() {
        let picks = &last[e];
        let stats = world.resource::<TraceStats>();
        let tried = |o: PlannedOption| {
            let row = stats
                .options
                .iter()
                .find(|r| r.entity == *e && r.option == o);
            row.is_some_and(|r| r.tried)
        };
        assert_eq!(picks[0], Some(options[0]), "mesh {i}: {picks:?}");
        assert!(!tried(options[0]), "mesh {i} picks on measurements");
        if options[0] == PlannedOption::Structure(StructureKind::Bvh) {
            // Wide and packets are planned only for a mesh whose BVH answers.
            assert_eq!(picks[1], Some(options[1]), "mesh {i}: {picks:?}");
            assert_eq!(picks[2], Some(options[2]), "mesh {i}: {picks:?}");
        }
        let (_, why) = world.resource::<TraceWorld>().structure(*e).unwrap();
        let StructureWhy::Rule(ChoiceReason::Measured { bvh, grid }) = why else {
            panic!("mesh {i}: {why:?}");
        };
        assert_eq!(
            grid < bvh,
            options[0] == PlannedOption::Structure(StructureKind::Grid),
            "mesh {i}: {bvh} vs {grid}"
        );
        // Both structures answered some frame (tried, then chosen or left).
        assert_eq!(used[i], [true, true], "mesh {i}");
    }
}

#[test]
fn ten_percent_noise_around_equal_costs_changes_no_option_more_than_a_try_and_back() {
    let (mut world, mut schedule, meshes) = scene();
    let counter = Arc::new(AtomicU64::new(0));
    let c = counter.clone();
    world
        .resource_mut::<TraceWorld>()
        .script_costs(Some(Arc::new(move |_, _| {
            Some(ScriptedCost {
                overhead_s: 1e-6 * (1.0 + 0.1 * noise(&c)),
                per_ray_s: 1e-6 * (1.0 + 0.1 * noise(&c)),
            })
        })));
    let mut previous: HashMap<Entity, [Option<PlannedOption>; KINDS]> = HashMap::new();
    let mut changes: HashMap<(Entity, usize), u32> = HashMap::new();
    let mut tries = 0;
    // Frames each mesh's rays met the grid (every mesh starts on the BVH, whatever the rule's pick).
    let mut other = [0u32; 4];
    for f in 0..40 {
        let picks = frame(&mut world, &mut schedule, &meshes, f, f % 8 == 0);
        let stats = world.resource::<TraceStats>();
        tries += stats.options.iter().filter(|o| o.tried).count();
        for (i, (e, _)) in meshes.iter().enumerate() {
            let planned = stats.options.iter().find_map(|o| match o.option {
                PlannedOption::Structure(s) if o.entity == *e => Some(s),
                _ => None,
            });
            other[i] += (planned == Some(StructureKind::Grid)) as u32;
        }
        for (e, now) in picks {
            let before = previous.entry(e).or_default();
            for k in 0..KINDS {
                if let (Some(a), Some(b)) = (before[k], now[k])
                    && a != b
                {
                    *changes.entry((e, k)).or_default() += 1;
                }
                if now[k].is_some() {
                    before[k] = now[k];
                }
            }
        }
    }
    // The scenario must exercise the hysteresis: options were tried, and measured side by side.
    assert!(tries > 0);
    // Nothing to gain, little paid: the other structure answered only while it was tried.
    for (i, n) in other.iter().enumerate() {
        assert!(
            (1..=3).contains(n),
            "mesh {i}: {n} frames on the other structure"
        );
    }
    for ((e, k), n) in changes {
        // Choice: with two options, a try and a return at most.
        assert!(n <= 2, "{e} option kind {k} changed {n} times");
    }
    let counted = counter.load(Ordering::Relaxed);
    assert!(counted > 0, "the script was read");
}

/// Issue 12: the planner kept a grid whose frames were spiky — a cost every other frame (in the report a
/// BVH rebuild charged to the grid's frames, or the loaded machine's stalls) — though its mean was several
/// times the BVH's, because its margin was one frame's spread. Scripted: the grid's overhead alternates
/// between 1 µs and 300 µs (mean 150 µs), the BVH's is 1 µs; per ray both cost the same. Every mesh
/// starts on the BVH (the soups' rule picks the grid, which they try) and must end on it.
#[test]
fn a_spiky_structure_in_use_is_left_for_one_cheaper_on_average() {
    let on_bvh = frames_on(32, 24, StructureKind::Bvh, |f, option| {
        let overhead_s = match option {
            PlannedOption::Structure(StructureKind::Grid) if f % 2 == 1 => 300e-6,
            _ => 1e-6,
        };
        ScriptedCost {
            overhead_s,
            per_ray_s: 1e-6,
        }
    });
    assert_eq!(on_bvh, [8; 4], "frames 24..32 on the BVH, per mesh");
}

/// Runs frames `0..frames` of [`scene`] (answers checked every eighth) with every mesh's costs scripted
/// by `cost(frame, option)`, and counts per mesh the frames from `from` on that `kind` answered.
fn frames_on(
    frames: u32,
    from: u32,
    kind: StructureKind,
    cost: impl Fn(u32, PlannedOption) -> ScriptedCost + Send + Sync + 'static,
) -> [u32; 4] {
    let (mut world, mut schedule, meshes) = scene();
    let frame_no = Arc::new(AtomicU64::new(0));
    let f = frame_no.clone();
    world
        .resource_mut::<TraceWorld>()
        .script_costs(Some(Arc::new(move |_, option| {
            Some(cost(f.load(Ordering::Relaxed) as u32, option))
        })));
    let mut on = [0u32; 4];
    for f in 0..frames {
        frame_no.store(f as u64, Ordering::Relaxed);
        frame(&mut world, &mut schedule, &meshes, f, f % 8 == 0);
        let stats = world.resource::<TraceStats>();
        for (i, (e, _)) in meshes.iter().enumerate() {
            let s = stats.structures.iter().find(|s| s.entity == *e).unwrap();
            on[i] += (f >= from && s.structure == kind) as u32;
        }
    }
    on
}

/// Issue 12: the frames in which a structure is tried must measure it as it would answer once chosen —
/// with the mesh's wide-tree and packet options as settled. The BVH's tried frames were also the first
/// frames of those two choices, which tried the binary tree and ray-by-ray packets there and charged
/// them to the BVH (the report's explosion and soup kept a slower grid 891 of 900 frames). Scripted
/// equal costs, so that each soup (the rule's pick: the grid, tried soonest) tries the grid from the
/// BVH; in no frame is another option of a mesh tried beside its structure's try.
#[test]
fn a_structure_being_tried_meets_its_other_options_as_settled() {
    let (mut world, mut schedule, meshes) = scene();
    world
        .resource_mut::<TraceWorld>()
        .script_costs(Some(Arc::new(|_, _| {
            Some(ScriptedCost {
                overhead_s: 1e-6,
                per_ray_s: 1e-6,
            })
        })));
    let mut grid_tries = [0u32; 4];
    for f in 0..16 {
        frame(&mut world, &mut schedule, &meshes, f, f % 8 == 0);
        let stats = world.resource::<TraceStats>();
        for (i, (e, _)) in meshes.iter().enumerate() {
            let rows: Vec<_> = stats.options.iter().filter(|o| o.entity == *e).collect();
            let trying = rows
                .iter()
                .find(|o| o.tried && matches!(o.option, PlannedOption::Structure(_)));
            let Some(trying) = trying else {
                continue;
            };
            grid_tries[i] +=
                (trying.option == PlannedOption::Structure(StructureKind::Grid)) as u32;
            let beside: Vec<_> = (rows.iter())
                .filter(|o| o.tried && !matches!(o.option, PlannedOption::Structure(_)))
                .collect();
            assert!(
                beside.is_empty(),
                "frame {f} mesh {i}: {beside:?} tried beside {trying:?}"
            );
        }
    }
    // The soups (odd meshes) tried the grid, for its three tries: the scenario exercises the case.
    assert_eq!([grid_tries[1], grid_tries[3]], [3, 3], "{grid_tries:?}");
}

/// Issue 12: the grid's triangle–cell overlap test is a planned option of a mesh kept as a grid. Scripted:
/// the grid answers every mesh's rays at half the BVH's cost; with the overlap test, meshes 0 and 1 answer
/// at half the cost per ray (fewer references), meshes 2 and 3 pay a hundred times the rebuild. Each mesh
/// tries the other setting and ends on the cheaper one, reported in `TraceStats::options`, and its grid
/// really bins with (or without) the test; every answer equals brute force.
#[test]
fn scripted_costs_plan_the_grids_overlap_test() {
    let (mut world, mut schedule, meshes) = scene();
    let gains: Vec<Entity> = meshes.iter().take(2).map(|(e, _)| *e).collect();
    world
        .resource_mut::<TraceWorld>()
        .script_costs(Some(Arc::new(move |e, option| {
            let gains = gains.contains(&e);
            Some(match option {
                PlannedOption::Structure(StructureKind::Bvh) => ScriptedCost {
                    overhead_s: 1e-6,
                    per_ray_s: 2e-6,
                },
                PlannedOption::Overlap(true) if gains => ScriptedCost {
                    overhead_s: 1e-6,
                    per_ray_s: 0.5e-6,
                },
                PlannedOption::Overlap(true) => ScriptedCost {
                    overhead_s: 1e-4,
                    per_ray_s: 1e-6,
                },
                _ => ScriptedCost {
                    overhead_s: 1e-6,
                    per_ray_s: 1e-6,
                },
            })
        })));
    let mut used = [[false; 2]; 4];
    let mut last = HashMap::new();
    for f in 0..32 {
        last = frame(&mut world, &mut schedule, &meshes, f, true);
        for (i, (e, _)) in meshes.iter().enumerate() {
            if let Some(PlannedOption::Overlap(on)) = last[e][3] {
                used[i][on as usize] = true;
            }
        }
    }
    let stats = world.resource::<TraceStats>();
    for (i, (e, _)) in meshes.iter().enumerate() {
        let on = i < 2;
        assert_eq!(
            last[e][0],
            Some(PlannedOption::Structure(StructureKind::Grid)),
            "mesh {i}: {:?}",
            last[e]
        );
        assert_eq!(last[e][3], Some(PlannedOption::Overlap(on)), "mesh {i}");
        let row = (stats.options.iter())
            .find(|o| o.entity == *e && o.option == PlannedOption::Overlap(on))
            .unwrap();
        assert!(!row.tried, "mesh {i} picks on measurements");
        let grid = world
            .resource::<TraceWorld>()
            .grid(*e)
            .expect("kept as a grid");
        assert_eq!(grid.options().overlap_test, on, "mesh {i}'s grid");
        assert_eq!(
            used[i],
            [true, true],
            "mesh {i}: both settings answered some frame"
        );
    }
}

/// Issue 12: an option measured clearly cheaper in its three tries, but on frames too noisy for a margin
/// resting on three samples, was never measured again, and the option in use was kept for good — the
/// report's explosion kept a grid its BVH had measured 19% cheaper for 300 frames. Here the costs
/// cycle through 0.3, 1 and 1.7 times their mean (any three frames average it exactly), the second option
/// costing 0.81 of the first: it must be in use at the end, and on every frame from 40 on but for the
/// first's remaining tries. With equal costs and ±10% noise (issue 19's stationary scene) the option in
/// use changes at most to a try and back, on every one of 40 seeds.
#[test]
fn an_option_measured_clearly_cheaper_on_noisy_frames_is_measured_until_it_wins() {
    let mut choice = Choice::new(&[('a', 1.0, 1.0), ('b', 1.0, 1.0)]).unwrap();
    let mut late_on_a = 0;
    for f in 0..80 {
        let option = choice.decide(1.0);
        let mean = if option == 'a' { 1.0 } else { 0.81 };
        choice.served(option, 1.0, mean * [0.3, 1.0, 1.7][f % 3]);
        late_on_a += (f >= 40 && option == 'a') as u32;
    }
    assert!(
        late_on_a <= 3,
        "{late_on_a} of frames 40..80 on the dearer option"
    );
    assert_eq!(choice.decide(1.0), 'b', "the cheaper option in use");
    for seed in 0..40u64 {
        let counter = AtomicU64::new(seed * 1000);
        let mut choice = Choice::new(&[('a', 1.0, 1.0), ('b', 1.0, 1.0)]).unwrap();
        let (mut changes, mut last) = (0, 'a');
        for _ in 0..80 {
            let option = choice.decide(1.0);
            choice.served(option, 1.0, 1.0 + 0.1 * noise(&counter));
            changes += (option != last) as u32;
            last = option;
        }
        assert!(
            changes <= 2,
            "seed {seed}: {changes} changes around equal costs"
        );
    }
}

/// The profile rule's pick `structure`, for a reason that leaves the other structure worth a try.
fn rule(structure: StructureKind) -> StructureChoice {
    let reason = match structure {
        StructureKind::Bvh => ChoiceReason::AlikeSizes(0.5),
        StructureKind::Grid => ChoiceReason::EvenlyMixed {
            empty_bins: 0.0,
            size_spread: 1.2,
            chi_square_uniform: false,
        },
    };
    StructureChoice { structure, reason }
}

/// A cost's scale at frame `f`: 1 until frame 20, then moving linearly by `by` (1 + `by` from frame 60 on).
fn ramp(f: u32, by: f64) -> f64 {
    1.0 + by * (f.clamp(20, 60) - 20) as f64 / 40.0
}

/// Teaches `choice` a frame of `option` costing `scale` times 100 µs of overhead and 10 µs per unit.
fn teach<T: Copy + PartialEq>(choice: &mut Choice<T>, option: T, units: f64, scale: f64) {
    choice.kept(option, 1e-4 * scale);
    choice.served(option, units, 1e-5 * scale * units);
}

/// Issue 12: an option measured in its tries only, while the scene was as it was then, is never
/// measured again — the report's explosion kept a grid whose cost drifted up past the BVH's, whose
/// estimate was three frames old. Scripted on the unit API, as the explosion: the grid in use first
/// (the rule's pick), the BVH tried at 2× its cost; from frame 20 to 60 the grid's cost rises by 60%
/// while the BVH's falls to the grid's first cost. The stale estimate (2×) says the BVH is still dearer
/// (2 against 1.6), so only a re-try finds it 37% cheaper: it must be in use from frame 90 on and
/// chosen, not tried, at the end.
#[test]
fn an_option_that_became_cheaper_since_its_tries_is_re_tried_and_chosen() {
    use kinetrace::grid::StructureKind::{Bvh, Grid};
    let mut choice = Choice::structure(&rule(Grid));
    let units = 100.0;
    let mut late_on_grid = 0;
    for f in 0..120 {
        let option = choice.decide(units);
        let scale = match option {
            Grid => ramp(f, 0.6),
            Bvh => 2.0 * ramp(f, -0.5),
        };
        teach(&mut choice, option, units, scale);
        late_on_grid += (f >= 90 && option == Grid) as u32;
    }
    assert_eq!(late_on_grid, 0, "frames 90..120 on the grid");
    assert_eq!(choice.decide(units), Bvh);
    assert!(!choice.explored(), "chosen on measurements");
}

/// The other side of re-trying stale options: what it costs where the choice holds. Both options'
/// costs drift up together, 3× from frame 20 to 60, the grid staying 1.5× the BVH's: the drift is seen
/// (a re-try) but each re-try confirms the choice and doubles the wait for the next, so over 400
/// frames there are at most log2(400 / 10) + 1 = 6 re-tries of at most three frames each. With
/// stationary costs and ±10% noise (40 seeds, 400 frames) nothing drifts: no re-try at all. Under a
/// load that moves every cost by about its frames' own noise, at most three.
#[test]
fn re_tries_of_a_stale_option_are_rare_where_the_choice_holds() {
    use kinetrace::grid::StructureKind::{Bvh, Grid};
    let units = 100.0;
    let dearer = |o| if o == Grid { 1.5 } else { 1.0 };
    let mut choice = Choice::structure(&rule(Bvh));
    let mut on_grid = 0;
    for f in 0..400 {
        let option = choice.decide(units);
        teach(&mut choice, option, units, dearer(option) * ramp(f, 2.0));
        on_grid += (f >= 10 && option == Grid) as u32;
    }
    let retries = choice.retries();
    assert!((1..=6).contains(&retries), "{retries} re-tries");
    // The first tries (once worth their price: they may come after frame 10) and the re-tries.
    assert!(on_grid <= 3 * (retries + 1), "{on_grid} frames on the grid");
    assert_eq!(choice.decide(units), Bvh);
    for seed in 0..40u64 {
        let counter = AtomicU64::new(seed * 1000);
        let mut choice = Choice::structure(&rule(Bvh));
        for _ in 0..400 {
            let option = choice.decide(units);
            teach(
                &mut choice,
                option,
                units,
                dearer(option) * (1.0 + 0.1 * noise(&counter)),
            );
        }
        assert_eq!(choice.retries(), 0, "seed {seed}");
        assert_eq!(choice.decide(units), Bvh, "seed {seed}");
    }
    // A loaded machine: frames ±40% around their mean, and every cost 30% dearer from frame 100 to
    // 200 (another process's build). The mean in use moves by about two of its frames' spreads at
    // most: mostly the machine's noise, not the scene's, so re-tries stay as rare as where the scene
    // drifts (without the noise test: 1–5 per seed, 145 over the 40 seeds; the report re-tried 4–5
    // times per scene in 300 loaded frames).
    let mut total = 0;
    for seed in 0..40u64 {
        let counter = AtomicU64::new(seed * 1000);
        let mut choice = Choice::structure(&rule(Bvh));
        for f in 0..400 {
            let option = choice.decide(units);
            let load = if (100..200).contains(&f) { 1.3 } else { 1.0 };
            let scale = dearer(option) * load * (1.0 + 0.4 * noise(&counter));
            teach(&mut choice, option, units, scale);
        }
        assert!(
            choice.retries() <= 3,
            "loaded, seed {seed}: {}",
            choice.retries()
        );
        total += choice.retries();
    }
    assert!(total <= 60, "loaded: {total} re-tries over 40 seeds");
}

/// Issue 12 through the ECS (`TraceWorld::script_costs`): the structure not in use is re-measured once
/// its estimate is stale. Scripted per ray: the grid 2 µs until frame 20, falling to 1 µs by frame 60;
/// the BVH 1 µs, rising to 1.6 µs. Every mesh measures the grid at twice the BVH early on (the tori in
/// the grid's tries, the soups on the grid their prior picks before they try the BVH and leave), so
/// only a re-try sees it 37% cheaper later: every mesh must answer with the grid from frame 90 on.
#[test]
fn a_structure_that_became_cheaper_since_its_tries_is_re_tried_and_chosen() {
    let late_on_grid = frames_on(100, 90, StructureKind::Grid, |f, option| {
        let per_ray_s = match option {
            PlannedOption::Structure(StructureKind::Grid) => 2e-6 * ramp(f, -0.5),
            PlannedOption::Structure(StructureKind::Bvh) => 1e-6 * ramp(f, 0.6),
            _ => 1e-6,
        };
        ScriptedCost {
            overhead_s: 1e-6,
            per_ray_s,
        }
    });
    assert_eq!(
        late_on_grid, [10; 4],
        "frames 90..100 on the grid, per mesh"
    );
}

/// Issue 12: where the profile rule picked the BVH for empty space (`ChoiceReason::Clustered`), the grid
/// is not worth a frame: on the report's clustered scene (rigid, `--quick`) it took 2× the BVH's
/// steps per ray, and at 20k triangles one tried grid frame cost 5% of the run. Scripted, the grid costing 1.2× the BVH (what the other
/// reasons assume): after the BVH's first frame, for alike sizes the grid is tried, for a clustered mesh
/// never.
#[test]
fn a_clustered_mesh_never_tries_the_grid() {
    use kinetrace::grid::StructureKind::{Bvh, Grid};
    let units = 100.0;
    for (reason, tried) in [
        (ChoiceReason::AlikeSizes(0.5), true),
        (ChoiceReason::Clustered(0.38), false),
    ] {
        let mut choice = Choice::structure(&StructureChoice {
            structure: Bvh,
            reason,
        });
        let mut on_grid = 0;
        for _ in 0..40 {
            let option = choice.decide(units);
            choice.kept(option, 1e-5);
            choice.served(
                option,
                units,
                units * if option == Grid { 1.2e-5 } else { 1e-5 },
            );
            on_grid += (option == Grid) as u32;
        }
        assert_eq!(
            on_grid > 0,
            tried,
            "{reason:?}: {on_grid} frames on the grid"
        );
    }
}

/// Issue 12: a structure's tried frame that follows a switch teaches no overhead (it pays the switch's
/// catch-up: the ECS and the report learn overhead only from a frame on the structure of the frame
/// before). Taken for 0, that overhead made a grid whose queries alone came near the BVH's frame worth
/// more tries (the report's cloth tried the grid three frames, each 1.8× a BVH frame). Scripted: the
/// BVH 10 ms of queries and 1 ms of overhead, the grid 16 and 4; after its first frame the grid, with
/// its prior overhead (2× the BVH's), no longer looks cheaper even optimistic by its spread: one try.
#[test]
fn a_try_that_taught_no_overhead_is_predicted_with_the_prior_overhead() {
    use kinetrace::grid::StructureKind::{Bvh, Grid};
    let units = 100.0;
    let mut choice = Choice::structure(&rule(Bvh));
    let (mut previous, mut on_grid) = (None, 0);
    for _ in 0..40 {
        let option = choice.decide(units);
        let (overhead, queries) = if option == Grid {
            (4e-3, 16e-3)
        } else {
            (1e-3, 10e-3)
        };
        if previous == Some(option) {
            choice.kept(option, overhead);
        }
        choice.served(option, units, queries);
        previous = Some(option);
        on_grid += (option == Grid) as u32;
    }
    assert_eq!(on_grid, 1, "frames on the grid");
}

/// Runs a structure choice of `rule`'s pick for `frames` frames of 4096 rays, each option's (overhead,
/// query) seconds per frame given by `cost(frame, option)` (the overhead learned, as in the ECS and the
/// report, only on a frame that follows one on the same structure), the grid's overhead expected at
/// `expected` where given; returns the frames on the grid and the choice.
fn run_structure(
    rule: StructureChoice,
    frames: u32,
    expected: Option<f64>,
    cost: impl Fn(u32, StructureKind) -> (f64, f64),
) -> (u32, Choice<StructureKind>) {
    let units = 4096.0;
    let mut choice = Choice::structure(&rule);
    let (mut previous, mut on_grid) = (None, 0);
    for f in 0..frames {
        if let Some(seconds) = expected {
            choice.expect_overhead(StructureKind::Grid, seconds);
        }
        let option = choice.decide(units);
        let (overhead, queries) = cost(f, option);
        if previous == Some(option) {
            choice.kept(option, overhead);
        }
        choice.served(option, units, queries);
        previous = Some(option);
        on_grid += (option == StructureKind::Grid) as u32;
    }
    (on_grid, choice)
}

/// Issue 12, the report's rigid bodies at 20k triangles: three grid tries cost about 18 BVH frames each.
/// A try must be worth its price. Scripted as measured there (loaded): the BVH's first frame cold (14
/// ms of queries; 10–16 ms there), then 1.5 ms of queries and 0.4 ms of refit; the grid 12 ms of queries
/// and 1.7 ms of update (its rebuild and the refit), expected at that from the grid frames' learned
/// seconds per triangle. Against the cold first frame a grid predicted at 1.2 × the BVH's seconds per
/// ray looked cheaper, optimistic by its spread, and was tried at once; over a horizon of two frames its
/// saving does not pay three tries, and later the BVH's frames leave it nothing to win: no grid frame
/// in 300. And a BVH not updated at all (rigid motion)
/// has nothing for a per-frame grid to win on update: with the priors' ratio its grid rebuild was
/// predicted at twice nothing, and the grid tried; expected at its rebuild's seconds, never. The other
/// side: where the BVH is rebuilt every frame (8 ms) and the grid answers at 1.1 × its queries with a
/// 1.5 ms rebuild, the grid is tried and kept.
#[test]
fn a_grid_try_must_pay_for_itself_over_the_horizon() {
    use kinetrace::grid::StructureKind::{Bvh, Grid};
    let rigid = |f: u32, o| match o {
        Bvh if f == 0 => (0.0, 14e-3),
        Bvh => (0.4e-3, 1.5e-3),
        Grid => (1.7e-3, 12e-3),
    };
    let (on_grid, _) = run_structure(rule(Bvh), 300, Some(1.7e-3), rigid);
    assert_eq!(on_grid, 0, "rigid bodies: frames on the grid");
    let still = |_, o| match o {
        Bvh => (0.0, 1.5e-3),
        Grid => (1.2e-3, 12e-3),
    };
    let (on_grid, _) = run_structure(rule(Bvh), 300, Some(1.2e-3), still);
    assert_eq!(on_grid, 0, "a BVH not updated: frames on the grid");
    let rebuilt = |_, o| match o {
        Bvh => (8e-3, 2e-3),
        Grid => (1.5e-3, 2.2e-3),
    };
    let (on_grid, mut choice) = run_structure(rule(Bvh), 300, Some(1.5e-3), rebuilt);
    assert!(
        on_grid >= 280,
        "rebuilt every frame: {on_grid} frames on the grid"
    );
    assert_eq!(choice.decide(4096.0), Grid);
    assert!(!choice.explored());
}

/// Issue 12, the report's soup: the profile rule picks the grid (sizes mixed), yet on an idle machine
/// the BVH was the cheaper structure by a few percent (stop 26), and the planner, started on the rule's
/// pick, kept the grid 162 of 900 frames (1.05 × the BVH's time): within the 15% hysteresis the structure
/// in use stays. Scripted: the grid 8% dearer than the BVH in both overhead and queries. Whatever the
/// rule picked, the BVH is in use first and the grid answers only in its tries; where the grid is 30%
/// cheaper it is chosen.
#[test]
fn a_grid_within_the_margin_of_the_bvh_does_not_keep_the_rules_pick() {
    use kinetrace::grid::StructureKind::{Bvh, Grid};
    let dearer = |by: f64| {
        move |_, o| match o {
            Bvh => (1e-3, 10e-3),
            Grid => (by * 1e-3, by * 10e-3),
        }
    };
    let (on_grid, mut choice) = run_structure(rule(Grid), 300, None, dearer(1.08));
    assert!(on_grid <= 3, "{on_grid} frames on the grid");
    assert_eq!(choice.decide(4096.0), Bvh);
    let (on_grid, mut choice) = run_structure(rule(Grid), 300, None, dearer(0.7));
    assert!(on_grid >= 280, "a cheaper grid: {on_grid} frames on it");
    assert_eq!(choice.decide(4096.0), Grid);
}

/// Shadow rays whose single walks are cheap against packets (`Choice::sparse_packets`: the crowd's
/// selective and ray-traced passes): single rays first; packets in use after
/// 80 passes only where they cost clearly less per ray (0.7 of single rays' seconds), single rays
/// kept where packets cost 5% less (within the planner's margin) or 5% more (as measured on the
/// crowd), packets then tried for at most three passes.
#[test]
fn sparse_packets_start_one_by_one_and_switch_only_for_a_clear_gain() {
    assert!(!Choice::sparse_packets().decide(1e4), "single rays first");
    for (packets, settles) in [(0.7, true), (0.95, false), (1.05, false)] {
        let mut choice = Choice::sparse_packets();
        let mut on_packets = 0;
        for _ in 0..80 {
            let option = choice.decide(1e4);
            let per_ray = if option { packets } else { 1.0 } * 1e-6;
            choice.served(option, 1e4, per_ray * 1e4);
            on_packets += option as u32;
        }
        assert_eq!(choice.decide(1e4), settles, "packets at {packets}×");
        if !settles {
            assert!(
                on_packets <= 3,
                "packets at {packets}×: {on_packets} passes"
            );
        }
    }
}
