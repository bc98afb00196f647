//! Four pixels at a time: the classification's per-pixel arithmetic in SIMD lanes (glam's `Vec4`: SSE2,
//! NEON or wasm SIMD where the target has them, four plain floats elsewhere), bit for bit what the scalar
//! tests compute — the same operations in the same order, lane by lane — so a pixel's class does not
//! depend on which path decided it.
//!
//! Most pixels of a hard-shadow pass face the light over an interior texel whose depth the pass trusts (a
//! smooth texel, or any texel for the shadow map alone): [`decide`] settles those four at a time, with one
//! scalar read of the table per lane, and leaves every other pixel (no surface, facing away, off the
//! map, at a shadow edge, non-finite input) to the mode's scalar test. On the crowd at 1024² the
//! selective classification takes about a fifth less time than pixel by pixel; it is bound by the
//! scattered reads of the table and the G-buffer's 24 bytes a pixel, not by arithmetic.

use super::classify::Class;
use super::{GBuffer, ShadowMap};
use glam::{BVec4A, Vec3, Vec4};
use std::ops::Range;

/// Up to four points (or normals) in lanes, one coordinate per vector; missing ones are zero.
#[derive(Clone, Copy)]
struct Quad {
    x: Vec4,
    y: Vec4,
    z: Vec4,
}

impl Quad {
    /// The first four of `v` (fewer: zero-padded).
    #[inline(always)]
    fn load(v: &[Vec3]) -> Self {
        let [a, b, c, d] = match v.first_chunk::<4>() {
            #[cfg(target_arch = "x86_64")]
            Some(four) => return Self::transpose_sse(four),
            #[cfg(not(target_arch = "x86_64"))]
            Some(&four) => four,
            None => std::array::from_fn(|k| v.get(k).copied().unwrap_or(Vec3::ZERO)),
        };
        Self {
            x: Vec4::new(a.x, b.x, c.x, d.x),
            y: Vec4::new(a.y, b.y, c.y, d.y),
            z: Vec4::new(a.z, b.z, c.z, d.z),
        }
    }

    /// [`load`](Self::load) of four points on x86-64: the 48 bytes they are, as three loads of four
    /// floats (`x0 y0 z0 x1 | y1 z1 x2 y2 | z2 x3 y3 z3`) transposed by six shuffles, the same lanes as
    /// gathering them coordinate by coordinate (twelve scalar loads and nine shuffles, which the compiler
    /// does not merge). About 2% of a quick selective pass.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn transpose_sse(four: &[Vec3; 4]) -> Self {
        use std::arch::x86_64::*;
        // `_MM_SHUFFLE(d, c, b, a)`: lanes a and b of the first operand, c and d of the second.
        const fn pick(a: i32, b: i32, c: i32, d: i32) -> i32 {
            d << 6 | c << 4 | b << 2 | a
        }
        let f = four.as_ptr().cast::<f32>();
        // SAFETY: SSE is part of the x86-64 baseline, and `Vec3` is three `f32`s (`repr(C)`, no padding),
        // so four of them are twelve floats: each unaligned load reads four of them, at 0, 4 and 8.
        let [x, y, z] = unsafe {
            let (m0, m1, m2) = (
                _mm_loadu_ps(f),
                _mm_loadu_ps(f.add(4)),
                _mm_loadu_ps(f.add(8)),
            );
            let x2x3 = _mm_shuffle_ps::<{ pick(2, 3, 0, 1) }>(m1, m2); // x2 y2 z2 x3
            let yz01 = _mm_shuffle_ps::<{ pick(1, 2, 0, 1) }>(m0, m1); // y0 z0 y1 z1
            let y2y3 = _mm_shuffle_ps::<{ pick(3, 3, 2, 2) }>(m1, m2); // y2 y2 y3 y3
            [
                _mm_shuffle_ps::<{ pick(0, 3, 0, 3) }>(m0, x2x3),
                _mm_shuffle_ps::<{ pick(0, 2, 0, 2) }>(yz01, y2y3),
                _mm_shuffle_ps::<{ pick(1, 3, 0, 3) }>(yz01, m2),
            ]
        };
        Self {
            x: Vec4::from(x),
            y: Vec4::from(y),
            z: Vec4::from(z),
        }
    }

    /// Each lane's dot product with `d`, summed in `Vec3::dot`'s order.
    #[inline(always)]
    fn dot(&self, d: Vec3) -> Vec4 {
        self.x * d.x + self.y * d.y + self.z * d.z
    }

    /// The lanes equal to the zero vector.
    #[inline(always)]
    fn is_zero(&self) -> BVec4A {
        self.x.cmpeq(Vec4::ZERO) & self.y.cmpeq(Vec4::ZERO) & self.z.cmpeq(Vec4::ZERO)
    }
}

/// Up to four neighbouring pixels of one image row: their surfaces, as slices (for the scalar tests), and
/// their normals in lanes, with `n · L` per lane; with a map, their positions' coordinates across it and
/// along the light, computed once for every test that reads them (where some pixel shows a surface). A
/// pass that only asks which pixels face the light reads half the G-buffer.
pub(super) struct Four<'a> {
    positions: &'a [Vec3],
    normals: &'a [Vec3],
    n: Quad,
    /// `n · towards` per lane.
    cos: Vec4,
    /// [`light`]`(map, positions)` for the map given to [`new`](Self::new).
    light: Option<[Vec4; 3]>,
}

impl<'a> Four<'a> {
    /// Pixels `positions[k]`, `normals[k]` (at most four, as many of each) lit from `towards`, with their
    /// positions across `map` when given (one aimed along `towards`).
    #[inline(always)]
    pub(super) fn new(
        positions: &'a [Vec3],
        normals: &'a [Vec3],
        towards: Vec3,
        map: Option<&ShadowMap>,
    ) -> Self {
        let n = Quad::load(normals);
        Self {
            positions,
            normals,
            n,
            cos: n.dot(towards),
            // Four pixels without a surface (the sky) need no place on the map: neither test reads it.
            light: map
                .filter(|_| !n.is_zero().all())
                .map(|m| light(m, Quad::load(positions))),
        }
    }

    /// The positions in lanes across `map` and along its light: the values [`new`](Self::new) computed
    /// when given the map (it must be this one), else computed now.
    #[inline(always)]
    fn light(&self, map: &ShadowMap) -> [Vec4; 3] {
        self.light
            .unwrap_or_else(|| light(map, Quad::load(self.positions)))
    }

    /// How many pixels.
    pub(super) fn len(&self) -> usize {
        self.positions.len()
    }
}

/// The coordinates of the points `p` across `map` and along its light: `p · u`, `p · v` and `p · towards`
/// per lane (in `Vec3::dot`'s order, as [`ShadowMap::project`] and `super::receiver` sum them).
#[inline(always)]
fn light(map: &ShadowMap, p: Quad) -> [Vec4; 3] {
    let (u, v, towards, ..) = map.frame();
    [p.dot(u), p.dot(v), p.dot(towards)]
}

/// The pixels `pixels` of `g` (indices into its arrays, row-major), four at a time from the first (the
/// last group may be shorter), each with the index of its first pixel, lit from `towards`, their
/// positions across `map` when given ([`Four::new`]).
#[inline(always)]
pub(super) fn fours<'a>(
    g: &'a GBuffer,
    pixels: Range<usize>,
    towards: Vec3,
    map: Option<&'a ShadowMap>,
) -> impl Iterator<Item = (usize, Four<'a>)> {
    let end = pixels.end;
    pixels.step_by(4).map(
        #[inline(always)]
        move |i| {
            let j = (i + 4).min(end);
            let four = Four::new(&g.positions[i..j], &g.normals[i..j], towards, map);
            (i, four)
        },
    )
}

/// Lane masks as bits (lane `k` is bit `k`).
pub(super) type Bits = u32;

/// The verdicts on the lanes of `px` without a surface facing the light — no surface ([`Class::Empty`]:
/// lit) or one whose `n · L` is at most `away` ([`Class::FacingAway`]: shadowed), as `classify::facing`
/// — and the lanes left: those that face it (`n · L` above `away`, or NaN).
#[inline(always)]
pub(super) fn surfaces(px: &Four, away: f32) -> (Verdicts, Bits) {
    let lanes = first(px.len());
    let empty = px.n.is_zero() & lanes;
    let facing = !px.n.is_zero() & !px.cos.cmple(Vec4::splat(away)) & lanes;
    let verdicts = Verdicts {
        lit: empty.bitmask(),
        ..Verdicts::default()
    };
    (verdicts, facing.bitmask())
}

/// The verdicts of a pass that marks every pixel facing the light (rays for all of them): [`surfaces`],
/// with the facing lanes marked.
#[inline(always)]
pub(super) fn mark_facing(px: &Four, away: f32) -> Verdicts {
    let (v, facing) = surfaces(px, away);
    Verdicts {
        facing,
        marked: facing,
        ..v
    }
}

/// [`surfaces`], then the shadow map's verdict for the facing lanes it settles by one read of `table`
/// (a `res × res` table of the map's texels, NaN or infinite where the map cannot decide by depth alone):
/// those with a finite `n · L`, over an interior texel (one with eight neighbours) whose table value `s`
/// is finite — lit when the receiver's depth `d` is at most `s` plus the bias (`map.texel_size() ×
/// bias_texels`, plus the slope-scaled part), else shadowed, as the scalar `classify::verdict`. Returns
/// the verdicts so far and the lanes the caller's scalar test must decide.
#[inline(always)]
pub(super) fn decide(
    map: &ShadowMap,
    table: &[f32],
    px: &Four,
    away: f32,
    bias_texels: f32,
) -> (Verdicts, Bits) {
    let (mut verdicts, facing) = surfaces(px, away);
    if facing == 0 {
        return (verdicts, 0);
    }
    let (.., corner, per_texel, top) = map.frame();
    let ([pu, pv, pt], cos) = (px.light(map), px.cos);
    let qx = (pu - corner.x) * per_texel;
    let qy = (pv - corner.y) * per_texel;
    // The interior is `[1, res − 1)` on both axes (as `classify::texel`; NaN is outside).
    let (one, last) = (Vec4::ONE, Vec4::splat((map.resolution() - 1) as f32));
    let inside = qx.cmpge(one) & qy.cmpge(one) & qx.cmplt(last) & qy.cmplt(last);
    let candidates = (inside & cos.is_finite_mask()).bitmask() & facing;
    if candidates == 0 {
        return (verdicts, facing);
    }
    let res = map.resolution();
    let (qx, qy) = (qx.to_array(), qy.to_array());
    let s = Vec4::from_array(std::array::from_fn(|k| {
        if candidates >> k & 1 == 0 {
            return f32::NAN;
        }
        // SAFETY: a candidate lane's `qx`, `qy` are finite and in `[1, 16383)` (checked above), so they
        // truncate to an `i32`.
        let (i, j) = unsafe {
            (
                qx[k].to_int_unchecked::<i32>() as usize,
                qy[k].to_int_unchecked::<i32>() as usize,
            )
        };
        table[j * res + i]
    }));
    let settled = s.is_finite_mask().bitmask() & candidates;
    let d = Vec4::splat(top) - pt;
    let texel = map.texel_size();
    let constant = Vec4::splat(texel * bias_texels);
    // `classify::slope_bias`, its operations in its order: the constant bias plus the receiver's reach
    // within one texel, from its slope.
    let c = cos.max(Vec4::splat(1.0 / 64.0));
    let tan = (Vec4::ONE - c * c).max(Vec4::ZERO).sqrt() / c;
    let reach = Vec4::splat(texel * std::f32::consts::SQRT_2) * tan;
    let slope_bias = constant + reach;
    let lit = (d.cmple(s + constant) | d.cmple(s + slope_bias)).bitmask() & settled;
    verdicts.lit |= lit;
    verdicts.facing |= settled;
    (verdicts, facing & !settled)
}

/// The first `n` lanes (of four).
#[inline(always)]
fn first(n: usize) -> BVec4A {
    BVec4A::new(n > 0, n > 1, n > 2, n > 3)
}

/// The lanes of `px` whose surface faces the light (`n · L` above 0) and whose receiver does not lie
/// within `fitted` across `map` (x and y inside it, z along the light not below it; z above it changes
/// no map): every pixel that would widen [`Receivers`]' bounds there, and those with a non-finite
/// coordinate, which widen nothing but fail the compares (so a broken G-buffer costs a second fit, never
/// a wrong one). Compares alone, no bounds carried from pixel to pixel.
#[inline(always)]
pub(super) fn outside(map: &ShadowMap, px: &Four, fitted: (Vec3, Vec3)) -> Bits {
    // Missing lanes have a zero normal: they do not face the light.
    let facing = px.cos.cmpgt(Vec4::ZERO);
    if !facing.any() {
        return 0;
    }
    let q = px.light(map);
    let (lo, hi) = (
        fitted.0.to_array().map(Vec4::splat),
        fitted.1.to_array().map(Vec4::splat),
    );
    let within = q[0].cmpge(lo[0])
        & q[0].cmple(hi[0])
        & q[1].cmpge(lo[1])
        & q[1].cmple(hi[1])
        & q[2].cmpge(lo[2]);
    (!within & facing).bitmask()
}

/// The bounds of the receivers among the pixels given to [`add`](Self::add): x and y across a map, z
/// along the light, as `super::receiver` grows them pixel by pixel; [`bounds`](Self::bounds) folds the
/// lanes. Four pixels whose coordinates are all finite (nearly all) are added in lanes, the others pixel
/// by pixel (where a pixel with a non-finite coordinate widens nothing).
pub(super) struct Receivers {
    lo: [Vec4; 3],
    hi: [Vec4; 3],
    /// The pixels added one at a time.
    odd: (Vec3, Vec3),
}

impl Receivers {
    /// None yet.
    pub(super) fn new() -> Self {
        Self {
            lo: [Vec4::MAX; 3],
            hi: [Vec4::MIN; 3],
            odd: super::NO_BOUNDS,
        }
    }

    /// Grows the bounds by the pixels of `px` whose surface faces the light (`n · L` above 0), across
    /// `map`, along its light.
    #[inline(always)]
    pub(super) fn add(&mut self, map: &ShadowMap, px: &Four) {
        let q = px.light(map);
        if px.len() < 4 || !(q[0] + q[1] + q[2]).is_finite() {
            let towards = map.frame().2;
            for (&p, &nrm) in px.positions.iter().zip(px.normals) {
                self.odd = super::receiver(self.odd, map, towards, p, nrm);
            }
            return;
        }
        // Every coordinate is finite: a lane facing away moves out to ±∞, where it widens nothing.
        let out = Vec4::select(px.cos.cmpgt(Vec4::ZERO), Vec4::ZERO, Vec4::INFINITY);
        for (k, q) in q.into_iter().enumerate() {
            self.lo[k] = self.lo[k].min(q + out);
            self.hi[k] = self.hi[k].max(q - out);
        }
    }

    /// The bounds (`super::NO_BOUNDS` where no pixel faced the light).
    pub(super) fn bounds(&self) -> (Vec3, Vec3) {
        let lanes = (
            Vec3::from_array(self.lo.map(Vec4::min_element)),
            Vec3::from_array(self.hi.map(Vec4::max_element)),
        );
        super::union(lanes, self.odd)
    }
}

/// Visibility of four pixels from their lit bits (bit `k`: pixel `k`), one table entry per mask.
const VISIBILITY: [[f32; 4]; 16] = {
    let mut t = [[0.0; 4]; 16];
    let mut m = 0;
    while m < 16 {
        let mut k = 0;
        while k < 4 {
            t[m][k] = (m >> k & 1) as f32;
            k += 1;
        }
        m += 1;
    }
    t
};

/// Writes the visibility of up to four pixels (`out`, as long as the pixels) from their lit bits: 1 where
/// lit, else 0.
#[inline(always)]
pub(super) fn write_visibility(lit: Bits, out: &mut [f32]) {
    let all = &VISIBILITY[lit as usize & 15];
    match out.first_chunk_mut::<4>() {
        // Four pixels (nearly always): a store of 16 bytes, not a copy of a length known only at run time.
        Some(four) => *four = *all,
        None => out.copy_from_slice(&all[..out.len()]),
    }
}

/// What a pass's test says about up to four pixels, one bit per pixel (bit `k`: pixel `k`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct Verdicts {
    /// Visibility 1 until rays say otherwise: no surface there, or lit by the map.
    pub(super) lit: Bits,
    /// A surface facing the light (one a shadow could fall on).
    pub(super) facing: Bits,
    /// Potentially incorrect: a shadow ray decides.
    pub(super) marked: Bits,
}

impl Verdicts {
    /// Records pixel `k`'s class.
    #[inline(always)]
    pub(super) fn set(&mut self, k: usize, class: Class) {
        let bit = 1 << k;
        if matches!(class, Class::Empty | Class::Lit) {
            self.lit |= bit;
        }
        if !matches!(class, Class::Empty | Class::FacingAway) {
            self.facing |= bit;
        }
        if class == Class::Marked {
            self.marked |= bit;
        }
    }
}

/// The verdicts on `px`'s pixels from the scalar `test(position, normal)`, pixel by pixel.
#[inline(always)]
pub(super) fn each(px: &Four, test: impl Fn(Vec3, Vec3) -> Class) -> Verdicts {
    let all = first(px.len()).bitmask();
    or_each(px, (Verdicts::default(), all), test)
}

/// `verdicts`, completed by the scalar `test(position, normal)` for the lanes in `rest` (as [`decide`]
/// returns them).
#[inline(always)]
pub(super) fn or_each(
    px: &Four,
    (mut verdicts, mut rest): (Verdicts, Bits),
    test: impl Fn(Vec3, Vec3) -> Class,
) -> Verdicts {
    while rest != 0 {
        let k = rest.trailing_zeros() as usize;
        verdicts.set(k, test(px.positions[k], px.normals[k]));
        rest &= rest - 1;
    }
    verdicts
}

#[cfg(test)]
mod tests {
    use super::super::{NO_BOUNDS, classify, deltas::Deltas, receiver};
    use super::*;
    use rand::{Rng, SeedableRng, rngs::SmallRng};

    /// A 32-texel map of random triangles over a 2-unit square and its smooth texels, aimed along
    /// `towards`.
    fn scene(r: &mut SmallRng, towards: Vec3) -> (ShadowMap, Deltas) {
        let mut v = || {
            Vec3::new(
                r.random_range(-1.0..1.0),
                r.random_range(0.0..0.6),
                r.random_range(-1.0..1.0),
            )
        };
        let tris: Vec<[Vec3; 3]> = (0..40).map(|_| [v(), v(), v()]).collect();
        let mut map = ShadowMap::default();
        map.aim(towards);
        let bounds = tris
            .iter()
            .flatten()
            .fold(NO_BOUNDS, |b, &p| receiver(b, &map, towards, p, towards));
        map.render(&tris, bounds, 0.0, 32, false);
        let mut deltas = Deltas::default();
        deltas.find(&map, 1.5 * map.texel_size(), false);
        (map, deltas)
    }

    /// A pixel's surface drawn to hit every path: on the map and off it, at the map's border, far away,
    /// non-finite; normals facing the light, grazing, facing away, zero, NaN.
    fn pixel(r: &mut SmallRng, towards: Vec3) -> (Vec3, Vec3) {
        let p = match r.random_range(0..10) {
            0 => Vec3::splat(f32::NAN),
            1 => Vec3::new(f32::INFINITY, 0.0, 0.0),
            2 => Vec3::new(r.random_range(-1e6..1e6), 0.0, r.random_range(-1e6..1e6)),
            3 => Vec3::new(-1.0, r.random_range(0.0..0.6), r.random_range(-1.0..1.0)),
            _ => Vec3::new(
                r.random_range(-1.1..1.1),
                r.random_range(-0.2..0.7),
                r.random_range(-1.1..1.1),
            ),
        };
        let n = match r.random_range(0..10) {
            0 => Vec3::ZERO,
            1 => Vec3::splat(f32::NAN),
            2 => towards.any_orthonormal_vector(),
            3 => -towards,
            _ => (towards * r.random_range(-0.5..1.0)
                + Vec3::new(
                    r.random_range(-1.0..1.0),
                    r.random_range(-1.0..1.0),
                    r.random_range(-1.0..1.0),
                ))
            .normalize_or_zero(),
        };
        (p, n)
    }

    fn expect(class: Class) -> Verdicts {
        let mut v = Verdicts::default();
        v.set(0, class);
        v
    }

    /// Four pixels at a time classify each pixel as the scalar tests do on their own, in every hard mode
    /// and for one to four pixels, with their positions across the map computed up front or not; their
    /// receivers' bounds are the scalar fold's, bit for bit (the map is fitted to them and compared with
    /// `==`); and the lanes found outside given bounds are the pixels facing the light whose scalar
    /// coordinates do not all lie within them.
    #[test]
    fn lanes_classify_as_the_scalar_tests() {
        let mut r = SmallRng::seed_from_u64(7);
        let (mut settled, mut flagged) = (0, [0; 2]);
        for round in 0..40 {
            let towards =
                Vec3::new(r.random_range(-1.0..1.0), 1.0, r.random_range(-1.0..1.0)).normalize();
            let (map, deltas) = scene(&mut r, towards);
            let bias = [0.0, 1.0, 2.5][round % 3];
            for len in [4, 4, 4, 3, 2, 1] {
                let px: Vec<(Vec3, Vec3)> = (0..len).map(|_| pixel(&mut r, towards)).collect();
                let (ps, ns): (Vec<Vec3>, Vec<Vec3>) = px.iter().copied().unzip();
                // With the positions across the map computed up front and without.
                let four = Four::new(&ps, &ns, towards, Some(&map));
                let bare = Four::new(&ps, &ns, towards, None);
                let scalar = |p: Vec3, n: Vec3, test: &dyn Fn(Vec3, Vec3, f32) -> Class| {
                    classify::facing(n, towards, 0.0).map_or_else(|c| c, |cos| test(p, n, cos))
                };
                let selective = |p, n, cos| classify::selective(&map, &deltas, p, n, cos, bias);
                let map_only = |p, _, cos| classify::shadow_map_only(&map, p, cos, bias);
                for (table, test, four) in [
                    (
                        deltas.table(),
                        &selective as &dyn Fn(Vec3, Vec3, f32) -> Class,
                        &four,
                    ),
                    (map.depths(), &map_only, &four),
                    (deltas.table(), &selective, &bare),
                    (map.depths(), &map_only, &bare),
                ] {
                    let decided = decide(&map, table, four, 0.0, bias);
                    settled += (first(len).bitmask() & !decided.1).count_ones();
                    let v = or_each(four, decided, |p, n| scalar(p, n, test));
                    let marks = mark_facing(four, 0.0);
                    for (k, &(p, n)) in px.iter().enumerate() {
                        let bit = |v: Verdicts| Verdicts {
                            lit: v.lit >> k & 1,
                            facing: v.facing >> k & 1,
                            marked: v.marked >> k & 1,
                        };
                        assert_eq!(bit(v), expect(scalar(p, n, test)), "pixel {p}, {n}");
                        let traced = scalar(p, n, &|_, _, _| Class::Marked);
                        assert_eq!(bit(marks), expect(traced), "pixel {p}, {n}");
                    }
                    assert_eq!(v.lit >> len | v.facing >> len | v.marked >> len, 0);
                }
                let mut lanes = Receivers::new();
                lanes.add(&map, &four);
                let one_by_one = px
                    .iter()
                    .fold(NO_BOUNDS, |b, &(p, n)| receiver(b, &map, towards, p, n));
                assert_eq!(lanes.bounds(), one_by_one, "pixels {px:?}");
                // Checked against the bounds of a few other receivers: a lane is outside when its
                // pixel faces the light and is not within them, coordinate by coordinate.
                let fitted = (0..6)
                    .map(|_| pixel(&mut r, towards))
                    .fold(NO_BOUNDS, |b, (p, _)| {
                        receiver(b, &map, towards, p, towards)
                    });
                for four in [&four, &bare] {
                    let bits = outside(&map, four, fitted);
                    for (k, &(p, n)) in px.iter().enumerate() {
                        let q = map.across(p).extend(p.dot(towards));
                        let within = q.x >= fitted.0.x
                            && q.x <= fitted.1.x
                            && q.y >= fitted.0.y
                            && q.y <= fitted.1.y
                            && q.z >= fitted.0.z;
                        let want = n.dot(towards) > 0.0 && !within;
                        assert_eq!(
                            bits >> k & 1 == 1,
                            want,
                            "pixel {p}, {n} against {fitted:?}"
                        );
                        flagged[want as usize] += 1;
                    }
                    assert_eq!(bits >> len, 0);
                }
            }
        }
        // The lanes themselves decided most of the pixels, not the scalar fallback, and the receivers
        // checked fell on both sides of the bounds.
        assert!(settled > 400, "{settled} pixels settled in lanes");
        assert!(
            flagged[0] > 100 && flagged[1] > 100,
            "{flagged:?} inside, outside"
        );
    }
}
