//! The ray-space hierarchy's node: a sphere holding the ray origins and a cone holding the directions (the
//! seed's 8 floats, plus the cone's cosine and sine so that the test needs no trigonometry).
//!
//! Rounding slack: [`RayNode::enclosing`] grows the radius by 1e-6 of itself plus 1e-6 of the coordinates'
//! magnitude, and the spread by 1e-6 of itself plus 2e-6 rad, so that every child's origins and directions
//! lie inside the parent when measured exactly (f64) — the f32 sums, differences and `atan2` err by a few
//! 1e-7 relative. [`RayNode::hits_sphere`] accepts distances up to 1e-5 of the point's distance beyond the
//! exact bound. Both only make culling more conservative.

use crate::Ray;
use glam::Vec3;
use std::f32::consts::PI;

/// Relative padding of the computed bounds (see the module docs).
const PAD: f32 = 1e-6;

/// A set of rays: every origin within `radius` of `center`, every direction within `spread` of `axis`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RayNode {
    /// Centre of the sphere over the origins.
    pub center: Vec3,
    /// Radius of that sphere.
    pub radius: f32,
    /// Unit axis of the cone over the directions.
    pub axis: Vec3,
    /// Half-angle of the cone, in radians, at most π.
    pub spread: f32,
    cos_spread: f32,
    sin_spread: f32,
}

impl RayNode {
    /// The node of one valid ray: radius and spread zero.
    pub fn of_ray(ray: &Ray) -> Self {
        Self::new(ray.origin, 0.0, ray.dir().normalize(), 0.0)
    }

    fn new(center: Vec3, radius: f32, axis: Vec3, spread: f32) -> Self {
        let spread = spread.min(PI);
        Self {
            center,
            radius,
            axis,
            spread,
            cos_spread: spread.cos(),
            sin_spread: spread.sin(),
        }
    }

    /// A node holding all of `children` (at least one): the sphere around the mean of their centres, the
    /// cone around the normalised sum of their axes (the first child's axis when the sum vanishes). Not the
    /// minimal enclosing sphere or cone; the seed's pairwise unions (its Eqs. 3.12–3.15) are looser still.
    pub fn enclosing(children: &[RayNode]) -> Self {
        let n = children.len() as f32;
        let center = children.iter().map(|c| c.center).sum::<Vec3>() / n;
        let (mut radius, mut scale) = (0.0f32, center.abs().max_element());
        for c in children {
            radius = radius.max(c.center.distance(center) + c.radius);
            scale = scale.max(c.center.abs().max_element());
        }
        let axis = children
            .iter()
            .map(|c| c.axis)
            .sum::<Vec3>()
            .try_normalize()
            .unwrap_or(children[0].axis);
        let spread = children.iter().fold(0.0f32, |s, c| {
            s.max(c.axis.cross(axis).length().atan2(c.axis.dot(axis)) + c.spread)
        });
        Self::new(
            center,
            radius * (1.0 + PAD) + PAD * scale,
            axis,
            spread * (1.0 + PAD) + 2.0 * PAD,
        )
    }

    /// The cone's cosine and sine of [`spread`](Self::spread), as the sphere test reads them.
    #[cfg(feature = "gpu")]
    pub(crate) fn spread_cos_sin(&self) -> (f32, f32) {
        (self.cos_spread, self.sin_spread)
    }

    /// False only when no ray of the node can meet the sphere (`center`, `radius`) at any `t >= 0`.
    ///
    /// The rays lie in the cone from `self.center` widened by `self.radius`; the test compares the exact
    /// distance from the sphere's centre to that cone (zero inside it, `|v|` behind its apex, else
    /// `|v| sin(angle - spread)`) with the sum of the radii. Cost: about 20 flops, no division.
    #[inline]
    pub fn hits_sphere(&self, center: Vec3, radius: f32) -> bool {
        let v = center - self.center;
        let len = v.length();
        let c = v.dot(self.axis);
        let reach = radius + self.radius + 1e-5 * (len + self.center.abs().max_element());
        if c >= len * self.cos_spread {
            return true;
        }
        let s = v.cross(self.axis).length();
        let dist = if c * self.cos_spread + s * self.sin_spread <= 0.0 {
            len
        } else {
            s * self.cos_spread - c * self.sin_spread
        };
        dist <= reach
    }
}

/// A sphere around `points` (at least one): the centre of their box, the largest distance to it, padded
/// like [`RayNode::enclosing`]. Not minimal (the seed uses Gärtner's minimal sphere for meshes).
pub(crate) fn bounding_sphere(points: &[Vec3]) -> (Vec3, f32) {
    let (lo, hi) = points.iter().fold((points[0], points[0]), |(lo, hi), &p| {
        (lo.min(p), hi.max(p))
    });
    let center = (lo + hi) * 0.5;
    let radius = points.iter().fold(0.0f32, |r, p| r.max(p.distance(center)));
    let scale = lo.abs().max(hi.abs()).max_element();
    (center, radius * (1.0 + PAD) + PAD * scale)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sphere_test_matches_the_geometry() {
        // One ray from the origin along +x.
        let n = RayNode::of_ray(&Ray::new(Vec3::ZERO, Vec3::X));
        assert!(n.hits_sphere(Vec3::new(5.0, 0.9, 0.0), 1.0));
        assert!(!n.hits_sphere(Vec3::new(5.0, 1.1, 0.0), 1.0));
        // Behind the origin only the distance to the apex counts.
        assert!(n.hits_sphere(Vec3::new(-0.9, 0.0, 0.0), 1.0));
        assert!(!n.hits_sphere(Vec3::new(-1.1, 0.0, 0.0), 1.0));
        // A 45° cone: a point at 60° from the axis, distance 2, is 2·sin(15°) ≈ 0.518 away.
        let m = RayNode::new(Vec3::ZERO, 0.0, Vec3::X, PI / 4.0);
        let p = Vec3::new(1.0, 3f32.sqrt(), 0.0);
        assert!(m.hits_sphere(p, 0.53));
        assert!(!m.hits_sphere(p, 0.50));
    }
}
