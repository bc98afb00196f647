//! Exact geometric predicates for `f32` input: the signs of the `orient2d` and `orient3d` determinants.
//!
//! They follow Shewchuk, "Adaptive precision floating-point arithmetic and fast robust geometric predicates"
//! (Discrete Comput. Geom. 18, 1997): the determinant is first evaluated in `f64` together with a static bound
//! on its rounding error; only when the bound does not settle the sign is it recomputed exactly as a
//! floating-point expansion (a sum of non-overlapping `f64` components). The exact path expands the
//! determinant into products of input coordinates, because differences of `f32` values are not always exact
//! in `f64` while products of two `f32` values always are, and products of three are exact as two `f64`
//! components (via a fused multiply–add). No intermediate can overflow or underflow `f64` for finite `f32`
//! input.
//!
//! Used by the exact triangle–triangle test ([`crate::collide::tri_tri`]) and by the point queries
//! ([`crate::queries`]).

use glam::{DVec3, Vec3};
use std::cmp::Ordering;

/// Exact sign of the orientation determinant `det[b-a, c-a, d-a]`: `Greater` when `d` lies on the side
/// of the plane `abc` that `(b-a)×(c-a)` points to, `Less` on the other side, `Equal` when the four
/// points are coplanar (or `a`, `b`, `c` are collinear).
///
/// The sign is exact for all finite input (Shewchuk's filter: an `f64` evaluation with a static error bound,
/// exact expansion arithmetic where the bound does not settle the sign). Returns `Equal` when any
/// coordinate is not finite.
///
/// Cost: about 30 flops when the filter decides, which is all but nearly degenerate cases; the exact
/// fallback costs a few thousand flops.
pub fn orient3d(a: Vec3, b: Vec3, c: Vec3, d: Vec3) -> Ordering {
    if !(a.is_finite() && b.is_finite() && c.is_finite() && d.is_finite()) {
        return Ordering::Equal;
    }
    sign(Plane::new(&[a, b, c]).side(d))
}

/// The normal `(t1-t0)×(t2-t0)`, each component an approximation with exact sign (zero iff the exact
/// component is zero), so the triangle is degenerate iff the result is zero. Its components are the
/// `orient2d` determinants of the projections onto the yz, zx and xy planes.
pub(crate) fn normal_est(t: &[Vec3; 3]) -> DVec3 {
    let [a, b, c] = *t;
    DVec3::new(
        orient2d_est([a.y, a.z], [b.y, b.z], [c.y, c.z]),
        orient2d_est([a.z, a.x], [b.z, b.x], [c.z, c.x]),
        orient2d_est([a.x, a.y], [b.x, b.y], [c.x, c.y]),
    )
}

/// Half an ulp of 1.0 in `f64` (Shewchuk's ε).
const EPS: f64 = f64::EPSILON * 0.5;
/// Relative error bound of the `f64` evaluation of `orient2d` (Shewchuk's `ccwerrboundA`).
const ORIENT2D_BOUND: f64 = (3.0 + 16.0 * EPS) * EPS;
/// Relative error bound of the `f64` evaluation of `orient3d` (Shewchuk's `o3derrboundA`).
const ORIENT3D_BOUND: f64 = (7.0 + 56.0 * EPS) * EPS;

/// The sign of `x` as an ordering against zero.
fn sign(x: f64) -> Ordering {
    if x > 0.0 {
        Ordering::Greater
    } else if x < 0.0 {
        Ordering::Less
    } else {
        Ordering::Equal
    }
}

/// `orient2d` of finite `f32` points: an approximation of `det[b-a, c-a]` whose sign is exact.
///
/// The `f64` evaluation from rounded differences is accepted when its magnitude exceeds Shewchuk's
/// error bound (differences of `f32` values are at least 2^-149 and products of two at least 2^-298,
/// so nothing underflows and the bound's assumptions hold). A zero bound means a zero difference in
/// each product, hence an exactly zero determinant. Otherwise the determinant is expanded into six
/// products of two coordinates, each exact in `f64`, and summed exactly.
pub(crate) fn orient2d_est(a: [f32; 2], b: [f32; 2], c: [f32; 2]) -> f64 {
    let [ax, ay, bx, by, cx, cy] = [a[0], a[1], b[0], b[1], c[0], c[1]].map(f64::from);
    let left = (bx - ax) * (cy - ay);
    let right = (by - ay) * (cx - ax);
    let det = left - right;
    let bound = ORIENT2D_BOUND * (left.abs() + right.abs());
    if det.abs() > bound || bound == 0.0 {
        return det;
    }
    let mut sum = Expansion::<6>::new();
    for term in [bx * cy, -bx * ay, -ax * cy, -by * cx, by * ax, ay * cx] {
        sum.add(term);
    }
    sum.estimate()
}

/// The plane through three finite `f32` points, prepared for filtered `orient3d` queries against it.
pub(crate) struct Plane {
    /// The three points in `f64` (exact), for the exact fallback.
    pts: [DVec3; 3],
    /// `(p1-p0)×(p2-p0)` evaluated in `f64`.
    n: DVec3,
    /// Per component of `n`, the sum of the magnitudes of its two products: the rounding error bound of
    /// `w·n` is `ORIENT3D_BOUND * (|w| · m)` (Shewchuk's permanent).
    m: DVec3,
}

impl Plane {
    pub(crate) fn new(t: &[Vec3; 3]) -> Self {
        let pts = t.map(Vec3::as_dvec3);
        let u = pts[1] - pts[0];
        let v = pts[2] - pts[0];
        let (yz, zy) = (u.y * v.z, u.z * v.y);
        let (zx, xz) = (u.z * v.x, u.x * v.z);
        let (xy, yx) = (u.x * v.y, u.y * v.x);
        Plane {
            pts,
            n: DVec3::new(yz - zy, zx - xz, xy - yx),
            m: DVec3::new(
                yz.abs() + zy.abs(),
                zx.abs() + xz.abs(),
                xy.abs() + yx.abs(),
            ),
        }
    }

    /// `orient3d(p0, p1, p2, d)` as an approximation of the determinant with exact sign (the signed
    /// distance of `d` to the plane, scaled by `|n|`).
    ///
    /// Filter as in [`orient2d_est`]: the `f64` value, evaluated in Shewchuk's order (each coordinate of
    /// `w = d - p0` times a 2×2 minor, summed left to right), is accepted beyond the error bound; a zero
    /// bound means an exactly zero determinant; otherwise [`orient3d_exact`] decides.
    pub(crate) fn side(&self, d: Vec3) -> f64 {
        let w = d.as_dvec3() - self.pts[0];
        let det = w.x * self.n.x + w.y * self.n.y + w.z * self.n.z;
        let permanent = w.x.abs() * self.m.x + w.y.abs() * self.m.y + w.z.abs() * self.m.z;
        let bound = ORIENT3D_BOUND * permanent;
        if det.abs() > bound || bound == 0.0 {
            det
        } else {
            orient3d_exact(self.pts, d.as_dvec3())
        }
    }
}

/// Exact `det[b-a, c-a, d-a]` for points with `f32` coordinates, returned as an approximation with
/// exact sign.
///
/// Expanding the 4×4 determinant `[[a,1],[b,1],[c,1],[d,1]]` along its last column gives
/// `det[b-a, c-a, d-a] = M(b,c,d) - M(a,c,d) + M(a,b,d) - M(a,b,c)` with `M(p,q,r) = det[p; q; r]`,
/// 24 signed products `p_i q_j r_k` of input coordinates. `p_i q_j` is exact in `f64` (24 + 24 bits),
/// its product with `r_k` is exact as two components (`two_product`); the 48 components are summed
/// exactly. Magnitudes stay within 2^-447 .. 2^390, far from `f64` underflow and overflow.
fn orient3d_exact([a, b, c]: [DVec3; 3], d: DVec3) -> f64 {
    // Permutations (i, j, k) of the axes with their signs (Leibniz formula).
    const PERMS: [(f64, usize, usize, usize); 6] = [
        (1.0, 0, 1, 2),
        (-1.0, 0, 2, 1),
        (-1.0, 1, 0, 2),
        (1.0, 1, 2, 0),
        (1.0, 2, 0, 1),
        (-1.0, 2, 1, 0),
    ];
    let mut sum = Expansion::<48>::new();
    for (s, [p, q, r]) in [
        (1.0, [b, c, d]),
        (-1.0, [a, c, d]),
        (1.0, [a, b, d]),
        (-1.0, [a, b, c]),
    ] {
        for (t, i, j, k) in PERMS {
            let (hi, lo) = two_product(p[i] * q[j], r[k]);
            sum.add(s * t * hi);
            sum.add(s * t * lo);
        }
    }
    sum.estimate()
}

/// `a + b` as `(sum, error)` with `sum + error` exactly equal to `a + b` (Knuth's TwoSum; Shewchuk
/// Theorem 7). Six flops.
fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let bv = s - a;
    let av = s - bv;
    (s, (a - av) + (b - bv))
}

/// `a * b` as `(product, error)` with `product + error` exactly equal to `a * b`, barring underflow
/// (the fused multiply–add computes the rounding error exactly).
fn two_product(a: f64, b: f64) -> (f64, f64) {
    let p = a * b;
    (p, a.mul_add(b, -p))
}

/// A floating-point expansion (Shewchuk §2): an exact sum of non-overlapping `f64` components stored
/// by increasing magnitude, zero components removed. Holds at most `N` components; each
/// [`add`](Expansion::add) adds at most one, so `N` additions always fit.
struct Expansion<const N: usize> {
    c: [f64; N],
    len: usize,
}

impl<const N: usize> Expansion<N> {
    fn new() -> Self {
        Expansion {
            c: [0.0; N],
            len: 0,
        }
    }

    /// Adds `x` exactly: Shewchuk's Grow-Expansion with zero elimination (Theorem 10), `O(len)`. The
    /// output component `h` is written at an index no larger than the input one being read, so it
    /// works in place.
    fn add(&mut self, x: f64) {
        let mut q = x;
        let mut h = 0;
        for i in 0..self.len {
            let (s, err) = two_sum(q, self.c[i]);
            q = s;
            if err != 0.0 {
                self.c[h] = err;
                h += 1;
            }
        }
        if q != 0.0 {
            self.c[h] = q;
            h += 1;
        }
        self.len = h;
    }

    /// An approximation of the sum with its exact sign. The largest component carries the sign of a
    /// non-overlapping expansion; the sum of the components (smallest first) is nearly exact, and is
    /// used unless rounding changed its sign.
    fn estimate(&self) -> f64 {
        let c = &self.c[..self.len];
        let Some(&top) = c.last() else {
            return 0.0;
        };
        let sum: f64 = c.iter().sum();
        if sign(sum) == sign(top) { sum } else { top }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A non-overlapping expansion whose left-to-right sum rounds to zero: `-(1 - 2^-54)` (split as
    /// `-(1 - 2^-53)` and `-2^-54`) rounds to `-1` (ties to even), cancelling the top component 1,
    /// while the exact sum is `2^-54`. The estimate must keep the sign of the top component.
    #[test]
    fn estimate_keeps_the_sign_when_the_sum_rounds_to_zero() {
        let mut e = Expansion::<3>::new();
        e.c = [-(2f64.powi(-54)), -(1.0 - 2f64.powi(-53)), 1.0];
        e.len = 3;
        assert_eq!(e.c.iter().sum::<f64>(), 0.0);
        assert_eq!(e.estimate(), 1.0);
    }
}
