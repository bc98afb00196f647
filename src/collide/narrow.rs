//! The narrow phase: exact triangle tests on the leaf pairs the traversal finds.
//!
//! [`Discrete`] tests this frame's triangles; [`super::swept`] tests their motion over the frame. Both
//! walk a leaf pair the same way ([`slot_pairs`]).

use super::Contact;
use super::bvtt::{Pair, PairStats, Visit};
use super::tri_tri::triangle_contact;
use crate::MeshBvh;
use crate::bvh::Node;
use glam::{Affine3A, Vec3};

/// One mesh's triangles as the narrow phase reads them.
#[derive(Clone, Copy)]
pub(crate) struct Side<'a> {
    tris: &'a [[Vec3; 3]],
    indices: &'a [[u32; 3]],
    prims: &'a [u32],
}

impl<'a> Side<'a> {
    pub(crate) fn of(m: &'a MeshBvh) -> Self {
        Side {
            tris: m.slot_triangles(),
            indices: m.slot_indices(),
            prims: m.bvh().prim_indices(),
        }
    }
}

/// The exact test run on the triangle pairs of overlapping leaves.
pub(crate) trait NarrowPhase: Sync {
    /// What a touching pair gives.
    type Out: Copy + Send + Sync;
    /// Tests the triangle pairs of two overlapping leaves, appending what touches to `out`.
    fn leaves(
        &self,
        a: &Node,
        b: &Node,
        same: bool,
        stats: &mut PairStats,
        out: &mut Vec<Self::Out>,
    );
    /// The triangles of a result, for sorting: `(triangle_a, triangle_b)`.
    fn key(out: &Self::Out) -> (u32, u32);
}

/// Calls `test(slot_a, slot_b)` for the triangle pairs of two leaves that need a test: slot pairs `i < j`
/// for a leaf against itself; and for one mesh against itself (`itself`: its slots' vertex indices and
/// triangle ids), only pairs that share no vertex — neighbours touch by construction — each with the
/// lower triangle id first, so that a pair is reported the same way whichever leaf order found it.
#[inline]
pub(crate) fn slot_pairs(
    a: &Node,
    b: &Node,
    same: bool,
    itself: Option<(&[[u32; 3]], &[u32])>,
    stats: &mut PairStats,
    mut test: impl FnMut(usize, usize),
) {
    stats.leaf_pairs += 1;
    for sa in a.slots() {
        for sb in b.slots() {
            if same && sb <= sa {
                continue;
            }
            let (mut sa, mut sb) = (sa, sb);
            if let Some((idx, prims)) = itself {
                if idx[sa].iter().any(|v| idx[sb].contains(v)) {
                    continue;
                }
                if prims[sb] < prims[sa] {
                    (sa, sb) = (sb, sa);
                }
            }
            stats.triangle_tests += 1;
            test(sa, sb);
        }
    }
}

/// Discrete contacts: both meshes, `b`'s placement in `a`'s frame (`None` when they share one) and
/// whether it is one mesh against itself.
#[derive(Clone, Copy)]
pub(crate) struct Discrete<'a> {
    pub(crate) a: Side<'a>,
    pub(crate) b: Side<'a>,
    pub(crate) b_to_a: Option<Affine3A>,
    pub(crate) itself: bool,
}

impl NarrowPhase for Discrete<'_> {
    type Out = Contact;

    /// Contacts are in `a`'s frame; against itself `triangle_a < triangle_b`.
    #[inline]
    fn leaves(
        &self,
        la: &Node,
        lb: &Node,
        same: bool,
        stats: &mut PairStats,
        out: &mut Vec<Contact>,
    ) {
        let itself = self.itself.then_some((self.a.indices, self.a.prims));
        slot_pairs(la, lb, same, itself, stats, |sa, sb| {
            let tb = match &self.b_to_a {
                Some(x) => self.b.tris[sb].map(|p| x.transform_point3(p)),
                None => self.b.tris[sb],
            };
            let contact = triangle_contact(&self.a.tris[sa], &tb);
            if let Some(c) = contact {
                out.push(Contact {
                    triangle_a: self.a.prims[sa],
                    triangle_b: self.b.prims[sb],
                    point: c.point,
                    normal: c.normal,
                    depth: c.depth,
                });
            }
        });
    }

    #[inline]
    fn key(c: &Contact) -> (u32, u32) {
        (c.triangle_a, c.triangle_b)
    }
}

/// A traversal visitor that runs the narrow phase and, when asked, records where the traversal stopped.
pub(crate) struct Collect<'a, N: NarrowPhase> {
    pub(crate) narrow: &'a N,
    pub(crate) found: &'a mut Vec<N::Out>,
    /// Where the traversal stopped (the front), when recorded.
    pub(crate) stopped: Option<&'a mut Vec<Pair>>,
}

impl<N: NarrowPhase> Visit for Collect<'_, N> {
    #[inline]
    fn leaves(&mut self, a: &Node, b: &Node, same: bool, stats: &mut PairStats) {
        self.narrow.leaves(a, b, same, stats, self.found);
    }

    #[inline]
    fn stopped(&mut self, pair: Pair) {
        if let Some(s) = self.stopped.as_deref_mut() {
            s.push(pair);
        }
    }
}
