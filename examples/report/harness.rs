//! The error-versus-run-time evaluation: every scene under every strategy, per frame: update time, query
//! time for a fixed ray load (closest + shadow), the error against a fresh binned-SAH build of the same
//! frame (SAH cost and traversal steps per ray), and sampled rays checked against brute force.

use super::grid_rows::{self, StructureStrategy};
use super::option_rows::{self, OptionStrategy};
use super::scenes::Scene;
use glam::Vec3;
use kinetrace::adaptive::{AdaptivePolicy, Asset, Build, CostTable, Device, TreeCost, Verdict};
use kinetrace::bvh::{BuildOptions, Builder, Hit, PartialOptions, TraversalStats};
use kinetrace::scenes::SceneRng;
use kinetrace::{Aabb, Mesh, MeshBvh, Ray};
use std::time::Instant;

/// The GPU that GPU strategies run on (there is never one without the `gpu` feature).
#[cfg(feature = "gpu")]
pub use kinetrace::gpu::GpuContext as Gpu;
/// The GPU that GPU strategies run on (there is never one without the `gpu` feature).
#[cfg(not(feature = "gpu"))]
pub enum Gpu {}

/// The device for the GPU strategies, or why there is none: a software adapter (lavapipe, llvmpipe,
/// WARP) only with `software` — it runs the kernels on the CPU's cores, its times say nothing of a GPU,
/// and the full report's GPU rows take it hours where the CPU rows take minutes.
pub fn find_gpu(software: bool) -> Result<Gpu, String> {
    #[cfg(feature = "gpu")]
    return Gpu::with_options(&kinetrace::gpu::GpuOptions {
        hardware_only: !software,
        ..Default::default()
    })
    .map_err(|e| e.to_string());
    #[cfg(not(feature = "gpu"))]
    {
        let _ = software;
        Err("built without the gpu feature".into())
    }
}

/// How a strategy maintains the tree.
#[derive(Clone, Copy, Debug)]
pub enum Strategy {
    Rebuild(Build),
    Refit,
    /// Refit, then rebuild the subtrees that degraded past the default [`PartialOptions`] (issue 17).
    RefitPartial,
    RefitEvery(u32),
    Lauterbach(f32),
    /// The adaptive policy over CPU LBVH, hybrid and SAH, and GPU LBVH when `gpu`; with `partial`, a
    /// rebuild due by the rent may rebuild only the degraded subtrees, as the plugin does (issue 17).
    Adaptive {
        gpu: bool,
        partial: bool,
    },
    /// A grid instead of a maintained BVH, or the structure rule's choice (see `grid_rows`).
    Structure(StructureStrategy),
    /// A per-mesh option fixed, or the planner's picks (see `option_rows`).
    Options(OptionStrategy),
}

impl Strategy {
    /// The strategies that run everywhere.
    pub const CPU: [Strategy; 11] = [
        Strategy::Rebuild(Build::cpu(Builder::LBVH)),
        Strategy::Rebuild(Build::cpu(Builder::HYBRID)),
        Strategy::Rebuild(Build::cpu(Builder::SAH)),
        Strategy::Refit,
        Strategy::RefitPartial,
        Strategy::RefitEvery(20),
        Strategy::Lauterbach(0.2),
        Strategy::Lauterbach(0.4),
        Strategy::Lauterbach(0.8),
        Strategy::Adaptive {
            gpu: false,
            partial: false,
        },
        Strategy::Adaptive {
            gpu: false,
            partial: true,
        },
    ];

    /// The strategies that need a GPU: LBVH, binned SAH, the hybrid (k = 6) and PLOC rebuilt on it every
    /// frame (and read back for the CPU's queries), and the adaptive policy that may choose GPU LBVH.
    pub const GPU: [Strategy; 5] = [
        Strategy::Rebuild(Build::GPU_LBVH),
        Strategy::Rebuild(Build::GPU_SAH),
        Strategy::Rebuild(Build::gpu_hybrid(6)),
        Strategy::Rebuild(Build::GPU_PLOC),
        Strategy::Adaptive {
            gpu: true,
            partial: false,
        },
    ];

    /// The strategies to run: the GPU ones too when there is a GPU.
    pub fn all(gpu: bool) -> Vec<Strategy> {
        let extra = if gpu { &Self::GPU[..] } else { &[] };
        let structures = grid_rows::STRATEGIES.map(Strategy::Structure);
        let options = option_rows::STRATEGIES.map(Strategy::Options);
        Self::CPU
            .iter()
            .chain(&structures)
            .chain(&options)
            .chain(extra)
            .copied()
            .collect()
    }

    pub fn name(&self) -> String {
        match self {
            Strategy::Rebuild(b) => format!("rebuild-{b}"),
            Strategy::Refit => "refit".into(),
            Strategy::RefitPartial => "refit-partial".into(),
            Strategy::RefitEvery(k) => format!("refit-rebuild-every-{k}"),
            Strategy::Lauterbach(t) => format!("lauterbach-{t}"),
            Strategy::Adaptive { gpu, partial } => {
                let gpu = if *gpu { "-gpu" } else { "" };
                let partial = if *partial { "-partial" } else { "" };
                format!("adaptive{gpu}{partial}")
            }
            Strategy::Structure(s) => s.name().into(),
            Strategy::Options(s) => s.name().into(),
        }
    }

    pub fn is_fixed(&self) -> bool {
        match self {
            Strategy::Adaptive { .. } => false,
            Strategy::Structure(s) => s.is_fixed(),
            Strategy::Options(s) => s.is_fixed(),
            _ => true,
        }
    }
}

/// One frame of one strategy on one scene.
#[derive(Clone, Debug)]
pub struct FrameRecord {
    pub frame: u32,
    pub update_s: f64,
    pub query_s: f64,
    pub rebuilt: bool,
    /// SAH cost over a fresh binned-SAH build's.
    pub sah_ratio: f64,
    /// Traversal steps (node visits + triangle tests) per ray over the fresh SAH tree's on the same rays.
    pub steps_ratio: f64,
    /// Sampled rays whose answer differs from brute force.
    pub mismatches: u32,
    /// The adaptive policy's guard's own estimate of `sah_ratio` for the refitted tree, made before it
    /// decided (NaN for other strategies, on the first frame and before it has a fresh cost): on a
    /// frame that kept the tree, `sah_ratio` below this is the guard's error, the margin the SAH bound
    /// rests on.
    pub guard_ratio: f64,
}

/// The run's sizes.
#[derive(Clone, Copy, Debug)]
pub struct Settings {
    pub triangles: usize,
    pub frames: u32,
    pub rays: usize,
    pub checked_rays: usize,
    /// Runs of every scene; the report takes each strategy's median run (by total time).
    pub runs: u32,
    /// Whether the GPU strategies may run on a software adapter ([`find_gpu`]).
    pub software_gpu: bool,
}

impl Settings {
    /// Why these settings cannot run, if they cannot: every count must be at least 1.
    pub fn problem(&self) -> Option<&'static str> {
        match (self.frames, self.triangles, self.rays) {
            (0, _, _) => Some("the frame count must be at least 1"),
            (_, 0, _) => Some("the triangle count must be at least 1"),
            (_, _, 0) => Some("the ray count must be at least 1"),
            _ => None,
        }
    }

    /// The `--quick` run (CI's smoke test): small scenes, few frames.
    pub const QUICK: Settings = Settings {
        triangles: 3000,
        frames: 24,
        rays: 512,
        checked_rays: 8,
        runs: 1,
        software_gpu: false,
    };
}

/// Per frame of a scene: what every strategy is compared with (a fresh SAH build's SAH cost and steps).
pub struct Reference {
    pub sah: f64,
    pub steps: f64,
}

/// One frame of a scene: the mesh, the rays, the light, and the reference.
pub type Frame = (Mesh, Vec<Ray>, Vec3, Reference);

/// Rays of a frame: from points on a sphere around the scene towards points inside it.
fn frame_rays(bounds: &Aabb, n: usize, frame: u32) -> Vec<Ray> {
    let mut r = SceneRng::new(0x5eed ^ frame as u64);
    let c = bounds.center();
    let radius = bounds.extent().length().max(1e-3);
    (0..n)
        .map(|_| {
            let from = c + r.direction() * radius;
            let to = bounds.min + (bounds.max - bounds.min) * r.vec3(0.0, 1.0);
            Ray::new(from, to - from)
        })
        .collect()
}

/// A frame's light: above and aside of its bounds, as far from the centre as the bounds' diagonal.
pub fn frame_light(bounds: &Aabb) -> Vec3 {
    bounds.center() + Vec3::new(0.3, 1.0, 0.2) * bounds.extent().length()
}

/// A structure the fixed ray load runs through, and how its work counts as traversal steps.
pub trait Traced {
    fn closest(&self, ray: &Ray, stats: &mut TraversalStats) -> Option<Hit>;
    fn any(&self, ray: &Ray, stats: &mut TraversalStats) -> bool;
    fn steps(stats: &TraversalStats) -> u64;
}

impl Traced for MeshBvh {
    fn closest(&self, ray: &Ray, stats: &mut TraversalStats) -> Option<Hit> {
        self.closest_hit_counted(ray, stats)
    }
    fn any(&self, ray: &Ray, stats: &mut TraversalStats) -> bool {
        self.any_hit_counted(ray, stats)
    }
    /// Node visits plus triangle tests.
    fn steps(stats: &TraversalStats) -> u64 {
        stats.inner_visits + stats.leaf_visits + stats.prim_tests
    }
}

/// The fixed ray load: closest hits, then a shadow ray from each hit towards a light. Returns seconds and
/// traversal steps.
pub fn query<T: Traced>(structure: &T, rays: &[Ray], light: Vec3) -> (f64, u64) {
    let mut stats = TraversalStats::default();
    let start = Instant::now();
    for ray in rays {
        if let Some(h) = structure.closest(ray, &mut stats) {
            let p = ray.at(h.t);
            structure.any(&Ray::with_range(p, light - p, 1e-4, 1.0), &mut stats);
        }
    }
    (start.elapsed().as_secs_f64(), T::steps(&stats))
}

/// Closest t by brute force in f64 (Möller–Trumbore), with the smallest barycentric margin of the hit, so
/// that hits grazing an edge (where f32 and f64 may rightly disagree) are not counted as mismatches.
fn brute(mesh: &Mesh, ray: &Ray) -> Option<(f64, f64)> {
    let o = ray.origin.as_dvec3();
    let d = ray.dir().as_dvec3();
    let mut best: Option<(f64, f64)> = None;
    for i in 0..mesh.triangle_count() {
        let [a, b, c] = mesh.triangle(i).map(|v| v.as_dvec3());
        let (e1, e2) = (b - a, c - a);
        let p = d.cross(e2);
        let det = e1.dot(p);
        if det == 0.0 {
            continue;
        }
        let s = o - a;
        let u = s.dot(p) / det;
        let q = s.cross(e1);
        let v = d.dot(q) / det;
        let t = e2.dot(q) / det;
        let margin = u.min(v).min(1.0 - u - v);
        if margin >= -1e-7 && t >= 0.0 && t <= ray.tmax as f64 && best.is_none_or(|(bt, _)| t < bt)
        {
            best = Some((t, margin));
        }
    }
    best
}

/// Sampled rays whose closest distance by `closest` differs from brute force's.
pub fn mismatches(closest: impl Fn(&Ray) -> Option<f32>, mesh: &Mesh, rays: &[Ray]) -> u32 {
    let mut bad = 0;
    for ray in rays {
        let got = closest(ray).map(|t| t as f64);
        let agree = match (got, brute(mesh, ray)) {
            (None, None) => true,
            (Some(t), Some((bt, _))) => (t - bt).abs() <= 1e-4 * bt.max(1.0),
            (None, Some((_, margin))) => margin < 1e-5,
            (Some(_), None) => false,
        };
        bad += !agree as u32;
    }
    bad
}

fn build(mesh: &Mesh, builder: Builder) -> MeshBvh {
    MeshBvh::build(mesh, &BuildOptions::new(builder)).expect("scene meshes are valid")
}

/// A GPU builder's buffers for one mesh: the tree's own (LBVH), with the SAH builder's scratch for SAH and
/// the hybrid; or PLOC's.
#[cfg(feature = "gpu")]
enum GpuBuilder {
    Tree(
        kinetrace::gpu::GpuMeshBvh,
        Option<kinetrace::gpu::GpuSahBuilder>,
    ),
    Ploc(kinetrace::gpu::GpuPloc),
}

/// Builds a scene's trees: on the CPU, or with one GPU builder read back for the CPU's queries (its
/// buffers made once per strategy and scene, outside the timings).
struct Rebuilder {
    #[cfg(feature = "gpu")]
    gpu: Option<(Gpu, Build, GpuBuilder)>,
}

impl Rebuilder {
    /// For `on_gpu`, the one GPU build the strategy runs (a hybrid keeps its k: the report's scenes are
    /// not treated as clustered).
    fn new(gpu: Option<&Gpu>, mesh: &Mesh, on_gpu: Build) -> Self {
        #[cfg(feature = "gpu")]
        return Rebuilder {
            gpu: gpu.map(|g| {
                let fits = "scene meshes fit the GPU";
                let made = match on_gpu.builder {
                    Builder::Ploc { radius } => {
                        GpuBuilder::Ploc(kinetrace::gpu::GpuPloc::new(g, mesh, radius).expect(fits))
                    }
                    b => {
                        let tree = kinetrace::gpu::GpuMeshBvh::new(g, mesh).expect(fits);
                        let sah = kinetrace::gpu::GpuSahOptions::for_builder(b, false)
                            .expect("a builder the GPU runs")
                            .map(|o| kinetrace::gpu::GpuSahBuilder::new(g, &tree, o).expect(fits));
                        GpuBuilder::Tree(tree, sah)
                    }
                };
                (g.clone(), on_gpu, made)
            }),
        };
        #[cfg(not(feature = "gpu"))]
        {
            let _ = (gpu, mesh, on_gpu);
            Rebuilder {}
        }
    }

    fn build(&mut self, mesh: &Mesh, b: Build) -> MeshBvh {
        #[cfg(feature = "gpu")]
        if b.device == Device::Gpu {
            let (g, on_gpu, made) = self
                .gpu
                .as_mut()
                .expect("GPU strategies run only with a GPU");
            assert_eq!(b, *on_gpu, "one GPU builder per strategy");
            return match made {
                GpuBuilder::Tree(tree, None) => tree.build_for_cpu(g, mesh),
                GpuBuilder::Tree(tree, Some(sah)) => sah.build_for_cpu(g, tree, mesh),
                GpuBuilder::Ploc(ploc) => ploc.build_for_cpu(g, mesh),
            }
            .expect("a GPU build");
        }
        assert_eq!(b.device, Device::Cpu, "GPU strategies run only with a GPU");
        build(mesh, b.builder)
    }
}

/// The planner of an adaptive strategy for `mesh`, learning into `costs`: CPU LBVH, hybrid and SAH, and
/// with `gpu` GPU LBVH second, as the plugin offers it.
pub fn adaptive_policy(strategy: Strategy, costs: &CostTable, mesh: &Mesh) -> AdaptivePolicy {
    let cpu = [Builder::LBVH, Builder::HYBRID, Builder::SAH].map(Build::cpu);
    let builds = match strategy {
        Strategy::Adaptive { gpu: true, .. } => vec![cpu[0], Build::GPU_LBVH, cpu[1], cpu[2]],
        _ => cpu.to_vec(),
    };
    let mut policy = AdaptivePolicy::shared(&builds, costs, Asset::of_indices(mesh.indices()));
    policy.calibrates = true;
    policy
}

/// Runs `strategies` on `scene` (GPU ones on `gpu`); returns a record list per strategy, in their order.
pub fn run_scene(
    scene: &Scene,
    settings: &Settings,
    strategies: &[Strategy],
    gpu: Option<&Gpu>,
) -> Vec<Vec<FrameRecord>> {
    let mut frames = Vec::with_capacity(settings.frames as usize);
    let mut pos = Vec::new();
    for f in 0..settings.frames {
        scene.positions(f, &mut pos);
        let mesh = scene.mesh(&pos);
        let sah = build(&mesh, Builder::SAH);
        let bounds = sah.bvh().bounds();
        let rays = frame_rays(&bounds, settings.rays, f);
        let light = frame_light(&bounds);
        let (_, steps) = query(&sah, &rays, light);
        let reference = Reference {
            sah: sah.bvh().sah_cost(),
            steps: steps as f64 / rays.len().max(1) as f64,
        };
        frames.push((mesh, rays, light, reference));
    }
    strategies
        .iter()
        .map(|s| run_strategy(*s, &frames, settings, gpu))
        .collect()
}

/// Runs one strategy over a scene's frames (GPU strategies on `gpu`).
pub fn run_strategy(
    strategy: Strategy,
    frames: &[Frame],
    settings: &Settings,
    gpu: Option<&Gpu>,
) -> Vec<FrameRecord> {
    if let Strategy::Structure(s) = strategy {
        return grid_rows::run(s, frames, settings);
    }
    if let Strategy::Options(s) = strategy {
        return option_rows::run(s, frames, settings);
    }
    let (mesh0, ..) = &frames[0];
    let mut adaptive = adaptive_policy(strategy, &CostTable::new(), mesh0);
    let first = match strategy {
        Strategy::Rebuild(b) => b,
        Strategy::Adaptive { .. } => adaptive.next_build(),
        _ => Build::cpu(Builder::LBVH),
    };
    let on_gpu = match strategy {
        Strategy::Rebuild(b) => b,
        _ => Build::GPU_LBVH,
    };
    let mut builder = Rebuilder::new(gpu, mesh0, on_gpu);
    let start = Instant::now();
    let mut bvh = builder.build(mesh0, first);
    adaptive.built(
        first,
        mesh0.triangle_count(),
        start.elapsed().as_secs_f64(),
        TreeCost::of(bvh.bvh()),
    );
    let mut since = 0u32;
    let mut records = Vec::with_capacity(frames.len());
    for (f, (mesh, rays, light, reference)) in frames.iter().enumerate() {
        let start = Instant::now();
        let mut guard_ratio = f64::NAN;
        let rebuilt = if f == 0 {
            true
        } else {
            match strategy {
                Strategy::Rebuild(b) => {
                    bvh = builder.build(mesh, b);
                    true
                }
                Strategy::Refit => {
                    bvh.refit(mesh.positions()).expect("same topology");
                    false
                }
                Strategy::RefitPartial => {
                    let (_, done) = (bvh
                        .refit_partial(mesh.positions(), &PartialOptions::default()))
                    .expect("same topology, default options");
                    done.subtrees > 0
                }
                Strategy::RefitEvery(k) => {
                    since += 1;
                    if since >= k {
                        since = 0;
                        bvh = build(mesh, Builder::LBVH);
                        true
                    } else {
                        bvh.refit(mesh.positions()).expect("same topology");
                        false
                    }
                }
                Strategy::Lauterbach(t) => {
                    let d = bvh.refit(mesh.positions()).expect("same topology");
                    if d > t {
                        bvh = build(mesh, Builder::LBVH);
                    }
                    d > t
                }
                Strategy::Structure(_) => unreachable!("run by grid_rows"),
                Strategy::Options(_) => unreachable!("run by option_rows"),
                Strategy::Adaptive { partial, .. } => {
                    // As the plugin: a motion that outpaces refitting is rebuilt without a refit.
                    let due = adaptive.outpaced() || {
                        let (_, sah) =
                            (bvh.refit_with_sah(mesh.positions())).expect("same topology");
                        let cost = TreeCost::measured(bvh.bvh(), sah);
                        adaptive.after_refit(cost, settings.rays as f64)
                    };
                    let p = adaptive.prediction();
                    if p.fresh_sah > 0.0 {
                        guard_ratio = p.sah / p.fresh_sah;
                    }
                    // As the plugin: the degraded triangles are counted only when the rent made a
                    // rebuild due.
                    let options = PartialOptions::default();
                    if partial
                        && adaptive.prediction().verdict == Verdict::Rent
                        && adaptive.prefer_partial(bvh.bvh().degraded_primitives(&options).unwrap())
                    {
                        let t = Instant::now();
                        let done = (bvh.rebuild_degraded(mesh.positions(), &options))
                            .expect("same topology, default options");
                        let sah = bvh.bvh().sah_cost();
                        adaptive.partially_rebuilt(done.primitives, t.elapsed().as_secs_f64(), sah);
                        done.subtrees > 0
                    } else if due {
                        let b = adaptive.prediction().build;
                        let t = Instant::now();
                        bvh = builder.build(mesh, b);
                        let cost = TreeCost::of(bvh.bvh());
                        adaptive.built(b, mesh.triangle_count(), t.elapsed().as_secs_f64(), cost);
                        while let Some(c) = adaptive.calibration() {
                            let t = Instant::now();
                            let tree = builder.build(mesh, c);
                            let s = t.elapsed().as_secs_f64();
                            adaptive.calibrated(c, mesh.triangle_count(), s, tree.bvh().sah_cost());
                        }
                        true
                    } else {
                        false
                    }
                }
            }
        };
        let update_s = if f == 0 {
            0.0
        } else {
            start.elapsed().as_secs_f64()
        };
        let cost = bvh.bvh().sah_cost();
        let (query_s, steps) = query(&bvh, rays, *light);
        if matches!(strategy, Strategy::Adaptive { .. }) {
            adaptive.queried(rays.len() as f64, cost, query_s);
        }
        let checked = &rays[..settings.checked_rays.min(rays.len())];
        records.push(FrameRecord {
            frame: f as u32,
            update_s,
            query_s,
            rebuilt,
            sah_ratio: cost / reference.sah.max(1e-30),
            steps_ratio: steps as f64 / rays.len().max(1) as f64 / reference.steps.max(1e-30),
            mismatches: mismatches(|r| bvh.closest_hit(r).map(|h| h.t), mesh, checked),
            guard_ratio,
        });
    }
    records
}

/// The middle value (the upper one of an even count): one preempted batch on a busy machine moves a mean
/// far more than it moves this.
pub fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// A planner row's name: `planned → ` the option it settled on, then in brackets how many rounds it used
/// each option in (`options`: name and count; unused ones left out).
pub fn planned_label<'a>(
    settled: &str,
    options: impl IntoIterator<Item = (&'a str, usize)>,
) -> String {
    let picked: Vec<String> = (options.into_iter())
        .filter(|(_, k)| *k > 0)
        .map(|(name, k)| format!("{name} {k}"))
        .collect();
    format!("planned → {settled} ({})", picked.join(", "))
}
