//! A compact 4-wide tree: the [`WideBvh`]'s nodes with child boxes quantised to 8 bits per plane relative
//! to the node's own box (CWBVH-style, Ylitie et al. 2017), 56 bytes a node instead of 112 (+16 of refit
//! sources).
//!
//! When to use: large static meshes whose memory matters more than the last bit of query speed
//! ([`MeshBvh::set_compact`](crate::MeshBvh::set_compact)). Answers stay exact: every quantised box contains
//! the float box it replaces, so no ray that reaches a triangle's box is culled, and the triangle test
//! decides as before (same triangle, or one hit at exactly the same `t`). Looser boxes only cost visits.
//!
//! Encoding, per node: `origin` = the node's box minimum, per axis a power-of-two `scale = 2^exp` large
//! enough that `origin + 255 · scale` reaches the box maximum; a lane's plane `p` is stored as `q` with
//! `q · scale + origin` (computed exactly so in `f32`, multiply then add, by the builder and by the
//! traversal) at or below a minimum plane (floor) and at or above a maximum plane (ceil). `q · scale` is
//! exact (8 bits times a power of two), so only the addition rounds, and the builder checks the rounded
//! value and steps `q` until it is conservative.
//!
//! Cost: quantising is one pass over the wide nodes; a node visit dequantises its 24 planes (a few
//! vector multiply-adds) before the same four-box test as the float tree. A refit re-derives the tree
//! (collapse + quantise): it is meant for meshes that do not deform.

use super::simd::RayLanes;
use super::{EMPTY_LANE, Visit, WIDTH, WideBvh, WideNode, walk};
use crate::bvh::traverse::Counter;
use crate::geometry::Ray;
use glam::Vec4;
use std::ops::Range;

/// One node of a [`CompactWideBvh`]: 56 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CompactNode {
    /// The node's box minimum: plane 0 of every lane.
    pub origin: [f32; 3],
    /// Per axis, `scale = 2^exp` (−126..=127).
    pub exp: [i8; 3],
    /// Unused (keeps the node at 56 bytes with 4-byte alignment).
    pub pad: u8,
    /// Quantised planes by row, as [`WideNode::bounds`]: `[min x, min y, min z, max x, max y, max z][lane]`.
    /// Unused lanes hold zeros (their payload says they are unused).
    pub q: [[u8; WIDTH]; 6],
    /// Lane payloads, exactly as [`WideNode::child`].
    pub child: [u32; WIDTH],
}

const _: () = assert!(std::mem::size_of::<CompactNode>() == 56);

/// `q · scale + origin`, the one dequantisation both the builder and the traversal compute (multiply then
/// add, no fused multiply-add, so the bits are the same everywhere).
#[inline(always)]
fn dequant(q: Vec4, scale: f32, origin: f32) -> Vec4 {
    q * Vec4::splat(scale) + Vec4::splat(origin)
}

/// `2^e` as an `f32`, for `e` in −126..=127.
#[inline(always)]
fn pow2(e: i8) -> f32 {
    f32::from_bits(((e as i32 + 127) as u32) << 23)
}

impl CompactNode {
    /// The float node with each lane's box dequantised (unused lanes empty).
    #[inline(always)]
    fn dequantise(&self) -> WideNode {
        let mut n = WideNode::EMPTY;
        let used = Vec4::from_array(self.child.map(|c| if c == EMPTY_LANE { 0.0 } else { 1.0 }))
            .cmpgt(Vec4::ZERO);
        for row in 0..6 {
            let a = row % 3;
            let q = Vec4::from_array(self.q[row].map(f32::from));
            let v = dequant(q, pow2(self.exp[a]), self.origin[a]);
            n.bounds[row] = Vec4::select(used, v, Vec4::from_array(n.bounds[row])).to_array();
        }
        n.child = self.child;
        n
    }

    /// Quantises a float node conservatively.
    fn quantise(node: &WideNode) -> CompactNode {
        let used: Vec<usize> = (0..WIDTH)
            .filter(|&i| node.child[i] != EMPTY_LANE)
            .collect();
        let mut c = CompactNode {
            origin: [0.0; 3],
            exp: [0; 3],
            pad: 0,
            q: [[0; WIDTH]; 6],
            child: node.child,
        };
        for a in 0..3 {
            let lo = used
                .iter()
                .map(|&i| node.bounds[a][i])
                .fold(f32::INFINITY, f32::min);
            let hi = used
                .iter()
                .map(|&i| node.bounds[3 + a][i])
                .fold(f32::NEG_INFINITY, f32::max);
            let at = |q: u8, e: i8| dequant(Vec4::splat(f32::from(q)), pow2(e), lo).x;
            // The least exponent whose 255 steps reach `hi` after rounding.
            let extent = f64::from(hi) - f64::from(lo);
            let mut e = if extent > 0.0 {
                ((extent / 255.0).log2().ceil() as i32).clamp(-126, 127) as i8
            } else {
                -126
            };
            while e < 127 && at(255, e) < hi {
                e += 1;
            }
            c.origin[a] = lo;
            c.exp[a] = e;
            let scale = f64::from(pow2(e));
            for &i in &used {
                let (pmin, pmax) = (node.bounds[a][i], node.bounds[3 + a][i]);
                let mut qmin = ((f64::from(pmin) - f64::from(lo)) / scale)
                    .floor()
                    .clamp(0.0, 255.0) as u8;
                while qmin > 0 && at(qmin, e) > pmin {
                    qmin -= 1;
                }
                let mut qmax = ((f64::from(pmax) - f64::from(lo)) / scale)
                    .ceil()
                    .clamp(0.0, 255.0) as u8;
                while qmax < 255 && at(qmax, e) < pmax {
                    qmax += 1;
                }
                debug_assert!(at(qmin, e) <= pmin && at(qmax, e) >= pmax);
                c.q[a][i] = qmin;
                c.q[3 + a][i] = qmax;
            }
        }
        c
    }
}

impl Visit for CompactNode {
    /// Dequantises the node, then tests it as a [`WideNode`].
    #[inline(always)]
    fn visit(&self, lanes: &RayLanes, tmax: f32) -> (u32, [f32; WIDTH], [u32; WIDTH]) {
        self.dequantise().visit(lanes, tmax)
    }
}

/// A [`WideBvh`] with quantised child boxes. See the [module docs](self).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CompactWideBvh {
    nodes: Vec<CompactNode>,
}

impl CompactWideBvh {
    /// Quantises every node of `wide` (same node order and payloads). O(wide nodes).
    pub fn quantise(wide: &WideBvh) -> CompactWideBvh {
        CompactWideBvh {
            nodes: wide.nodes().iter().map(CompactNode::quantise).collect(),
        }
    }

    /// The nodes, root first.
    pub fn nodes(&self) -> &[CompactNode] {
        &self.nodes
    }

    /// Bytes held by the nodes.
    pub fn memory_bytes(&self) -> usize {
        std::mem::size_of_val(self.nodes.as_slice())
    }

    /// The float box of lane `lane` of node `node` as the traversal sees it (empty for an unused lane).
    pub fn lane_box(&self, node: usize, lane: usize) -> crate::geometry::Aabb {
        self.nodes[node].dequantise().lane_box(lane)
    }

    /// [`WideBvh::traverse`] over the dequantised boxes.
    #[inline]
    pub(crate) fn traverse<C: Counter, T>(
        &self,
        slot_data: &[T],
        ray: &Ray,
        slack: f32,
        counter: &mut C,
        leaf: impl FnMut(Range<usize>, &mut f32) -> bool,
    ) {
        walk(&self.nodes, slot_data, ray, slack, counter, leaf);
    }
}
