//! Rays and the conservative ray–box slab test.

use super::Aabb;
use glam::{BVec3, Vec3};

/// A ray `origin + t·dir` for `t` in `[tmin, tmax]`.
///
/// `dir` need not be normalised: every `t` the crate reports is in units of `dir`. The reciprocal direction
/// used by the box test is computed once here. Direction components that are zero or subnormal are flushed to
/// signed zero, whose reciprocal is `±∞`; the box test is written so that the `0 · ∞ = NaN` of a ray lying
/// exactly in a slab plane means "no limit on this axis" (see [`Ray::intersect_aabb`]).
///
/// A ray whose origin or direction is not finite, or whose direction is zero, is *invalid*: queries return
/// no hit for it rather than panicking (see [`Ray::is_valid`]).
///
/// The direction and the state derived from it are private so that they cannot go stale: build a new ray
/// ([`Ray::new`], [`Ray::with_range`], [`Ray::segment`], [`Ray::with_dir`]) to change the direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Start point.
    pub origin: Vec3,
    /// Direction (any non-zero length), zero and subnormal components flushed to signed zero.
    dir: Vec3,
    /// Reciprocal of `dir` per component, `±∞` where the component is (flushed to) zero.
    inv_dir: Vec3,
    /// Which components of `dir` have their sign bit set (`-0.0` included): selects the near slab plane.
    dir_neg: BVec3,
    /// Smallest accepted hit distance.
    pub tmin: f32,
    /// Largest accepted hit distance.
    pub tmax: f32,
}

impl Ray {
    /// A ray over `t ∈ [0, ∞)`.
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        Self::with_range(origin, dir, 0.0, f32::INFINITY)
    }

    /// A ray over `t ∈ [tmin, tmax]`. A range with `tmin > tmax` is empty (nothing is hit); a NaN bound
    /// makes the ray invalid. A negative `tmin` reaches behind the origin, on the CPU and the GPU alike.
    pub fn with_range(origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Self {
        let flush = |d: f32| {
            if d.abs() < f32::MIN_POSITIVE {
                0.0f32.copysign(d)
            } else {
                d
            }
        };
        let dir = Vec3::new(flush(dir.x), flush(dir.y), flush(dir.z));
        Self {
            origin,
            dir,
            inv_dir: dir.recip(),
            dir_neg: BVec3::new(
                dir.x.is_sign_negative(),
                dir.y.is_sign_negative(),
                dir.z.is_sign_negative(),
            ),
            tmin,
            tmax,
        }
    }

    /// The segment from `from` to `to` as a ray with `dir = to - from` over `t ∈ [0, 1]`: the form shadow
    /// (occlusion) queries take.
    pub fn segment(from: Vec3, to: Vec3) -> Self {
        Self::with_range(from, to - from, 0.0, 1.0)
    }

    /// The same ray (origin and range) with another direction; the derived state is recomputed.
    pub fn with_dir(&self, dir: Vec3) -> Self {
        Self::with_range(self.origin, dir, self.tmin, self.tmax)
    }

    /// The same ray with its range cut at `max_t`: `tmax` becomes `min(tmax, max_t)`. A NaN on either side
    /// gives a NaN `tmax`, so an invalid ray stays invalid ([`Ray::is_valid`]) and a NaN limit makes one,
    /// rather than `f32::min` quietly taking the other value (which turned a NaN range into an unlimited
    /// ray).
    #[inline]
    pub fn clipped(&self, max_t: f32) -> Self {
        let tmax = if max_t.is_nan() || self.tmax.is_nan() {
            f32::NAN
        } else {
            self.tmax.min(max_t)
        };
        Self { tmax, ..*self }
    }

    /// The direction, with zero and subnormal components flushed to signed zero.
    #[inline]
    pub fn dir(&self) -> Vec3 {
        self.dir
    }

    /// The reciprocal of [`Ray::dir`] per component, `±∞` where the component is zero.
    #[inline]
    pub fn inv_dir(&self) -> Vec3 {
        self.inv_dir
    }

    /// How far, in units of `t`, a triangle inside `bounds` may compute its hit nearer than the box it lies
    /// in admits: [`HIT_SLACK`] times the largest `t` at which the ray reaches one of the box's corner
    /// coordinates (the largest distance to a corner along an axis over the largest direction component).
    ///
    /// Why: the watertight test's `t` errs by ulps of the vertices' depths along the ray, not of `t`. A
    /// short hit on a large triangle — a face 0.005 from the origin whose corners lie a unit away, met at
    /// an angle — can come out a hundred ulps of `t` below the entry distance of its own box. A traversal
    /// that culled boxes at its best `t` moved out by [`robust_far`]'s few ulps then skipped such a
    /// triangle or not depending on the order it visited the tree in: different trees of one mesh (and the
    /// CPU's against the GPU's) kept different hits. Every ray traversal of a tree adds this slack for its
    /// root's box to its limit ([`robust_far`]`(tmax) + slack`); it costs the boxes it lets through, a hair
    /// beyond the best hit. Not a bound for a triangle met at a grazing angle, whose edge functions carry
    /// the rounding of its width across the ray. Zero for an empty box (nothing to hit), `+∞` when the
    /// distances overflow (nothing is culled).
    ///
    /// ```
    /// use kinetrace::{Aabb, Ray};
    /// use glam::Vec3;
    /// let ray = Ray::new(Vec3::ZERO, Vec3::new(0.0, 0.0, 2.0));
    /// let slack = ray.hit_slack(&Aabb::new(Vec3::splat(-1.0), Vec3::splat(4.0)));
    /// assert_eq!(slack, kinetrace::geometry::HIT_SLACK * 4.0 / 2.0);
    /// ```
    #[inline]
    pub fn hit_slack(&self, bounds: &Aabb) -> f32 {
        if bounds.is_empty() {
            return 0.0;
        }
        let reach = (bounds.min - self.origin)
            .abs()
            .max((bounds.max - self.origin).abs())
            .max_element();
        // `|1/d|` is `∞` along an axis the ray does not move on: the smallest is the largest component's.
        HIT_SLACK * reach * self.inv_dir.abs().min_element()
    }

    /// Which components of [`Ray::dir`] have their sign bit set (`-0.0` included).
    #[inline]
    pub fn dir_neg(&self) -> BVec3 {
        self.dir_neg
    }

    /// The point at distance `t`.
    #[inline]
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }

    /// False for rays that no query can answer: non-finite origin or direction, zero direction, NaN range.
    #[inline]
    pub fn is_valid(&self) -> bool {
        self.origin.is_finite()
            && self.dir.is_finite()
            && self.dir != Vec3::ZERO
            && !self.tmin.is_nan()
            && !self.tmax.is_nan()
    }

    /// Conservative slab test: the entry distance into `b` when the ray's `[tmin, tmax]` overlaps the box,
    /// else `None`.
    ///
    /// Follows Ize, "Robust BVH Ray Traversal" (JCGT 2013): the far distance is moved outward by `2 ulp` of
    /// its size ([`robust_far`]; behind the origin too, for a negative `tmin`), which covers the rounding of
    /// the subtractions and products, so a box the ray touches is never culled. It may accept boxes the ray
    /// misses by a rounding error; the triangle test settles those. The crate's traversals pass their
    /// current closest hit moved outward the same way (`robust_far(tmax)`), since a triangle's `t` may
    /// round below the entry distance of a box it lies in.
    ///
    /// The near and far planes of each axis are chosen by the direction's sign. On an axis where the
    /// direction is zero the distances are `±∞` (origin inside or outside the slab) or NaN (origin exactly
    /// on a plane). The per-axis distances are combined with `if a > b { a } else { b }` and the running
    /// value second — exactly what `maxss`/`minss` do — so a NaN axis falls out and a ray running inside a
    /// face of the box keeps it, on the min face and on the max face alike.
    #[inline]
    pub fn intersect_aabb(&self, b: &Aabb, tmax: f32) -> Option<f32> {
        let t0 = (b.min - self.origin) * self.inv_dir;
        let t1 = (b.max - self.origin) * self.inv_dir;
        let near = Vec3::select(self.dir_neg, t1, t0);
        let far = Vec3::select(self.dir_neg, t0, t1);
        let tnear = max_keep(near.x, max_keep(near.y, max_keep(near.z, self.tmin)));
        let tfar = min_keep(far.x, min_keep(far.y, min_keep(far.z, f32::INFINITY)));
        (tnear <= min_keep(robust_far(tfar), tmax)).then_some(tnear)
    }
}

/// `max(x, acc)`, returning `acc` when `x` is NaN (one `maxss`).
#[inline(always)]
pub(crate) fn max_keep(x: f32, acc: f32) -> f32 {
    if x > acc { x } else { acc }
}

/// `min(x, acc)`, returning `acc` when `x` is NaN (one `minss`).
#[inline(always)]
pub(crate) fn min_keep(x: f32, acc: f32) -> f32 {
    if x < acc { x } else { acc }
}

/// Ize's rounding bound for the far slab distance, `2 ulp(1)` of its size (see [`robust_far`]).
pub const ROBUST_FAR_SLACK: f32 = 2.0 * f32::EPSILON;

/// The absolute part of a traversal's limit ([`Ray::hit_slack`]), in `ulp(1)` of the largest `t` at which
/// the ray reaches a corner coordinate of the tree's box: 16, about twice the leading terms of the
/// watertight test's rounding bound on `t` (Pharr, Jakob and Humphreys, *Physically Based Rendering*, 3rd
/// ed., §3.9.6: `6·γ₃` of the vertices' largest depth along the ray, for a hit whose edge functions agree in
/// sign).
pub const HIT_SLACK: f32 = 16.0 * f32::EPSILON;

/// The far slab distance `far` moved outward by [`ROBUST_FAR_SLACK`] of its size, so that rounding never
/// culls a box the ray touches: `far · (1 + 2ε)` for a far plane ahead of the origin, `far · (1 − 2ε)` for
/// one behind it (a range with a negative `tmin`: scaling by `1 + 2ε` there would pull it inward and cull
/// a flat box the ray crosses behind its origin). Infinities stay infinite (an empty box's `−∞` too).
#[inline(always)]
pub fn robust_far(far: f32) -> f32 {
    far * (1.0 + ROBUST_FAR_SLACK.copysign(far))
}

/// The bound a nearest-first traversal tests boxes against when its best hit so far is at `tmax`:
/// [`robust_far`]`(tmax)` plus the ray's [`hit_slack`](Ray::hit_slack) for the tree (`slack`).
#[inline(always)]
pub(crate) fn hit_limit(tmax: f32, slack: f32) -> f32 {
    robust_far(tmax) + slack
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The slack's edge cases, against its definition worked by hand: axes the ray does not move on are
    /// skipped, an empty box has none, distances that overflow give `+∞` (nothing culled), never NaN.
    #[test]
    fn hit_slack_at_its_edges() {
        let b = Aabb::new(Vec3::new(-1.0, 2.0, -8.0), Vec3::new(3.0, 5.0, 1.0));
        // Reach 8 (z), largest direction component 4 (y; x and z do not move): 16 ε · 8 / 4.
        let r = Ray::new(Vec3::ZERO, Vec3::new(0.0, -4.0, 0.0));
        assert_eq!(r.hit_slack(&b), 32.0 * f32::EPSILON);
        // From (1, 1, 1) along (1, 2, −0.5): reach max(2, 4, 9) = 9 (z), over 2.
        let r = Ray::new(Vec3::ONE, Vec3::new(1.0, 2.0, -0.5));
        assert_eq!(r.hit_slack(&b), HIT_SLACK * 9.0 * 0.5);
        assert_eq!(r.hit_slack(&Aabb::EMPTY), 0.0);
        let far = Ray::new(Vec3::splat(-3e38), Vec3::new(1e-30, 0.0, 0.0));
        assert_eq!(
            far.hit_slack(&Aabb::new(Vec3::ZERO, Vec3::splat(3e38))),
            f32::INFINITY
        );
    }

    #[test]
    fn zero_direction_components_do_not_cull_touching_boxes() {
        let b = Aabb::new(Vec3::ZERO, Vec3::ONE);
        // Origin exactly on the box's x = 0 face, running along +y inside that plane.
        let r = Ray::new(Vec3::new(0.0, -1.0, 0.5), Vec3::Y);
        assert_eq!(r.intersect_aabb(&b, f32::INFINITY), Some(1.0));
        // Same on the max face.
        let r = Ray::new(Vec3::new(1.0, -1.0, 1.0), Vec3::Y);
        assert!(r.intersect_aabb(&b, f32::INFINITY).is_some());
        // Just outside the face: a miss.
        let r = Ray::new(Vec3::new(-1e-6, -1.0, 0.5), Vec3::Y);
        assert!(r.intersect_aabb(&b, f32::INFINITY).is_none());
        // Negative zero behaves as zero, on both faces.
        for x in [0.0, 0.5, 1.0] {
            let r = Ray::new(Vec3::new(x, 2.0, 1.0), Vec3::new(-0.0, -1.0, -0.0));
            assert_eq!(r.intersect_aabb(&b, f32::INFINITY), Some(1.0), "x = {x}");
        }
        // Along an edge of the box (two zero components, origin on two planes).
        let r = Ray::new(Vec3::new(1.0, 1.0, -3.0), Vec3::Z);
        assert_eq!(r.intersect_aabb(&b, f32::INFINITY), Some(3.0));
    }

    #[test]
    fn invalid_rays_are_flagged() {
        assert!(!Ray::new(Vec3::ZERO, Vec3::ZERO).is_valid());
        assert!(!Ray::new(Vec3::NAN, Vec3::X).is_valid());
        assert!(!Ray::new(Vec3::ZERO, Vec3::new(f32::INFINITY, 0.0, 0.0)).is_valid());
        assert!(Ray::new(Vec3::ZERO, Vec3::new(1e-40, 0.0, 1.0)).is_valid());
        assert_eq!(Ray::new(Vec3::ZERO, Vec3::new(1e-40, 0.0, 1.0)).dir.x, 0.0);
    }

    #[test]
    fn clipping_keeps_nan_ranges_invalid() {
        let r = Ray::new(Vec3::ZERO, Vec3::X);
        assert_eq!(r.clipped(2.0).tmax, 2.0);
        assert_eq!(r.clipped(f32::INFINITY).tmax, f32::INFINITY);
        assert!(!r.clipped(f32::NAN).is_valid());
        let nan = Ray::with_range(Vec3::ZERO, Vec3::X, 0.0, f32::NAN);
        assert!(!nan.clipped(2.0).is_valid());
        assert_eq!(
            Ray::with_range(Vec3::ZERO, Vec3::X, 0.0, 1.0)
                .clipped(5.0)
                .tmax,
            1.0
        );
    }

    #[test]
    fn range_limits_are_honoured() {
        let b = Aabb::new(Vec3::new(0.0, 0.0, 5.0), Vec3::new(1.0, 1.0, 6.0));
        let r = Ray::new(Vec3::new(0.5, 0.5, 0.0), Vec3::Z);
        assert_eq!(r.intersect_aabb(&b, f32::INFINITY), Some(5.0));
        assert!(r.intersect_aabb(&b, 4.9).is_none());
        let r = Ray::with_range(Vec3::new(0.5, 0.5, 0.0), Vec3::Z, 6.5, 10.0);
        assert!(r.intersect_aabb(&b, 10.0).is_none());
    }
}
