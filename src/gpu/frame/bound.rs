//! A conservative box of a resident mesh's current vertices, known on the CPU without reading anything
//! back: for a skin, from this frame's joint matrices (O(joints)); for positions uploaded from the CPU,
//! from the positions. The frame culls collider pairs with it and the adaptive policy weighs the rays a
//! mesh receives by it.
//!
//! Why it holds for linear-blend skinning: a skinned vertex is `Σ w_k · M_{j_k} p` with `p` in the
//! bind-pose box `B_j` of the vertices that joint `j` moves (weight > 0), widened for blend shapes by
//! `Σ_t |weight_t| · reach_jt`, `reach_jt` the largest displacement per axis that target `t` gives any of
//! those vertices. Each `M_j p` lies in the box of
//! `M_j`'s image of `B_j`, so the vertex lies in `W · H`, `H` the union of those boxes (convex) and `W =
//! Σ w_k`, between the least and greatest weight sum of any vertex. The box is widened by a relative
//! 2^-16 of its coordinates (about 500 f32 roundings), for the rounding of the GPU's skinning against this
//! arithmetic. Negative or non-finite weights break the argument: such a skin has no bound.

use crate::Aabb;
use crate::anim::{MorphTargets, SkinWeights};
use glam::{Affine3A, Mat4, Vec3};

/// Per joint, the bind-pose box of the vertices it moves and each blend shape's reach over them, and the
/// range of the vertices' weight sums. Made once per skinned mesh: O(vertices · (4 + targets)), 24 bytes
/// per joint plus 12 per joint and target.
pub(crate) struct SkinBound {
    boxes: Vec<Aabb>,
    /// `reach[joint · targets + t]`.
    reach: Vec<Vec3>,
    targets: usize,
    weight_sums: (f32, f32),
}

impl SkinBound {
    /// The joints' boxes over `rest` (and `morphs`' reach); `None` for weights outside `[0, ∞)`.
    pub fn new(
        rest: &[Vec3],
        skin: &SkinWeights,
        joints: usize,
        morphs: Option<&MorphTargets>,
    ) -> Option<Self> {
        let deltas = morphs.map_or(&[][..], |m| &m.deltas[..]);
        let targets = deltas.len();
        let mut boxes = vec![Aabb::EMPTY; joints];
        let mut reach = vec![Vec3::ZERO; joints * targets];
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for (v, ((p, j), w)) in rest.iter().zip(&skin.joints).zip(&skin.weights).enumerate() {
            if w.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
                return None;
            }
            for k in (0..4).filter(|&k| w[k] > 0.0) {
                let joint = j[k] as usize;
                boxes.get_mut(joint)?.grow(*p);
                for (t, d) in deltas.iter().enumerate() {
                    let r = &mut reach[joint * targets + t];
                    *r = r.max(d.get(v)?.abs());
                }
            }
            let sum: f32 = w.iter().sum();
            lo = lo.min(sum);
            hi = hi.max(sum);
        }
        Some(Self {
            boxes,
            reach,
            targets,
            weight_sums: (lo, hi),
        })
    }

    /// The object-space box of the vertices skinned with `matrices` after the blend shapes at
    /// `morph_weights` (missing weights count as 0): O(joints · (1 + targets)).
    pub fn bound(&self, matrices: &[Mat4], morph_weights: &[f32]) -> Aabb {
        let mut hull = Aabb::EMPTY;
        for (joint, (b, m)) in self.boxes.iter().zip(matrices).enumerate() {
            if b.is_empty() {
                continue;
            }
            let reach = &self.reach[joint * self.targets..][..self.targets];
            let grow: Vec3 = (reach.iter().zip(morph_weights))
                .map(|(r, w)| *r * w.abs())
                .sum();
            let morphed = Aabb::new(b.min - grow, b.max + grow);
            hull = hull.union(&transformed(&morphed, &Affine3A::from_mat4(*m)));
        }
        if hull.is_empty() {
            return hull;
        }
        let (a, b) = self.weight_sums;
        let ends = [hull.min * a, hull.min * b, hull.max * a, hull.max * b];
        let scaled = Aabb::new(
            ends.iter().copied().reduce(Vec3::min).expect("four"),
            ends.iter().copied().reduce(Vec3::max).expect("four"),
        );
        widened(&scaled)
    }
}

/// The box of `points`, widened as the skin's (the GPU rounds nothing here, but the caller compares it
/// with boxes that are).
pub(crate) fn of_points(points: &[Vec3]) -> Aabb {
    let mut b = Aabb::EMPTY;
    for p in points {
        b.grow(*p);
    }
    widened(&b)
}

/// The world box of `b` under `t`: its eight corners transformed, widened for the rounding.
pub(crate) fn world(b: &Aabb, t: &Affine3A) -> Aabb {
    if b.is_empty() {
        return *b;
    }
    widened(&transformed(b, t))
}

fn transformed(b: &Aabb, t: &Affine3A) -> Aabb {
    let mut out = Aabb::EMPTY;
    for c in b.corners() {
        out.grow(t.transform_point3(c));
    }
    out
}

/// `b` widened by 2^-16 of `|min| + |max| + extent` per axis.
fn widened(b: &Aabb) -> Aabb {
    if b.is_empty() {
        return *b;
    }
    let pad = (b.min.abs() + b.max.abs() + (b.max - b.min)) * (1.0 / 65536.0)
        + Vec3::splat(f32::MIN_POSITIVE);
    Aabb::new(b.min - pad, b.max + pad)
}
