//! The ray sets every suite traces: coherent camera rays over a mesh and random rays through its box.

use glam::Vec3;
use kinetrace::scenes::SceneRng;
use kinetrace::{Aabb, Mesh, Ray};

pub use crate::camera::Orbit;

impl Orbit {
    /// The camera around `mesh`'s box.
    pub fn of(mesh: &Mesh, from: Vec3, distance: f32) -> Orbit {
        let bounds = mesh
            .triangle_bounds()
            .iter()
            .fold(Aabb::EMPTY, |a, t| a.union(t));
        Orbit::around(bounds, from, distance)
    }
}

/// About `n` camera rays (row-major, a pinhole camera looking at the mesh from outside) and as many random
/// rays (origins uniform in the mesh's box, uniform directions); unit directions, unbounded.
pub fn camera_and_random(mesh: &Mesh, n: usize) -> [(&'static str, Vec<Ray>); 2] {
    let Orbit {
        bounds: b,
        eye,
        fwd,
        right,
        up,
        ..
    } = Orbit::of(mesh, Vec3::new(0.55, 0.45, 0.7), 1.1);
    let side = (n as f64).sqrt() as usize;
    let camera = (0..side * side)
        .map(|i| {
            let (x, y) = (
                (i % side) as f32 / side as f32 - 0.5,
                (i / side) as f32 / side as f32 - 0.5,
            );
            Ray::new(eye, (fwd + right * x * 0.9 + up * y * 0.9).normalize())
        })
        .collect();
    let mut r = SceneRng::new(99);
    let random = (0..side * side)
        .map(|_| Ray::new(b.min + b.extent() * r.vec3(0.0, 1.0), r.direction()))
        .collect();
    [("coherent", camera), ("random", random)]
}
