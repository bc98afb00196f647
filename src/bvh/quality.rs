//! Tree quality: the surface area heuristic (SAH) cost.
//!
//! `cost = Σ_inner A(n)/A(root) · C_TRAV + Σ_leaf A(l)/A(root) · N(l) · C_ISECT`: the expected work of a
//! random ray that hits the root, under the usual assumption that a ray hits a box with probability
//! proportional to its surface area. Lower is better; only ratios between trees over the same primitives are
//! meaningful. The constants are those of the binned SAH builder.

use super::Bvh;

/// Cost of visiting an inner node (box tests of its two children).
pub const C_TRAV: f64 = 1.0;
/// Cost of one primitive test.
pub const C_ISECT: f64 = 1.0;

impl Bvh {
    /// SAH cost of the tree with [`C_TRAV`] and [`C_ISECT`] (0 for an empty tree). Areas are summed in `f64`,
    /// so huge and tiny coordinates give finite, exact-enough costs. When the root has no area (all
    /// primitives on one line or point), every node counts with probability 1.
    pub fn sah_cost(&self) -> f64 {
        let Some(root) = self.nodes.first() else {
            return 0.0;
        };
        let ra = root.aabb().half_area_f64();
        let p = |a: f64| if ra > 0.0 { a / ra } else { 1.0 };
        self.nodes
            .iter()
            .map(|n| {
                let a = p(n.aabb().half_area_f64());
                if n.is_leaf() {
                    a * n.count() as f64 * C_ISECT
                } else {
                    a * C_TRAV
                }
            })
            .sum()
    }
}
