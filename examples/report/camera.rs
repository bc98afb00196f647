//! A pinhole camera orbiting a mesh's box, and its primary hits in pixel order: the camera of the
//! bench's ray sets and of the report's and the bench's secondary rays (shadow rays toward lights,
//! reflection rays).

use glam::Vec3;
use kinetrace::raysort::RayScene;
use kinetrace::{Aabb, Hit, Ray};

/// A pinhole camera outside a box, looking at its centre from direction `from`, at `distance` box
/// diagonals: the box and its diagonal, and the camera's eye and unit axes.
pub struct Orbit {
    pub bounds: Aabb,
    pub size: f32,
    pub eye: Vec3,
    pub fwd: Vec3,
    pub right: Vec3,
    pub up: Vec3,
}

impl Orbit {
    /// The camera around `bounds` (a diagonal of at least 1e-3; a camera straight above the box
    /// takes +x for its right).
    pub fn around(bounds: Aabb, from: Vec3, distance: f32) -> Orbit {
        let (centre, size) = (bounds.center(), bounds.extent().length().max(1e-3));
        let eye = centre + from.normalize() * size * distance;
        let fwd = (centre - eye).normalize();
        let right = fwd.cross(Vec3::Y).normalize_or(Vec3::X);
        Orbit {
            bounds,
            size,
            eye,
            fwd,
            right,
            up: right.cross(fwd),
        }
    }

    /// Calls `f(pixel, primary ray, hit)` for each pixel of a `side`² image (the image plane one unit
    /// ahead, spanned by the unit axes: a 53° view), row by row, whose ray hits `scene`'s mesh.
    pub fn hits(&self, scene: &RayScene, side: usize, mut f: impl FnMut(u32, &Ray, &Hit)) {
        for pixel in 0..side * side {
            let (x, y) = (
                (pixel % side) as f32 / side as f32 - 0.5,
                (pixel / side) as f32 / side as f32 - 0.5,
            );
            let primary = Ray::new(self.eye, self.fwd + self.right * x + self.up * y);
            if let Some(h) = scene.bvh().closest_hit(&primary) {
                f(pixel as u32, &primary, &h);
            }
        }
    }
}
