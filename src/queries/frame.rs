//! The frame a query runs in: the mesh's own, or the world's through an instance's affine map.
//!
//! A query whose shape survives the map (any shape under a rotation, translation and uniform scale; a
//! point under any affine map) is better carried into the mesh's frame, where the tree is. A sphere under
//! a non-uniform scale or a shear is no longer a sphere; such queries run in the world instead, on the
//! tree's boxes and triangles carried through the map: the triangles exactly (in `f64`), the boxes as the
//! box around their eight carried corners, widened to hold every carried triangle despite rounding.

use crate::bvh::Node;
use crate::geometry::Aabb;
use glam::{Affine3A, DAffine3, DVec3, Vec3};

/// Where a query's geometry lives.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Frame {
    /// The mesh's own frame: boxes and triangles as the tree stores them.
    Mesh,
    /// The world: boxes and triangles carried through this map (mesh → world).
    World(DAffine3),
}

impl Frame {
    /// The world frame of an instance placed by `to_world`.
    pub(crate) fn world(to_world: &Affine3A) -> Frame {
        Frame::World(DAffine3 {
            matrix3: glam::DMat3::from_cols(
                Vec3::from(to_world.matrix3.x_axis).as_dvec3(),
                Vec3::from(to_world.matrix3.y_axis).as_dvec3(),
                Vec3::from(to_world.matrix3.z_axis).as_dvec3(),
            ),
            translation: Vec3::from(to_world.translation).as_dvec3(),
        })
    }

    /// The node's box in this frame (in the world: holds every carried triangle of the node).
    #[inline(always)]
    pub(crate) fn node_box(&self, n: &Node) -> Aabb {
        match self {
            Frame::Mesh => n.aabb(),
            Frame::World(m) => {
                let b = n.aabb();
                let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
                for c in b.corners() {
                    let w = m.transform_point3(c.as_dvec3());
                    lo = lo.min(w);
                    hi = hi.max(w);
                }
                // The f64 corners are within 1e-15 of the true ones; 2 f32 ulp of the magnitude covers that
                // and the rounding to f32.
                let pad = lo.abs().max(hi.abs()).max_element() as f32 * 2.0 * f32::EPSILON;
                Aabb::new(lo.as_vec3() - pad, hi.as_vec3() + pad)
            }
        }
    }

    /// A stored triangle's corners in this frame, in `f64`.
    #[inline(always)]
    pub(crate) fn triangle(&self, t: &[Vec3; 3]) -> [DVec3; 3] {
        match self {
            Frame::Mesh => t.map(Vec3::as_dvec3),
            Frame::World(m) => t.map(|p| m.transform_point3(p.as_dvec3())),
        }
    }
}
