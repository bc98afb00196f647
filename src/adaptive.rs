//! The adaptive rebuild policy: a cost model of one mesh's frame, with its constants learned online from
//! measured timings. Our design (the research gives a fixed threshold, thesis §4.1.5, and the observation
//! that SAH pays off with many rays per triangle, seed 004 §6.3); the evaluation harness
//! (`examples/report`) measures it against every fixed strategy.
//!
//! The model: a frame costs update time plus query time, and query time is proportional to rays × the
//! tree's SAH cost. Each builder is tried once (on the refits after the first build); from then on the
//! builder is the one whose predicted rebuild time plus query time over the typical interval between
//! rebuilds is least. After each refit, the extra query time the refitted tree costs against a fresh tree
//! of that builder, `rate · rays · (C_now − C_fresh)`, is accumulated, and the mesh is rebuilt once the sum
//! exceeds the predicted rebuild time (the ski-rental rule: pay for the rebuild once the rent paid equals
//! it). Learned constants, exponentially weighted means of measurements: seconds per triangle per build and
//! SAH cost relative to the other builders (per builder), seconds per ray per unit of SAH cost, rays per
//! frame and frames between rebuilds. A guard rebuilds when the cost exceeds a fresh tree's by
//! [`AdaptivePolicy::max_cost_rise`] whatever the model says, which bounds the error when few rays are cast.
//!
//! Cost: a few arithmetic operations per call; the caller supplies the tree's SAH cost
//! ([`crate::bvh::Bvh::sah_cost`], one pass over the nodes, about the cost of a refit).
//!
//! ```
//! use kinetrace::adaptive::AdaptivePolicy;
//! use kinetrace::bvh::Builder;
//! let mut policy = AdaptivePolicy::new(&[Builder::LBVH]);
//! policy.built(Builder::LBVH, 10_000, 0.004, 55.0); // a 10k-triangle build took 4 ms; SAH cost 55
//! policy.queried(20_000, 55.0, 0.010); // 20k rays took 10 ms
//! // Each frame at cost 70 costs about 2.7 ms more in queries than the fresh tree did:
//! assert!(!policy.after_refit(70.0, 20_000)); // 2.7 ms of rent < 4 ms: keep refitting
//! assert!(policy.after_refit(70.0, 20_000)); // 5.5 ms > 4 ms: rebuild now
//! assert!(!AdaptivePolicy::new(&[]).after_refit(1.0, 0)); // nothing learned, nothing to pay
//! ```

use crate::bvh::Builder;

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

/// What is learned about one builder.
#[derive(Clone, Copy, Debug)]
struct BuilderModel {
    builder: Builder,
    seconds_per_triangle: Mean,
    /// SAH cost reached, relative to the running reference cost (the first builder's).
    cost: Mean,
}

/// The adaptive policy of one mesh (see the module docs). Keep one per mesh; it allocates only in `new`.
#[derive(Clone, Debug)]
pub struct AdaptivePolicy {
    builders: Vec<BuilderModel>,
    /// Seconds per ray per unit of SAH cost.
    query_rate: Mean,
    /// Frames between rebuilds.
    interval: Mean,
    /// Rays per frame.
    rays: Mean,
    /// SAH cost of the first tree built: builders' costs are relative to it.
    reference: f64,
    triangles: usize,
    cost_built: f64,
    rent: f64,
    frames: u32,
    /// Rebuild when the SAH cost exceeds the built tree's by this factor (1.4 by default).
    pub max_cost_rise: f64,
}

impl AdaptivePolicy {
    /// A policy choosing among `builders` (at least one; an empty slice means LBVH).
    pub fn new(builders: &[Builder]) -> Self {
        let list = if builders.is_empty() {
            &[Builder::LBVH][..]
        } else {
            builders
        };
        Self {
            builders: list
                .iter()
                .map(|&builder| BuilderModel {
                    builder,
                    seconds_per_triangle: Mean::default(),
                    cost: Mean::default(),
                })
                .collect(),
            query_rate: Mean::default(),
            interval: Mean::default(),
            rays: Mean::default(),
            reference: 0.0,
            triangles: 0,
            cost_built: 0.0,
            rent: 0.0,
            frames: 0,
            max_cost_rise: 1.4,
        }
    }

    /// The builder to use for the next rebuild: an untried one first, then the cheapest predicted.
    pub fn builder(&self) -> Builder {
        if let Some(b) = self.builders.iter().find(|b| b.cost.0.is_none()) {
            return b.builder;
        }
        let interval = self.interval.0.unwrap_or(1.0).max(1.0);
        let rate = self.query_rate.0.unwrap_or(0.0);
        let rays = self.rays.0.unwrap_or(0.0);
        let predicted = |b: &BuilderModel| {
            b.seconds_per_triangle.0.unwrap_or(0.0) * self.triangles as f64
                + rate * rays * b.cost.0.unwrap_or(1.0) * self.reference * interval
        };
        self.builders
            .iter()
            .min_by(|a, b| predicted(a).total_cmp(&predicted(b)))
            .map_or(Builder::LBVH, |b| b.builder)
    }

    /// Records a rebuild: its builder, triangle count, measured seconds and the new tree's SAH cost.
    /// A non-finite or negative cost or time is not learned from (the rebuild still resets the rent).
    pub fn built(&mut self, builder: Builder, triangles: usize, seconds: f64, sah_cost: f64) {
        let valid =
            sah_cost.is_finite() && sah_cost >= 0.0 && seconds.is_finite() && seconds >= 0.0;
        if let Some(i) = self
            .builders
            .iter()
            .position(|b| b.builder == builder)
            .filter(|_| valid)
        {
            // Re-anchor the unit of cost to this frame (the scene's cost drifts as it moves), then learn.
            match self.builders[i].cost.0 {
                Some(rel) if rel > 0.0 => self.reference = sah_cost / rel,
                _ if self.reference <= 0.0 => self.reference = sah_cost,
                _ => {}
            }
            let reference = if self.reference > 0.0 {
                self.reference
            } else {
                1.0
            };
            let b = &mut self.builders[i];
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

    /// Records a frame's queries: rays cast, the tree's SAH cost and the measured seconds.
    pub fn queried(&mut self, rays: usize, sah_cost: f64, seconds: f64) {
        if rays > 0 && sah_cost > 0.0 {
            self.query_rate.add(seconds / (rays as f64 * sah_cost));
            self.rays.add(rays as f64);
        }
    }

    /// After a refit to SAH cost `sah_cost`, with `rays` rays expected this frame: true to rebuild now
    /// (with [`builder`](Self::builder)). The refits after the first build try each untried builder once.
    pub fn after_refit(&mut self, sah_cost: f64, rays: usize) -> bool {
        self.frames += 1;
        if self.cost_built <= 0.0 {
            return false;
        }
        let next = self.builder();
        let Some(rel) = self.model(next).and_then(|b| b.cost.0) else {
            return true; // an untried builder: measure it
        };
        let target = rel * self.reference;
        if sah_cost > self.max_cost_rise * target {
            return true;
        }
        let rate = self.query_rate.0.unwrap_or(0.0);
        self.rent += rate * rays as f64 * (sah_cost - target).max(0.0);
        self.rent > self.predicted_rebuild(next)
    }

    fn model(&self, builder: Builder) -> Option<&BuilderModel> {
        self.builders.iter().find(|b| b.builder == builder)
    }

    /// Predicted seconds of a rebuild with `builder` (0 before it was measured).
    pub fn predicted_rebuild(&self, builder: Builder) -> f64 {
        self.model(builder)
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
        p.queried(1000, 10.0, 1e-5); // 1 ns per ray per unit of cost
        // The cost rises by 1 per frame: the rent after k frames is 1e-6 · k(k+1)/2 s, first above 1 ms
        // at k = 45.
        let k = (1..1000)
            .find(|&k| p.after_refit(10.0 + k as f64, 1000))
            .unwrap();
        assert_eq!(k, 45);
    }

    #[test]
    fn non_finite_measurements_are_not_learned() {
        let mut p = AdaptivePolicy::new(&[Builder::LBVH]);
        p.built(Builder::LBVH, 1000, 1e-3, 10.0);
        p.queried(1000, 10.0, 1e-5);
        p.built(Builder::LBVH, 1000, f64::NAN, f64::INFINITY);
        p.queried(1000, f64::NAN, f64::NAN);
        assert!((p.predicted_rebuild(Builder::LBVH) - 1e-3).abs() < 1e-12);
        // Still the analytic rebuild frame of rebuilds_when_the_rent_reaches_the_rebuild_cost.
        p.max_cost_rise = f64::INFINITY;
        let k = (1..1000)
            .find(|&k| p.after_refit(10.0 + k as f64, 1000))
            .unwrap();
        assert_eq!(k, 45);
    }

    #[test]
    fn the_guard_bounds_the_cost_rise() {
        let mut p = AdaptivePolicy::new(&[Builder::LBVH]);
        p.built(Builder::LBVH, 1000, 1.0, 10.0);
        assert!(!p.after_refit(13.9, 0));
        assert!(p.after_refit(14.1, 0));
    }

    /// LBVH builds in 1 ms to twice the SAH tree's cost; SAH builds in 100 ms. With a rebuild every frame,
    /// SAH pays off once 1e-8 · rays > 0.099 s, i.e. above 9.9 million rays per frame.
    fn choice(rays: usize) -> Builder {
        let mut p = AdaptivePolicy::new(&[Builder::LBVH, Builder::SAH]);
        p.built(Builder::LBVH, 1000, 1e-3, 20.0);
        assert!(p.after_refit(20.0, rays), "SAH is untried");
        assert_eq!(p.builder(), Builder::SAH);
        p.built(Builder::SAH, 1000, 0.1, 10.0);
        p.queried(rays, 10.0, 1e-8 * rays as f64);
        p.builder()
    }

    #[test]
    fn the_builder_follows_the_ray_load() {
        assert_eq!(choice(1_000_000), Builder::LBVH);
        assert_eq!(choice(100_000_000), Builder::SAH);
    }
}
