//! The BVTT front kept between frames (after thesis §6.2.3, "BVTT front tracking").
//!
//! The front is where last frame's traversal stopped: pairs of disjoint nodes and pairs of overlapping
//! leaves. Together they cover every leaf pair of the BVTT exactly once, so while both trees keep their
//! topology (refitted, not rebuilt) the next query can start from them instead of from the roots: a front
//! pair that overlaps now is walked down as usual, one that does not stays. What that saves is the box
//! tests of the BVTT above the front — at most half of all tests (thesis), since every front pair is
//! tested anyway.
//!
//! Fronts only sink: as things move, pairs are split where boxes came to overlap and nothing merges them
//! back. The thesis moves the front up pair by pair (a disjoint pair is replaced by its parent when the
//! parent is disjoint too); that needs every pair's sibling found in the front each frame, which we
//! measured to cost more than it saved on the CPU. Instead the front remembers what a traversal from the
//! roots cost, and is dropped — the next query starts from the roots and records a fresh, shallow front —
//! as soon as restarting from it costs more box tests than that.
//!
//! Memory: 12 bytes per front pair.

use super::bvtt::Pair;

/// The front of one pair of trees (or one tree against itself), reused from query to query.
///
/// Give it to [`PairQuery::meshes_with_front`](super::PairQuery::meshes_with_front) or
/// [`PairQuery::itself_with_front`](super::PairQuery::itself_with_front) each frame. It notices by itself
/// when either tree was rebuilt ([`MeshBvh::topology_id`](crate::MeshBvh::topology_id) changed) and starts
/// again from the roots then. Allocates only when the front grows.
#[derive(Clone, Debug, Default)]
pub struct PairFront {
    /// Topology ids of the two trees the front belongs to.
    trees: Option<(u64, u64)>,
    pub(crate) pairs: Vec<Pair>,
    /// Where this query's traversal stopped.
    pub(crate) stopped: Vec<Pair>,
    /// Box tests of the last query that started from the roots.
    from_roots: u64,
    /// Whether the current query started from the front.
    resumed: bool,
}

impl PairFront {
    /// An empty front: the first query starts from the roots.
    pub fn new() -> Self {
        Self::default()
    }

    /// Pairs in the front (0 before the first query).
    pub fn len(&self) -> usize {
        self.pairs.len()
    }

    /// True before the first query.
    pub fn is_empty(&self) -> bool {
        self.pairs.is_empty()
    }

    /// Forgets the front: the next query starts from the roots.
    pub fn clear(&mut self) {
        self.trees = None;
        self.pairs.clear();
    }

    /// True when the front can restart a query over trees with these topology ids; otherwise it is reset
    /// for them and the query starts from the roots.
    pub(crate) fn resume(&mut self, trees: (u64, u64)) -> bool {
        self.resumed = self.trees == Some(trees) && !self.pairs.is_empty();
        if !self.resumed {
            self.trees = Some(trees);
            self.pairs.clear();
        }
        self.stopped.clear();
        self.resumed
    }

    /// Takes this query's stopping pairs as the next front, or drops the front when restarting from it
    /// cost more than starting from the roots did (`box_tests`: this query's).
    pub(crate) fn finish(&mut self, box_tests: u64) {
        if !self.resumed {
            self.from_roots = box_tests;
        }
        if self.resumed && box_tests > self.from_roots {
            self.pairs.clear();
        } else {
            std::mem::swap(&mut self.pairs, &mut self.stopped);
        }
        self.stopped.clear();
    }
}
