//! Simultaneous traversal of two BVHs, or of one BVH against itself: a walk of the bounding volume test tree
//! (BVTT, thesis §6.2.3), whose nodes are pairs of tree nodes.
//!
//! A pair whose boxes are disjoint ends its branch; a pair of overlapping leaves is handed to the narrow
//! phase; otherwise one node of the pair is split, always by the same rule:
//!
//! > split `a` when it is an inner node and `b` is a leaf or no shallower than `a`; else split `b`.
//!
//! The rule depends on topology only (depths, not box sizes), so a refitted tree has the same BVTT as the
//! tree it was built as, and a front recorded on it stays a cover of its leaf pairs (see [`super::front`]).
//! Against itself a tree's pairs `(x, x)` always overlap and split into `(l, l)`, `(r, r)` and `(l, r)`,
//! with no box test.
//!
//! Cost: one box test per visited pair (6 comparisons; 3 small matrix-vector products more when tree `b`
//! moves relative to tree `a`), no allocation beyond the caller's stack.

use crate::bvh::Node;
use glam::{Affine3A, Mat3A, Vec3A};

/// Relative rounding slack of a box moved into the other tree's frame (see [`Frame::place`]): far above the
/// few ulps a transform costs, so any point of a moved box lies inside its placed box on the CPU and on
/// the GPU alike, whatever order either rounds in.
pub(crate) const PLACE_SLACK: f32 = 8.0 * f32::EPSILON;

/// Where tree `b`'s boxes are tested: in `b`'s own frame when the trees share one, else moved into `a`'s.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Frame {
    /// Both trees live in the same frame: boxes are compared as stored.
    Same,
    /// `b`'s boxes are moved into `a`'s frame by `m · x + t`.
    Moved { m: Mat3A, abs_m: Mat3A, t: Vec3A },
}

impl Frame {
    /// The frame for tree `b` placed in tree `a`'s frame by `b_to_a`.
    pub(crate) fn new(b_to_a: &Affine3A) -> Frame {
        if *b_to_a == Affine3A::IDENTITY {
            return Frame::Same;
        }
        let m = b_to_a.matrix3;
        let abs_m = Mat3A::from_cols(m.x_axis.abs(), m.y_axis.abs(), m.z_axis.abs());
        Frame::Moved {
            m,
            abs_m,
            t: b_to_a.translation,
        }
    }

    /// Box of `b`-node `n` in `a`'s frame: the moved box of center and half-extent, widened by
    /// [`PLACE_SLACK`] times the magnitudes involved. The GPU's `place` in `shaders/collide.wgsl` is this
    /// expression.
    #[inline]
    pub(crate) fn place(&self, n: &Node) -> (Vec3A, Vec3A) {
        let (min, max) = (Vec3A::from_array(n.min), Vec3A::from_array(n.max));
        match self {
            Frame::Same => (min, max),
            Frame::Moved { m, abs_m, t } => {
                let c = (min + max) * 0.5;
                let e = (max - min) * 0.5;
                let c2 = *m * c + *t;
                let e2 = *abs_m * e + (*abs_m * (c.abs() + e) + t.abs()) * PLACE_SLACK;
                (c2 - e2, c2 + e2)
            }
        }
    }
}

/// A node of the BVTT: node `a` of the first tree, node `b` of the second, with their depths.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Pair {
    pub(crate) a: u32,
    pub(crate) b: u32,
    pub(crate) depth_a: u16,
    pub(crate) depth_b: u16,
}

impl Pair {
    /// The pair of the two roots.
    pub(crate) const ROOTS: Pair = Pair {
        a: 0,
        b: 0,
        depth_a: 0,
        depth_b: 0,
    };
}

/// Work counts of a collision query.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PairStats {
    /// Box–box tests (pairs of a node with itself are not tested).
    pub box_tests: u64,
    /// Pairs of overlapping leaves handed to the narrow phase.
    pub leaf_pairs: u64,
    /// Exact triangle–triangle tests run.
    pub triangle_tests: u64,
}

impl PairStats {
    /// Adds another count.
    pub fn add(&mut self, o: &PairStats) {
        self.box_tests += o.box_tests;
        self.leaf_pairs += o.leaf_pairs;
        self.triangle_tests += o.triangle_tests;
    }
}

/// What a traversal reports, besides the leaf pairs it finds.
pub(crate) trait Visit {
    /// Leaves `a` and `b` (node indices) overlap; `a == b` for a leaf against itself.
    fn leaves(&mut self, a: &Node, b: &Node, same: bool, stats: &mut PairStats);
    /// The traversal stopped at `pair` (disjoint boxes, or leaves): the pairs reported here form the front.
    #[inline]
    fn stopped(&mut self, _pair: Pair) {}
}

/// The BVTT of two trees (or of one tree and itself) in a frame.
#[derive(Clone, Copy)]
pub(crate) struct Bvtt<'a> {
    pub(crate) a: &'a [Node],
    pub(crate) b: &'a [Node],
    pub(crate) frame: Frame,
    /// One tree against itself (`a` and `b` are the same nodes).
    pub(crate) itself: bool,
}

impl<'a> Bvtt<'a> {
    /// The BVTT of trees `a` and `b`, with `b` placed in `a`'s frame by `b_to_a`.
    pub(crate) fn pair(a: &'a [Node], b: &'a [Node], b_to_a: &Affine3A) -> Self {
        Bvtt {
            a,
            b,
            frame: Frame::new(b_to_a),
            itself: false,
        }
    }

    /// The BVTT of a tree against itself.
    pub(crate) fn itself(nodes: &'a [Node]) -> Self {
        Bvtt {
            a: nodes,
            b: nodes,
            frame: Frame::Same,
            itself: true,
        }
    }

    /// True when either tree is empty: no pairs at all.
    pub(crate) fn is_empty(&self) -> bool {
        self.a.is_empty() || self.b.is_empty()
    }

    /// True for a node paired with itself (self-collision only).
    #[inline]
    pub(crate) fn is_self_pair(&self, p: &Pair) -> bool {
        self.itself && p.a == p.b
    }

    /// Box test of a pair.
    #[inline]
    pub(crate) fn overlap(&self, p: &Pair) -> bool {
        let na = &self.a[p.a as usize];
        let (bmin, bmax) = self.frame.place(&self.b[p.b as usize]);
        let (amin, amax) = (Vec3A::from_array(na.min), Vec3A::from_array(na.max));
        amin.cmple(bmax).all() && bmin.cmple(amax).all()
    }

    /// True when the rule splits `a` (the pair is not a leaf pair and not a self pair).
    #[inline]
    fn splits_a(&self, p: &Pair) -> bool {
        let (na, nb) = (&self.a[p.a as usize], &self.b[p.b as usize]);
        !na.is_leaf() && (nb.is_leaf() || p.depth_a <= p.depth_b)
    }

    /// The children of a pair that is neither a leaf pair nor a self pair, in traversal order.
    #[inline]
    pub(crate) fn children(&self, p: &Pair) -> [Pair; 2] {
        if self.splits_a(p) {
            let l = self.a[p.a as usize].left() as u32;
            let c = |a| Pair {
                a,
                depth_a: p.depth_a + 1,
                ..*p
            };
            [c(l), c(l + 1)]
        } else {
            let l = self.b[p.b as usize].left() as u32;
            let c = |b| Pair {
                b,
                depth_b: p.depth_b + 1,
                ..*p
            };
            [c(l), c(l + 1)]
        }
    }

    /// True when both nodes of the pair are leaves.
    #[inline]
    pub(crate) fn is_leaf_pair(&self, p: &Pair) -> bool {
        self.a[p.a as usize].is_leaf() && self.b[p.b as usize].is_leaf()
    }

    /// Visits one pair: a self pair or a pair of overlapping inner nodes gives its children to `push`; a
    /// pair of overlapping leaves goes to the narrow phase; a pair that ends is reported to `visit`.
    #[inline]
    fn step(
        &self,
        p: &Pair,
        visit: &mut impl Visit,
        stats: &mut PairStats,
        mut push: impl FnMut(Pair),
    ) {
        if self.is_self_pair(p) {
            let n = &self.a[p.a as usize];
            if n.is_leaf() {
                visit.leaves(n, n, true, stats);
                visit.stopped(*p);
            } else {
                let (l, depth) = (n.left() as u32, p.depth_a + 1);
                for (a, b) in [(l, l), (l + 1, l + 1), (l, l + 1)] {
                    push(Pair {
                        a,
                        b,
                        depth_a: depth,
                        depth_b: depth,
                    });
                }
            }
            return;
        }
        stats.box_tests += 1;
        if !self.overlap(p) {
            visit.stopped(*p);
        } else if self.is_leaf_pair(p) {
            visit.leaves(&self.a[p.a as usize], &self.b[p.b as usize], false, stats);
            visit.stopped(*p);
        } else {
            self.children(p).into_iter().for_each(push);
        }
    }

    /// Walks the BVTT below `start` (inclusive), depth first, with `stack` as scratch.
    pub(crate) fn walk(
        &self,
        start: Pair,
        stack: &mut Vec<Pair>,
        visit: &mut impl Visit,
        stats: &mut PairStats,
    ) {
        stack.clear();
        stack.push(start);
        while let Some(p) = stack.pop() {
            self.step(&p, visit, stats, |c| stack.push(c));
        }
    }

    /// Expands the BVTT breadth first from the roots into `out` until it holds at least `want` pairs or
    /// nothing is left to expand; pairs that end on the way are visited. The pairs in `out` are roots of
    /// disjoint sub-walks that together cover the rest of the BVTT: the way to split a query over threads.
    pub(crate) fn split(
        &self,
        want: usize,
        out: &mut Vec<Pair>,
        next: &mut Vec<Pair>,
        visit: &mut impl Visit,
        stats: &mut PairStats,
    ) {
        out.clear();
        if self.is_empty() {
            return;
        }
        out.push(Pair::ROOTS);
        while out.len() < want && !out.is_empty() {
            next.clear();
            for p in out.iter() {
                self.step(p, visit, stats, |c| next.push(c));
            }
            std::mem::swap(out, next);
        }
    }
}
