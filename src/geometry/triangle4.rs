//! The watertight ray–triangle test ([`TriangleRay::intersect`]) for four rays of a packet against one
//! triangle at once.
//!
//! When to use: a packet's leaf, where several rays meet the same triangles. Lane by lane the SSE path
//! performs the scalar test's `f32` operations in the scalar test's order (no fused multiply-add), so each
//! lane's `t`, `u` and `v` are the scalar test's bits; a lane whose edge function rounds to exactly zero —
//! where the scalar test recomputes the three in `f64` — is left to the scalar test ([`Hits4::exact`]).
//!
//! Cost: about a quarter of four scalar tests (one pass of packed operations for the four rays). x86-64
//! only (SSE is its baseline); elsewhere a packet's leaf tests its rays one at a time.

use super::TriangleRay;
use glam::Vec3;

/// The constants of up to `N` rays' watertight tests, by component: the origin and the three rows of each
/// ray's shear (see [`TriangleRay`]), twelve columns of `N` lanes.
pub(crate) struct TriangleRays<const N: usize> {
    columns: [[f32; N]; 12],
}

/// What the four-ray test found for lanes `g..g + 4`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Hits4 {
    /// Lanes (bit `i` for lane `g + i`) that hit within their range, with `t`, `u`, `v` below.
    pub(crate) hit: u32,
    /// Lanes the four-ray test does not decide (an edge function of exactly zero): test them alone.
    pub(crate) exact: u32,
    pub(crate) t: [f32; 4],
    pub(crate) u: [f32; 4],
    pub(crate) v: [f32; 4],
}

impl<const N: usize> TriangleRays<N> {
    /// No rays (every lane's constants zero until [`set`](Self::set)).
    pub(crate) const EMPTY: Self = Self {
        columns: [[0.0; N]; 12],
    };

    /// Sets lane `i` to the constants of `ray`.
    #[inline]
    pub(crate) fn set(&mut self, i: usize, ray: &TriangleRay) {
        for (k, v) in ray.parts().iter().enumerate() {
            for a in 0..3 {
                self.columns[3 * k + a][i] = v[a];
            }
        }
    }

    /// Lanes `g..g + 4` (`g + 4 ≤ N`) against the triangle `(v0, v1, v2)`, each within its own
    /// `tmin[i]..=tmax[i]`: as [`TriangleRay::intersect`] lane by lane, except for the lanes in
    /// [`Hits4::exact`].
    #[inline]
    pub(crate) fn intersect4(
        &self,
        g: usize,
        [v0, v1, v2]: [Vec3; 3],
        tmin: &[f32],
        tmax: &[f32],
    ) -> Hits4 {
        use std::arch::x86_64::*;
        assert!(g + 4 <= N && tmin.len() >= g + 4 && tmax.len() >= g + 4);
        // SAFETY: SSE and SSE2 are part of the x86-64 baseline; every unaligned load reads four floats of
        // a column or of `tmin`/`tmax` at `g..g + 4`, in bounds by the assertion above, and the stores
        // write the four-float arrays of the result.
        unsafe {
            let col = |k: usize| _mm_loadu_ps(self.columns[k][g..].as_ptr());
            let (ox, oy, oz) = (col(0), col(1), col(2));
            // The vertex relative to each ray's origin, then its three shear rows' dot products, as
            // `Vec3::dot`: (x·x + y·y) + z·z.
            let rel = |v: Vec3| {
                (
                    _mm_sub_ps(_mm_set1_ps(v.x), ox),
                    _mm_sub_ps(_mm_set1_ps(v.y), oy),
                    _mm_sub_ps(_mm_set1_ps(v.z), oz),
                )
            };
            let dot = |row: usize, (x, y, z): (__m128, __m128, __m128)| {
                _mm_add_ps(
                    _mm_add_ps(_mm_mul_ps(col(row), x), _mm_mul_ps(col(row + 1), y)),
                    _mm_mul_ps(col(row + 2), z),
                )
            };
            let (a, b, c) = (rel(v0), rel(v1), rel(v2));
            let (ax, ay) = (dot(3, a), dot(6, a));
            let (bx, by) = (dot(3, b), dot(6, b));
            let (cx, cy) = (dot(3, c), dot(6, c));
            let edge = |px, py, qx, qy| _mm_sub_ps(_mm_mul_ps(px, qy), _mm_mul_ps(py, qx));
            let u = edge(cx, cy, bx, by);
            let v = edge(ax, ay, cx, cy);
            let w = edge(bx, by, ax, ay);
            let zero = _mm_setzero_ps();
            let exact = _mm_movemask_ps(_mm_or_ps(
                _mm_or_ps(_mm_cmpeq_ps(u, zero), _mm_cmpeq_ps(v, zero)),
                _mm_cmpeq_ps(w, zero),
            )) as u32;
            let any_neg = _mm_or_ps(
                _mm_or_ps(_mm_cmplt_ps(u, zero), _mm_cmplt_ps(v, zero)),
                _mm_cmplt_ps(w, zero),
            );
            let any_pos = _mm_or_ps(
                _mm_or_ps(_mm_cmpgt_ps(u, zero), _mm_cmpgt_ps(v, zero)),
                _mm_cmpgt_ps(w, zero),
            );
            let det = _mm_add_ps(_mm_add_ps(u, v), w);
            let big_t = _mm_add_ps(
                _mm_add_ps(_mm_mul_ps(u, dot(9, a)), _mm_mul_ps(v, dot(9, b))),
                _mm_mul_ps(w, dot(9, c)),
            );
            let rcp = _mm_div_ps(_mm_set1_ps(1.0), det);
            let t = _mm_mul_ps(big_t, rcp);
            // Inside (no edge of each sign), a non-zero determinant, `tmin ≤ t ≤ tmax` (NaN fails).
            let inside = _mm_andnot_ps(_mm_and_ps(any_neg, any_pos), _mm_cmpneq_ps(det, zero));
            let range = _mm_and_ps(
                _mm_cmpge_ps(t, _mm_loadu_ps(tmin[g..].as_ptr())),
                _mm_cmple_ps(t, _mm_loadu_ps(tmax[g..].as_ptr())),
            );
            let hit = _mm_movemask_ps(_mm_and_ps(inside, range)) as u32 & !exact;
            let mut out = Hits4 {
                hit,
                exact,
                t: [0.0; 4],
                u: [0.0; 4],
                v: [0.0; 4],
            };
            _mm_storeu_ps(out.t.as_mut_ptr(), t);
            _mm_storeu_ps(out.u.as_mut_ptr(), _mm_mul_ps(v, rcp));
            _mm_storeu_ps(out.v.as_mut_ptr(), _mm_mul_ps(w, rcp));
            out
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Ray;
    use crate::scenes::SceneRng;

    /// Tests `rays` (in lanes `g..g + 4` of `lanes`, `tmin`, `tmax`) against `tri` four at a time and
    /// each alone with [`TriangleRay::intersect`], the oracle: every lane the four-ray test decides must
    /// be the scalar answer bit for bit (`t`, `u`, `v`, or no hit). Returns the hits and the lanes left
    /// to the scalar test.
    fn agree(
        lanes: &TriangleRays<8>,
        g: usize,
        rays: &[TriangleRay],
        tri: [Vec3; 3],
        tmin: &[f32; 8],
        tmax: &[f32; 8],
    ) -> (usize, usize) {
        let four = lanes.intersect4(g, tri, tmin, tmax);
        let (mut hits, mut deferred) = (0, 0);
        for k in 0..4 {
            let i = g + k;
            if four.exact >> k & 1 == 1 {
                deferred += 1;
                continue;
            }
            let alone = rays[i].intersect(tri[0], tri[1], tri[2], tmin[i], tmax[i]);
            let bits = |t: f32, u: f32, v: f32| [t, u, v].map(f32::to_bits);
            let got = (four.hit >> k & 1 == 1).then(|| bits(four.t[k], four.u[k], four.v[k]));
            assert_eq!(
                got,
                alone.map(|h| bits(h.t, h.u, h.v)),
                "lane {i}: {tri:?} {:?} {} {}",
                rays[i],
                tmin[i],
                tmax[i]
            );
            hits += usize::from(got.is_some());
        }
        (hits, deferred)
    }

    /// Four rays at a time equal the scalar test bit for bit (hit or miss, `t`, `u`, `v`), or defer to it:
    /// random rays and triangles, and rays through vertices and shared edges, along the axes, with
    /// zero-area and needle triangles, at scales from 1e-4 to 1e4 and offsets to 1e5.
    #[test]
    fn four_rays_equal_the_scalar_test() {
        let mut rng = SceneRng::new(29);
        let (mut hits, mut deferred) = (0, 0);
        for round in 0..20_000 {
            let scale = [1e-4, 1.0, 1e4][round % 3];
            let offset = [Vec3::ZERO, Vec3::splat(1e5), Vec3::new(-3.0, 7.0, 1.0)][round / 3 % 3];
            let v = |rng: &mut SceneRng| offset + rng.vec3(-scale, scale);
            let (a, b) = (v(&mut rng), v(&mut rng));
            let tri = match round % 5 {
                0 => [a, b, a],
                1 => [a, b, a + (b - a) * 2.0],
                2 => [a, b, a + (b - a) * 0.5 + rng.vec3(-1e-6, 1e-6) * scale],
                _ => [a, b, v(&mut rng)],
            };
            let axes = [Vec3::X, -Vec3::Y, Vec3::Z, Vec3::new(0.0, 1.0, -1.0)];
            let rays: [Ray; 4] = std::array::from_fn(|i| {
                // Aimed at a corner, an edge's midpoint, a random point of the triangle, or anywhere.
                let target = match (round + i) % 4 {
                    0 => tri[i % 3],
                    1 => (tri[0] + tri[1]) * 0.5,
                    2 => {
                        tri[0]
                            + (tri[1] - tri[0]) * rng.unit() * 0.5
                            + (tri[2] - tri[0]) * rng.unit() * 0.5
                    }
                    _ => v(&mut rng),
                };
                let dir = if (round + i) % 3 == 0 {
                    axes[(round + i) % 4]
                } else {
                    rng.vec3(-1.0, 1.0)
                };
                Ray::with_range(
                    target - dir * 2.0 * scale,
                    dir * scale,
                    0.0,
                    rng.range(1.0, 4.0),
                )
            });
            // The rays in lanes 4..8, behind four lanes of no ray.
            let mut shear = vec![TriangleRay::EMPTY; 4];
            shear.extend(rays.iter().map(TriangleRay::new));
            let mut lanes = TriangleRays::<8>::EMPTY;
            let (mut tmin, mut tmax) = ([0.0; 8], [0.0; 8]);
            for (i, r) in rays.iter().enumerate() {
                lanes.set(4 + i, &shear[4 + i]);
                (tmin[4 + i], tmax[4 + i]) = (r.tmin, r.tmax);
            }
            let (h, d) = agree(&lanes, 4, &shear, tri, &tmin, &tmax);
            (hits, deferred) = (hits + h, deferred + d);
        }
        assert!(
            hits > 5_000 && deferred > 100,
            "{hits} hits, {deferred} deferred"
        );
    }

    /// The same on arbitrary bits: rows, origins, corners and ranges drawn from NaN, ±∞, ±0, subnormals,
    /// huge and tiny values and small dyadic numbers (many exact zeros), no ray needed to derive them.
    #[test]
    fn four_rays_equal_the_scalar_test_on_any_bits() {
        fn any(rng: &mut SceneRng) -> f32 {
            match rng.next_u64() % 8 {
                0 => f32::from_bits(rng.next_u64() as u32),
                1 => [
                    0.0,
                    -0.0,
                    1.0,
                    -1.0,
                    f32::INFINITY,
                    f32::NEG_INFINITY,
                    f32::NAN,
                    f32::MIN_POSITIVE / 4.0,
                ][(rng.next_u64() % 8) as usize],
                2 => rng.range(-1e30, 1e30),
                3 => rng.range(-1e-30, 1e-30),
                _ => (rng.range(-4.0, 4.0) * 8.0).round() / 8.0,
            }
        }
        let vec = |rng: &mut SceneRng| Vec3::new(any(rng), any(rng), any(rng));
        let mut rng = SceneRng::new(7);
        let mut hits = 0;
        for round in 0..100_000 {
            let rays: [TriangleRay; 8] = std::array::from_fn(|_| {
                TriangleRay::from_parts(std::array::from_fn(|_| vec(&mut rng)))
            });
            let tri = [vec(&mut rng), vec(&mut rng), vec(&mut rng)];
            let tmin: [f32; 8] =
                std::array::from_fn(|_| [0.0, any(&mut rng)][(rng.next_u64() % 2) as usize]);
            let tmax: [f32; 8] = std::array::from_fn(|_| {
                [f32::INFINITY, any(&mut rng)][(rng.next_u64() % 2) as usize]
            });
            let mut lanes = TriangleRays::<8>::EMPTY;
            for (i, r) in rays.iter().enumerate() {
                lanes.set(i, r);
            }
            hits += agree(&lanes, 4 * (round % 2), &rays, tri, &tmin, &tmax).0;
        }
        // 771 of the 400,000 lanes hit: the rest miss, or meet NaN ranges or corners.
        assert!(hits > 500, "{hits}");
    }
}
