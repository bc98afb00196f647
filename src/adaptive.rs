//! The adaptive rebuild policy: a cost model of one mesh's frame, with its constants learned online from
//! measured timings. Our design (the research gives a fixed threshold, thesis §4.1.5, and the observation
//! that SAH pays off with many rays per triangle, seed 004 §6.3); the evaluation harness
//! (`examples/report`) measures it against every fixed strategy.
//!
//! The model: a frame costs update time plus query time, and query time is proportional to rays × the
//! tree's SAH cost. The policy chooses among [`Build`]s — a builder on a [`Device`], e.g. CPU LBVH, CPU
//! hybrid with k LBVH levels, CPU binned SAH, GPU LBVH — each learned apart. Each build is tried once (on
//! the refits after the first build); from then on the build is the one whose predicted rebuild time plus
//! query time over the typical interval between rebuilds is least. After each refit, the extra query time
//! the refitted tree costs against a fresh tree of that build, `rate · rays · (C_now − C_fresh)`, is
//! accumulated, and the mesh is rebuilt once the sum exceeds the predicted rebuild time (the ski-rental
//! rule: pay for the rebuild once the rent paid equals it). Learned constants, exponentially weighted means
//! of measurements: seconds per triangle per build and SAH cost relative to the other builds (per build),
//! seconds per ray per unit of SAH cost, rays per frame and frames between rebuilds. A guard rebuilds when
//! the cost exceeds a fresh tree's by [`AdaptivePolicy::max_cost_rise`] whatever the model says, which
//! bounds the error when few rays are cast. A policy only ever picks one of the builds it was given: give
//! it GPU builds only where a GPU exists.
//!
//! Cost: a few arithmetic operations per call; the caller supplies the tree's SAH cost
//! ([`crate::bvh::Bvh::sah_cost`], one pass over the nodes, about the cost of a refit).
//!
//! ```
//! use kinetrace::adaptive::{AdaptivePolicy, Verdict};
//! use kinetrace::bvh::Builder;
//! let mut policy = AdaptivePolicy::new(&[Builder::LBVH]);
//! policy.built(Builder::LBVH, 10_000, 0.004, 55.0); // a 10k-triangle build took 4 ms; SAH cost 55
//! policy.queried(20_000.0, 55.0, 0.010); // 20k rays took 10 ms
//! // Each frame at cost 70 costs about 2.7 ms more in queries than the fresh tree did:
//! assert!(!policy.after_refit(70.0, 20_000.0)); // 2.7 ms of rent < 4 ms: keep refitting
//! assert!(policy.after_refit(70.0, 20_000.0)); // 5.5 ms > 4 ms: rebuild now
//! let why = policy.prediction();
//! assert_eq!(why.verdict, Verdict::Rent);
//! assert!(why.rent_s > why.rebuild_s);
//! assert!(!AdaptivePolicy::new(&[]).after_refit(1.0, 0.0)); // nothing learned, nothing to pay
//! ```

use crate::bvh::Builder;
use std::fmt;

/// Where a tree is built.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Device {
    /// On the CPU (all threads with the `parallel` feature).
    #[default]
    Cpu,
    /// On the GPU (feature `gpu`), which builds LBVH over 30-bit codes only ([`Build::GPU_LBVH`]); the
    /// tree is read back so that CPU queries can use it.
    Gpu,
}

/// A way to rebuild a tree: a builder on a device.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Build {
    /// The algorithm ([`Builder::Hybrid`] takes its number of LBVH levels `k`).
    pub builder: Builder,
    /// Where it runs.
    pub device: Device,
}

impl Build {
    /// `builder` on the CPU.
    pub const fn cpu(builder: Builder) -> Build {
        Build {
            builder,
            device: Device::Cpu,
        }
    }

    /// LBVH over 30-bit codes on the GPU: the one build the GPU back end has.
    pub const GPU_LBVH: Build = Build {
        builder: Builder::LBVH,
        device: Device::Gpu,
    };
}

impl From<Builder> for Build {
    fn from(builder: Builder) -> Build {
        Build::cpu(builder)
    }
}

impl fmt::Display for Build {
    /// The builder's name, with `-gpu` for GPU builds (`lbvh`, `lbvh-gpu`).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let device = match self.device {
            Device::Cpu => "",
            Device::Gpu => "-gpu",
        };
        write!(f, "{}{device}", self.builder.name())
    }
}

/// What [`AdaptivePolicy::after_refit`] decided, and on which ground.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Verdict {
    /// Keep the refitted tree: the rent paid so far is below the rebuild's predicted cost (or nothing was
    /// built yet to compare with).
    #[default]
    Keep,
    /// Rebuild to measure a build not tried yet.
    Explore,
    /// Rebuild: the SAH cost rose past [`AdaptivePolicy::max_cost_rise`] × a fresh tree's.
    Guard,
    /// Rebuild: the extra query time paid since the last rebuild exceeds the rebuild's predicted time.
    Rent,
}

/// The numbers behind the last decision of [`AdaptivePolicy::after_refit`]: what users see in
/// [`TraceStats`](crate::ecs::TraceStats) to learn why a mesh was or was not rebuilt.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Prediction {
    /// The decision.
    pub verdict: Verdict,
    /// The build a rebuild uses now.
    pub build: Build,
    /// Its predicted seconds (0 before it was measured).
    pub rebuild_s: f64,
    /// Extra query seconds the refitted tree has cost since the last rebuild, this frame included.
    pub rent_s: f64,
    /// The refitted tree's SAH cost.
    pub sah: f64,
    /// The predicted SAH cost of a fresh tree of `build` (0 while unknown).
    pub fresh_sah: f64,
}

impl Default for Prediction {
    fn default() -> Self {
        Self {
            verdict: Verdict::Keep,
            build: Build::cpu(Builder::LBVH),
            rebuild_s: 0.0,
            rent_s: 0.0,
            sah: 0.0,
            fresh_sah: 0.0,
        }
    }
}

/// Weight of a new measurement in the running means.
const LEARN: f64 = 0.3;

/// A running mean that starts at its first sample.
#[derive(Clone, Copy, Debug, Default)]
struct Mean(Option<f64>);

impl Mean {
    fn add(&mut self, x: f64) {
        if x.is_finite() {
            self.0 = Some(self.0.map_or(x, |m| m + LEARN * (x - m)));
        }
    }
}

/// What is learned about one build.
#[derive(Clone, Copy, Debug)]
struct BuildModel {
    build: Build,
    seconds_per_triangle: Mean,
    /// SAH cost reached, relative to the running reference cost (the first build's).
    cost: Mean,
}

/// The adaptive policy of one mesh (see the module docs). Keep one per mesh; it allocates only when made.
#[derive(Clone, Debug)]
pub struct AdaptivePolicy {
    builds: Vec<BuildModel>,
    /// Seconds per ray per unit of SAH cost.
    query_rate: Mean,
    /// Frames between rebuilds.
    interval: Mean,
    /// Rays per frame.
    rays: Mean,
    /// SAH cost of the first tree built: builds' costs are relative to it.
    reference: f64,
    triangles: usize,
    cost_built: f64,
    rent: f64,
    frames: u32,
    last: Prediction,
    /// Rebuild when the SAH cost exceeds the built tree's by this factor (1.4 by default).
    pub max_cost_rise: f64,
}

impl AdaptivePolicy {
    /// A policy choosing among `builders` on the CPU (at least one; an empty slice means LBVH).
    pub fn new(builders: &[Builder]) -> Self {
        Self::from_builds(builders.iter().map(|&b| Build::cpu(b)))
    }

    /// A policy choosing among `builds` (at least one; an empty slice means CPU LBVH), e.g. the CPU
    /// builders plus [`Build::GPU_LBVH`] where a GPU exists. Each build's time is learned apart, so the
    /// policy picks the cheaper device for this mesh's size.
    pub fn with_builds(builds: &[Build]) -> Self {
        Self::from_builds(builds.iter().copied())
    }

    fn from_builds(builds: impl Iterator<Item = Build>) -> Self {
        let mut builds: Vec<BuildModel> = builds
            .map(|build| BuildModel {
                build,
                seconds_per_triangle: Mean::default(),
                cost: Mean::default(),
            })
            .collect();
        if builds.is_empty() {
            builds.push(BuildModel {
                build: Build::cpu(Builder::LBVH),
                seconds_per_triangle: Mean::default(),
                cost: Mean::default(),
            });
        }
        Self {
            builds,
            query_rate: Mean::default(),
            interval: Mean::default(),
            rays: Mean::default(),
            reference: 0.0,
            triangles: 0,
            cost_built: 0.0,
            rent: 0.0,
            frames: 0,
            last: Prediction::default(),
            max_cost_rise: 1.4,
        }
    }

    /// The build to use for the next rebuild: an untried one first (in the order given), then the cheapest
    /// predicted.
    pub fn next_build(&self) -> Build {
        if let Some(b) = self.builds.iter().find(|b| b.cost.0.is_none()) {
            return b.build;
        }
        let interval = self.interval.0.unwrap_or(1.0).max(1.0);
        let rate = self.query_rate.0.unwrap_or(0.0);
        let rays = self.rays.0.unwrap_or(0.0);
        let predicted = |b: &BuildModel| {
            b.seconds_per_triangle.0.unwrap_or(0.0) * self.triangles as f64
                + rate * rays * b.cost.0.unwrap_or(1.0) * self.reference * interval
        };
        self.builds
            .iter()
            .min_by(|a, b| predicted(a).total_cmp(&predicted(b)))
            .map_or(Build::cpu(Builder::LBVH), |b| b.build)
    }

    /// Records a rebuild: its build, triangle count, measured seconds and the new tree's SAH cost.
    /// A non-finite or negative cost or time is not learned from (the rebuild still resets the rent).
    pub fn built(
        &mut self,
        build: impl Into<Build>,
        triangles: usize,
        seconds: f64,
        sah_cost: f64,
    ) {
        let build = build.into();
        let valid =
            sah_cost.is_finite() && sah_cost >= 0.0 && seconds.is_finite() && seconds >= 0.0;
        if let Some(i) = self
            .builds
            .iter()
            .position(|b| b.build == build)
            .filter(|_| valid)
        {
            // Re-anchor the unit of cost to this frame (the scene's cost drifts as it moves), then learn.
            match self.builds[i].cost.0 {
                Some(rel) if rel > 0.0 => self.reference = sah_cost / rel,
                _ if self.reference <= 0.0 => self.reference = sah_cost,
                _ => {}
            }
            let reference = if self.reference > 0.0 {
                self.reference
            } else {
                1.0
            };
            let b = &mut self.builds[i];
            b.seconds_per_triangle
                .add(seconds / triangles.max(1) as f64);
            b.cost.add(sah_cost / reference);
        }
        if self.frames > 0 {
            self.interval.add(self.frames as f64);
        }
        self.triangles = triangles;
        if valid {
            self.cost_built = sah_cost;
        }
        self.rent = 0.0;
        self.frames = 0;
    }

    /// Records a frame's queries: rays cast (fractional where a caller apportions a batch over meshes), the
    /// tree's SAH cost and the measured seconds.
    pub fn queried(&mut self, rays: f64, sah_cost: f64, seconds: f64) {
        if rays > 0.0 && sah_cost > 0.0 {
            self.query_rate.add(seconds / (rays * sah_cost));
            self.rays.add(rays);
        }
    }

    /// After a refit to SAH cost `sah_cost`, with `rays` rays expected this frame: true to rebuild now
    /// (with [`next_build`](Self::next_build)); the grounds are in [`prediction`](Self::prediction). The
    /// refits after the first build try each untried build once.
    pub fn after_refit(&mut self, sah_cost: f64, rays: f64) -> bool {
        self.frames += 1;
        let build = self.next_build();
        let mut p = Prediction {
            verdict: Verdict::Keep,
            build,
            rebuild_s: self.predicted_rebuild(build),
            rent_s: self.rent,
            sah: sah_cost,
            fresh_sah: 0.0,
        };
        if self.cost_built > 0.0 {
            p.verdict = match self.model(build).and_then(|b| b.cost.0) {
                None => Verdict::Explore,
                Some(rel) => {
                    p.fresh_sah = rel * self.reference;
                    if sah_cost > self.max_cost_rise * p.fresh_sah {
                        Verdict::Guard
                    } else {
                        let rate = self.query_rate.0.unwrap_or(0.0);
                        self.rent += rate * rays.max(0.0) * (sah_cost - p.fresh_sah).max(0.0);
                        p.rent_s = self.rent;
                        if self.rent > p.rebuild_s {
                            Verdict::Rent
                        } else {
                            Verdict::Keep
                        }
                    }
                }
            };
        }
        self.last = p;
        p.verdict != Verdict::Keep
    }

    /// Why the last [`after_refit`](Self::after_refit) decided as it did (the default before any).
    pub fn prediction(&self) -> Prediction {
        self.last
    }

    fn model(&self, build: Build) -> Option<&BuildModel> {
        self.builds.iter().find(|b| b.build == build)
    }

    /// Predicted seconds of a rebuild with `build` (0 before it was measured).
    pub fn predicted_rebuild(&self, build: impl Into<Build>) -> f64 {
        self.model(build.into())
            .and_then(|b| b.seconds_per_triangle.0)
            .unwrap_or(0.0)
            * self.triangles as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rebuilds_when_the_rent_reaches_the_rebuild_cost() {
        let mut p = AdaptivePolicy::new(&[Builder::LBVH]);
        p.max_cost_rise = f64::INFINITY;
        p.built(Builder::LBVH, 1000, 1e-3, 10.0); // 1 ms per rebuild
        p.queried(1000.0, 10.0, 1e-5); // 1 ns per ray per unit of cost
        // The cost rises by 1 per frame: the rent after k frames is 1e-6 · k(k+1)/2 s, first above 1 ms
        // at k = 45.
        let k = (1..1000)
            .find(|&k| p.after_refit(10.0 + k as f64, 1000.0))
            .unwrap();
        assert_eq!(k, 45);
    }

    #[test]
    fn non_finite_measurements_are_not_learned() {
        let mut p = AdaptivePolicy::new(&[Builder::LBVH]);
        p.built(Builder::LBVH, 1000, 1e-3, 10.0);
        p.queried(1000.0, 10.0, 1e-5);
        p.built(Builder::LBVH, 1000, f64::NAN, f64::INFINITY);
        p.queried(1000.0, f64::NAN, f64::NAN);
        assert!((p.predicted_rebuild(Builder::LBVH) - 1e-3).abs() < 1e-12);
        // Still the analytic rebuild frame of rebuilds_when_the_rent_reaches_the_rebuild_cost.
        p.max_cost_rise = f64::INFINITY;
        let k = (1..1000)
            .find(|&k| p.after_refit(10.0 + k as f64, 1000.0))
            .unwrap();
        assert_eq!(k, 45);
    }

    #[test]
    fn the_guard_bounds_the_cost_rise() {
        let mut p = AdaptivePolicy::new(&[Builder::LBVH]);
        p.built(Builder::LBVH, 1000, 1.0, 10.0);
        assert!(!p.after_refit(13.9, 0.0));
        assert!(p.after_refit(14.1, 0.0));
        let why = p.prediction();
        assert_eq!((why.verdict, why.rent_s), (Verdict::Guard, 0.0));
        assert_eq!((why.sah, why.fresh_sah), (14.1, 10.0));
    }

    /// LBVH builds in 1 ms to twice the SAH tree's cost; SAH builds in 100 ms. With a rebuild every frame,
    /// SAH pays off once 1e-8 · rays > 0.099 s, i.e. above 9.9 million rays per frame.
    fn choice(rays: f64) -> Build {
        let mut p = AdaptivePolicy::new(&[Builder::LBVH, Builder::SAH]);
        p.built(Builder::LBVH, 1000, 1e-3, 20.0);
        assert!(p.after_refit(20.0, rays), "SAH is untried");
        assert_eq!(p.prediction().verdict, Verdict::Explore);
        assert_eq!(p.next_build(), Build::cpu(Builder::SAH));
        p.built(Builder::SAH, 1000, 0.1, 10.0);
        p.queried(rays, 10.0, 1e-8 * rays);
        p.next_build()
    }

    #[test]
    fn the_builder_follows_the_ray_load() {
        assert_eq!(choice(1e6), Build::cpu(Builder::LBVH));
        assert_eq!(choice(1e8), Build::cpu(Builder::SAH));
    }

    /// The same builder on two devices: each device's time is learned apart, and the cheaper one wins
    /// whichever it is.
    #[test]
    fn the_device_is_the_cheaper_one() {
        for (cpu_s, gpu_s, expect) in [(1e-3, 4e-3, Device::Cpu), (4e-3, 1e-3, Device::Gpu)] {
            let mut p = AdaptivePolicy::with_builds(&[Build::cpu(Builder::LBVH), Build::GPU_LBVH]);
            assert_eq!(p.next_build(), Build::cpu(Builder::LBVH));
            p.built(Builder::LBVH, 1000, cpu_s, 20.0);
            assert!(p.after_refit(20.0, 0.0), "the GPU build is untried");
            assert_eq!(p.next_build(), Build::GPU_LBVH);
            p.built(Build::GPU_LBVH, 1000, gpu_s, 20.0);
            assert_eq!(p.next_build().device, expect);
            assert_eq!(p.predicted_rebuild(Build::GPU_LBVH), gpu_s);
        }
    }

    /// Given only CPU builds, no history of measurements makes the policy choose a GPU build.
    #[test]
    fn no_gpu_build_unless_given_one() {
        let mut p = AdaptivePolicy::new(&[Builder::LBVH, Builder::HYBRID, Builder::SAH]);
        let mut cost = 10.0;
        for frame in 0..200 {
            let next = p.next_build();
            assert_eq!(next.device, Device::Cpu);
            if frame == 0 || p.after_refit(cost, 1e4) {
                // The GPU-like timing of a build that was never offered is simply not learned.
                p.built(Build::GPU_LBVH, 1000, 1e-9, 5.0);
                p.built(next, 1000, 1e-3 * (1 + frame % 3) as f64, 10.0);
                cost = 10.0;
            }
            p.queried(1e4, cost, 1e-3);
            cost += 1.0;
            assert_eq!(p.prediction().build.device, Device::Cpu);
        }
    }
}
