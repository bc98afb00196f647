//! Runs of neighbouring pixels at a time: the classification's per-pixel arithmetic in SIMD lanes, eight
//! with AVX2 where the CPU has it, else four (glam's `Vec4`: SSE2, NEON or wasm SIMD where the target has
//! them, four plain floats elsewhere; [`widest`] picks). Bit for bit what the scalar tests compute — the
//! same operations in the same order, lane by lane — so a pixel's class depends neither on which path
//! decided it nor on how many lanes there were.
//!
//! [`surfaces`] settles the pixels without a surface facing the light. Most others face it over an
//! interior texel whose depth the pass trusts (a smooth texel, or any texel for the shadow map alone):
//! [`decide`] settles those, with one read of the table per lane (one masked gather for eight lanes);
//! for the selective test, [`edges`] settles those over the other interior texels (a shadow edge) from
//! the four texels around each. What is left (off the map, a normal that is not finite; for the shadow
//! map alone, any texel the table leaves) goes to the mode's scalar test. On the crowd at 1024² the
//! selective classification takes about a fifth less time in four lanes than pixel by pixel, and eight
//! lanes with the edges in them take about a third less again (`bench shadows`; docs/BENCHMARKS.md,
//! stop 50).

#[cfg(target_arch = "x86_64")]
mod eight;
mod four;

use super::classify::Class;
use super::{GBuffer, ShadowMap};
use glam::{Vec3, Vec4};
use std::ops::{Add, Div, Mul, Range, Sub};

/// A row of `f32` lanes the classification computes in: [`Vec4`], or eight with AVX2 (x86-64). Every
/// operation is IEEE single precision lane by lane, as the scalar `f32` operation; compares are ordered
/// (false where either side is NaN) and give their lanes as [`Bits`].
pub(super) trait Lanes:
    Copy + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + Div<Output = Self>
{
    /// How many lanes.
    const N: usize;

    /// Every lane `v`.
    fn splat(v: f32) -> Self;

    /// The first [`N`](Self::N) of `v` (fewer: zero-padded), one coordinate per row of lanes.
    fn load(v: &[Vec3]) -> [Self; 3];

    /// Calls `f` compiled for these lanes' instruction set (see [`dispatch`](crate::dispatch)): mark it
    /// `#[inline(always)]`.
    fn compiled<R>(f: impl FnOnce() -> R) -> R;

    /// Per lane, the larger of the two (which one where either is NaN depends on the target: the
    /// callers only keep it for finite lanes).
    fn max(self, other: Self) -> Self;

    /// Per lane, the correctly rounded square root.
    fn sqrt(self) -> Self;

    /// Per lane, rounded towards zero to a whole number.
    fn trunc(self) -> Self;

    /// The lanes where `self ≤ other`.
    fn le(self, other: Self) -> Bits;

    /// The lanes where `self < other`.
    fn lt(self, other: Self) -> Bits;

    /// The lanes where `self ≥ other`.
    fn ge(self, other: Self) -> Bits;

    /// The lanes where `self > other`.
    fn gt(self, other: Self) -> Bits;

    /// The lanes where `self = other`.
    fn equal(self, other: Self) -> Bits;

    /// The lanes neither infinite nor NaN.
    fn finite(self) -> Bits;

    /// Per lane of `lanes` whose `x` and `y` lie in `[0, res)`, `table[⌊y⌋ · res + ⌊x⌋]` (a row-major
    /// `res × res` table); NaN in every other lane. Panics where the table is smaller or `res` above
    /// 16384. The checks that make [`gather_within`](Self::gather_within) safe, once for every width.
    #[inline(always)]
    fn gather(table: &[f32], res: usize, x: Self, y: Self, lanes: Bits) -> Self {
        assert!(
            res <= 1 << 14 && table.len() >= res * res,
            "a table of {} texels for a map of {res}²",
            table.len()
        );
        let (zero, r) = (Self::splat(0.0), Self::splat(res as f32));
        let read = x.ge(zero) & x.lt(r) & y.ge(zero) & y.lt(r) & lanes;
        // SAFETY: exactly what `gather_within` asks, checked just above (NaN is in no lane of `read`).
        unsafe { Self::gather_within(table, res, x, y, read) }
    }

    /// [`gather`](Self::gather) without its checks: NaN in the lanes not in `read`.
    ///
    /// # Safety
    ///
    /// `res` is at most 16384, `table` holds at least `res²` floats, and every lane of `read` has `x` and
    /// `y` in `[0, res)`, so each truncates to an `i32` and `⌊y⌋ · res + ⌊x⌋` indexes the table.
    unsafe fn gather_within(table: &[f32], res: usize, x: Self, y: Self, read: Bits) -> Self;
}

/// Work generic over its lanes, run by [`widest`].
pub(super) trait WithLanes {
    type Output;

    /// Does the work in lanes `L`.
    fn run<L: Lanes>(self) -> Self::Output;
}

/// Runs `work` in the widest lanes the CPU has: eight where it has the AVX2 generation
/// ([`wide_available`](crate::dispatch::wide_available)), else four. Wrap a loop in
/// [`Lanes::compiled`] inside `work` so that it is compiled for its lanes (eight need AVX2's).
pub(super) fn widest<W: WithLanes>(work: W) -> W::Output {
    #[cfg(target_arch = "x86_64")]
    if crate::dispatch::wide_available() {
        return work.run::<eight::F8>();
    }
    work.run::<Vec4>()
}

/// Each lane's dot product with `d`, summed in `Vec3::dot`'s order.
#[inline(always)]
fn dot<L: Lanes>(p: &[L; 3], d: Vec3) -> L {
    p[0] * L::splat(d.x) + p[1] * L::splat(d.y) + p[2] * L::splat(d.z)
}

/// The lanes equal to the zero vector.
#[inline(always)]
fn is_zero<L: Lanes>(p: &[L; 3]) -> Bits {
    let zero = L::splat(0.0);
    p[0].equal(zero) & p[1].equal(zero) & p[2].equal(zero)
}

/// Up to [`N`](Lanes::N) neighbouring pixels of one image row: their surfaces, as slices (for the scalar
/// tests), and their normals in lanes, with `n · L` per lane; with a map, their positions' coordinates
/// across it and along the light, computed once for every test that reads them (where some pixel shows
/// a surface). A pass that only asks which pixels face the light reads half the G-buffer.
pub(super) struct Run<'a, L> {
    positions: &'a [Vec3],
    normals: &'a [Vec3],
    n: [L; 3],
    /// `n · towards` per lane.
    cos: L,
    /// [`light`]`(map, positions)` for the map given to [`new`](Self::new).
    light: Option<[L; 3]>,
}

impl<'a, L: Lanes> Run<'a, L> {
    /// Pixels `positions[k]`, `normals[k]` (at most [`N`](Lanes::N), as many of each) lit from
    /// `towards`, with their positions across `map` when given (one aimed along `towards`).
    #[inline(always)]
    pub(super) fn new(
        positions: &'a [Vec3],
        normals: &'a [Vec3],
        towards: Vec3,
        map: Option<&ShadowMap>,
    ) -> Self {
        let n = L::load(normals);
        // Pixels without a surface (the sky) need no place on the map: neither test reads it. (No
        // closures here, nor anywhere on the lanes' way: one not inlined would take eight lanes' every
        // instruction out of the AVX2 build as a call.)
        let light = match map {
            Some(m) if is_zero(&n) != first(L::N) => Some(light(m, &L::load(positions))),
            _ => None,
        };
        Self {
            positions,
            normals,
            n,
            cos: dot(&n, towards),
            light,
        }
    }

    /// The positions in lanes across `map` and along its light: the values [`new`](Self::new) computed
    /// when given the map (it must be this one), else computed now.
    #[inline(always)]
    fn light(&self, map: &ShadowMap) -> [L; 3] {
        match self.light {
            Some(q) => q,
            None => light(map, &L::load(self.positions)),
        }
    }

    /// How many pixels.
    pub(super) fn len(&self) -> usize {
        self.positions.len()
    }
}

/// The coordinates of the points `p` across `map` and along its light: `p · u`, `p · v` and `p · towards`
/// per lane (in `Vec3::dot`'s order, as [`ShadowMap::project`] and `super::receiver` sum them).
#[inline(always)]
fn light<L: Lanes>(map: &ShadowMap, p: &[L; 3]) -> [L; 3] {
    let (u, v, towards, ..) = map.frame();
    [dot(p, u), dot(p, v), dot(p, towards)]
}

/// The pixels `pixels` of `g` (indices into its arrays, row-major), four at a time from the first (the
/// last group may be shorter), each with the index of its first pixel, lit from `towards`, their
/// positions across `map` when given ([`Run::new`]).
#[inline(always)]
pub(super) fn fours<'a>(
    g: &'a GBuffer,
    pixels: Range<usize>,
    towards: Vec3,
    map: Option<&'a ShadowMap>,
) -> impl Iterator<Item = (usize, Run<'a, Vec4>)> {
    let end = pixels.end;
    pixels.step_by(4).map(
        #[inline(always)]
        move |i| {
            let j = (i + 4).min(end);
            let four = Run::new(&g.positions[i..j], &g.normals[i..j], towards, map);
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
pub(super) fn surfaces<L: Lanes>(px: &Run<L>, away: f32) -> (Verdicts, Bits) {
    let lanes = first(px.len());
    let zero = is_zero(&px.n);
    let facing = !zero & !px.cos.le(L::splat(away)) & lanes;
    let verdicts = Verdicts {
        lit: zero & lanes,
        ..Verdicts::default()
    };
    (verdicts, facing)
}

/// The verdicts of a pass that marks every pixel facing the light (rays for all of them): [`surfaces`],
/// with the facing lanes marked.
#[inline(always)]
pub(super) fn mark_facing<L: Lanes>(px: &Run<L>, away: f32) -> Verdicts {
    let (v, facing) = surfaces(px, away);
    Verdicts {
        facing,
        marked: facing,
        ..v
    }
}

/// What [`decide`] settled, and what it left.
pub(super) struct Decided<L> {
    /// The verdicts on the lanes it settled, and on those without a surface facing the light.
    pub(super) verdicts: Verdicts,
    /// The lanes it left to the mode's scalar test.
    pub(super) rest: Bits,
    /// Those of `rest` with a finite `n · L` over an interior texel that the table does not settle:
    /// the ones [`edges`] decides for the selective test.
    pub(super) edge: Bits,
    /// The receivers' coordinates on the map and depths ([`map_coordinates`]), for [`edges`]: meaningful
    /// only where `edge` has lanes (NaN where `decide` stopped before it needed them).
    pub(super) at: ([L; 2], L),
}

/// [`surfaces`], then the shadow map's verdict for the facing lanes it settles by one read of `table`
/// (a `res × res` table of the map's texels, NaN or infinite where the map cannot decide by depth alone):
/// those with a finite `n · L`, over an interior texel (one with eight neighbours) whose table value `s`
/// is finite — lit when the receiver's depth `d` is at most `s` plus the bias (`map.texel_size() ×
/// bias_texels`, plus the slope-scaled part), else shadowed, as the scalar `classify::verdict`.
#[inline(always)]
pub(super) fn decide<L: Lanes>(
    map: &ShadowMap,
    table: &[f32],
    px: &Run<L>,
    away: f32,
    bias_texels: f32,
) -> Decided<L> {
    let (mut verdicts, facing) = surfaces(px, away);
    // What is left where no lane faces the light over the map's interior.
    let nan = L::splat(f32::NAN);
    let unsettled = Decided {
        verdicts,
        rest: facing,
        edge: 0,
        at: ([nan; 2], nan),
    };
    if facing == 0 {
        return unsettled;
    }
    let at @ ([qx, qy], d) = map_coordinates(map, px);
    let cos = px.cos;
    let res = map.resolution();
    // The interior is `[1, res − 1)` on both axes (as `classify::texel`; NaN is outside).
    let (one, last) = (L::splat(1.0), L::splat((res - 1) as f32));
    let inside = qx.ge(one) & qy.ge(one) & qx.lt(last) & qy.lt(last);
    let candidates = inside & cos.finite() & facing;
    if candidates == 0 {
        return unsettled;
    }
    let s = L::gather(table, res, qx, qy, candidates);
    let settled = s.finite() & candidates;
    let texel = map.texel_size();
    let constant = L::splat(texel * bias_texels);
    // `classify::verdict`: lit within the constant bias; past it, within the slope-scaled bias, which only
    // adds to it (a square root and a division, for the lanes that need them only).
    let mut lit = d.le(s + constant) & settled;
    if settled & !lit != 0 {
        // `classify::slope_bias`, its operations in its order: the constant bias plus the receiver's
        // reach within one texel, from its slope.
        let c = cos.max(L::splat(1.0 / 64.0));
        let tan = (L::splat(1.0) - c * c).max(L::splat(0.0)).sqrt() / c;
        let reach = L::splat(texel * std::f32::consts::SQRT_2) * tan;
        let slope_bias = constant + reach;
        lit |= d.le(s + slope_bias) & settled;
    }
    verdicts.lit |= lit;
    verdicts.facing |= settled;
    Decided {
        verdicts,
        rest: facing & !settled,
        edge: candidates & !settled,
        at,
    }
}

/// The receivers' coordinates on `map` in texels (`x`, `y`) and their depths from its light, as
/// [`ShadowMap::project`] computes them.
#[inline(always)]
fn map_coordinates<L: Lanes>(map: &ShadowMap, px: &Run<L>) -> ([L; 2], L) {
    let (.., corner, per_texel, top) = map.frame();
    let [pu, pv, pt] = px.light(map);
    let qx = (pu - L::splat(corner.x)) * L::splat(per_texel);
    let qy = (pv - L::splat(corner.y)) * L::splat(per_texel);
    ([qx, qy], L::splat(top) - pt)
}

/// The selective test at a shadow edge for the lanes [`Decided::edge`] of `px` (each with a finite
/// `n · L`, over an interior texel that is not smooth), at the map coordinates `decide` found for them,
/// as the scalar `classify::selective` decides them, its operations in its order: marked over an empty
/// texel; else the depths of the four texels whose centres surround the receiver (four reads of the map a lane,
/// gathered) compared with its tangent plane there, less the constant bias — lit when none lies in front
/// of it, shadowed when all do, else marked (and marked when the plane's slope is not finite). Four
/// gathers a run.
#[inline(always)]
pub(super) fn edges<L: Lanes>(
    map: &ShadowMap,
    px: &Run<L>,
    decided: &Decided<L>,
    bias_texels: f32,
) -> Verdicts {
    let (lanes, ([qx, qy], d)) = (decided.edge, decided.at);
    if lanes == 0 {
        return Verdicts::default();
    }
    let (res, depth) = (map.resolution(), map.depths());
    // `ShadowMap::around`: the texel whose centre lies below and left of the receiver, and where the
    // receiver lies from that centre. (`q − ½` is exact below 2¹⁴ texels.)
    let half = L::splat(0.5);
    let (i, j) = ((qx - half).trunc(), (qy - half).trunc());
    let first = [(i + half) - qx, (j + half) - qy];
    // The four in `ShadowMap::around`'s order. (Loops, not closures, here: see `Run::new`.)
    let (zero, one) = (L::splat(0.0), L::splat(1.0));
    let offsets = [(zero, zero), (one, zero), (zero, one), (one, one)];
    let mut corners = [zero; 4];
    for (s, &(dx, dy)) in corners.iter_mut().zip(&offsets) {
        *s = L::gather(depth, res, i + dx, j + dy, lanes);
    }
    // The receiver's own texel is one of the four: `(i, j)` moved by one along each axis where `q` lies
    // past the next texel's edge. Over an empty one (no occluder the map saw), marked.
    let (past_x, past_y) = (qx.ge(i + one), qy.ge(j + one));
    let full = lanes
        & ((corners[0].finite() & !past_x & !past_y)
            | (corners[1].finite() & past_x & !past_y)
            | (corners[2].finite() & !past_x & past_y)
            | (corners[3].finite() & past_x & past_y));
    // `classify::slope`: `map.across(nrm) · (texel / max(n·L, 1/64))`.
    let (u, v, ..) = map.frame();
    let texel = map.texel_size();
    let k = L::splat(texel) / px.cos.max(L::splat(1.0 / 64.0));
    let slope = [dot(&px.n, u) * k, dot(&px.n, v) * k];
    let plane = full & slope[0].finite() & slope[1].finite();
    let bias = L::splat(texel * bias_texels);
    let (mut any, mut all) = (0, plane);
    for (&s, &(dx, dy)) in corners.iter().zip(&offsets) {
        let at = [first[0] + dx, first[1] + dy];
        // An empty texel (infinitely deep) lies in front of nothing.
        let front = s.lt(d + slope[0] * at[0] + slope[1] * at[1] - bias) & plane;
        any |= front;
        all &= front;
    }
    Verdicts {
        lit: plane & !any,
        facing: lanes,
        marked: lanes & !(plane & !any) & !all,
    }
}

/// The first `n` lanes as bits.
#[inline(always)]
fn first(n: usize) -> Bits {
    (1 << n) - 1
}

/// The lanes of `px` whose surface faces the light (`n · L` above 0) and whose receiver does not lie
/// within `fitted` across `map` (x and y inside it, z along the light not below it; z above it changes
/// no map): every pixel that would widen [`Receivers`]' bounds there, and those with a non-finite
/// coordinate, which widen nothing but fail the compares (so a broken G-buffer costs a second fit, never
/// a wrong one). Compares alone, no bounds carried from pixel to pixel.
#[inline(always)]
pub(super) fn outside<L: Lanes>(map: &ShadowMap, px: &Run<L>, fitted: (Vec3, Vec3)) -> Bits {
    // Missing lanes have a zero normal: they do not face the light.
    let facing = px.cos.gt(L::splat(0.0));
    if facing == 0 {
        return 0;
    }
    let q = px.light(map);
    let (lo, hi) = fitted;
    let within = q[0].ge(L::splat(lo.x))
        & q[0].le(L::splat(hi.x))
        & q[1].ge(L::splat(lo.y))
        & q[1].le(L::splat(hi.y))
        & q[2].ge(L::splat(lo.z));
    !within & facing
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
    pub(super) fn add(&mut self, map: &ShadowMap, px: &Run<Vec4>) {
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

/// Writes the visibility of a run's pixels (`out`, as long as the run) from their lit bits: 1 where lit,
/// else 0.
#[inline(always)]
pub(super) fn write_visibility(lit: Bits, out: &mut [f32]) {
    for (k, part) in out.chunks_mut(4).enumerate() {
        let all = &VISIBILITY[(lit >> (4 * k)) as usize & 15];
        match part.first_chunk_mut::<4>() {
            // Four pixels (nearly always): a store of 16 bytes, not a copy of a length known only at
            // run time.
            Some(four) => *four = *all,
            None => part.copy_from_slice(&all[..part.len()]),
        }
    }
}

/// What a pass's test says about a run's pixels, one bit per pixel (bit `k`: pixel `k`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct Verdicts {
    /// Visibility 1 until rays say otherwise: no surface there, or lit by the map.
    pub(super) lit: Bits,
    /// A surface facing the light (one a shadow could fall on).
    pub(super) facing: Bits,
    /// Potentially incorrect: a shadow ray decides.
    pub(super) marked: Bits,
}

impl std::ops::BitOr for Verdicts {
    type Output = Verdicts;

    /// The verdicts of both, on lanes each settled (a pixel's bits come from one of them).
    #[inline(always)]
    fn bitor(self, other: Verdicts) -> Verdicts {
        Verdicts {
            lit: self.lit | other.lit,
            facing: self.facing | other.facing,
            marked: self.marked | other.marked,
        }
    }
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
pub(super) fn each<L: Lanes>(px: &Run<L>, test: impl Fn(Vec3, Vec3) -> Class) -> Verdicts {
    let all = first(px.len());
    or_each(px, Verdicts::default(), all, test)
}

/// `verdicts`, completed by the scalar `test(position, normal)` for the lanes in `rest` (as [`decide`]
/// returns them).
#[inline(always)]
pub(super) fn or_each<L: Lanes>(
    px: &Run<L>,
    mut verdicts: Verdicts,
    mut rest: Bits,
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
    use super::super::modes::{self, RunTest};
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
        let n = match r.random_range(0..12) {
            0 => Vec3::ZERO,
            1 => Vec3::splat(f32::NAN),
            2 => towards.any_orthonormal_vector(),
            3 => -towards,
            // Far from unit length and grazing (under a light along an axis, the plane's slope then
            // overflows), or not finite at all.
            4 => towards.any_orthonormal_vector() * 1e38 + towards * 1e-3,
            5 => Vec3::new(f32::INFINITY, 1.0, 0.0),
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

    /// Runs of `L::N` pixels and fewer classify each pixel as the scalar tests do on their own, in every
    /// hard mode's test as the pass runs it (shadow edges in lanes too), with their positions across the
    /// map computed up front or not; and the lanes found
    /// outside given bounds are the pixels facing the light whose scalar coordinates do not all lie within
    /// them.
    fn lanes_classify_as_the_scalar_tests<L: Lanes>() {
        let mut r = SmallRng::seed_from_u64(7);
        let (mut settled, mut at_edges, mut flagged) = (0, 0, [0; 2]);
        for round in 0..40 {
            let towards = match round % 4 {
                3 => Vec3::Y,
                _ => {
                    Vec3::new(r.random_range(-1.0..1.0), 1.0, r.random_range(-1.0..1.0)).normalize()
                }
            };
            let (map, deltas) = scene(&mut r, towards);
            let bias = [0.0, 1.0, 2.5][round % 3];
            // A hard selective pass's `away` is −0 (−sin 0), the shadow map's +0.
            let away = [0.0, -0.0][round / 3 % 2];
            for len in [L::N; 3].into_iter().chain((1..L::N).rev()) {
                let px: Vec<(Vec3, Vec3)> = (0..len).map(|_| pixel(&mut r, towards)).collect();
                let (ps, ns): (Vec<Vec3>, Vec<Vec3>) = px.iter().copied().unzip();
                // With the positions across the map computed up front and without.
                let run = Run::<L>::new(&ps, &ns, towards, Some(&map));
                let bare = Run::<L>::new(&ps, &ns, towards, None);
                let scalar = |p: Vec3, n: Vec3, test: &dyn Fn(Vec3, Vec3, f32) -> Class| {
                    classify::facing(n, towards, away).map_or_else(|c| c, |cos| test(p, n, cos))
                };
                let selective = |p, n, cos| classify::selective(&map, &deltas, p, n, cos, bias);
                let map_only = |p, _, cos| classify::shadow_map_only(&map, p, cos, bias);
                // The modes' tests as the pass runs them, in lanes.
                let light = modes::Light {
                    towards,
                    away,
                    bias,
                };
                let in_lanes = modes::Selective {
                    map: &map,
                    deltas: &deltas,
                    light,
                };
                let map_in_lanes = modes::MapOnly { map: &map, light };
                for run in [&run, &bare] {
                    let decided = decide(&map, deltas.table(), run, away, bias);
                    settled += (first(len) & !decided.rest).count_ones();
                    at_edges += decided.edge.count_ones();
                    for (v, test) in [
                        (
                            in_lanes.verdicts(run),
                            &selective as &dyn Fn(Vec3, Vec3, f32) -> Class,
                        ),
                        (map_in_lanes.verdicts(run), &map_only),
                        (modes::MarkFacing(light).verdicts(run), &|_, _, _| {
                            Class::Marked
                        }),
                    ] {
                        for (k, &(p, n)) in px.iter().enumerate() {
                            let bit = |v: Verdicts| Verdicts {
                                lit: v.lit >> k & 1,
                                facing: v.facing >> k & 1,
                                marked: v.marked >> k & 1,
                            };
                            assert_eq!(bit(v), expect(scalar(p, n, test)), "pixel {p}, {n}");
                        }
                        assert_eq!(v.lit >> len | v.facing >> len | v.marked >> len, 0);
                    }
                }
                // Checked against the bounds of a few other receivers: a lane is outside when its
                // pixel faces the light and is not within them, coordinate by coordinate.
                let fitted = (0..6)
                    .map(|_| pixel(&mut r, towards))
                    .fold(NO_BOUNDS, |b, (p, _)| {
                        receiver(b, &map, towards, p, towards)
                    });
                for run in [&run, &bare] {
                    let bits = outside(&map, run, fitted);
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
        // The lanes themselves decided most of the pixels, not the scalar fallback, many of them at
        // shadow edges, and the receivers checked fell on both sides of the bounds.
        assert!(
            settled > 100 * L::N as u32,
            "{settled} pixels settled in lanes"
        );
        assert!(at_edges > 25 * L::N as u32, "{at_edges} pixels at edges");
        assert!(
            flagged[0] > 25 * L::N && flagged[1] > 25 * L::N,
            "{flagged:?} inside, outside"
        );
    }

    #[test]
    fn four_lanes_classify_as_the_scalar_tests() {
        lanes_classify_as_the_scalar_tests::<Vec4>();
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn eight_lanes_classify_as_the_scalar_tests() {
        if !crate::dispatch::wide_available() {
            eprintln!("SKIPPED: this CPU lacks AVX2; only four lanes run here");
            return;
        }
        lanes_classify_as_the_scalar_tests::<eight::F8>();
    }

    /// [`widest`] runs eight lanes exactly where the CPU has the AVX2 generation.
    #[test]
    fn widest_picks_eight_lanes_with_avx2() {
        struct Width;
        impl WithLanes for Width {
            type Output = usize;
            fn run<L: Lanes>(self) -> usize {
                L::N
            }
        }
        let wide = cfg!(target_arch = "x86_64") && crate::dispatch::wide_available();
        assert_eq!(widest(Width), if wide { 8 } else { 4 });
    }

    /// The receivers' bounds of pixels added four at a time are the scalar fold's, bit for bit (the map
    /// is fitted to them and compared with `==`), for one to four pixels at a time.
    #[test]
    fn receivers_in_lanes_are_the_scalar_bounds() {
        let mut r = SmallRng::seed_from_u64(11);
        for _ in 0..40 {
            let towards =
                Vec3::new(r.random_range(-1.0..1.0), 1.0, r.random_range(-1.0..1.0)).normalize();
            let (map, _) = scene(&mut r, towards);
            for len in [4, 4, 4, 3, 2, 1] {
                let px: Vec<(Vec3, Vec3)> = (0..len).map(|_| pixel(&mut r, towards)).collect();
                let (ps, ns): (Vec<Vec3>, Vec<Vec3>) = px.iter().copied().unzip();
                for map_given in [Some(&map), None] {
                    let mut lanes = Receivers::new();
                    lanes.add(&map, &Run::new(&ps, &ns, towards, map_given));
                    let one_by_one = px
                        .iter()
                        .fold(NO_BOUNDS, |b, &(p, n)| receiver(b, &map, towards, p, n));
                    assert_eq!(lanes.bounds(), one_by_one, "pixels {px:?}");
                }
            }
        }
    }
}
