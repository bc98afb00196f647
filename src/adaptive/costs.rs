//! The planner's learned costs, shared by every mesh that plans with the same table: build times per
//! build (and so per device) as seconds per unit of `n·log2 n`, the query rate, and per asset the relative
//! SAH cost each build reaches. Sharing is what lets the second instance of a character plan without
//! measuring anything, and a mesh of a new size start from the others' build times.

use super::{Build, Estimate};
use std::collections::HashMap;
use std::sync::{Arc, Mutex, MutexGuard};

/// The identity of a mesh asset: meshes with the same one share a topology, so each build makes trees of
/// the same relative quality on them. In the ECS it is the index buffer the meshes share; elsewhere
/// [`Asset::of_indices`] hashes one.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Asset {
    /// Triangles of the mesh.
    pub triangles: usize,
    /// Anything that tells assets of the same size apart (an index-buffer address or hash, an asset id).
    pub id: u64,
}

impl Asset {
    /// The asset of an index buffer, by an FNV-1a hash of its indices: O(n), once per mesh.
    pub fn of_indices(indices: &[u32]) -> Asset {
        let id = indices.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &i| {
            (h ^ i as u64).wrapping_mul(0x0100_0000_01b3)
        });
        Asset {
            triangles: indices.len() / 3,
            id,
        }
    }
}

/// The size term of a build's time: `n·log2 n` (at least `n`), the work of a sort-based or binned build
/// over `n` triangles. A build's seconds over this unit are what is learned and shared, so a time
/// measured at one size predicts another.
pub fn size_unit(triangles: usize) -> f64 {
    let n = triangles.max(1) as f64;
    n * n.log2().max(1.0)
}

#[derive(Default, Debug)]
pub(super) struct Tables {
    /// Seconds per [`size_unit`] of each build measured.
    pub time: Vec<(Build, Estimate)>,
    /// Query seconds per ray per unit of SAH cost.
    pub query_rate: Estimate,
    /// Per asset: the SAH cost each build reached, relative to the asset's unit (the cost of its first
    /// tree, carried over frames by each mesh's reference).
    pub quality: HashMap<Asset, Vec<(Build, Estimate)>>,
    /// Per asset: the per-frame change of `ln` of a fresh tree's cost (how the scene's own cost drifts
    /// as it moves), shared because instances of one character move alike.
    pub drift: HashMap<Asset, Estimate>,
    /// Per asset: the variance per frame of the random walk of `ln` of a fresh tree's cost around its
    /// trend, learned only from intervals between two exact (binned-SAH) anchors, whose own error is 0.
    pub walk: HashMap<Asset, Estimate>,
    /// Per asset: an upper bound of [`walk`](Self::walk), learned from every interval between rebuilds
    /// (whose anchors' own errors add to the walk's): it caps a walk learned in a phase the scene has
    /// left, where no two binned-SAH trees come to revise it.
    pub walk_bound: HashMap<Asset, Estimate>,
}

impl Tables {
    pub fn time(&self, build: Build) -> Option<&Estimate> {
        self.time.iter().find(|t| t.0 == build).map(|t| &t.1)
    }

    pub fn quality(&self, asset: &Asset, build: Build) -> Option<&Estimate> {
        self.quality
            .get(asset)?
            .iter()
            .find(|t| t.0 == build)
            .map(|t| &t.1)
    }
}

fn learn(list: &mut Vec<(Build, Estimate)>, build: Build, x: f64) {
    match list.iter_mut().find(|t| t.0 == build) {
        Some(t) => t.1.add(x),
        None => {
            let mut e = Estimate::default();
            e.add(x);
            list.push((build, e));
        }
    }
}

/// A cost table, cheap to clone: clones share one table (an `Arc` around a mutex). Give every mesh of a
/// world the same one ([`AdaptivePolicy::shared`](super::AdaptivePolicy::shared)); the ECS plugin does.
/// Lookups and updates lock it for a few operations and allocate only for a build or asset not seen
/// before.
#[derive(Clone, Debug, Default)]
pub struct CostTable(Arc<Mutex<Tables>>);

impl CostTable {
    /// An empty table.
    pub fn new() -> CostTable {
        CostTable::default()
    }

    pub(super) fn lock(&self) -> MutexGuard<'_, Tables> {
        // A panic elsewhere cannot leave the numbers half-written in a way that matters: keep using them.
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Learns that `build` built `triangles` triangles in `seconds`.
    pub(super) fn learn_time(&self, build: Build, triangles: usize, seconds: f64) {
        learn(&mut self.lock().time, build, seconds / size_unit(triangles));
    }

    /// Learns that `build` reached `relative` × the asset's unit of SAH cost.
    pub(super) fn learn_quality(&self, asset: Asset, build: Build, relative: f64) {
        learn(
            self.lock().quality.entry(asset).or_default(),
            build,
            relative,
        );
    }

    /// Learns one per-frame drift of `ln` of a fresh tree's cost on `asset`.
    pub(super) fn learn_drift(&self, asset: Asset, per_frame: f64) {
        self.lock().drift.entry(asset).or_default().add(per_frame);
    }

    /// Learns one per-frame variance of the random walk of `ln` of a fresh tree's cost on `asset`.
    pub(super) fn learn_walk(&self, asset: Asset, per_frame: f64) {
        self.lock().walk.entry(asset).or_default().add(per_frame);
    }

    /// Learns one per-frame upper bound of that variance (see [`Tables::walk_bound`]).
    pub(super) fn learn_walk_bound(&self, asset: Asset, per_frame: f64) {
        self.lock()
            .walk_bound
            .entry(asset)
            .or_default()
            .add(per_frame);
    }

    /// Forgets what was learned per asset (relative tree costs, drift and its walk) for every asset `keep` rejects:
    /// call it when an asset's last mesh is gone, so that a long-running world that streams meshes in
    /// and out does not grow the table without bound. Per-build times and the query rate are kept: they
    /// generalise across assets. O(assets).
    pub fn retain_assets(&self, mut keep: impl FnMut(&Asset) -> bool) {
        let mut t = self.lock();
        t.quality.retain(|a, _| keep(a));
        t.drift.retain(|a, _| keep(a));
        t.walk.retain(|a, _| keep(a));
        t.walk_bound.retain(|a, _| keep(a));
    }

    /// Whether `build` was measured on `asset` by any mesh sharing the table.
    pub fn measured(&self, asset: &Asset, build: Build) -> bool {
        self.lock().quality(asset, build).is_some()
    }

    /// The predicted seconds of building `triangles` triangles with `build`, if it was measured at any size.
    pub fn predicted_build_s(&self, build: Build, triangles: usize) -> Option<f64> {
        Some(self.lock().time(build)?.mean()? * size_unit(triangles))
    }
}
