//! A pinhole camera's primary hits, in pixel order: where the report's and the bench's secondary rays
//! (shadow rays toward lights, reflection rays) start.

use glam::Vec3;
use kinetrace::raysort::RayScene;
use kinetrace::{Hit, Ray};

/// A square image of `side`² pixels seen from `eye` along `fwd`, the image plane one unit ahead and
/// spanned by `right` and `up` (unit vectors: a 53° view).
pub struct Camera {
    pub eye: Vec3,
    pub fwd: Vec3,
    pub right: Vec3,
    pub up: Vec3,
    pub side: usize,
}

impl Camera {
    /// Calls `f(pixel, primary ray, hit)` for each pixel, row by row, whose ray hits `scene`'s mesh.
    pub fn hits(&self, scene: &RayScene, mut f: impl FnMut(u32, &Ray, &Hit)) {
        let side = self.side;
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
