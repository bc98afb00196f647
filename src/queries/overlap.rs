//! Which triangles of a mesh a shape overlaps.

use super::closest::is_absent;
use super::shapes::Shape;
use crate::MeshBvh;
use crate::bvh::MAX_DEPTH;
use glam::Vec3;

impl MeshBvh {
    /// Writes into `out` (cleared first) the primitive indices of the triangles that the closed `shape`
    /// touches or overlaps, in ascending order.
    ///
    /// Each candidate from the tree is decided in `f64` (closest point for spheres, segment–triangle distance
    /// for capsules, a separating-axis test for boxes), so a triangle at exactly the shape's surface counts up
    /// to `f64` rounding. Zero-area triangles are absent. An invalid shape ([`Shape::is_valid`]) overlaps
    /// nothing.
    ///
    /// Cost: a traversal of the boxes that overlap the shape's bounding box, one exact test per triangle in
    /// them, and a sort of the result. No allocation once `out` has grown to the result's size.
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
        if !shape.is_valid() {
            return;
        }
        let nodes = self.bvh().nodes();
        let Some(root) = nodes.first() else { return };
        let bounds = shape.bounds();
        if !root.aabb().overlaps(&bounds) {
            return;
        }
        let tris = self.slot_triangles();
        let prims = self.bvh().prim_indices();
        let mut stack = [0u32; MAX_DEPTH];
        let mut sp = 0;
        let mut cur = 0usize;
        loop {
            let n = &nodes[cur];
            if n.is_leaf() {
                for slot in n.slots() {
                    let t = &tris[slot];
                    if !is_absent(t) && shape.overlaps_triangle(t.map(Vec3::as_dvec3)) {
                        out.push(prims[slot]);
                    }
                }
            } else {
                let c = n.left();
                let (a, b) = (
                    nodes[c].aabb().overlaps(&bounds),
                    nodes[c + 1].aabb().overlaps(&bounds),
                );
                if a || b {
                    if a && b {
                        stack[sp] = (c + 1) as u32;
                        sp += 1;
                    }
                    cur = if a { c } else { c + 1 };
                    continue;
                }
            }
            if sp == 0 {
                break;
            }
            sp -= 1;
            cur = stack[sp] as usize;
        }
        out.sort_unstable();
    }
}
