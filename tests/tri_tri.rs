//! Tests of the exact triangle–triangle intersection test, its contact, and `orient3d`.
//!
//! Oracles, all independent of the code under test:
//! - parry3d's GJK `intersection_test`, tolerance based, for random pairs in several distributions;
//! - an exact separating-axis test written here over integer arithmetic (`i128`, or a small
//!   big-integer type for arbitrary `f32` input scaled to integers by a common power of two), which
//!   adjudicates every near-touching pair (where parry's tolerance may decide differently) and checks
//!   integer-grid pairs, which are full of exactly touching configurations;
//! - the same exact arithmetic evaluating the orientation determinant, for `orient3d` itself.

use std::cmp::Ordering;

mod common;

use common::closest_on_triangle;
use glam::{DVec3, Vec3};
use kinetrace::collide::tri_tri::*;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

type Tri = [Vec3; 3];

// ---------------------------------------------------------------------------------------------------
// Exact integer arithmetic
// ---------------------------------------------------------------------------------------------------

/// The integer operations the exact oracles need.
trait Ring: Clone {
    fn plus(&self, o: &Self) -> Self;
    fn minus(&self, o: &Self) -> Self;
    fn times(&self, o: &Self) -> Self;
    fn sgn(&self) -> i32;
}

impl Ring for i128 {
    fn plus(&self, o: &Self) -> Self {
        self.checked_add(*o).expect("i128 overflow")
    }
    fn minus(&self, o: &Self) -> Self {
        self.checked_sub(*o).expect("i128 overflow")
    }
    fn times(&self, o: &Self) -> Self {
        self.checked_mul(*o).expect("i128 overflow")
    }
    fn sgn(&self) -> i32 {
        self.signum() as i32
    }
}

/// Signed big integer: sign and magnitude in little-endian `u32` limbs without leading zero limbs.
#[derive(Clone, Debug)]
struct Big {
    neg: bool,
    mag: Vec<u32>,
}

impl Big {
    fn zero() -> Big {
        Big {
            neg: false,
            mag: Vec::new(),
        }
    }

    /// `±m · 2^shift`.
    fn from_parts(neg: bool, m: u64, shift: u32) -> Big {
        let mut mag = vec![0; (shift / 32) as usize];
        let wide = u128::from(m) << (shift % 32);
        mag.extend((0..4).map(|i| (wide >> (32 * i)) as u32));
        Big { neg, mag }.trim()
    }

    fn trim(mut self) -> Big {
        while self.mag.last() == Some(&0) {
            self.mag.pop();
        }
        self.neg &= !self.mag.is_empty();
        self
    }

    fn to_small(&self) -> Option<i128> {
        match self.mag[..] {
            [] => Some(0),
            [m] if m < 1 << 28 => Some(if self.neg {
                -i128::from(m)
            } else {
                i128::from(m)
            }),
            _ => None,
        }
    }
}

fn cmp_mag(a: &[u32], b: &[u32]) -> Ordering {
    a.len()
        .cmp(&b.len())
        .then_with(|| a.iter().rev().cmp(b.iter().rev()))
}

fn add_mag(a: &[u32], b: &[u32]) -> Vec<u32> {
    let mut out = Vec::with_capacity(a.len().max(b.len()) + 1);
    let mut carry = 0u64;
    for i in 0..a.len().max(b.len()) {
        let s = carry + u64::from(*a.get(i).unwrap_or(&0)) + u64::from(*b.get(i).unwrap_or(&0));
        out.push(s as u32);
        carry = s >> 32;
    }
    out.push(carry as u32);
    out
}

/// `a - b` for `|a| >= |b|`.
fn sub_mag(a: &[u32], b: &[u32]) -> Vec<u32> {
    let mut out = Vec::with_capacity(a.len());
    let mut borrow = 0i64;
    for (i, &x) in a.iter().enumerate() {
        let mut d = i64::from(x) - i64::from(*b.get(i).unwrap_or(&0)) - borrow;
        borrow = i64::from(d < 0);
        if d < 0 {
            d += 1 << 32;
        }
        out.push(d as u32);
    }
    out
}

impl Ring for Big {
    fn plus(&self, o: &Self) -> Self {
        if self.neg == o.neg {
            return Big {
                neg: self.neg,
                mag: add_mag(&self.mag, &o.mag),
            }
            .trim();
        }
        match cmp_mag(&self.mag, &o.mag) {
            Ordering::Less => Big {
                neg: o.neg,
                mag: sub_mag(&o.mag, &self.mag),
            },
            _ => Big {
                neg: self.neg,
                mag: sub_mag(&self.mag, &o.mag),
            },
        }
        .trim()
    }
    fn minus(&self, o: &Self) -> Self {
        self.plus(&Big {
            neg: !o.neg,
            mag: o.mag.clone(),
        })
    }
    fn times(&self, o: &Self) -> Self {
        if self.mag.is_empty() || o.mag.is_empty() {
            return Big::zero();
        }
        let mut out = vec![0u32; self.mag.len() + o.mag.len()];
        for (i, &x) in self.mag.iter().enumerate() {
            let mut carry = 0u64;
            for (j, &y) in o.mag.iter().enumerate() {
                let t = u64::from(out[i + j]) + u64::from(x) * u64::from(y) + carry;
                out[i + j] = t as u32;
                carry = t >> 32;
            }
            out[i + o.mag.len()] = carry as u32;
        }
        Big {
            neg: self.neg != o.neg,
            mag: out,
        }
        .trim()
    }
    fn sgn(&self) -> i32 {
        match (self.mag.is_empty(), self.neg) {
            (true, _) => 0,
            (false, true) => -1,
            (false, false) => 1,
        }
    }
}

type V<T> = [T; 3];

fn vsub<T: Ring>(a: &V<T>, b: &V<T>) -> V<T> {
    [a[0].minus(&b[0]), a[1].minus(&b[1]), a[2].minus(&b[2])]
}

fn cross<T: Ring>(a: &V<T>, b: &V<T>) -> V<T> {
    [
        a[1].times(&b[2]).minus(&a[2].times(&b[1])),
        a[2].times(&b[0]).minus(&a[0].times(&b[2])),
        a[0].times(&b[1]).minus(&a[1].times(&b[0])),
    ]
}

fn dot<T: Ring>(a: &V<T>, b: &V<T>) -> T {
    a[0].times(&b[0])
        .plus(&a[1].times(&b[1]))
        .plus(&a[2].times(&b[2]))
}

fn is_zero<T: Ring>(v: &V<T>) -> bool {
    v.iter().all(|x| x.sgn() == 0)
}

/// Exact separating-axis test for closed triangles with integer coordinates. Degenerate (zero-area)
/// triangles never intersect. Two non-degenerate triangles are disjoint iff their projections on one
/// of 17 axes are strictly separated: the two normals, the 9 edge×edge cross products (the facet
/// normals of the Minkowski difference when the planes cross) and the 6 normal×edge products (the
/// in-plane edge normals when the triangles are coplanar).
fn sat_intersect<T: Ring>(a: &[V<T>; 3], b: &[V<T>; 3]) -> bool {
    let edges = |t: &[V<T>; 3]| [vsub(&t[1], &t[0]), vsub(&t[2], &t[1]), vsub(&t[0], &t[2])];
    let (ea, eb) = (edges(a), edges(b));
    let (na, nb) = (cross(&ea[0], &ea[1]), cross(&eb[0], &eb[1]));
    if is_zero(&na) || is_zero(&nb) {
        return false;
    }
    let mut axes = vec![na.clone(), nb.clone()];
    axes.extend(ea.iter().flat_map(|e| eb.iter().map(|f| cross(e, f))));
    axes.extend(ea.iter().map(|e| cross(&na, e)));
    axes.extend(eb.iter().map(|f| cross(&nb, f)));
    let below = |lo: &[T], hi: &[T]| lo.iter().all(|x| hi.iter().all(|y| x.minus(y).sgn() < 0));
    !axes.iter().filter(|ax| !is_zero(ax)).any(|ax| {
        let pa: Vec<T> = a.iter().map(|p| dot(ax, p)).collect();
        let pb: Vec<T> = b.iter().map(|p| dot(ax, p)).collect();
        below(&pa, &pb) || below(&pb, &pa)
    })
}

/// A finite `f32` as `(negative, m, e)` with value `±m · 2^e` and `m` odd (or zero).
fn decompose(x: f32) -> (bool, u64, i32) {
    let bits = x.to_bits();
    let exp = ((bits >> 23) & 0xff) as i32;
    let frac = u64::from(bits & 0x7f_ffff);
    let (mut m, mut e) = if exp == 0 {
        (frac, -149)
    } else {
        (frac | 0x80_0000, exp - 150)
    };
    if m == 0 {
        return (false, 0, 0);
    }
    while m & 1 == 0 {
        m >>= 1;
        e += 1;
    }
    (bits >> 31 == 1, m, e)
}

/// The points' coordinates as exact integers, all scaled by one common power of two (which changes
/// no orientation sign and no intersection answer).
fn exact_points<const N: usize>(pts: [Vec3; N]) -> [V<Big>; N] {
    let parts = pts.map(|p| p.to_array().map(decompose));
    let emin = parts
        .iter()
        .flatten()
        .filter(|d| d.1 != 0)
        .map(|d| d.2)
        .min()
        .unwrap_or(0);
    parts.map(|p| {
        p.map(|(neg, m, e)| {
            if m == 0 {
                Big::zero()
            } else {
                Big::from_parts(neg, m, (e - emin) as u32)
            }
        })
    })
}

/// Exact oracle for `f32` triangles (`i128` when the scaled integers are small, else `Big`).
fn exact_intersect(a: &Tri, b: &Tri) -> bool {
    let pts = exact_points([a[0], a[1], a[2], b[0], b[1], b[2]]);
    let small: Option<Vec<V<i128>>> = pts
        .iter()
        .map(|p| Some([p[0].to_small()?, p[1].to_small()?, p[2].to_small()?]))
        .collect();
    match small {
        Some(s) => sat_intersect(&[s[0], s[1], s[2]], &[s[3], s[4], s[5]]),
        None => {
            let [a0, a1, a2, b0, b1, b2] = pts;
            sat_intersect(&[a0, a1, a2], &[b0, b1, b2])
        }
    }
}

/// Exact sign of `det[b-a, c-a, d-a]`.
fn orient_exact(p: [Vec3; 4]) -> Ordering {
    let [a, b, c, d] = exact_points(p);
    let det = dot(&cross(&vsub(&b, &a), &vsub(&c, &a)), &vsub(&d, &a));
    det.sgn().cmp(&0)
}

// ---------------------------------------------------------------------------------------------------
// f64 geometry and parry
// ---------------------------------------------------------------------------------------------------

/// Largest coordinate extent of the pair (the length scale of tolerances).
fn extent(a: &Tri, b: &Tri) -> f64 {
    let pts = a.iter().chain(b).map(|p| p.as_dvec3());
    let lo = pts.clone().fold(DVec3::INFINITY, DVec3::min);
    let hi = pts.fold(DVec3::NEG_INFINITY, DVec3::max);
    (hi - lo).max_element()
}

/// Separation margin in f64 over the 17 normalized candidate axes: the largest signed gap between
/// the projections. Above `tol`: separated by more than `tol` (the gap is a lower bound of the
/// distance). Below `-tol`: every candidate axis overlaps by more than `tol`, so the triangles cross
/// clearly. (Axes from nearly parallel factors are skipped; random input rarely has them.)
fn sat_margin(a: &Tri, b: &Tri) -> f64 {
    let (ta, tb) = (a.map(Vec3::as_dvec3), b.map(Vec3::as_dvec3));
    let edges = |t: [DVec3; 3]| [t[1] - t[0], t[2] - t[1], t[0] - t[2]];
    let (ea, eb) = (edges(ta), edges(tb));
    let (na, nb) = (ea[0].cross(ea[1]), eb[0].cross(eb[1]));
    let factor = |u: DVec3, v: DVec3| (u.cross(v), u.length() * v.length());
    let mut axes = vec![factor(ea[0], ea[1]), factor(eb[0], eb[1])];
    axes.extend(
        ea.iter()
            .flat_map(|&e| eb.iter().map(move |&f| factor(e, f))),
    );
    axes.extend(ea.iter().map(|&e| factor(na, e)));
    axes.extend(eb.iter().map(|&f| factor(nb, f)));
    axes.iter()
        .filter(|(ax, s)| ax.length() > 1e-9 * s)
        .map(|(ax, _)| {
            let n = ax.normalize();
            let pa = ta.map(|p| p.dot(n));
            let pb = tb.map(|p| p.dot(n));
            let (amin, amax) = (
                pa.iter().copied().fold(f64::INFINITY, f64::min),
                pa.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            );
            let (bmin, bmax) = (
                pb.iter().copied().fold(f64::INFINITY, f64::min),
                pb.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            );
            (bmin - amax).max(amin - bmax)
        })
        .fold(f64::NEG_INFINITY, f64::max)
}

fn dist_to_triangle(p: Vec3, t: &Tri) -> f64 {
    let p = p.as_dvec3();
    (closest_on_triangle(p, t.map(Vec3::as_dvec3)) - p).length()
}

/// Checks a contact: point on both triangles within `1e-4 · extent` (plus the f32 rounding of the
/// point's coordinates), normal = b's unit normal, depth = largest distance of a vertex of `a`
/// behind b's plane.
fn check_contact(a: &Tri, b: &Tri, c: TriContact) {
    let scale = extent(a, b);
    let magnitude = a
        .iter()
        .chain(b)
        .map(|p| f64::from(p.abs().max_element()))
        .fold(0.0, f64::max);
    let tol = 1e-4 * scale + 4.0 * f64::from(f32::EPSILON) * magnitude;
    let (da, db) = (dist_to_triangle(c.point, a), dist_to_triangle(c.point, b));
    assert!(
        da <= tol && db <= tol,
        "point {c:?} off: {da} {db} for {a:?} {b:?}"
    );
    let tb = b.map(Vec3::as_dvec3);
    let n = (tb[1] - tb[0]).cross(tb[2] - tb[0]).normalize();
    assert!((c.normal.length() - 1.0).abs() < 1e-6, "{c:?}");
    assert!((c.normal.as_dvec3() - n).length() < 1e-5, "{c:?} vs {n}");
    let depth = a
        .iter()
        .map(|v| -(v.as_dvec3() - tb[0]).dot(n))
        .fold(0.0, f64::max);
    assert!(c.depth >= 0.0, "{c:?}");
    assert!(
        (f64::from(c.depth) - depth).abs() <= 1e-6 * scale + 1e-6 * depth,
        "depth {c:?} vs {depth} for {a:?} {b:?}"
    );
}

/// parry3d's answer. Its GJK stops at an absolute tolerance (10 · f32::EPSILON), so it gets the pair
/// scaled to unit extent by a power of two, which is exact and changes no answer.
fn parry_intersects(a: &Tri, b: &Tri) -> bool {
    use parry3d::math::{Pose, Vector};
    use parry3d::query::intersection_test;
    use parry3d::shape::Triangle;
    let s = 2f32.powi(-(extent(a, b).log2().round() as i32));
    let tri = |t: &Tri| {
        let [p, q, r] = t.map(|v| Vector::from_array((v * s).to_array()));
        Triangle::new(p, q, r)
    };
    intersection_test(&Pose::IDENTITY, &tri(a), &Pose::IDENTITY, &tri(b))
        .expect("triangle pairs are supported")
        .intersecting
}

// ---------------------------------------------------------------------------------------------------
// Random pairs against parry, adjudicated exactly
// ---------------------------------------------------------------------------------------------------

#[derive(Clone, Copy, Debug)]
enum Dist {
    /// Vertices uniform in the unit cube.
    UnitCube,
    /// Small triangles (size ≤ 0.1) around a common point.
    SmallNear,
    /// Exactly coplanar: a random dyadic plane whose points are exact in f32.
    CoplanarExact,
    /// A random plane, vertices rounded to f32 (nearly coplanar: decided by tiny tilts).
    CoplanarRounded,
    /// Unit-cube triangles offset by up to 1e4.
    Offset,
    /// Unit-cube triangles scaled by 1e-4.
    Tiny,
    /// A vertex of `b` (rounded) on a face or an edge of `a`, the rest of `b` on one side.
    VertexOnA,
}

fn unit(rng: &mut SmallRng) -> Vec3 {
    Vec3::new(rng.random(), rng.random(), rng.random())
}

fn centered(rng: &mut SmallRng) -> DVec3 {
    DVec3::new(rng.random(), rng.random(), rng.random()) * 2.0 - 1.0
}

fn tri(rng: &mut SmallRng, f: &mut dyn FnMut(&mut SmallRng) -> Vec3) -> Tri {
    [f(rng), f(rng), f(rng)]
}

fn gen_pair(rng: &mut SmallRng, dist: Dist) -> (Tri, Tri) {
    match dist {
        Dist::UnitCube => (tri(rng, &mut unit), tri(rng, &mut unit)),
        Dist::SmallNear => {
            let c = unit(rng);
            let mut near = |r: &mut SmallRng| c + (unit(r) - 0.5) * 0.1;
            (tri(rng, &mut near), tri(rng, &mut near))
        }
        Dist::CoplanarExact => {
            // z = sx·x + sy·y + s0 with eighths for the slopes and 1/1024 steps for x, y: every term
            // and sum is exact in f32. A random axis permutation varies the plane's orientation.
            let slope = |r: &mut SmallRng| r.random_range(-16..=16) as f32 / 8.0;
            let (sx, sy, s0) = (slope(rng), slope(rng), slope(rng));
            let axes = [[0, 1, 2], [1, 2, 0], [2, 0, 1]][rng.random_range(0..3)];
            let mut on_plane = |r: &mut SmallRng| {
                let x = r.random_range(-1024..=1024) as f32 / 1024.0;
                let y = r.random_range(-1024..=1024) as f32 / 1024.0;
                let p = [x, y, sx * x + sy * y + s0];
                Vec3::new(p[axes[0]], p[axes[1]], p[axes[2]])
            };
            (tri(rng, &mut on_plane), tri(rng, &mut on_plane))
        }
        Dist::CoplanarRounded => {
            let o = centered(rng);
            let u = centered(rng).normalize();
            let v = u.cross(centered(rng)).normalize();
            let mut on_plane = |r: &mut SmallRng| {
                (o + u * (r.random::<f64>() - 0.5) + v * (r.random::<f64>() - 0.5)).as_vec3()
            };
            (tri(rng, &mut on_plane), tri(rng, &mut on_plane))
        }
        Dist::Offset => {
            let off = (centered(rng) * 1e4).as_vec3();
            let mut shifted = |r: &mut SmallRng| off + unit(r);
            (tri(rng, &mut shifted), tri(rng, &mut shifted))
        }
        Dist::Tiny => {
            let mut tiny = |r: &mut SmallRng| unit(r) * 1e-4;
            (tri(rng, &mut tiny), tri(rng, &mut tiny))
        }
        Dist::VertexOnA => {
            let a = tri(rng, &mut unit);
            let ta = a.map(Vec3::as_dvec3);
            let (mut s, mut t) = (rng.random::<f64>(), rng.random::<f64>());
            if s + t > 1.0 {
                (s, t) = (1.0 - s, 1.0 - t);
            }
            if rng.random_bool(0.3) {
                s = 0.0; // on an edge
            }
            let p = ta[0] + (ta[1] - ta[0]) * s + (ta[2] - ta[0]) * t;
            let n = (ta[1] - ta[0]).cross(ta[2] - ta[0]).normalize();
            let away = |r: &mut SmallRng| {
                let d = centered(r) * 0.3;
                (p + d + n * (d.dot(n).abs() - d.dot(n) + 0.01)).as_vec3()
            };
            let b = [p.as_vec3(), away(rng), away(rng)];
            (a, b)
        }
    }
}

#[test]
fn random_pairs_agree_with_parry_and_exact_oracle() {
    let dists = [
        Dist::UnitCube,
        Dist::SmallNear,
        Dist::CoplanarExact,
        Dist::CoplanarRounded,
        Dist::Offset,
        Dist::Tiny,
        Dist::VertexOnA,
    ];
    const PER_DIST: usize = 30_000;
    // Pairs whose f64 separation margin is within NEAR · extent of zero are near-touching: parry's
    // tolerances may decide them either way, so the exact oracle adjudicates them (all of them, not
    // only those where parry disagrees). Elsewhere parry must agree, except for its rare plain
    // errors: parry 0.31's GJK reports some clearly separated pairs as intersecting (seen up to
    // ~1e-2 · extent for thin, nearly coplanar pairs; its `distance` query agrees with it there). Such
    // a disagreement passes only if the f64 margin itself proves the decision (a positive gap along a
    // unit axis proves separation; overlaps beyond NEAR on all 17 candidate axes prove intersection)
    // and the exact oracle agrees; they are counted and must stay rare.
    const NEAR: f64 = 1e-4;
    let mut rng = SmallRng::seed_from_u64(0x7121_7121);
    let (mut total, mut total_near, mut total_disagree, mut total_parry_wrong) = (0, 0, 0, 0);
    for dist in dists {
        let (mut hits, mut near, mut disagree, mut parry_wrong) = (0, 0, 0, 0);
        for i in 0..PER_DIST {
            let (a, b) = gen_pair(&mut rng, dist);
            let mine = triangles_intersect(&a, &b);
            let contact = triangle_contact(&a, &b);
            assert_eq!(contact.is_some(), mine, "{a:?} {b:?}");
            let margin = sat_margin(&a, &b);
            let is_near = margin.abs() <= NEAR * extent(&a, &b);
            near += usize::from(is_near);
            let parry_agrees = mine == parry_intersects(&a, &b);
            if !parry_agrees && !is_near {
                parry_wrong += 1;
                assert_eq!(
                    mine,
                    margin < 0.0,
                    "f64 margin {margin}, {dist:?}: {a:?} {b:?}"
                );
            }
            disagree += usize::from(!parry_agrees);
            // Near-touching pairs, parry disagreements, and every 16th pair regardless are checked
            // exactly.
            if is_near || !parry_agrees || i % 16 == 0 {
                let exact = exact_intersect(&a, &b);
                assert_eq!(mine, exact, "exact oracle, {dist:?}: {a:?} {b:?}");
            }
            if let Some(c) = contact {
                hits += 1;
                check_contact(&a, &b, c);
                if matches!(dist, Dist::CoplanarExact) {
                    assert_eq!(c.depth, 0.0);
                }
            }
        }
        println!(
            "{dist:?}: {PER_DIST} pairs, {hits} intersecting, {near} near-touching (all checked \
             exactly), {disagree} parry disagreements (all adjudicated exactly; {parry_wrong} of \
             them on clear pairs)"
        );
        assert!(
            parry_wrong <= PER_DIST / 2_000,
            "parry should rarely err on clear pairs"
        );
        total += PER_DIST;
        total_near += near;
        total_disagree += disagree;
        total_parry_wrong += parry_wrong;
    }
    println!(
        "total: {total} pairs, {total_near} near-touching, {total_disagree} parry disagreements, \
         {total_parry_wrong} of them on clear pairs"
    );
}

// ---------------------------------------------------------------------------------------------------
// Integer grids: exactly touching configurations galore
// ---------------------------------------------------------------------------------------------------

/// The 72 equivalent forms of a pair: swapped or not, each triangle rotated and/or reversed.
fn equivalent_forms(a: &Tri, b: &Tri) -> Vec<(Tri, Tri)> {
    let forms = |t: &Tri| {
        let mut out = Vec::new();
        for k in 0..3 {
            let r = [t[k], t[(k + 1) % 3], t[(k + 2) % 3]];
            out.push(r);
            out.push([r[0], r[2], r[1]]);
        }
        out
    };
    let mut out = Vec::new();
    for fa in forms(a) {
        for fb in forms(b) {
            out.push((fa, fb));
            out.push((fb, fa));
        }
    }
    out
}

fn coord(r: &mut SmallRng, m: i64) -> i64 {
    r.random_range(-m..=m)
}

fn to_tri(t: [[i64; 3]; 3]) -> Tri {
    t.map(|p| Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32))
}

#[test]
fn integer_grid_pairs_match_exact_oracle() {
    let mut rng = SmallRng::seed_from_u64(42);
    let (mut count, mut hits) = (0, 0);
    for round in 0..120_000 {
        let (a, b): ([[i64; 3]; 3], [[i64; 3]; 3]) = match round % 4 {
            // Tiny coordinate range: coplanar, touching and degenerate pairs are frequent.
            0 => {
                let p = |r: &mut SmallRng| [coord(r, 2), coord(r, 2), coord(r, 2)];
                (
                    [p(&mut rng), p(&mut rng), p(&mut rng)],
                    [p(&mut rng), p(&mut rng), p(&mut rng)],
                )
            }
            // Vertices from a small pool: shared vertices and edges.
            1 => {
                let pool: Vec<[i64; 3]> = (0..5)
                    .map(|_| [coord(&mut rng, 3), coord(&mut rng, 3), coord(&mut rng, 3)])
                    .collect();
                let p = |r: &mut SmallRng| pool[r.random_range(0..pool.len())];
                (
                    [p(&mut rng), p(&mut rng), p(&mut rng)],
                    [p(&mut rng), p(&mut rng), p(&mut rng)],
                )
            }
            // Coplanar on the plane x + y + z = k (touching edges and vertices in the plane).
            2 => {
                let k = coord(&mut rng, 1);
                let p = |r: &mut SmallRng| {
                    let (x, y) = (coord(r, 3), coord(r, 3));
                    [x, y, k - x - y]
                };
                (
                    [p(&mut rng), p(&mut rng), p(&mut rng)],
                    [p(&mut rng), p(&mut rng), p(&mut rng)],
                )
            }
            // A wider range: general position with occasional contacts.
            _ => {
                let p = |r: &mut SmallRng| [coord(r, 6), coord(r, 6), coord(r, 6)];
                (
                    [p(&mut rng), p(&mut rng), p(&mut rng)],
                    [p(&mut rng), p(&mut rng), p(&mut rng)],
                )
            }
        };
        let int = |t: [[i64; 3]; 3]| t.map(|p| p.map(i128::from));
        let expected = sat_intersect(&int(a), &int(b));
        let (fa, fb) = (to_tri(a), to_tri(b));
        hits += usize::from(expected);
        // Exact power-of-two scalings (down to subnormal coordinates) and a 2^20 translation keep the
        // answer.
        let scaled = |t: &Tri, s: f32| t.map(|p| p * s);
        let shifted = |t: &Tri| t.map(|p| p + 1048576.0);
        let cases = [
            (fa, fb),
            (scaled(&fa, 2f32.powi(-140)), scaled(&fb, 2f32.powi(-140))),
            (scaled(&fa, 2f32.powi(-70)), scaled(&fb, 2f32.powi(-70))),
            (scaled(&fa, 2f32.powi(100)), scaled(&fb, 2f32.powi(100))),
            (shifted(&fa), shifted(&fb)),
        ];
        for (p, q) in cases {
            assert_eq!(triangles_intersect(&p, &q), expected, "{p:?} {q:?}");
            count += 1;
        }
        if round % 16 == 0 {
            for (p, q) in equivalent_forms(&fa, &fb) {
                assert_eq!(triangles_intersect(&p, &q), expected, "{p:?} {q:?}");
                assert_eq!(triangle_contact(&p, &q).is_some(), expected, "{p:?} {q:?}");
                count += 1;
            }
        }
        if let Some(c) = triangle_contact(&fa, &fb) {
            check_contact(&fa, &fb, c);
        }
    }
    println!("grid: {count} evaluations, {hits} of 120000 base pairs intersecting");
}

/// Huge triangles (coordinates up to 1e30) against small ones near their plane and one of their
/// edges. The f64 evaluation of the predicates cancels catastrophically here (differences of huge and
/// small coordinates round away the small ones), so the decisions come from the exact fallbacks of
/// both `orient3d` (crossing pairs) and `orient2d` (coplanar pairs).
#[test]
fn mixed_scale_pairs_match_exact_oracle() {
    let mut rng = SmallRng::seed_from_u64(99);
    let (mut hits, mut naive_wrong) = (0, 0);
    const N: usize = 9_000;
    for i in 0..N {
        let big = [1e30f32, 2f32.powi(70), 1e10][i % 3];
        let small = [1.0, 2f32.powi(-10), 2f32.powi(-100)][(i / 3) % 3];
        // `a` lies in the plane x + y + z = 0 (exactly); its edge a0–a1 passes through the origin
        // along (1, -2, 1), which is not axis-aligned in any coordinate projection.
        let a = [
            v(-big, 2. * big, -big),
            v(big, -2. * big, big),
            v(big, big, -2. * big),
        ];
        // Dyadic coordinates, so that points (t, s, -(t + s)) lie exactly on that plane.
        let d = |r: &mut SmallRng| r.random_range(-1024i32..=1024) as f32 / 1024.0 * small;
        let on_plane = |r: &mut SmallRng| {
            let (t, s) = (d(r), d(r));
            v(t, s, -(t + s))
        };
        let free = |r: &mut SmallRng| v(d(r), d(r), d(r));
        let b = match (i / 9) % 3 {
            0 => [on_plane(&mut rng), on_plane(&mut rng), on_plane(&mut rng)],
            1 => [free(&mut rng), free(&mut rng), free(&mut rng)],
            _ => [on_plane(&mut rng), free(&mut rng), free(&mut rng)],
        };
        let expected = exact_intersect(&a, &b);
        hits += usize::from(expected);
        for (p, q) in [(a, b), (b, a), ([a[1], a[2], a[0]], [b[0], b[2], b[1]])] {
            assert_eq!(triangles_intersect(&p, &q), expected, "{p:?} {q:?}");
            let contact = triangle_contact(&p, &q);
            assert_eq!(contact.is_some(), expected, "{p:?} {q:?}");
            if let Some(c) = contact {
                check_contact(&p, &q, c);
            }
        }
        for p in b {
            naive_wrong += usize::from(
                orient_naive([a[0], a[1], a[2], p]) != orient_exact([a[0], a[1], a[2], p]),
            );
        }
    }
    println!(
        "mixed scales: {N} pairs, {hits} intersecting, naive f64 orient3d wrong for {naive_wrong} vertices"
    );
    assert!(
        naive_wrong > N / 2,
        "these pairs should defeat naive f64 evaluation"
    );
}

// ---------------------------------------------------------------------------------------------------
// Analytic cases
// ---------------------------------------------------------------------------------------------------

fn v(x: f32, y: f32, z: f32) -> Vec3 {
    Vec3::new(x, y, z)
}

/// Asserts the decision for every equivalent form of the pair, and for its 2^-20 scaling (≈1e-6) and,
/// when exactly representable, its translation by 2^20 (≈1e6). Returns whether the translation ran.
fn check(name: &str, a: Tri, b: Tri, expected: bool) -> bool {
    let scale = |t: &Tri| t.map(|p| p * 2f32.powi(-20));
    let off = 1048576.0;
    let exact_shift = a.iter().chain(&b).all(|p| (*p + off) - off == *p);
    let shift = |t: &Tri| t.map(|p| p + off);
    let mut pairs = vec![(a, b), (scale(&a), scale(&b))];
    if exact_shift {
        pairs.push((shift(&a), shift(&b)));
    }
    for (p, q) in pairs {
        assert_eq!(
            exact_intersect(&p, &q),
            expected,
            "oracle disagrees with the analytic answer: {name}"
        );
        for (s, t) in equivalent_forms(&p, &q) {
            assert_eq!(triangles_intersect(&s, &t), expected, "{name}: {s:?} {t:?}");
            let contact = triangle_contact(&s, &t);
            assert_eq!(contact.is_some(), expected, "{name}");
            if let Some(c) = contact {
                check_contact(&s, &t, c);
            }
        }
    }
    exact_shift
}

/// A reference triangle in the plane z = 0.
const T: Tri = [
    Vec3::new(0.0, 0.0, 0.0),
    Vec3::new(4.0, 0.0, 0.0),
    Vec3::new(0.0, 4.0, 0.0),
];

#[test]
fn analytic_coplanar_cases() {
    let e = 2f32.powi(-18);
    let cases = [
        (
            "overlapping",
            [v(1., 1., 0.), v(5., 1., 0.), v(1., 5., 0.)],
            true,
        ),
        (
            "disjoint",
            [v(3., 3., 0.), v(6., 3., 0.), v(3., 6., 0.)],
            false,
        ),
        (
            "disjoint by 2^-18",
            [v(2. + e, 2., 0.), v(5., 2., 0.), v(2., 5., 0.)],
            false,
        ),
        (
            "overlapping by 2^-18",
            [v(2. - e, 2., 0.), v(5., 2., 0.), v(2., 5., 0.)],
            true,
        ),
        (
            "inside",
            [v(1., 1., 0.), v(2., 1., 0.), v(1., 2., 0.)],
            true,
        ),
        ("identical", T, true),
        (
            "sharing an edge",
            [v(4., 0., 0.), v(0., 4., 0.), v(4., 4., 0.)],
            true,
        ),
        (
            "sharing a vertex",
            [v(4., 0., 0.), v(8., 0., 0.), v(4., -4., 0.)],
            true,
        ),
        (
            "vertex on edge",
            [v(2., 2., 0.), v(5., 3., 0.), v(3., 5., 0.)],
            true,
        ),
        (
            "collinear edges overlapping",
            [v(2., 0., 0.), v(6., 0., 0.), v(4., -3., 0.)],
            true,
        ),
        (
            "collinear edges touching",
            [v(4., 0., 0.), v(6., 0., 0.), v(5., -3., 0.)],
            true,
        ),
        (
            "collinear edges apart",
            [v(4. + e, 0., 0.), v(6., 0., 0.), v(5., -3., 0.)],
            false,
        ),
        (
            "star crossing",
            [v(-1., 1., 0.), v(5., 1., 0.), v(2., -2., 0.)],
            true,
        ),
    ];
    for (name, a, expected) in cases {
        check(name, a, T, expected);
    }
    // A tilted plane x + y + z = 4 with exact coordinates.
    let t = [v(4., 0., 0.), v(0., 4., 0.), v(0., 0., 4.)];
    check(
        "tilted inside",
        [v(2., 2., 0.), v(2., 0., 2.), v(0., 2., 2.)],
        t,
        true,
    );
    check(
        "tilted outside",
        [v(5., 0., -1.), v(5., -1., 0.), v(6., -1., -1.)],
        t,
        false,
    );
    check(
        "tilted touching",
        [v(2., 2., 0.), v(3., 2., -1.), v(2., 3., -1.)],
        t,
        true,
    );
}

#[test]
fn analytic_touching_and_crossing_cases() {
    let e = 2f32.powi(-20);
    let cases = [
        // Edge (0,0,0)-(2,0,0) of `a` meets edge (1,-1,0)-(1,1,0) of `b` at (1,0,0) only.
        (
            "edge touches edge",
            [v(0., 0., 0.), v(2., 0., 0.), v(1., 0., -1.)],
            [v(1., -1., 0.), v(1., 1., 0.), v(1., 0., 1.)],
            true,
        ),
        (
            "edge misses edge by 2^-20",
            [v(0., 0., 0.), v(2., 0., 0.), v(1., 0., -1.)],
            [v(1., -1., e), v(1., 1., e), v(1., 0., 1.)],
            false,
        ),
        (
            "vertex on face",
            [v(1., 1., 0.), v(2., 1., 2.), v(1., 2., 2.)],
            T,
            true,
        ),
        (
            "vertex 2^-20 above face",
            [v(1., 1., e), v(2., 1., 2.), v(1., 2., 2.)],
            T,
            false,
        ),
        (
            "vertex 2^-20 through face",
            [v(1., 1., -e), v(2., 1., 2.), v(1., 2., 2.)],
            T,
            true,
        ),
        (
            "vertex on edge",
            [v(2., 0., 0.), v(2., -1., 1.), v(3., 1., 1.)],
            T,
            true,
        ),
        (
            "vertex beside edge",
            [v(2., -e, 0.), v(2., -1., 1.), v(3., -1., 1.)],
            T,
            false,
        ),
        (
            "vertex on vertex",
            [v(0., 0., 0.), v(-1., 0., 1.), v(0., -1., 1.)],
            T,
            true,
        ),
        (
            "shared edge",
            [v(0., 0., 0.), v(4., 0., 0.), v(0., 0., 4.)],
            T,
            true,
        ),
        (
            "edge in face",
            [v(1., 1., 0.), v(2., 1., 0.), v(1., 1., 3.)],
            T,
            true,
        ),
        (
            "edge 2^-20 above face",
            [v(1., 1., e), v(2., 1., e), v(1., 1., 3.)],
            T,
            false,
        ),
        (
            "piercing",
            [v(1., 1., -1.), v(2., 1., 1.), v(1., 2., 1.)],
            T,
            true,
        ),
        (
            "touching the boundary",
            [v(-1., 1., -1.), v(1., 1., 1.), v(-1., 1., 1.)],
            T,
            true,
        ),
        (
            "crossing the boundary",
            [v(-1., 1., -1.), v(2., 1., 1.), v(-1., 1., 1.)],
            T,
            true,
        ),
        (
            "passing beside",
            [v(-1., 1., -1.), v(-e, 1., 1.), v(-1., 1., 1.)],
            T,
            false,
        ),
        // Needles: a thin but non-degenerate triangle through the face, and along the face.
        (
            "needle through face",
            [v(1., 1., -1.), v(1., 1., 1.), v(1. + e, 1., 1.)],
            T,
            true,
        ),
        (
            "needle beside face",
            [v(-e, 1., -1.), v(-e, 1., 1.), v(-2. * e, 1., 1.)],
            T,
            false,
        ),
        // Degenerate triangles never intersect, even lying on or crossing the face.
        (
            "collinear crossing",
            [v(0., 0., -1.), v(1., 1., 1.), v(2., 2., 3.)],
            T,
            false,
        ),
        (
            "collinear in face",
            [v(1., 1., 0.), v(2., 1., 0.), v(3., 1., 0.)],
            T,
            false,
        ),
        ("point on face", [v(1., 1., 0.); 3], T, false),
        (
            "two equal corners",
            [v(1., 1., -1.), v(1., 1., -1.), v(1., 1., 1.)],
            T,
            false,
        ),
    ];
    let mut shifted = 0;
    for (name, a, b, expected) in cases {
        shifted += usize::from(check(name, a, b, expected));
    }
    assert_eq!(
        shifted,
        cases.len() - 8,
        "the 2^-20 cases cannot be shifted by 2^20 exactly"
    );
}

#[test]
fn analytic_near_touching_cases() {
    // Parallel planes 1e-7 apart, a vertex 1e-7 above or below a face.
    let up = |t: Tri, dz: f32| t.map(|p| p + Vec3::Z * dz);
    check("parallel planes 1e-7 apart", up(T, 1e-7), T, false);
    check(
        "vertex 1e-7 above",
        [v(1., 1., 1e-7), v(2., 1., 2.), v(1., 2., 2.)],
        T,
        false,
    );
    check(
        "vertex 1e-7 below",
        [v(1., 1., -1e-7), v(2., 1., 2.), v(1., 2., 2.)],
        T,
        true,
    );
    check(
        "edge 1e-7 above",
        [v(1., 1., 1e-7), v(2., 1., 1e-7), v(1., 2., 2.)],
        T,
        false,
    );
    check(
        "crossing by 1e-7",
        [v(1., 1., -1e-7), v(2., 1., 1e-7), v(1., 2., 1e-7)],
        T,
        true,
    );
    // On the tilted plane x + y + z = 4: f32(4/3) exceeds 4/3, so (f32(4/3),)*3 lies above it by
    // about 4e-8, and the next float down lies below it.
    let t = [v(4., 0., 0.), v(0., 4., 0.), v(0., 0., 4.)];
    let third = 4f32 / 3.0;
    assert!(f64::from(third) > 4.0 / 3.0);
    let above = Vec3::splat(third);
    let below = Vec3::splat(f32::from_bits(third.to_bits() - 1));
    check(
        "1 ulp above a tilted face",
        [above, v(2., 2., 2.), v(1., 2., 2.)],
        t,
        false,
    );
    check(
        "1 ulp below a tilted face",
        [below, v(2., 2., 2.), v(1., 2., 2.)],
        t,
        true,
    );
}

#[test]
fn contact_values_in_constructed_cases() {
    let b = [v(-4., -4., 0.), v(4., -4., 0.), v(0., 4., 0.)];
    // `a` pokes 0.25 through b's face; it crosses z = 0 along (0.2,0,0)-(0,0.2,0).
    let a = [v(0., 0., -0.25), v(1., 0., 1.), v(0., 1., 1.)];
    let c = triangle_contact(&a, &b).expect("intersecting");
    assert_eq!(c.normal, Vec3::Z);
    assert!((c.depth - 0.25).abs() < 1e-7, "{c:?}");
    assert!((c.point - v(0.1, 0.1, 0.)).length() < 1e-6, "{c:?}");
    // Reversing b's winding reverses the normal; the vertices at z = 1 are now 1 behind.
    let c = triangle_contact(&a, &[b[0], b[2], b[1]]).expect("intersecting");
    assert_eq!(c.normal, -Vec3::Z);
    assert!((c.depth - 1.0).abs() < 1e-7, "{c:?}");
    // Touching at a vertex only: depth 0, the point is the vertex.
    let a = [v(1., 1., 0.), v(2., 1., 2.), v(1., 2., 2.)];
    let c = triangle_contact(&a, &b).expect("touching");
    assert_eq!((c.point, c.depth), (v(1., 1., 0.), 0.0));
    // Coplanar, `a` inside `b`: the centroid of a's vertices, depth 0.
    let a = [v(0., 0., 0.), v(1., 0., 0.), v(0., 1., 0.)];
    let c = triangle_contact(&a, &b).expect("overlapping");
    assert!((c.point - v(1. / 3., 1. / 3., 0.)).length() < 1e-6, "{c:?}");
    assert_eq!((c.normal, c.depth), (Vec3::Z, 0.0));
    // Coplanar, partial overlap: b's edge 2x + y = 4 cuts a's vertex (2,1) off and passes through
    // (1,2); the overlap's vertices found are (1,1), (1,2) and the crossing (1.5,1).
    let a = [v(1., 1., 0.), v(2., 1., 0.), v(1., 2., 0.)];
    let c = triangle_contact(&a, &b).expect("overlapping");
    assert!(
        (c.point - v(3.5 / 3., 4. / 3., 0.)).length() < 1e-6,
        "{c:?}"
    );
    // Huge coordinates: all fields stay finite (the depth, f32::MAX, is the largest finite value).
    let m = f32::MAX;
    let a = [v(-m, -m, 0.), v(m, -m, 0.), v(0., m, 0.)];
    let b = [v(0., -m, -m), v(0., -m, m), v(0., m, 0.)];
    let c = triangle_contact(&a, &b).expect("crossing");
    assert!(c.point.is_finite() && c.normal.is_finite(), "{c:?}");
    assert_eq!((c.normal, c.depth), (-Vec3::X, f32::MAX));
}

#[test]
fn non_finite_input_never_intersects() {
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let a = [v(0., 0., 0.), v(bad, 0., 0.), v(0., 1., 0.)];
        assert!(!triangles_intersect(&a, &T) && !triangles_intersect(&T, &a));
        assert!(triangle_contact(&a, &T).is_none() && triangle_contact(&T, &a).is_none());
        assert_eq!(orient3d(T[0], T[1], T[2], a[1]), Ordering::Equal);
    }
}

// ---------------------------------------------------------------------------------------------------
// orient3d
// ---------------------------------------------------------------------------------------------------

/// The naive f64 evaluation, to count how often exactness matters.
fn orient_naive([a, b, c, d]: [Vec3; 4]) -> Ordering {
    let [a, b, c, d] = [a, b, c, d].map(Vec3::as_dvec3);
    (b - a)
        .cross(c - a)
        .dot(d - a)
        .partial_cmp(&0.0)
        .unwrap_or(Ordering::Equal)
}

/// A random f32 with a random sign and mantissa and a decimal exponent in `lo..=hi`.
fn wild(rng: &mut SmallRng, lo: i32, hi: i32) -> f32 {
    let m: f32 = rng.random_range(1.0..10.0);
    let s = if rng.random_bool(0.5) { -1.0 } else { 1.0 };
    s * m * 10f32.powi(rng.random_range(lo..=hi))
}

#[test]
fn orient3d_matches_exact_oracle() {
    let mut rng = SmallRng::seed_from_u64(7);
    let (mut checked, mut naive_wrong, mut zero) = (0, 0, 0);
    let mut check = |p: [Vec3; 4]| {
        let expected = orient_exact(p);
        assert_eq!(orient3d(p[0], p[1], p[2], p[3]), expected, "{p:?}");
        // Swapping two points flips the sign; rotating the base triangle keeps it.
        assert_eq!(
            orient3d(p[1], p[0], p[2], p[3]),
            expected.reverse(),
            "{p:?}"
        );
        assert_eq!(orient3d(p[1], p[2], p[0], p[3]), expected, "{p:?}");
        checked += 1;
        naive_wrong += usize::from(orient_naive(p) != expected);
        zero += usize::from(expected == Ordering::Equal);
    };
    for i in 0..40_000 {
        match i % 4 {
            // Mixed magnitudes from 1e-30 to 1e30 (and subnormals), general position.
            0 => {
                // Every other one reaches the subnormal range.
                let (lo, hi) = if i % 8 == 0 { (-44, 37) } else { (-30, 30) };
                check([(); 4].map(|_| {
                    Vec3::new(
                        wild(&mut rng, lo, hi),
                        wild(&mut rng, lo, hi),
                        wild(&mut rng, lo, hi),
                    )
                }));
            }
            // Near-coplanar: d on the plane through a, b, c (mixed scales) rounded to f32, then moved
            // by up to 2 ulps per coordinate.
            1 | 2 => {
                let e = if i % 4 == 1 { 1 } else { 30 };
                let [a, b, c] = [(); 3].map(|_| {
                    Vec3::new(
                        wild(&mut rng, -e, e),
                        wild(&mut rng, -e, e),
                        wild(&mut rng, -e, e),
                    )
                });
                let (s, t): (f64, f64) = (rng.random(), rng.random());
                let (a64, b64, c64) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
                let d = (a64 + (b64 - a64) * s + (c64 - a64) * t).as_vec3();
                let nudge = |x: f32, k: i32| {
                    let y = f32::from_bits((x.to_bits() as i32 + k) as u32);
                    if x == 0.0 || !y.is_finite() { x } else { y }
                };
                let d = Vec3::new(
                    nudge(d.x, rng.random_range(-2..=2)),
                    nudge(d.y, rng.random_range(-2..=2)),
                    nudge(d.z, rng.random_range(-2..=2)),
                );
                check([a, b, c, d]);
            }
            // Exactly coplanar with mixed magnitudes: all points on the plane x = y.
            _ => {
                let [a, b, c, d] = [(); 4].map(|_| {
                    let t = wild(&mut rng, -30, 30);
                    Vec3::new(t, t, wild(&mut rng, -30, 30))
                });
                assert_eq!(orient_exact([a, b, c, d]), Ordering::Equal);
                check([a, b, c, d]);
            }
        }
    }
    // Small integers against i128 directly.
    for _ in 0..20_000 {
        let p = [(); 4].map(|_| [(); 3].map(|_| rng.random_range(-3i64..=3)));
        let ip = p.map(|q| q.map(i128::from));
        let det = dot(
            &cross(&vsub(&ip[1], &ip[0]), &vsub(&ip[2], &ip[0])),
            &vsub(&ip[3], &ip[0]),
        );
        let fp = p.map(|q| Vec3::new(q[0] as f32, q[1] as f32, q[2] as f32));
        assert_eq!(orient3d(fp[0], fp[1], fp[2], fp[3]), det.sgn().cmp(&0));
    }
    println!(
        "orient3d: {checked} mixed-scale cases, {zero} exactly coplanar, naive f64 sign wrong in {naive_wrong}"
    );
    assert!(
        naive_wrong > 0,
        "the near-degenerate cases should defeat naive f64 evaluation"
    );
}

#[test]
fn orient3d_basic_signs() {
    let o = Vec3::ZERO;
    assert_eq!(orient3d(o, Vec3::X, Vec3::Y, Vec3::Z), Ordering::Greater);
    assert_eq!(orient3d(o, Vec3::X, Vec3::Y, -Vec3::Z), Ordering::Less);
    assert_eq!(
        orient3d(o, Vec3::X, Vec3::Y, v(5., -7., 0.)),
        Ordering::Equal
    );
    // One ulp off the plane z = 1e30, and the smallest subnormal off z = 0.
    let big = 1e30f32;
    let up = f32::from_bits(big.to_bits() + 1);
    let base = [v(0., 0., big), v(1e-30, 0., big), v(0., 1e-30, big)];
    assert_eq!(
        orient3d(base[0], base[1], base[2], v(1e30, -1e30, up)),
        Ordering::Greater
    );
    assert_eq!(
        orient3d(base[0], base[1], base[2], v(1e30, -1e30, big)),
        Ordering::Equal
    );
    let tiny = f32::from_bits(1);
    assert_eq!(
        orient3d(o, v(1e30, 0., 0.), v(0., 1e30, 0.), v(-1e30, 1e30, tiny)),
        Ordering::Greater
    );
    assert_eq!(
        orient3d(o, v(1e30, 0., 0.), v(0., 1e30, 0.), v(-1e30, 1e30, -tiny)),
        Ordering::Less
    );
}
