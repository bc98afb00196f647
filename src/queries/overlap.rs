//! Which triangles of a mesh a shape overlaps.

use super::ascending::sort_ascending;
use super::frame::Frame;
use super::shapes::{OverlapTest, Shape};
use crate::MeshBvh;
use crate::bvh::{is_collapsed, traverse_by};
use std::ops::Range;

impl MeshBvh {
    /// Writes into `out` (cleared first) the primitive indices of the triangles that the closed `shape`
    /// touches or overlaps, in ascending order.
    ///
    /// Each candidate from the tree is decided in `f64` (closest point for spheres, segment–triangle distance
    /// for capsules, a separating-axis test for boxes), so a triangle at exactly the shape's surface counts up
    /// to `f64` rounding. Zero-area triangles are absent. An invalid shape ([`Shape::is_valid`]) overlaps
    /// nothing.
    ///
    /// Cost: a traversal of the boxes that overlap the shape's bounding box (for a sphere on the wide tree:
    /// the boxes within its radius), four boxes per test when the mesh has a wide tree, one exact test per
    /// triangle in them, and a sort of the result. On the wide tree a subtree whose box lies inside a sphere
    /// or box is reported whole, without tests below it (the same answer: every triangle in it passes the
    /// exact test); a box's test accepts a triangle with a corner well inside it before its separating
    /// axes. No allocation once `out` has grown to the result's size.
    ///
    /// ```
    /// use kinetrace::{Mesh, MeshBvh, bvh::BuildOptions, queries::Shape};
    /// use glam::Vec3;
    /// let quad = Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y], vec![0, 1, 2, 0, 2, 3])?;
    /// let bvh = MeshBvh::build(&quad, &BuildOptions::default())?;
    /// let mut touched = Vec::new();
    /// bvh.overlapping(&Shape::sphere(Vec3::new(0.9, 0.1, 0.05), 0.1), &mut touched);
    /// assert_eq!(touched, [0]);
    /// bvh.overlapping(&Shape::sphere(Vec3::new(0.5, 0.5, 0.05), 0.1), &mut touched);
    /// assert_eq!(touched, [0, 1]);
    /// # Ok::<(), kinetrace::Error>(())
    /// ```
    pub fn overlapping(&self, shape: &Shape, out: &mut Vec<u32>) {
        out.clear();
        self.overlapping_each(shape, Frame::Mesh, |p| out.push(p));
        sort_ascending(out);
    }

    /// Calls `found` with each triangle that `shape` (given in `frame`) overlaps, in tree order.
    pub(crate) fn overlapping_each(&self, shape: &Shape, frame: Frame, mut found: impl FnMut(u32)) {
        if !shape.is_valid() {
            return;
        }
        let bounds = shape.bounds();
        let test = OverlapTest::new(shape);
        let tris = self.slot_triangles();
        let prims = self.bvh().prim_indices();
        // A leaf's slots, and whether the walk found the leaf inside the shape: every present triangle of
        // such a leaf overlaps, by the exact test below too (see `walk_within`, `OverlapTest::holds`).
        let mut visit = |slots: Range<usize>, whole: bool| {
            if whole {
                for slot in slots.filter(|&s| !is_collapsed(&tris[s])) {
                    found(prims[slot]);
                }
                return;
            }
            // The frame by reference: `present` would copy it (13 words) into each leaf's iterator.
            for slot in slots.filter(|&s| !is_collapsed(&tris[s])) {
                let t = frame.triangle(&tris[slot]);
                // The triangle's box against the shape's (conservative) box first: exact comparisons.
                let (lo, hi) = (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]));
                let reach = lo.cmple(bounds.max.as_dvec3()) & hi.cmpge(bounds.min.as_dvec3());
                if reach.all() && test.triangle(t) {
                    found(prims[slot]);
                }
            }
        };
        match (frame, self.wide()) {
            // In the mesh's frame the wide tree's lanes are the boxes as stored: four at a time.
            // A ball's whole leaves lie within `r·(1 − 4·10⁻⁷)` of its centre: their corners pass the
            // corner test (exact to 10⁻¹⁵) and lie in the ball's box.
            (Frame::Mesh, Some(wide)) => match *shape {
                Shape::Sphere { center, radius } => {
                    wide.walk_within(center, f64::from(radius).powi(2), visit)
                }
                _ => wide.walk_overlapping(
                    &bounds,
                    |b| test.holds(b) && bounds.contains_box(b),
                    visit,
                ),
            },
            _ => traverse_by(
                self.bvh().nodes(),
                (),
                &mut (),
                |n, _| frame.node_box(n).overlaps(&bounds).then_some(()),
                |slots, _| {
                    visit(slots, false);
                    false
                },
            ),
        }
    }
}
