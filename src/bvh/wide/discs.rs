//! Lane discs: per wide leaf lane, a flat disc (centre, unit normal, thickness, radius) holding the leaf's
//! triangles, a lower bound on a point's distance to them far tighter than the lane's box.
//!
//! Why: a box around a tilted triangle is as thick as the triangle is wide, so a point at distance `d` from
//! a smooth surface finds every triangle within about half a triangle's width of its sphere "nearer" than
//! the answer (on the `bench queries` torus, 36 of the 39 leaves a closest-point query opens). A disc is as
//! thin as the triangle (zero, up to rounding) and only as wide as it, so it rules out nearly all of them
//! before their leaves are opened.
//!
//! Bound: every point `y` of the leaf has `y − c = a·n + b` with `b ⊥ n`, `|a| ≤ τ`, `|b| ≤ ρ` (the slab and
//! the cylinder are convex and hold the corners), so for `w = p − c`, `h = w·n`, `l = |w − h·n|`:
//! `|p − y|² ≥ (|h| − τ)₊² + (l − ρ)₊²`. The discs are fitted in `f64` and rounded outwards; the query side
//! evaluates the bound in `f32` with explicit margins for its rounding (see [`disc4`]).
//!
//! Cost: fitting is one pass over the wide nodes and the leaves' triangles (O(n)); a query pays about as
//! much again as the four-box distance test per node, and skips most leaves it would have opened.

use super::{EMPTY_LANE, WIDTH, WideBvh, is_leaf, leaf_slots};
use glam::{Vec3, Vec4};
use std::fmt;
use std::ops::Range;
use std::sync::{Mutex, OnceLock, PoisonError};

/// The discs of one wide node's four lanes, structure of arrays: rows centre x, y, z, unit normal x, y, z,
/// thickness `τ` (half, along the normal) and radius `ρ` (across it). A lane with no disc (an inner lane,
/// an unused one, a leaf of absent triangles) has normal 0, thickness 0 and radius `+∞`: its bound is 0.
#[repr(C, align(16))]
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct LaneDiscs {
    rows: [[f32; WIDTH]; 8],
}

const _: () = assert!(std::mem::size_of::<LaneDiscs>() == 128);

impl LaneDiscs {
    const NONE: LaneDiscs = LaneDiscs {
        rows: [
            [0.0; WIDTH],
            [0.0; WIDTH],
            [0.0; WIDTH],
            [0.0; WIDTH],
            [0.0; WIDTH],
            [0.0; WIDTH],
            [0.0; WIDTH],
            [f32::INFINITY; WIDTH],
        ],
    };
}

/// Relative margin of the fit's `f32` rounding (`u = 2⁻²⁴`): the corner differences, the dot product with a
/// normal whose length is 1 within [`MARGIN`]'s quarter, the squared lengths and the square root each lose
/// a few `u`, `2⁻²⁰` covers them all.
const FIT_MARGIN: f32 = 1.0 / (1 << 20) as f32;

/// Absolute margin for values too small for a relative one (squares that underflow: `√(2⁻¹²⁶) < 2⁻⁶⁰`).
const FIT_TINY: f32 = 1.0 / (1u64 << 60) as f32;

/// Three-vectors of four lanes.
type V4 = [Vec4; 3];

#[inline(always)]
fn dot(v: &V4, w: &V4) -> Vec4 {
    v[0] * w[0] + v[1] * w[1] + v[2] * w[2]
}

/// The `j`-th triangle of each lane as lanes (corner, axis), read straight from `tris`: lane `i`'s slot
/// `first[i] + j`, or its `last[i]` past its end (a lane without a leaf reads slot 0, any triangle: its
/// lane is masked out). No per-lane branch and no detour through memory (assembling the lanes from a
/// stack copy stalled on store forwarding, the fit's largest cost).
#[inline(always)]
fn round(tris: &[[Vec3; 3]], first: &[usize; WIDTH], last: &[usize; WIDTH], j: usize) -> [V4; 3] {
    let t: [&[Vec3; 3]; WIDTH] = std::array::from_fn(|i| &tris[(first[i] + j).min(last[i])]);
    std::array::from_fn(|k| {
        std::array::from_fn(|a| Vec4::new(t[0][k][a], t[1][k][a], t[2][k][a], t[3][k][a]))
    })
}

/// The discs of four lanes' triangles (`slots[i]` for lane `i`, empty for a lane without a leaf), four
/// lanes at a time: centred on the corners' mean, normal along the sum of the triangles' area vectors (0
/// when that is too short to normalise well: the disc is then a ball). The thickness and radius are measured
/// in `f32` against the stored centre and normal and grown by that measurement's rounding. A lane without
/// a leaf, or whose fit overflows, gets no disc. (Absent triangles, collapsed to a point, are fitted too:
/// a disc that holds more is still a bound.)
fn fit4(tris: &[[Vec3; 3]], slots: &[Range<usize>; WIDTH]) -> LaneDiscs {
    let len: [usize; WIDTH] = std::array::from_fn(|i| slots[i].len());
    let rounds = len.into_iter().max().unwrap_or(0);
    if rounds == 0 {
        return LaneDiscs::NONE;
    }
    let first = std::array::from_fn(|i| slots[i].start);
    let last = std::array::from_fn(|i| (slots[i].start + len[i]).saturating_sub(1));
    let count = Vec4::from_array(len.map(|l| l as f32));
    let (mut sum, mut normal) = ([Vec4::ZERO; 3], [Vec4::ZERO; 3]);
    for j in 0..rounds {
        let [a, b, c] = &round(tris, &first, &last, j);
        let (e, f) = (sub(b, a), sub(c, a));
        let area = [
            e[1] * f[2] - e[2] * f[1],
            e[2] * f[0] - e[0] * f[2],
            e[0] * f[1] - e[1] * f[0],
        ];
        // Lanes past their last triangle re-read it: counted once only.
        let has = Vec4::splat(j as f32).cmplt(count);
        for x in 0..3 {
            sum[x] += Vec4::select(has, a[x] + b[x] + c[x], Vec4::ZERO);
            normal[x] += Vec4::select(has, area[x], Vec4::ZERO);
        }
    }
    let corners = count * 3.0;
    let centre = sum.map(|s| s / corners);
    let inv = Vec4::ONE / dot(&normal, &normal).sqrt();
    let n = normal.map(|x| x * inv);
    let unit = (dot(&n, &n) - Vec4::ONE)
        .abs()
        .cmple(Vec4::splat(MARGIN / 4.0));
    let n = n.map(|x| Vec4::select(unit, x, Vec4::ZERO));
    let (mut h, mut r2) = (Vec4::ZERO, Vec4::ZERO);
    // The triangles are read again (in cache), cheaper than zeroing room for eight rounds. A lane's
    // re-read last triangle changes no maximum; a lane without a leaf has no centre (0 / 0) and gets no
    // disc below.
    for j in 0..rounds {
        for v in &round(tris, &first, &last, j) {
            let r = std::array::from_fn(|x| v[x] - centre[x]);
            h = h.max(dot(&r, &n).abs());
            r2 = r2.max(dot(&r, &r));
        }
    }
    let rho = r2.sqrt() * (1.0 + FIT_MARGIN) + Vec4::splat(FIT_TINY);
    // `h`'s rounding is a few `u` of `|r| ≤ ρ`.
    let tau = (h + rho * FIT_MARGIN) * (1.0 + FIT_MARGIN) + Vec4::splat(FIT_TINY);
    let ok = centre[0].is_finite_mask()
        & centre[1].is_finite_mask()
        & centre[2].is_finite_mask()
        & rho.is_finite_mask()
        & tau.is_finite_mask();
    let none = LaneDiscs::NONE.rows;
    let rows = [centre[0], centre[1], centre[2], n[0], n[1], n[2], tau, rho];
    LaneDiscs {
        rows: std::array::from_fn(|i| {
            Vec4::select(ok, rows[i], Vec4::from_array(none[i])).to_array()
        }),
    }
}

fn sub(v: &V4, w: &V4) -> V4 {
    [v[0] - w[0], v[1] - w[1], v[2] - w[2]]
}

impl WideBvh {
    /// Fits the discs of every node's leaf lanes to `tris` (the slot triangles) into `out`, one entry per
    /// node. O(n); no allocation once `out` has the nodes' length.
    pub(crate) fn fit_discs(&self, tris: &[[Vec3; 3]], out: &mut Vec<LaneDiscs>) {
        out.clear();
        out.extend(self.nodes.iter().map(|node| {
            // A lane that is not a leaf gets no slots: `0..0` by multiplication, without a branch.
            let slots = node.child.map(|c| {
                let s = leaf_slots(c);
                let leaf = usize::from((c != EMPTY_LANE) & is_leaf(c));
                s.start * leaf..s.end * leaf
            });
            fit4(tris, &slots)
        }));
    }
}

/// The lane discs of a mesh's wide tree, fitted on the first proximity query after its triangles changed,
/// so that meshes that only answer rays never pay for them. Fitting costs about three fifths of a refit's time
/// (one pass over the wide nodes and their leaves' triangles, four lanes at a time); the discs take 128
/// bytes per wide node, about 51 per triangle.
#[derive(Default)]
pub(crate) struct DiscCache {
    fitted: OnceLock<Vec<LaneDiscs>>,
    /// The memory of the last fit, for the next (a warm fit allocates nothing).
    spare: Mutex<Vec<LaneDiscs>>,
}

impl DiscCache {
    /// The discs of `wide` over `tris` (its slot triangles), fitted now if they are not yet. Threads that
    /// ask at once wait for one fit.
    pub(crate) fn get(&self, wide: &WideBvh, tris: &[[Vec3; 3]]) -> &[LaneDiscs] {
        self.fitted.get_or_init(|| {
            let mut discs =
                std::mem::take(&mut *self.spare.lock().unwrap_or_else(PoisonError::into_inner));
            wide.fit_discs(tris, &mut discs);
            discs
        })
    }

    /// Forgets the discs (the triangles or the tree changed), keeping their memory.
    pub(crate) fn clear(&mut self) {
        if let Some(discs) = self.fitted.take() {
            *self.spare.get_mut().unwrap_or_else(PoisonError::into_inner) = discs;
        }
    }
}

/// A clone fits its own discs when first asked.
impl Clone for DiscCache {
    fn clone(&self) -> Self {
        DiscCache::default()
    }
}

impl fmt::Debug for DiscCache {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("DiscCache")
            .field("fitted", &self.fitted.get().map(Vec::len))
            .finish()
    }
}

/// Margin on the `f32` evaluation: `2⁻¹⁸ · |w|₁` covers the rounding of `w`, of `h` (against the stored
/// normal, whose length is 1 within `2u`) and of `|w|² − h²` many times over (`u = 2⁻²⁴`).
const MARGIN: f32 = 1.0 / (1 << 18) as f32;

/// Per lane, a lower bound on the squared distance from `p` to anything inside the lane's disc (0 for a
/// lane without one, or when the `f32` evaluation overflows).
#[inline(always)]
pub(crate) fn disc4(d: &LaneDiscs, p: Vec3) -> Vec4 {
    let row = |i: usize| Vec4::from_array(d.rows[i]);
    let w = [
        Vec4::splat(p.x) - row(0),
        Vec4::splat(p.y) - row(1),
        Vec4::splat(p.z) - row(2),
    ];
    let h = dot(&w, &[row(3), row(4), row(5)]).abs();
    let ww = dot(&w, &w);
    let e = (w[0].abs() + w[1].abs() + w[2].abs()) * MARGIN;
    // `x.max(0)` turns a NaN `x` into 0 (SSE `max` answers its second operand then): no bound, no prune.
    let lat2 = (ww - h * h - ww * (4.0 * MARGIN)).max(Vec4::ZERO);
    let lat = lat2.sqrt() * (1.0 - MARGIN);
    let a = (h - (row(6) + e)).max(Vec4::ZERO);
    let b = (lat - (row(7) + e)).max(Vec4::ZERO);
    (a * a + b * b) * (1.0 - MARGIN)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::queries::closest_on_triangle;
    use crate::scenes::SceneRng;

    /// Leaves of one to three triangles (well shaped, needles, slivers, collapsed to a point, a quad's two
    /// halves) at scales from 1e-4 to 1e4 and offsets to 1e5, against the exact `f64` distance (Ericson's
    /// test, which shares no code with the discs): the bound never exceeds the nearest triangle's distance,
    /// and for a point straight above a lone triangle (whose corners round finely) it is within a
    /// thousandth of it.
    #[test]
    fn disc_bound_is_below_the_exact_distance_and_tight_above_the_face() {
        let mut rng = SceneRng::new(7);
        // Uniform in the cube of side `s` around the origin.
        let v = |rng: &mut SceneRng, s: f32| rng.vec3(-0.5 * s, 0.5 * s);
        let (mut above, mut bounded) = (0, 0);
        for round in 0..5_000 {
            let scale = [1e-4, 1.0, 1e4][round % 3];
            let offset = [Vec3::ZERO, Vec3::splat(1e5), Vec3::new(-3.0, 7.0, 1.0)][round / 3 % 3];
            let mut tris = Vec::new();
            let mut slots: [Range<usize>; WIDTH] = std::array::from_fn(|_| 0..0);
            for (lane, s) in slots.iter_mut().enumerate() {
                let start = tris.len();
                let count = (round + lane) % 4;
                for k in 0..count {
                    let a = offset + v(&mut rng, scale);
                    let (b, c) = (a + v(&mut rng, scale), a + v(&mut rng, scale));
                    tris.push(match (round + lane + k) % 6 {
                        0 => [a, b, a + (b - a) * 0.5 + v(&mut rng, 1e-6 * scale)],
                        1 => [a; 3],
                        2 => [a, b, a + (b - a) * 2.0],
                        3 if k > 0 => {
                            // The other half of the previous triangle's parallelogram.
                            let [p, q, r] = tris[tris.len() - 1];
                            [q, q + (r - p), r]
                        }
                        _ => [a, b, c],
                    });
                }
                *s = start..tris.len();
            }
            let discs = fit4(&tris, &slots);
            let exact = |p: Vec3, s: &Range<usize>| {
                tris[s.clone()]
                    .iter()
                    .map(|t| closest_on_triangle(p.as_dvec3(), t.map(Vec3::as_dvec3)).dist2)
                    .fold(f64::INFINITY, f64::min)
            };
            let mut points: Vec<Vec3> = (0..4).map(|_| offset + v(&mut rng, 3.0 * scale)).collect();
            // Straight above the first lone, well-shaped triangle, a few of its sizes away.
            let lone = (0..WIDTH).find(|&l| slots[l].len() == 1 && (round + l) % 6 >= 4);
            // (At a 1e5 offset a 1e-4 triangle rounds to a point or a line: no normal, no such point.)
            let lift = lone
                .map(|lane| {
                    let [a, b, c] = tris[slots[lane].start];
                    let n = (b - a).cross(c - a).normalize();
                    ((a + b + c) / 3.0 + n * (b - a).length() * 3.0, lane)
                })
                .filter(|(p, _)| p.is_finite());
            points.extend(lift.iter().map(|l| l.0));
            for &p in &points {
                let bound = disc4(&discs, p).to_array();
                for (lane, s) in slots.iter().enumerate() {
                    let (x, b) = (exact(p, s), f64::from(bound[lane]));
                    assert!(!b.is_nan(), "round {round} lane {lane}");
                    // The exact test's own rounding: a few ulp of the squared distance.
                    assert!(
                        b <= x * (1.0 + 1e-12),
                        "round {round} lane {lane}: {b} > {x}"
                    );
                    bounded += usize::from(b > 0.0);
                }
            }
            // Tight where the corners' rounding is small against the triangle (at a 1e5 offset a unit
            // triangle's plane is only known to a few thousandths: the thickness covers that).
            let fine = offset.abs().max_element() * f32::EPSILON < scale * 1e-4;
            if let Some((p, lane)) = lift.filter(|_| fine) {
                let (x, b) = (
                    exact(p, &slots[lane]),
                    f64::from(disc4(&discs, p).to_array()[lane]),
                );
                assert!(b >= x * 0.999, "round {round}: {b} vs {x}");
                above += 1;
            }
        }
        assert!(above > 1_000 && bounded > 10_000, "{above} {bounded}");
    }

    /// A lane without a leaf, or with coordinates whose squares overflow `f32`, bounds nothing (0), and
    /// never NaN.
    #[test]
    fn lanes_without_a_usable_disc_bound_nothing() {
        let big = 3e38f32;
        let tris = vec![
            [Vec3::ZERO, Vec3::X, Vec3::Y],
            [
                Vec3::splat(big),
                Vec3::new(big, -big, 0.0),
                Vec3::new(-big, big, 1.0),
            ],
        ];
        let discs = fit4(&tris, &[0..1, 1..2, 0..0, 0..0]);
        let far = disc4(&discs, Vec3::splat(-big)).to_array();
        assert!(far.iter().all(|b| !b.is_nan()));
        assert_eq!(&far[1..], &[0.0; 3]);
        let near = disc4(&discs, Vec3::new(0.25, 0.25, 2.0)).to_array();
        assert!(
            (3.99..=4.0).contains(&near[0]) && near[2..] == [0.0; 2],
            "{near:?}"
        );
    }
}
