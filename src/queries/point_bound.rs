//! A conservative `f32` lower bound on the distance from a point to four triangles at once, to skip the exact
//! `f64` point–triangle test for triangles that cannot beat the best one found so far.
//!
//! When to use: a closest-point walk that has opened many leaves (a point almost equidistant from a whole
//! band of the surface, such as one near a torus's axis, opens thousands): there most triangles whose box
//! lies within the best distance are still farther than it, and four of them are ruled out for about the
//! price of one exact test.
//!
//! How: any vector `m` gives `distance ≥ min over the corners v of (v − p)·m / |m|` (the triangle is the
//! convex hull of its corners, and `(y − p)·m / |m| ≤ |y − p|` for every point `y`). With `m` pointing from
//! `p` to the triangle's nearest point the bound equals the distance, so `m` is that direction as found in
//! `f32` — the face normal when `p` projects inside the face, else the nearest point of the nearest edge.
//! Whatever rounding does to `m` (a wrong region, a needle, NaN), the bound stays a bound: only its
//! evaluation is rounded, and that is covered by an explicit margin. A lane whose bound is not finite and
//! positive is never skipped.
//!
//! Cost: about as much as one scalar exact test for four triangles, no allocation.

use glam::{BVec4A, Vec3, Vec4};

/// Relative margin on each `f32` dot product `r·m` (`r = v − p` rounded once, then three products and two
/// sums: at most `4.1u · Σ|rᵢ mᵢ|` with `u = 2⁻²⁴`), taken as `2⁻²⁰` (more than three times that).
const DOT_MARGIN: f32 = 1.0 / (1 << 20) as f32;

/// Absolute margin for products that underflow (each loses at most `2⁻¹⁴⁹`).
const TINY: f32 = f32::MIN_POSITIVE * 16.0;

/// Relative margin of the final `f64` comparison: the rounding of the margin's own subtraction, of `|m|²`
/// in `f32` (`≤ 4u`) and of the exact test's `f64` distance against the bound (`≤ 1e-15`), `2⁻¹⁸` covering
/// them all many times over.
const COMPARE_MARGIN: f64 = 1.0 + 1.0 / (1u64 << 18) as f64;

/// Four triangles as lanes: `corner[k][axis]`.
type Lanes = [[Vec4; 3]; 3];

/// The lanes of `tris` (four triangles) whose squared distance to `p` certainly exceeds `bound`, as bits
/// (bit `i` for `tris[i]`). A lane not set may be farther too: test it exactly.
pub(crate) fn farther_than(p: Vec3, tris: [&[Vec3; 3]; 4], bound: f64) -> u32 {
    // Corners relative to `p` (one rounding each), so that `p` is the origin below.
    let r: Lanes = std::array::from_fn(|k| {
        std::array::from_fn(|a| {
            Vec4::new(tris[0][k][a], tris[1][k][a], tris[2][k][a], tris[3][k][a])
                - Vec4::splat(p[a])
        })
    });
    let m = direction(&r);
    let dot = |v: &[Vec4; 3], w: &[Vec4; 3]| v[0] * w[0] + v[1] * w[1] + v[2] * w[2];
    let abs = |v: &[Vec4; 3]| [v[0].abs(), v[1].abs(), v[2].abs()];
    let m_abs = abs(&m);
    let low = |v: &[Vec4; 3]| dot(v, &m) - DOT_MARGIN * dot(&abs(v), &m_abs) - Vec4::splat(TINY);
    let lows = [low(&r[0]), low(&r[1]), low(&r[2])];
    // SSE's `min` drops a NaN operand: a lane with any NaN corner term is kept whole.
    let nan = (lows[0].is_nan_mask() | lows[1].is_nan_mask() | lows[2].is_nan_mask()).bitmask();
    let least = lows[0].min(lows[1]).min(lows[2]).to_array();
    let norm2 = dot(&m, &m).to_array();
    let far = (0..4).fold(0, |mask, i| {
        let (l, n) = (f64::from(least[i]), f64::from(norm2[i]));
        // `>` on a NaN is false: such a lane is kept.
        let far = l > 0.0 && l * l > bound * n * COMPARE_MARGIN;
        mask | (u32::from(far) << i)
    });
    far & !nan
}

/// Per lane, a vector from the origin towards the triangle's nearest point, found in `f32` without
/// branches: the face normal (oriented towards the triangle) when the origin projects inside the face,
/// else the nearest point of the nearest edge; its largest component is ±1.
#[inline(always)]
fn direction(r: &Lanes) -> [Vec4; 3] {
    let sub = |x: &[Vec4; 3], y: &[Vec4; 3]| [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
    let dot = |v: &[Vec4; 3], w: &[Vec4; 3]| v[0] * w[0] + v[1] * w[1] + v[2] * w[2];
    let cross = |v: &[Vec4; 3], w: &[Vec4; 3]| {
        [
            v[1] * w[2] - v[2] * w[1],
            v[2] * w[0] - v[0] * w[2],
            v[0] * w[1] - v[1] * w[0],
        ]
    };
    let select = |c: BVec4A, x: [Vec4; 3], y: [Vec4; 3]| {
        [
            Vec4::select(c, x[0], y[0]),
            Vec4::select(c, x[1], y[1]),
            Vec4::select(c, x[2], y[2]),
        ]
    };
    // The nearest point of each edge, the nearest of the three kept.
    let mut best = r[0];
    let mut best2 = dot(&best, &best);
    for k in 0..3 {
        let (s, t) = (&r[k], &r[(k + 1) % 3]);
        let e = sub(t, s);
        // A zero-length edge gives NaN here, and `max` (SSE: NaN in the first operand yields the second)
        // turns it into 0: its start point.
        let f = (-dot(s, &e) / dot(&e, &e)).max(Vec4::ZERO).min(Vec4::ONE);
        let x = [s[0] + e[0] * f, s[1] + e[1] * f, s[2] + e[2] * f];
        let x2 = dot(&x, &x);
        let nearer = x2.cmplt(best2);
        best = select(nearer, x, best);
        best2 = x2.min(best2);
    }
    // The face: the origin's projection is inside when it is on the inner side of all three edges.
    let n = cross(&sub(&r[1], &r[0]), &sub(&r[2], &r[0]));
    let side = |k: usize| dot(&n, &cross(&r[k], &r[(k + 1) % 3]));
    let inside = side(0).cmpge(Vec4::ZERO) & side(1).cmpge(Vec4::ZERO) & side(2).cmpge(Vec4::ZERO);
    // The normal towards the triangle: `n·a` has the sign of the triangle's side.
    let h = dot(&n, &r[0]).signum();
    let m = select(inside, [n[0] * h, n[1] * h, n[2] * h], best);
    // Scaled to a largest component of 1, so that `|m|²` and the dot products neither underflow (a tiny
    // triangle's normal is its size squared) nor overflow; the division's rounding only turns `m` a little,
    // and any `m` gives a bound. A zero `m` becomes NaN: the lane is kept.
    let big = m[0].abs().max(m[1].abs()).max(m[2].abs());
    [m[0] / big, m[1] / big, m[2] / big]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::queries::closest::closest_on_triangle;
    use crate::scenes::SceneRng;

    /// Random triangles (well shaped, needles, slivers, zero-length edges, single points) at scales from
    /// 1e-4 to 1e4 and offsets to 1e5, against the exact `f64` distance (Ericson's test, which shares no code
    /// with the bound): a lane is only ever reported farther when it is, and a well-shaped triangle farther
    /// than the bound by a thousandth is reported.
    #[test]
    fn bound_is_below_the_exact_distance_and_tight_on_well_shaped_triangles() {
        let mut rng = SceneRng::new(3);
        // Uniform in the cube of side `s` around the origin.
        let v = |rng: &mut SceneRng, s: f32| rng.vec3(-0.5 * s, 0.5 * s);
        let (mut reported, mut tight) = (0, 0);
        for round in 0..20_000 {
            let scale = [1e-4, 1.0, 1e4][round % 3];
            let offset = [Vec3::ZERO, Vec3::splat(1e5), Vec3::new(-3.0, 7.0, 1.0)][round / 3 % 3];
            let p = offset + v(&mut rng, 2.0 * scale);
            let tris: [[Vec3; 3]; 4] = std::array::from_fn(|i| {
                let a = offset + v(&mut rng, 2.0 * scale);
                let (b, c) = (a + v(&mut rng, scale), a + v(&mut rng, scale));
                match (round + i) % 7 {
                    0 => [a, b, a + (b - a) * 0.5 + v(&mut rng, 1e-6 * scale)],
                    1 => [a, a, b],
                    2 => [a, a, a],
                    3 => [a, b, a + (b - a) * 2.0],
                    _ => [a, b, c],
                }
            });
            let exact =
                tris.map(|t| closest_on_triangle(p.as_dvec3(), t.map(Vec3::as_dvec3)).dist2);
            // Bounds between the nearest and the farthest lane, and exactly at one lane's distance.
            let mut sorted = exact;
            sorted.sort_by(f64::total_cmp);
            for bound in [
                sorted[0],
                sorted[1],
                (sorted[1] + sorted[2]) * 0.5,
                sorted[3],
            ] {
                let far = farther_than(p, [&tris[0], &tris[1], &tris[2], &tris[3]], bound);
                for (i, (&x, t)) in exact.iter().zip(&tris).enumerate() {
                    let set = far & (1 << i) != 0;
                    // The exact test's own rounding: a few ulp of the squared corner distances (the
                    // differences from `p` are exact in `f64`).
                    let spread = t
                        .iter()
                        .map(|c| (c.as_dvec3() - p.as_dvec3()).length_squared())
                        .fold(0.0, f64::max);
                    assert!(
                        !set || x > bound - 1e-12 * spread,
                        "lane {i} of round {round}: {x} ≤ {bound}"
                    );
                    reported += usize::from(set);
                    if (round + i) % 7 >= 4 && x > bound * 1.001 {
                        assert!(set, "round {round} lane {i}: {x} vs {bound}");
                        tight += 1;
                    }
                }
            }
        }
        assert!(reported > tight && tight > 10_000, "{reported} {tight}");
    }
}
