//! Axis-aligned bounding boxes.

use glam::{Vec3, Vec3A, Vec3Swizzles};

/// An axis-aligned box, `min <= max` on every axis when non-empty.
///
/// [`Aabb::EMPTY`] (min = +inf, max = -inf) is the identity of [`Aabb::union`], so boxes can be grown from
/// nothing without a special case.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Smallest corner.
    pub min: Vec3,
    /// Largest corner.
    pub max: Vec3,
}

impl Default for Aabb {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl Aabb {
    /// The empty box: contains nothing, and `EMPTY.union(b) == b`.
    pub const EMPTY: Aabb = Aabb {
        min: Vec3::INFINITY,
        max: Vec3::NEG_INFINITY,
    };

    /// A box from its two corners (not reordered).
    #[inline]
    pub const fn new(min: Vec3, max: Vec3) -> Self {
        Self { min, max }
    }

    /// The box around one point.
    #[inline]
    pub fn from_point(p: Vec3) -> Self {
        Self { min: p, max: p }
    }

    /// The tight box around a triangle.
    #[inline]
    pub fn from_triangle(a: Vec3, b: Vec3, c: Vec3) -> Self {
        Self {
            min: a.min(b).min(c),
            max: a.max(b).max(c),
        }
    }

    /// The eight corners (bit 0 of the index picks max x, bit 1 max y, bit 2 max z).
    pub fn corners(&self) -> [Vec3; 8] {
        std::array::from_fn(|i| {
            Vec3::new(
                if i & 1 == 0 { self.min.x } else { self.max.x },
                if i & 2 == 0 { self.min.y } else { self.max.y },
                if i & 4 == 0 { self.min.z } else { self.max.z },
            )
        })
    }

    /// True when the box contains no point (some `min > max`).
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.min.cmpgt(self.max).any()
    }

    /// The corners as SIMD lanes (`min`, `max`), as a refit combines boxes.
    #[inline]
    pub(crate) fn lanes(&self) -> (Vec3A, Vec3A) {
        (self.min.into(), self.max.into())
    }

    /// The smallest box holding both.
    #[inline]
    #[must_use]
    pub fn union(&self, other: &Aabb) -> Aabb {
        Aabb {
            min: self.min.min(other.min),
            max: self.max.max(other.max),
        }
    }

    /// Grows the box to hold `p`.
    #[inline]
    pub fn grow(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }

    /// Centre point (the "centroid" builders sort by).
    #[inline]
    pub fn center(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }

    /// `max - min`; zero or negative for empty boxes.
    #[inline]
    pub fn extent(&self) -> Vec3 {
        self.max - self.min
    }

    /// Index (0, 1, 2) of the longest axis.
    #[inline]
    pub fn largest_axis(&self) -> usize {
        let e = self.extent();
        if e.x >= e.y && e.x >= e.z {
            0
        } else if e.y >= e.z {
            1
        } else {
            2
        }
    }

    /// Half the surface area, `dx·dy + dy·dz + dz·dx` (0 for an empty box). Only ratios of areas matter to
    /// the SAH, so the factor 2 is left out.
    #[inline]
    pub fn half_area(&self) -> f32 {
        if self.is_empty() {
            return 0.0;
        }
        let e = self.extent();
        e.x * e.y + e.y * e.z + e.z * e.x
    }

    /// The same in `f64`, which neither overflows nor underflows for any finite `f32` box: use it where areas
    /// of huge or tiny boxes are summed (quality metrics).
    #[inline]
    pub fn half_area_f64(&self) -> f64 {
        if self.is_empty() {
            return 0.0;
        }
        let e = self.extent().as_dvec3();
        e.x * e.y + e.y * e.z + e.z * e.x
    }

    /// True when `other` lies inside `self` (boundaries included). Every box contains the empty box.
    #[inline]
    pub fn contains_box(&self, other: &Aabb) -> bool {
        other.is_empty() || (self.min.cmple(other.min).all() && self.max.cmpge(other.max).all())
    }

    /// True when the point lies inside or on the boundary.
    #[inline]
    pub fn contains_point(&self, p: Vec3) -> bool {
        self.min.cmple(p).all() && self.max.cmpge(p).all()
    }

    /// True when the two boxes share at least one point (touching counts).
    #[inline]
    pub fn overlaps(&self, other: &Aabb) -> bool {
        self.min.cmple(other.max).all() && other.min.cmple(self.max).all()
    }
}

/// Surface-area ratio `SA(parent) / (SA(left) + SA(right))` of an inner node: the per-node quality term of
/// Lauterbach's rebuild criterion (thesis §4.1.5). It is at least 0.5 for a parent that holds its children, and
/// grows as the children drift apart inside it.
///
/// Computed scale-free, so that huge, tiny and flat boxes all give finite answers: the extents are divided by
/// the parent's largest extent first (children inside the parent then have extents in `[0, 1]`). Guards:
/// a parent that is a single point gives 1; children whose areas vanish inside a parent that has area give
/// [`MAX_SA_RATIO`], the same cap that bounds every other ratio. The GPU refit computes the same expression.
#[inline]
pub fn sa_ratio(parent: &Aabb, left: &Aabb, right: &Aabb) -> f32 {
    sa_ratio_of_extents(
        parent.extent().into(),
        left.extent().into(),
        right.extent().into(),
    )
}

/// [`sa_ratio`] from the three boxes' extents, in SIMD lanes (a refit has its boxes in them): the same
/// operations in the same order, so the same bits.
#[inline]
pub(crate) fn sa_ratio_of_extents(pe: Vec3A, le: Vec3A, re: Vec3A) -> f32 {
    let scale = pe.max_element();
    if scale.is_nan() || scale <= 0.0 || scale.is_infinite() {
        // A point (or extents past f32::MAX, which only coordinates near ±3e38 produce): nothing to compare.
        return 1.0;
    }
    let inv = 1.0 / scale;
    let ha = |e: Vec3A| {
        let e = (e * inv).max(Vec3A::ZERO);
        // `x·y + y·z + z·x`, summed left to right.
        let p = e * e.yzx();
        p.x + p.y + p.z
    };
    let sp = ha(pe);
    let sc = ha(le) + ha(re);
    if sp <= 0.0 {
        // A flat line segment: every box involved has zero area, nothing to compare.
        return 1.0;
    }
    if sc <= 0.0 {
        return MAX_SA_RATIO;
    }
    (sp / sc).min(MAX_SA_RATIO)
}

/// Upper bound of [`sa_ratio`], reached when both children collapse to lines or points inside a parent with
/// area. One such node in a tree of a thousand adds about 1.0 to the degradation metric, enough to ask for a
/// rebuild, which is what such a tree needs.
pub const MAX_SA_RATIO: f32 = 1024.0;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn union_with_empty_is_identity() {
        let b = Aabb::new(Vec3::new(-1.0, 2.0, 3.0), Vec3::new(4.0, 5.0, 6.0));
        assert_eq!(Aabb::EMPTY.union(&b), b);
        assert!(Aabb::EMPTY.is_empty());
        assert_eq!(Aabb::EMPTY.half_area(), 0.0);
    }

    #[test]
    fn sa_ratio_is_scale_free_and_guarded() {
        let l = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let r = Aabb::new(Vec3::new(2.0, 0.0, 0.0), Vec3::new(3.0, 1.0, 1.0));
        let p = l.union(&r);
        // Analytic: parent 3x1x1 has half area 3+1+3 = 7, children 3 + 3.
        assert!((sa_ratio(&p, &l, &r) - 7.0 / 6.0).abs() < 1e-6);
        for s in [1e-30f32, 1e-4, 1e4, 1e30] {
            let sc = |b: &Aabb| Aabb::new(b.min * s, b.max * s);
            let got = sa_ratio(&sc(&p), &sc(&l), &sc(&r));
            assert!((got - 7.0 / 6.0).abs() < 1e-5, "scale {s}: {got}");
        }
        let pt = Aabb::from_point(Vec3::ONE);
        assert_eq!(sa_ratio(&pt, &pt, &pt), 1.0);
        let a = Aabb::from_point(Vec3::ZERO);
        let b = Aabb::from_point(Vec3::ONE);
        assert_eq!(sa_ratio(&a.union(&b), &a, &b), MAX_SA_RATIO);
    }
}
