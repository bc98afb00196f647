//! The ray–triangle oracle: exact answers for `f32` rays and triangles, computed without any of the crate's
//! code, plus the bound within which the crate's `f32` watertight test may differ from them.
//!
//! # The exact answer
//!
//! With `Δv = v − o` for the ray's origin `o` and direction `d`, the three edge volumes
//! `T₀ = d·(Δ₁×Δ₂)`, `T₁ = d·(Δ₂×Δ₀)`, `T₂ = d·(Δ₀×Δ₁)` decide the hit: the line meets the closed triangle
//! iff they are all `≥ 0` or all `≤ 0`, and their sum `D = d·((v₁−v₀)×(v₂−v₀))` is not zero (zero: the ray
//! runs in the triangle's plane, or the triangle has zero area — never a hit, as in the crate). Then
//! `bᵢ = Tᵢ/D` are the barycentrics and `t = Σ bᵢ (Δᵢ·d)/(d·d) = Δ₀·n / d·n`. Each `Tᵢ` is computed in `f64`
//! with a forward error bound (`FILTER`·its permanent); where that cannot decide the sign, and where two
//! distances or a distance and `tmin`/`tmax` are too close for `f64`, the sign is computed exactly with
//! floating-point expansions ([`super::exact`]). So "hit on the edge" (a `Tᵢ` exactly zero) and "two
//! triangles at exactly the same `t`" are decided exactly.
//!
//! # What `f32` allows (the crate's bound)
//!
//! The crate (Woop et al.) shears the ray onto +z: with `kz` the largest `|d|` axis and `s = d_k/d_kz`
//! (`|s| ≤ 1`), a vertex's coordinates `x = Δ_kx − s_x·Δ_kz` (and `y`) are computed from `f32` `Δ`, `s`
//! and one product and one difference, so (unit roundoff `ε = 2⁻²⁴`) `|x̃ − x| ≤ 4.01ε·Mx` with
//! `Mx = |Δ_kx| + |s_x||Δ_kz|`. An edge function `U = x_c y_b − y_c x_b` then errs by at most
//! `(8.02 + 2)ε·(Mx_c My_b + My_c Mx_b)` (the perturbed inputs, two product roundings and the difference;
//! the crate's `f64` recomputation of zeros only removes roundings) — `EDGE_ERR` = 10.1ε, plus an absolute
//! `2⁻¹⁴⁶` per unit of magnitude for underflow. `|U| = |T|/|d_kz|` (the shear has determinant 1), so the bound
//! is used as `Bᵢ = EDGE_ERR·(…)·|d_kz|` on `Tᵢ`: an edge whose exact `|Tᵢ|` exceeds `Bᵢ` has the same sign
//! in the crate. A triangle whose three signs are all so decided is a *certain* hit or miss; otherwise it is
//! *disputed* — the ray passes within rounding of an edge — and the crate may answer either way there (its
//! guarantee there is watertightness, tested on closed meshes, not agreement with exact arithmetic).
//!
//! The crate's distance is `t̃ = Σ ũᵢ z̃ᵢ / Σ ũᵢ` with `zᵢ = Δᵢ_kz/d_kz` (three roundings each), a sum of three
//! products and its division: with the edge errors `Bᵢ`, `r = (Σ|Tᵢ| + ΣBᵢ)/(|D| − ΣBᵢ)` (1 for a certain
//! hit),
//! `|t̃ − t| ≤ ΣBᵢ|zᵢ − t|/(|D| − ΣBᵢ) + ε·(6.1·r·max|zᵢ| + 2.1·(r + 1)·|t|)`; its barycentrics
//! `ũᵢ/Σũ` are within `(Bᵢ + |bᵢ|ΣB)/(|D| − ΣB) + 2.1·(r + 1)·ε·|bᵢ|`. These are the tolerances the
//! comparisons use: rigorous, and for a well-conditioned hit a few ulps of the coordinates.

use super::exact::{Exact, Exact3};
use glam::{DVec3, Vec3};
use kinetrace::{Mesh, Ray};
use std::cmp::Ordering;

/// Unit roundoff of `f32`.
const EPS32: f64 = 1.0 / (1u64 << 24) as f64;
/// Unit roundoff of `f64`.
const EPS64: f64 = f64::EPSILON / 2.0;
/// The crate's edge-function error per unit of `Mx·My` (derived above).
const EDGE_ERR: f64 = 10.1 * EPS32;
/// Absolute slack per unit of magnitude for `f32` products that underflow (2⁻¹⁴⁶).
const UNDERFLOW: f64 = 1.4e-44;
/// Forward error of an `f64` triple product `d·(Δa×Δb)` per unit of its permanent (seven roundings, rounded
/// up generously: it only decides when to fall back to exact arithmetic, never what a test accepts).
const FILTER: f64 = 16.0 * EPS64;

/// What the oracle knows about one ray and one triangle.
#[derive(Clone, Copy, Debug)]
pub struct TriangleVerdict {
    /// Exact: the ray meets the closed, non-degenerate triangle at `tmin ≤ t ≤ tmax`.
    pub hit: bool,
    /// The crate's `f32` test must agree with `hit` (false: the ray passes within rounding of an edge or of
    /// the range's ends, or the triangle is nearly edge-on).
    pub certain: bool,
    /// The hit distance (the exact value to `f64` rounding; meaningless when the plane is parallel).
    pub t: f64,
    /// Bound on the crate's `|t̃ − t|`.
    pub t_err: f64,
    /// Barycentric weights of the three corners.
    pub bary: [f64; 3],
    /// Bounds on the crate's barycentric errors.
    pub bary_err: [f64; 3],
    /// Bound on this `t`'s own `f64` error, below which distances are compared exactly.
    t_f64_err: f64,
}

/// The three edge volumes `Tᵢ` in `f64`, each with its exact sign (`Tᵢ` is set to exactly zero when it is).
fn edge_volumes(o: Vec3, d: Vec3, tri: [Vec3; 3]) -> ([f64; 3], [f64; 3]) {
    let (od, dd) = (o.as_dvec3(), d.as_dvec3());
    let dl = tri.map(|v| v.as_dvec3() - od);
    let mut t = [0.0; 3];
    let mut perm = [0.0; 3];
    for k in 0..3 {
        let (i, j) = ((k + 1) % 3, (k + 2) % 3);
        t[k] = dd.dot(dl[i].cross(dl[j]));
        let (a, b) = (dl[i].abs(), dl[j].abs());
        perm[k] = dd.abs().dot(DVec3::new(
            a.y * b.z + a.z * b.y,
            a.z * b.x + a.x * b.z,
            a.x * b.y + a.y * b.x,
        ));
        if t[k].abs() <= FILTER * perm[k] {
            let e = |v: Vec3| Exact3::from_vec3(v).sub(&Exact3::from_vec3(o));
            let s = Exact3::from_vec3(d)
                .dot(&e(tri[i]).cross(&e(tri[j])))
                .signum();
            // Keep the f64 magnitude (accurate to the filter) but the exact sign; exactly zero stays zero.
            t[k] = if s == 0 {
                0.0
            } else {
                t[k].abs().copysign(s as f64)
            };
        }
    }
    (t, perm)
}

/// The exact distance as a fraction `(Δ₀·n, d·n)`, `n = (v₁−v₀)×(v₂−v₀)`.
fn exact_t(o: Vec3, d: Vec3, tri: [Vec3; 3]) -> (Exact, Exact) {
    let [a, b, c] = tri.map(Exact3::from_vec3);
    let n = b.sub(&a).cross(&c.sub(&a));
    (
        a.sub(&Exact3::from_vec3(o)).dot(&n),
        Exact3::from_vec3(d).dot(&n),
    )
}

/// Exact sign of `num/den − x`.
fn cmp_fraction(num: &Exact, den: &Exact, x: f32) -> Ordering {
    let s = num.sub(&den.mul(&Exact::from_f32(x))).signum() * den.signum();
    s.cmp(&0)
}

/// The oracle's verdict for one ray and one triangle (see the module docs).
pub fn ray_triangle(ray: &Ray, tri: [Vec3; 3]) -> TriangleVerdict {
    let (o, d) = (ray.origin, ray.dir());
    let (tv, perm) = edge_volumes(o, d, tri);
    let big_d: f64 = tv.iter().sum();
    let inside = tv.iter().all(|&x| x >= 0.0) || tv.iter().all(|&x| x <= 0.0);
    let plane_hit = inside && tv.iter().any(|&x| x != 0.0);

    // The crate's frame and its edge bounds Bᵢ, in units of Tᵢ.
    let (od, dd) = (o.as_dvec3(), d.as_dvec3());
    let a = dd.abs();
    let kz = if a.x >= a.y && a.x >= a.z {
        0
    } else if a.y >= a.z {
        1
    } else {
        2
    };
    let (kx, ky) = ((kz + 1) % 3, (kz + 2) % 3);
    let (sx, sy) = ((dd[kx] / dd[kz]).abs(), (dd[ky] / dd[kz]).abs());
    let dl = tri.map(|v| v.as_dvec3() - od);
    let mx = dl.map(|p| p[kx].abs() + sx * p[kz].abs());
    let my = dl.map(|p| p[ky].abs() + sy * p[kz].abs());
    let mut b = [0.0; 3];
    for k in 0..3 {
        let (i, j) = ((k + 1) % 3, (k + 2) % 3);
        let mag = mx[i] * my[j] + my[i] * mx[j];
        let sum = mx[i] + my[i] + mx[j] + my[j];
        // Plus the oracle's own f64 error, so "certain" is rigorous.
        b[k] = (EDGE_ERR * mag + UNDERFLOW * (1.0 + sum)) * dd[kz].abs() + FILTER * perm[k];
    }
    let sum_b: f64 = b.iter().sum();
    let decided = (0..3).all(|k| tv[k].abs() > b[k]);
    let opposite = (0..3).any(|i| (0..3).any(|j| tv[i] > b[i] && tv[j] < -b[j]));

    let bary = tv.map(|x| if big_d == 0.0 { 0.0 } else { x / big_d });
    let tau = dl.map(|p| p.dot(dd) / dd.length_squared());
    let t = bary[0] * tau[0] + bary[1] * tau[1] + bary[2] * tau[2];
    let max_tau = tau.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    let t_f64_err = if big_d == 0.0 {
        f64::INFINITY
    } else {
        max_tau * (64.0 * EPS64 * perm.iter().sum::<f64>() / big_d.abs() + 8.0 * EPS64)
    };

    // The crate's distance and barycentric bounds.
    let z = dl.map(|p| p[kz] / dd[kz]);
    let max_z = z.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    let slack = big_d.abs() - sum_b;
    let (t_err, bary_err) = if slack > 0.0 {
        let r = (tv.iter().map(|x| x.abs()).sum::<f64>() + sum_b) / slack;
        let k: f64 = (0..3).map(|i| b[i] * (z[i] - t).abs()).sum::<f64>() / slack;
        let round = 2.1 * (r + 1.0) * EPS32;
        let t_err = k + EPS32 * 6.1 * r * max_z + round * (t.abs() + k) + t_f64_err;
        let be = [0, 1, 2].map(|i| {
            let e = (b[i] + bary[i].abs() * sum_b) / slack;
            e + round * (bary[i].abs() + e)
        });
        (t_err, be)
    } else {
        (f64::INFINITY, [f64::INFINITY; 3])
    };

    // The range, exactly where f64 cannot tell.
    let (tmin, tmax) = (ray.tmin, ray.tmax);
    let cmp = |x: f32| -> Ordering {
        if x.is_infinite() || (t - x as f64).abs() > t_f64_err + f64::EPSILON * (x as f64).abs() {
            t.partial_cmp(&(x as f64)).unwrap()
        } else {
            let (n, dn) = exact_t(o, d, tri);
            cmp_fraction(&n, &dn, x)
        }
    };
    let in_range = plane_hit && cmp(tmin) != Ordering::Less && cmp(tmax) != Ordering::Greater;
    let range_certain = t - t_err > tmin as f64 && t + t_err < tmax as f64;
    let certain = if opposite {
        true // two edges certainly disagree: a miss in any arithmetic within the bound
    } else if decided {
        // Inside for sure: the range decides, certainly only away from its ends.
        range_certain || (t + t_err < tmin as f64) || (t - t_err > tmax as f64)
    } else {
        false
    };
    TriangleVerdict {
        hit: in_range,
        certain,
        t,
        t_err,
        bary,
        bary_err,
        t_f64_err,
    }
}

/// Exact order of two hit distances (`f64` where it decides, expansions where it cannot).
fn cmp_t(
    ray: &Ray,
    a: (&TriangleVerdict, [Vec3; 3]),
    b: (&TriangleVerdict, [Vec3; 3]),
) -> Ordering {
    if (a.0.t - b.0.t).abs() > a.0.t_f64_err + b.0.t_f64_err {
        return a.0.t.partial_cmp(&b.0.t).unwrap();
    }
    let (na, da) = exact_t(ray.origin, ray.dir(), a.1);
    let (nb, db) = exact_t(ray.origin, ray.dir(), b.1);
    let s = na.mul(&db).sub(&nb.mul(&da)).signum() * da.signum() * db.signum();
    s.cmp(&0)
}

/// Every triangle of a mesh under one ray that is not a certain miss: the oracle's whole knowledge of the
/// query, computed once (brute force over all triangles) and checked against any number of answers.
pub struct RayOracle {
    ray: Ray,
    candidates: Vec<(u32, [Vec3; 3], TriangleVerdict)>,
}

impl RayOracle {
    /// Brute force over `triangles` (numbered from 0).
    pub fn new(ray: &Ray, triangles: impl IntoIterator<Item = [Vec3; 3]>) -> Self {
        let candidates = if ray.is_valid() {
            triangles
                .into_iter()
                .enumerate()
                .map(|(i, tri)| (i as u32, tri, ray_triangle(ray, tri)))
                .filter(|(_, _, v)| v.hit || !v.certain)
                .collect()
        } else {
            Vec::new()
        };
        Self {
            ray: *ray,
            candidates,
        }
    }

    /// Brute force over a mesh's triangles.
    pub fn of_mesh(m: &Mesh, ray: &Ray) -> Self {
        Self::new(ray, (0..m.triangle_count()).map(|i| m.triangle(i)))
    }

    /// The exact closest hit: smallest exact `t`, then lowest index; on-edge counts as a hit.
    pub fn closest(&self) -> Option<(u32, f64)> {
        self.candidates
            .iter()
            .filter(|c| c.2.hit)
            .min_by(|a, b| cmp_t(&self.ray, (&a.2, a.1), (&b.2, b.1)).then(a.0.cmp(&b.0)))
            .map(|c| (c.0, c.2.t))
    }

    /// Whether the ray exactly hits any triangle.
    pub fn any(&self) -> bool {
        self.candidates.iter().any(|c| c.2.hit)
    }

    /// The verdict for triangle `i`, if it is not a certain miss.
    pub fn verdict(&self, i: u32) -> Option<&TriangleVerdict> {
        self.candidates.iter().find(|c| c.0 == i).map(|c| &c.2)
    }

    /// Asserts that `got` (triangle, `t`) is a closest hit an `f32` watertight test may report: the triangle
    /// is hit or disputed, `t` is within its bound of the exact distance, and no certainly-hit triangle is
    /// certainly nearer. Where every triangle is certain and distances are apart by more than their bounds,
    /// this is exactly "the same triangle"; exact ties (shared edges and vertices) accept any tied triangle,
    /// as the crate documents.
    pub fn check_closest(&self, got: Option<(u32, f32)>, what: &str) {
        let ray = &self.ray;
        match got {
            None => {
                let missed = self.candidates.iter().find(|c| c.2.hit && c.2.certain);
                assert!(missed.is_none(), "{what}: missed {missed:?} {ray:?}");
            }
            Some((p, t)) => {
                let v = self.verdict(p);
                let v =
                    v.unwrap_or_else(|| panic!("{what}: triangle {p} is certainly missed {ray:?}"));
                assert!(
                    (t as f64 - v.t).abs() <= v.t_err,
                    "{what}: triangle {p} at t {t}, exactly {} (bound {:e}) {ray:?}",
                    v.t,
                    v.t_err
                );
                for (q, _, w) in self.candidates.iter().filter(|c| c.2.hit && c.2.certain) {
                    assert!(
                        t as f64 <= w.t + w.t_err,
                        "{what}: reported {p} at {t}, but {q} is certainly hit nearer, at {} {ray:?}",
                        w.t
                    );
                }
            }
        }
    }

    /// Asserts that `got` is an any-hit answer an `f32` test may give: true needs a hit or disputed triangle,
    /// false needs no certain hit.
    pub fn check_any(&self, got: bool, what: &str) {
        let ray = &self.ray;
        if got {
            assert!(
                !self.candidates.is_empty(),
                "{what}: any-hit true, nothing is hit {ray:?}"
            );
        } else {
            let missed = self.candidates.iter().find(|c| c.2.hit && c.2.certain);
            assert!(
                missed.is_none(),
                "{what}: any-hit false, missed {missed:?} {ray:?}"
            );
        }
    }
}
