//! The shadow map of a directional light: the scene's triangles rasterised orthographically along the
//! light into a square depth map that just covers them.

use super::Occluders;
use crate::parallel;
use glam::{Affine3A, Mat3A, Vec2, Vec3, Vec3A};

/// Rows of the map one worker rasterises at a time (each band visits only the triangles binned to it).
const BAND_ROWS: usize = 32;

/// A depth map seen from a directional light: depth is the distance along the light's rays from the plane
/// through the scene's point nearest the light, so 0 is nearest and `f32::INFINITY` marks an empty texel.
///
/// Use it through [`HardShadows`](super::HardShadows); on its own it answers "what does the light see
/// nearest at this point". Rendering costs one pass over the triangles, in parallel chunks, that places
/// each across the map (finding the point nearest the light on the way) and sorts those that cover a
/// texel centre, projected, into bands of 32 rows, chunk by chunk (an area light's map first finds the
/// nearest point in a pass of its own: how far it widens depends on it); then, in parallel over bands,
/// a few steps per row a triangle spans plus one per covered texel (O(triangles + texels)). The buffers
/// are kept (36 bytes per covering triangle and band), so a warm map of the same resolution does not
/// allocate.
#[derive(Clone, Debug, Default)]
pub struct ShadowMap {
    res: usize,
    depth: Vec<f32>,
    /// Light-space axes: `u`, `v` across the map, `towards` the unit direction to the light.
    u: Vec3,
    v: Vec3,
    towards: Vec3,
    /// Light-space coordinates of texel (0, 0)'s corner.
    corner: Vec2,
    /// `p · towards` of the scene's point nearest the light (depth 0).
    top: f32,
    texel: f32,
    /// `1 / texel`: points are projected with a product, not a division.
    per_texel: f32,
    /// The occluders' pieces — each group's triangles cut into runs of at most [`PLACE_CHUNK`] — as (group,
    /// first triangle), and each piece's triangles placed across the map and sorted into bands; kept
    /// between frames.
    pieces: Vec<(usize, usize)>,
    placed: Vec<Placed>,
}

/// How a group of occluders goes into light space ([`ShadowMap::light`]): its transform composed with the
/// light, `m · p + t` — for triangles in world space the light alone and `t = −0`, which adds nothing
/// to any float (not even the sign of a zero), so they project bit for bit as [`ShadowMap::project`]
/// does. One form for both: no branch per point.
#[derive(Clone, Copy)]
pub(crate) struct ToLight {
    pub(crate) m: Mat3A,
    pub(crate) t: Vec3A,
}

impl ToLight {
    /// For a group placed by `place` (`None`: in world space) under the light transform `light`.
    pub(crate) fn new(light: Mat3A, place: Option<Affine3A>) -> Self {
        match place {
            None => Self {
                m: light,
                t: Vec3A::splat(-0.0),
            },
            Some(a) => Self {
                m: light * a.matrix3,
                t: light * a.translation,
            },
        }
    }

    /// Point `p` in light space.
    #[inline(always)]
    fn apply(&self, p: Vec3) -> Vec3A {
        self.m * Vec3A::from(p) + self.t
    }
}

/// Triangles one worker places across the map and sorts into bands at a time.
const PLACE_CHUNK: usize = 8_192;

/// One chunk of a render's triangles placed across the map ([`Placed::place`]).
#[derive(Clone, Debug, Default)]
struct Placed {
    /// The chunk's triangles that may cover a texel centre, projected as in `binned`, with the first and
    /// last band of rows they may cover ([`reach_lanes`]).
    covering: Vec<([Vec3; 3], [u32; 2])>,
    /// Band `b` rasterises the chunk's triangles `binned[bins[b]..bins[b + 1]]`, each corner in texels
    /// across the map and its `p · towards` (the depth once the nearest point is known): projected here,
    /// so the bands read them in order instead of gathering triangles from all over the scene.
    bins: Vec<u32>,
    binned: Vec<[Vec3; 3]>,
    /// The largest `p · towards` of the chunk's corners as a [`key`]: the chunk's point nearest the light.
    top: u32,
}

impl Placed {
    /// Finds the bands each triangle of `tris` (taken into light space by `to`) may cover on `map`
    /// ([`reach_lanes`], [`LANES`] triangles at a time) and the chunk's point nearest the light, then
    /// sorts the projected triangles into the bands (a counting sort; triangles off the map or between
    /// texel centres go nowhere). For triangles in world space the projection is
    /// [`ShadowMap::project`]'s, bit for bit, but for the depth's origin. No allocation once warm.
    #[inline(always)]
    fn place(&mut self, tris: &[[Vec3; 3]], to: ToLight, map: &ShadowMap) {
        let count = map.res.div_ceil(BAND_ROWS);
        // Corner `k` of lane `l` in texels across the map, and its `p · towards`.
        let texels = |q: &Lanes, l: usize| {
            [0, 1, 2].map(|k| {
                map.in_texels(Vec2::new(q[k][0][l], q[k][1][l]))
                    .extend(q[k][2][l])
            })
        };
        self.bins.clear();
        self.bins.resize(count + 1, 0);
        self.covering.clear();
        let mut top = 0;
        for block in tris.chunks(LANES) {
            let (reach, nearest, q) = reach_lanes(block, to, map);
            top = top.max(nearest);
            for (l, &[b0, b1]) in reach[..block.len()].iter().enumerate() {
                if b0 <= b1 {
                    for b in b0..=b1 {
                        self.bins[b as usize + 1] += 1;
                    }
                    self.covering.push((texels(&q, l), [b0, b1]));
                }
            }
        }
        self.top = top;
        for b in 0..count {
            self.bins[b + 1] += self.bins[b];
        }
        self.binned
            .resize(self.bins[count] as usize, [Vec3::ZERO; 3]);
        // Scatter with `bins[b]` as band b's cursor: it ends at band b + 1's start, so the starts are
        // the cursors shifted by one band.
        for &(t, [b0, b1]) in &self.covering {
            for at in &mut self.bins[b0 as usize..=b1 as usize] {
                self.binned[*at as usize] = t;
                *at += 1;
            }
        }
        self.bins.copy_within(..count, 1);
        self.bins[0] = 0;
    }

    /// The chunk's triangles band `b` rasterises (see `binned`).
    fn band(&self, b: usize) -> &[[Vec3; 3]] {
        &self.binned[self.bins[b] as usize..self.bins[b + 1] as usize]
    }
}

impl ShadowMap {
    /// Points the map along `towards` (unit, from the scene to the light): sets the axes that
    /// [`across`](Self::across) and [`render`](Self::render) use.
    pub(super) fn aim(&mut self, towards: Vec3) {
        self.towards = towards;
        self.u = towards.any_orthonormal_vector();
        self.v = towards.cross(self.u);
    }

    /// World point `p`'s coordinates across the light (world units, along the map's axes).
    pub(super) fn across(&self, p: Vec3) -> Vec2 {
        Vec2::new(p.dot(self.u), p.dot(self.v))
    }

    /// Renders `occluders` (each group taken into light space through its transform, in pieces of at most
    /// [`PLACE_CHUNK`] triangles) as seen from the light the map is [aimed](Self::aim) at into a
    /// `res × res` map that covers the receivers' bounds (`receivers`, lower and upper corner: x, y from
    /// [`across`](Self::across), z = `p · towards`; empty when lower > upper), widened by `spread` (the
    /// tangent of an area light's angular radius, 0 for a point-like one) times the depth from the
    /// nearest triangle to the deepest receiver — as far as a penumbra reaches — plus a
    /// margin of one texel so every receiver has its eight neighbours. A directional light's occluder of a
    /// receiver lies on the receiver's line towards the light, so it projects onto the same spot: fitting
    /// the map to the receivers (the pixels the camera sees) rather than the scene loses no shadow and
    /// spends every texel where it is looked at. No receivers or no triangles give an empty map; a
    /// triangle with a non-finite corner (or one beyond `f32` once projected) is left out.
    pub(super) fn render(
        &mut self,
        occluders: &(impl Occluders + ?Sized),
        receivers: (Vec3, Vec3),
        spread: f32,
        res: usize,
        parallel: bool,
    ) {
        let light = self.light();
        self.pieces.clear();
        for g in 0..occluders.groups() {
            let n = occluders.group(g).0.len();
            self.pieces
                .extend((0..n).step_by(PLACE_CHUNK).map(|first| (g, first)));
        }
        // Piece `(g, first)`'s triangles, and how they go into light space.
        let piece = |&(g, first): &(usize, usize)| {
            let (tris, place) = occluders.group(g);
            let tris = &tris[first..(first + PLACE_CHUNK).min(tris.len())];
            (tris, ToLight::new(light, place))
        };
        let highest = |pieces: &[(usize, usize)]| {
            (pieces.iter().map(piece))
                .flat_map(|(tris, to)| tris.iter().filter_map(move |t| in_light(to, t)))
                .flat_map(|q| q.map(|q| key(q.z)))
                .fold(0, u32::max)
        };
        // A soft light's map reaches as far as the penumbrae, which depends on the point nearest the
        // light: a pass of its own. A hard light's map does not, and the placing pass finds it.
        let early = (spread > 0.0).then(|| {
            nearest(parallel::map_reduce(
                parallel,
                &self.pieces,
                1,
                0,
                highest,
                u32::max,
            ))
        });
        if !self.fit(receivers, spread, early, res, !self.pieces.is_empty()) {
            return;
        }
        // Most of a detailed scene's triangles are smaller than a texel and cover no texel centre (three in
        // four on the 696k-triangle crowd): the placing pass finds each one's bands, across the light, and
        // keeps in full only the few that cover one, projected and in band order for the bands to read.
        let mut placed = std::mem::take(&mut self.placed);
        placed.resize_with(self.pieces.len(), Placed::default);
        let this = &*self;
        parallel::for_each_mut(parallel, &mut placed, |c, chunk| {
            let (tris, to) = piece(&this.pieces[c]);
            crate::dispatch::widest(
                #[inline(always)]
                || chunk.place(tris, to, this),
            );
        });
        self.top = early.unwrap_or_else(|| nearest(placed.iter().map(|p| p.top).fold(0, u32::max)));
        let mut depth = std::mem::take(&mut self.depth);
        depth.resize(res * res, f32::INFINITY);
        let this = &*self;
        parallel::fill_chunks(parallel, &mut depth, BAND_ROWS * res, |band, out| {
            crate::dispatch::widest(
                #[inline(always)]
                || {
                    out.fill(f32::INFINITY);
                    // Nested loops, not a flattened iterator: its `next` was not inlined, a call
                    // per triangle.
                    for p in &placed {
                        for t in p.band(band) {
                            let t = t.map(|q| q.truncate().extend(this.top - q.z));
                            rasterise(&t, band * BAND_ROWS, res, out);
                        }
                    }
                },
            )
        });
        self.depth = depth;
        self.placed = placed;
    }

    /// Sizes the map to `res × res` texels over the receivers' bounds (see [`render`](Self::render)),
    /// widened by `spread` times the depth from `nearest` (the occluders' largest `p · towards`, known
    /// first only for an area light's map) to the deepest receiver. False, with every texel empty, when
    /// there is nothing to render (`occupied` false: no triangles) or no receiver: then the map is done.
    pub(crate) fn fit(
        &mut self,
        receivers: (Vec3, Vec3),
        spread: f32,
        nearest: Option<f32>,
        res: usize,
        occupied: bool,
    ) -> bool {
        let widen = Vec2::splat((nearest.unwrap_or(f32::MIN) - receivers.0.z).max(0.0) * spread);
        let (lo, hi) = (
            receivers.0.truncate() - widen,
            receivers.1.truncate() + widen,
        );
        self.res = res;
        if !occupied || lo.x > hi.x {
            self.clear(res);
            (self.corner, self.top) = (Vec2::ZERO, 0.0);
            (self.texel, self.per_texel) = (1.0, 1.0);
            return false;
        }
        let extent = (hi - lo).max_element().max(f32::MIN_POSITIVE);
        // One texel of margin on each side.
        self.texel = extent / (res as f32 - 2.0).max(1.0);
        self.per_texel = self.texel.recip();
        self.corner = lo - Vec2::splat(self.texel);
        true
    }

    /// Makes the map `res × res` empty texels.
    pub(crate) fn clear(&mut self, res: usize) {
        self.res = res;
        self.depth.clear();
        self.depth.resize(res * res, f32::INFINITY);
    }

    /// Takes a map rendered elsewhere over the frame [`fit`](Self::fit) set: the point nearest the light
    /// (`top`), and each texel's depth as `depth(k)` for texel `k`, row by row.
    #[cfg(feature = "gpu")]
    pub(crate) fn take_rendered(&mut self, top: f32, depth: impl Fn(usize) -> f32) {
        self.top = top;
        let n = self.res * self.res;
        self.depth.clear();
        self.depth.extend((0..n).map(depth));
    }

    /// The light-space transform as a matrix with rows `u`, `v` and `towards`: `light() * p` is
    /// `across(p)` and `p · towards` bit for bit (glam multiplies a matrix by a vector column by column,
    /// `(u.x·x + u.y·y) + u.z·z`, the order of `Vec3::dot`), the three products at once for passes that
    /// project many points.
    pub(crate) fn light(&self) -> Mat3A {
        Mat3A::from_cols(self.u.into(), self.v.into(), self.towards.into()).transpose()
    }

    /// Coordinates across the map ([`across`](Self::across)) in texels.
    fn in_texels(&self, across: Vec2) -> Vec2 {
        (across - self.corner) * self.per_texel
    }

    /// Map coordinates of a world point: x and y in texels (texel `(i, j)` covers `[i, i+1) × [j, j+1)`),
    /// z its depth from the light.
    pub fn project(&self, p: Vec3) -> Vec3 {
        self.in_texels(self.across(p))
            .extend(self.top - p.dot(self.towards))
    }

    /// What [`project`](Self::project) reads, for computing it several points at a time in the same
    /// order: the axes across (`u`, `v`) and towards the light, texel (0, 0)'s corner, the inverse of the
    /// texel size and the depth origin.
    #[inline(always)]
    pub(crate) fn frame(&self) -> (Vec3, Vec3, Vec3, Vec2, f32, f32) {
        (
            self.u,
            self.v,
            self.towards,
            self.corner,
            self.per_texel,
            self.top,
        )
    }

    /// Texels per side.
    pub fn resolution(&self) -> usize {
        self.res
    }

    /// Edge length of one texel in world units.
    pub fn texel_size(&self) -> f32 {
        self.texel
    }

    /// Depth of texel `(i, j)`: the nearest surface the light sees there, `f32::INFINITY` when none.
    pub fn depth(&self, i: usize, j: usize) -> f32 {
        self.depth[j * self.res + i]
    }

    /// Every texel's depth, row by row.
    pub(super) fn depths(&self) -> &[f32] {
        &self.depth
    }

    /// The depths of the four texels whose centres surround map point `(x, y)` (texel `i`'s centre is at
    /// `i + 0.5`), a point with `x` and `y` in `[1, resolution − 1)`: the texel it falls in and those of
    /// its neighbours on the sides it is nearer, rows `⌊y − ½⌋` and the next, columns `⌊x − ½⌋` and the
    /// next, in that order (column first); and where the first one's centre lies from the point, in
    /// texels (both in `(−1, 0]`; the others' are one more across, along or both).
    pub(super) fn around(&self, x: f32, y: f32) -> ([f32; 4], Vec2) {
        // `x − ½ ≥ ½` truncates to its floor, at most `res − 2`.
        let (i, j) = ((x - 0.5) as usize, (y - 0.5) as usize);
        let at = j * self.res + i;
        let d = &self.depth;
        let first = Vec2::new(i as f32 + 0.5 - x, j as f32 + 0.5 - y);
        (
            [d[at], d[at + 1], d[at + self.res], d[at + self.res + 1]],
            first,
        )
    }

    /// The 3 × 3 texels centred on interior texel `(i, j)`, as three rows of three.
    pub(super) fn rows3(&self, i: usize, j: usize) -> [&[f32; 3]; 3] {
        [j - 1, j, j + 1].map(|r| {
            let at = r * self.res + i - 1;
            self.depth[at..at + 3].try_into().expect("three texels")
        })
    }
}

/// Triangle `t` in light space (each corner taken there by `to`), or `None` when a
/// coordinate is not finite — a broken mesh's corner, or one beyond `f32` once projected: such a triangle
/// covers nothing and moves no depth, in an area light's nearest-point pass and in the placing pass alike
/// (whose lanes, [`reach_lanes`], repeat this test's operations). A NaN or infinity in any coordinate makes
/// the sum non-finite (as does a sum past `f32`).
#[inline(always)]
fn in_light(to: ToLight, t: &[Vec3; 3]) -> Option<[Vec3A; 3]> {
    let q = t.map(|p| to.apply(p));
    (q[0] + q[1] + q[2]).is_finite().then_some(q)
}

/// An order-preserving key of a float: larger floats, larger keys (−0 below +0; every number's key is
/// above 0, so 0 stands for none), so that the point nearest the light is one maximum whatever the order
/// its candidates come in, as the GPU's (`shaders/shadow_map.wgsl`'s `key`), where `f32::max` may return
/// either zero.
#[inline(always)]
fn key(f: f32) -> u32 {
    let b = f.to_bits();
    if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    }
}

/// The float a [`key`] stands for.
pub(crate) fn unkey(k: u32) -> f32 {
    f32::from_bits(if k & 0x8000_0000 != 0 {
        k & 0x7fff_ffff
    } else {
        !k
    })
}

/// The point nearest the light from the largest [`key`] of the corners' `p · towards`: `f32::MIN` where
/// there was none (0).
pub(crate) fn nearest(k: u32) -> f32 {
    if k == 0 { f32::MIN } else { unkey(k) }
}

/// Triangles the placing pass takes into light space at once, lane by lane: loops over the lanes that
/// the compiler vectorises (eight floats of AVX2), where a triangle at a time used a third of each
/// 128-bit register and branched per triangle (a placing pass over the 696k-triangle crowd took 8.8 ms
/// on 2 cores).
const LANES: usize = 8;

/// Up to [`LANES`] triangles lane by lane: coordinate `a` of corner `k` is `[k][a]`.
type Lanes = [[[f32; LANES]; 3]; 3];

/// For up to [`LANES`] triangles `tris` taken into light space by `to`: per triangle the first and last
/// band of [`BAND_ROWS`] rows of `map` whose texel centres its bounds may cover (`[1, 0]` when none, or
/// when a corner is not finite, see [`in_light`]), and the largest [`key`] of its finite triangles'
/// `p · towards` (0 when none), and the triangles in light space (lanes past the triangles NaN), which
/// the caller keeps for the few that cover a centre (a quarter of a detailed scene's triangles): a second
/// pass that projected those again cost 7% of the placing. The operations of [`ToLight::apply`],
/// [`in_light`] and [`ShadowMap::project`] in their order, lane by lane: bit for bit a triangle at a time.
#[inline(always)]
fn reach_lanes(
    tris: &[[Vec3; 3]],
    to: ToLight,
    map: &ShadowMap,
) -> ([[u32; 2]; LANES], u32, Lanes) {
    // Coordinate `a` of corner `k` is `p[k][a]`, lane by lane; lanes past the triangles are NaN.
    let mut p = [[[f32::NAN; LANES]; 3]; 3];
    for (l, t) in tris.iter().enumerate() {
        for (pk, c) in p.iter_mut().zip(t) {
            (pk[0][l], pk[1][l], pk[2][l]) = (c.x, c.y, c.z);
        }
    }
    let (m, t) = ([to.m.x_axis, to.m.y_axis, to.m.z_axis], to.t);
    // `m · p + t` as glam's `Mat3A * Vec3A` computes it: the columns' products summed in column order.
    let mut q = [[[0.0f32; LANES]; 3]; 3];
    for (qk, [x, y, z]) in q.iter_mut().zip(&p) {
        for (a, qa) in qk.iter_mut().enumerate() {
            for l in 0..LANES {
                qa[l] = ((m[0][a] * x[l] + m[1][a] * y[l]) + m[2][a] * z[l]) + t[a];
            }
        }
    }
    let (corner, per_texel) = (map.corner, map.per_texel);
    let mut reach = [[1, 0]; LANES];
    let mut top = [0u32; LANES];
    for l in 0..LANES {
        // Indexed in place (no per-lane copies), so the loop runs as vector operations.
        let [x, y, z] = [0, 1, 2].map(|a| [q[0][a][l], q[1][a][l], q[2][a][l]]);
        let finite = ((x[0] + x[1]) + x[2]).is_finite()
            & ((y[0] + y[1]) + y[2]).is_finite()
            & ((z[0] + z[1]) + z[2]).is_finite();
        let (x, y) = (
            x.map(|v| (v - corner.x) * per_texel),
            y.map(|v| (v - corner.y) * per_texel),
        );
        let (x0, x1) = lane_span(x[0].min(x[1]).min(x[2]), x[0].max(x[1]).max(x[2]), map.res);
        let (y0, y1) = lane_span(y[0].min(y[1]).min(y[2]), y[0].max(y[1]).max(y[2]), map.res);
        let covers = finite & (x0 <= x1) & (y0 <= y1);
        let band = |y: i32| y as u32 / BAND_ROWS as u32;
        reach[l] = if covers { [band(y0), band(y1)] } else { [1, 0] };
        let nearest = key(z[0]).max(key(z[1])).max(key(z[2]));
        top[l] = if finite { nearest } else { 0 };
    }
    (reach, top.into_iter().fold(0, u32::max), q)
}

/// [`span`]'s first and last centre as integers, decided alike where the span is not empty, for every
/// lane without a branch or a saturating conversion (both keep the placing pass's lanes from
/// vectorising): the bounds are clamped to `[−1, n]` first (NaN to −1), so each converts in one
/// instruction.
#[inline(always)]
fn lane_span(lo: f32, hi: f32, n: usize) -> (i32, i32) {
    let n = n as f32;
    // Clamped to `[−1, n]`, `n` at most 16384; `f32::max` turns NaN into −1.
    let (a, b) = ((lo - 0.5).max(-1.0).min(n), (hi - 0.5).max(-1.0).min(n));
    // SAFETY: `a` and `b` are finite and within `[−1, 16384]` (clamped above): well within `i32`.
    let trunc = |x: f32| unsafe { x.to_int_unchecked::<i32>() };
    let (ta, tb) = (trunc(a), trunc(b));
    // Truncation towards zero, then one up (ceil) or down (floor) where it moved the other way.
    let first = ta + ((ta as f32) < a) as i32;
    let last = tb - ((tb as f32) > b) as i32;
    (first.max(0), last.min(n as i32 - 1))
}

/// `x` rounded up, exact for |x| below 2³¹ and clamped to ±2³¹ beyond (NaN gives 0): all the callers
/// clamp to the map, far inside. Inline, where `f32::ceil` is a library call on targets without SSE4.1
/// (it was a tenth of the map's time).
fn ceil(x: f32) -> f32 {
    let t = x as i32 as f32;
    if t < x { t + 1.0 } else { t }
}

/// `x` rounded down, as [`ceil`].
fn floor(x: f32) -> f32 {
    let t = x as i32 as f32;
    if t > x { t - 1.0 } else { t }
}

/// The first and last texel whose centre (`i + 0.5`) lies in `[lo, hi]`, clamped to `0..n`, as whole
/// floats; empty when the first is past the last.
fn span(lo: f32, hi: f32, n: usize) -> (f32, f32) {
    (ceil(lo - 0.5).max(0.0), floor(hi - 0.5).min(n as f32 - 1.0))
}

/// [`span`] as indices; `(1, 0)` when empty.
fn centres(lo: f32, hi: f32, n: usize) -> (usize, usize) {
    let (first, last) = span(lo, hi, n);
    if last < first {
        (1, 0)
    } else {
        (first as usize, last as usize)
    }
}

/// Twice the area, in texels², from which a triangle covers nothing (2¹²⁶; also a non-finite one): its
/// reciprocal would be subnormal, which a GPU may flush to zero (`GpuShadowMap` renders the same map).
/// Such a triangle is 2⁶³ texels across: a receiver under it sees an empty texel and is marked for a ray.
const MAX_AREA: f32 = (1u128 << 126) as f32;

/// Triangles whose bounds span fewer texel centres than this along a row are rasterised centre by centre;
/// wider ones solve each row's covered span.
const NARROW: usize = 4;

/// Writes the nearest depth of triangle `t` (map coordinates) into the texels of rows `row0..` whose centres
/// it covers, edges and corners included (a centre on a shared edge belongs to both triangles, up to
/// rounding). A triangle a few texels wide (the crowd's: about a texel each) tests each centre of its
/// bounds; a wider one solves each row's covered span from the three edge functions and checks its two
/// ends exactly (a weight is monotone along the row, so the covered centres are one run), so the cost is
/// one depth-plane step per covered texel plus a few per row. One division per triangle. Triangles seen
/// edge-on by the light cover nothing, nor do those of [`MAX_AREA`] or more.
#[inline(always)]
fn rasterise(t: &[Vec3; 3], row0: usize, res: usize, out: &mut [f32]) {
    let rows = out.len() / res;
    let (lo, hi) = (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]));
    let (y0, y1) = centres(lo.y, hi.y, res);
    let (y0, y1) = (y0.max(row0), y1.min(row0 + rows - 1));
    let (x0, x1) = centres(lo.x, hi.x, res);
    if y1 < y0 || x1 < x0 {
        return;
    }
    // Edge k's weight is a_k x + b_k y + c_k, normalised so the three sum to 1 (barycentrics).
    let area = (t[1].x - t[0].x) * (t[2].y - t[0].y) - (t[1].y - t[0].y) * (t[2].x - t[0].x);
    if area == 0.0 || !area.is_finite() || area.abs() >= MAX_AREA {
        return;
    }
    let per_area = area.recip();
    let coef = |a: Vec3, b: Vec3| {
        let (ea, eb) = ((a.y - b.y) * per_area, (b.x - a.x) * per_area);
        (ea, eb, -(ea * a.x + eb * a.y))
    };
    let e = [coef(t[1], t[2]), coef(t[2], t[0]), coef(t[0], t[1])];
    // Depth is the weights' blend of the corners' depths: linear along a row, `dz · x + z_row`.
    let dz = e[0].0 * t[0].z + e[1].0 * t[1].z + e[2].0 * t[2].z;
    let inside = |cx: f32, cy: f32| e.iter().all(|&(a, b, c)| a * cx + b * cy + c >= 0.0);
    // Where along a row each edge's weight crosses 0, per unit of its `b · y + c`.
    let crossing = e.map(|(a, ..)| -a.recip());
    for y in y0..=y1 {
        let cy = y as f32 + 0.5;
        let z_row = e
            .iter()
            .zip(t)
            .map(|(&(_, b, c), p)| (b * cy + c) * p.z)
            .sum::<f32>();
        let row = &mut out[(y - row0) * res..(y - row0 + 1) * res];
        // Through `i32` (exact: at most 16383): a vector conversion, where one from `usize` is several
        // instructions a texel.
        let centre = |x: usize| x as i32 as f32 + 0.5;
        if x1 - x0 < NARROW {
            for (x, d) in row.iter_mut().enumerate().take(x1 + 1).skip(x0) {
                if inside(centre(x), cy) {
                    *d = d.min(dz * centre(x) + z_row);
                }
            }
            continue;
        }
        // The span of centres where all three weights are ≥ 0, one centre of slack each way, then
        // trimmed at both ends by the exact test.
        let (mut from, mut to) = (x0 as f32, x1 as f32);
        for (&(a, b, c), &cross) in e.iter().zip(&crossing) {
            let r = b * cy + c; // weight = a·(x + 0.5) + r ≥ 0
            if a > 0.0 {
                from = from.max(ceil(r * cross - 0.5) - 1.0);
            } else if a < 0.0 {
                to = to.min(floor(r * cross - 0.5) + 1.0);
            } else if r < 0.0 {
                to = -1.0;
            }
        }
        if to < from {
            continue;
        }
        let (mut from, mut to) = (from as usize, to as usize);
        while from <= to && !inside(centre(from), cy) {
            from += 1;
        }
        while to > from && !inside(centre(to), cy) {
            to -= 1;
        }
        if from > to || !inside(centre(from), cy) {
            continue;
        }
        for (x, d) in row[from..=to].iter_mut().enumerate() {
            *d = d.min(dz * centre(from + x) + z_row);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng, rngs::SmallRng};

    /// A map aimed along `towards`, and the receivers' bounds of the square from (10, 0, 10) to
    /// (90, 0, 90) across it.
    fn aimed(towards: Vec3) -> (ShadowMap, (Vec3, Vec3)) {
        let mut map = ShadowMap::default();
        map.aim(towards);
        let across = |p: Vec3| map.across(p).extend(p.dot(towards));
        let (lo, hi) = (
            across(Vec3::new(10.0, 0.0, 10.0)),
            across(Vec3::new(90.0, 0.0, 90.0)),
        );
        (map, (lo.min(hi), lo.max(hi)))
    }

    /// The rendered map equals every triangle projected with [`ShadowMap::project`] and rasterised
    /// into every band, bit for bit: the placing pass bins each triangle into all the bands it covers
    /// (its own projection agreeing with `project`), over several chunks of triangles, in parallel or
    /// not, hard (the nearest point found while placing) or soft (found first: the map widens).
    #[test]
    fn placed_and_binned_triangles_render_as_all_triangles_in_every_band() {
        let mut r = SmallRng::seed_from_u64(5);
        let towards = Vec3::new(0.3, 1.0, 0.2).normalize();
        // Small triangles (many between texel centres), some large, a few far off the map on either
        // side, some beyond `i32` in texels; a count that leaves a partial block of lanes.
        let tris: Vec<[Vec3; 3]> = (0..2 * PLACE_CHUNK + 1003)
            .map(|k| {
                let size = if k % 97 == 0 { 30.0 } else { 0.3 };
                let far: f32 = match (k % 1001, k % 2003, k % 4001) {
                    (0, ..) => 500.0,
                    (_, 0, _) => -500.0,
                    (.., 0) => [1e12, -1e12][k % 2],
                    _ => 0.0,
                };
                if k == 77 {
                    // The point nearest the light, on a triangle off the map (it covers no centre).
                    let o = Vec3::new(-400.0, 200.0, 300.0);
                    return [o, o + Vec3::X, o + Vec3::Z];
                }
                // Far off across the light (perpendicular to `towards` below) and a little away from
                // it, so that the nearest point (triangle 77's) and a soft map's extent stay put.
                let o = Vec3::new(
                    r.random_range(0.0..100.0),
                    r.random_range(0.0..20.0),
                    r.random_range(0.0..100.0),
                ) + Vec3::new(1.0, -0.3, 0.0) * far
                    - towards * (far.abs() * 1e-5);
                let mut corner = || {
                    let d = Vec3::new(r.random(), r.random(), r.random()) * size;
                    o + d
                };
                [corner(), corner(), corner()]
            })
            .collect();
        for (spread, parallel) in [(0.0, true), (0.0, false), (0.01, true)] {
            let (mut map, receivers) = aimed(towards);
            map.render(&tris, receivers, spread, 256, parallel);
            let nearest = (tris.iter().flatten())
                .map(|p| map.project(*p).z)
                .fold(f32::INFINITY, f32::min);
            assert_eq!(nearest, 0.0, "depth starts at the point nearest the light");
            let mut want = vec![f32::INFINITY; 256 * 256];
            for (band, out) in want.chunks_mut(BAND_ROWS * 256).enumerate() {
                for t in &tris {
                    rasterise(&t.map(|p| map.project(p)), band * BAND_ROWS, 256, out);
                }
            }
            let covered = want.iter().filter(|d| d.is_finite()).count();
            assert!(covered > 256 * 256 / 4, "{covered} texels covered");
            let bits = |d: &[f32]| d.iter().map(|d| d.to_bits()).collect::<Vec<_>>();
            assert!(
                bits(map.depths()) == bits(&want),
                "spread {spread}, parallel {parallel}"
            );
        }
    }

    /// Occluders in groups, each placed by its own transform, one empty, one broken (a NaN translation:
    /// its triangles cover nothing): the map equals every group's triangles taken into light space by the
    /// transform composed with the light (`light · M`, `light · t`) and rasterised into every band, bit for
    /// bit — the pieces cut at [`PLACE_CHUNK`] within each group and across them, in parallel or not, hard
    /// and soft.
    #[test]
    fn grouped_occluders_render_as_their_placed_triangles() {
        struct Groups(Vec<(Vec<[Vec3; 3]>, Option<Affine3A>)>);
        impl Occluders for Groups {
            fn groups(&self) -> usize {
                self.0.len()
            }
            fn group(&self, g: usize) -> (&[[Vec3; 3]], Option<Affine3A>) {
                (&self.0[g].0, self.0[g].1)
            }
        }
        let mut r = SmallRng::seed_from_u64(9);
        let mut group = |n: usize| -> Vec<[Vec3; 3]> {
            (0..n)
                .map(|_| {
                    let o = Vec3::new(
                        r.random_range(-40.0..40.0),
                        r.random_range(0.0..10.0),
                        r.random_range(-40.0..40.0),
                    );
                    let mut corner = || o + Vec3::new(r.random(), r.random(), r.random()) * 0.5;
                    [corner(), corner(), corner()]
                })
                .collect()
        };
        let placed = |yaw: f32, at: Vec3| {
            Some(Affine3A::from_scale_rotation_translation(
                Vec3::splat(1.1),
                glam::Quat::from_rotation_y(yaw),
                at,
            ))
        };
        let groups = Groups(vec![
            (
                group(PLACE_CHUNK + 5),
                placed(0.3, Vec3::new(50.0, 0.0, 50.0)),
            ),
            (Vec::new(), placed(1.0, Vec3::ZERO)),
            (group(7), None),
            // A broken transform: its triangles cover nothing and move no depth.
            (group(50), placed(0.0, Vec3::NAN)),
            (
                group(2 * PLACE_CHUNK),
                placed(-2.0, Vec3::new(45.0, 1.0, 55.0)),
            ),
        ]);
        let towards = Vec3::new(0.3, 1.0, 0.2).normalize();
        for (spread, parallel) in [(0.0, true), (0.0, false), (0.01, true)] {
            let (mut map, receivers) = aimed(towards);
            map.render(&groups, receivers, spread, 256, parallel);
            let light = map.light();
            let in_light = |p: Vec3, a: Option<Affine3A>| match a {
                Some(a) => (light * a.matrix3) * Vec3A::from(p) + light * a.translation,
                None => light * Vec3A::from(p),
            };
            let corners = || {
                (groups.0.iter())
                    .flat_map(|(tris, a)| tris.iter().map(move |t| t.map(|p| in_light(p, *a))))
            };
            let top = corners().flatten().map(|q| q.z).fold(f32::MIN, f32::max);
            assert_eq!(map.top, top, "depth starts at the point nearest the light");
            let mut want = vec![f32::INFINITY; 256 * 256];
            for (band, out) in want.chunks_mut(BAND_ROWS * 256).enumerate() {
                for q in corners() {
                    let t = q.map(|q| map.in_texels(q.truncate()).extend(top - q.z));
                    rasterise(&t, band * BAND_ROWS, 256, out);
                }
            }
            let covered = want.iter().filter(|d| d.is_finite()).count();
            assert!(covered > 1000, "{covered} texels covered");
            let bits = |d: &[f32]| d.iter().map(|d| d.to_bits()).collect::<Vec<_>>();
            assert!(
                bits(map.depths()) == bits(&want),
                "spread {spread}, parallel {parallel}"
            );
        }
    }

    /// [`lane_span`] decides as [`span`] (the rasteriser's): the same first and last centre wherever the
    /// span is not empty, and empty where it is, for bounds on, between and beyond the centres, at the
    /// clamps, at ±0, beyond `i32` and infinite. (NaN bounds come only from a triangle that is not
    /// finite, which [`reach_lanes`] leaves out whatever its span.)
    #[test]
    fn lane_span_decides_as_span() {
        let n = 64;
        let edges = [
            f32::NEG_INFINITY,
            -1e12,
            -3.0,
            -1.5,
            -1.0,
            -0.5,
            -0.25,
            -0.0,
            0.0,
            0.25,
            0.5,
            0.75,
            1.0,
            1.5,
            31.5,
            32.0,
            62.5,
            63.0,
            63.5,
            64.0,
            64.5,
            65.0,
            1e12,
            f32::INFINITY,
        ];
        for &lo in &edges {
            for &hi in &edges {
                let (first, last) = span(lo, hi, n);
                let (a, b) = lane_span(lo, hi, n);
                if first <= last {
                    assert_eq!((a, b), (first as i32, last as i32), "[{lo}, {hi}]");
                } else {
                    assert!(a > b, "[{lo}, {hi}]: {a}..={b}, not empty");
                }
            }
        }
    }

    /// Triangles covering texel centres as a brute-force test in f64 says: each centre the triangle's
    /// barycentric weights all cover gets the nearest interpolated depth, in bands of rows as the map
    /// renders them. Centres within a rounding band of an edge (weight below 1e-4) are left out of the
    /// comparison, both ways.
    #[test]
    fn rasterised_texels_equal_a_brute_force_coverage() {
        let mut r = SmallRng::seed_from_u64(3);
        let res = 96;
        let mut checked = [0usize; 2];
        for _ in 0..60 {
            let tris: Vec<[Vec3; 3]> = (0..30)
                .map(|k| {
                    // Tiny, medium and long thin triangles, some reaching past the map.
                    let size = [0.8, 3.0, 20.0, 70.0][k % 4];
                    let o = Vec2::new(r.random_range(-10.0..100.0), r.random_range(-10.0..100.0));
                    let mut corner = || {
                        let c = o + Vec2::new(r.random_range(0.0..size), r.random_range(0.0..size));
                        c.extend(r.random_range(0.0..10.0))
                    };
                    [corner(), corner(), corner()]
                })
                .collect();
            let mut depth = vec![f32::INFINITY; res * res];
            for (band, out) in depth.chunks_mut(BAND_ROWS * res).enumerate() {
                for t in &tris {
                    rasterise(t, band * BAND_ROWS, res, out);
                }
            }
            for y in 0..res {
                for x in 0..res {
                    let c = (x as f64 + 0.5, y as f64 + 0.5);
                    let (mut want, mut tolerance) = (f64::INFINITY, 0.0);
                    let mut unsure = false;
                    for t in &tris {
                        let p = t.map(|v| (v.x as f64, v.y as f64, v.z as f64));
                        // Twice the signed area of (a, b, q).
                        let edge = |a: (f64, f64, f64), b: (f64, f64, f64), q: (f64, f64)| {
                            (b.0 - a.0) * (q.1 - a.1) - (b.1 - a.1) * (q.0 - a.0)
                        };
                        let area = edge(p[0], p[1], (p[2].0, p[2].1));
                        if area == 0.0 {
                            continue;
                        }
                        let weights = |q| {
                            [
                                edge(p[1], p[2], q),
                                edge(p[2], p[0], q),
                                edge(p[0], p[1], q),
                            ]
                            .map(|e| e / area)
                        };
                        let depth = |w: [f64; 3]| w[0] * p[0].2 + w[1] * p[1].2 + w[2] * p[2].2;
                        let w = weights(c);
                        if w.iter().any(|w| w.abs() < 1e-4) {
                            unsure = true;
                        } else if w.iter().all(|&w| w > 0.0) && depth(w) < want {
                            want = depth(w);
                            // f32 blends the corners' depths by weights `a·x + b·y + c` and steps
                            // the plane as `dz · x + z_row`: its rounding grows with each term's
                            // size, a few units in the last place of each.
                            let (w0, wx, wy) = (
                                weights((0.0, 0.0)),
                                weights((1.0, 0.0)),
                                weights((0.0, 1.0)),
                            );
                            let terms: f64 = (0..3)
                                .map(|k| {
                                    let (a, b) = (wx[k] - w0[k], wy[k] - w0[k]);
                                    p[k].2 * (a.abs() * c.0 + b.abs() * c.1 + w0[k].abs())
                                })
                                .sum();
                            let dz = depth(wx) - depth(w0);
                            let plane = dz.abs() * c.0 + (want - dz * c.0).abs();
                            tolerance = 8.0 * f32::EPSILON as f64 * (terms + plane);
                        }
                    }
                    if unsure {
                        continue;
                    }
                    let got = depth[y * res + x] as f64;
                    checked[want.is_finite() as usize] += 1;
                    if want.is_finite() {
                        assert!(
                            (got - want).abs() <= tolerance,
                            "texel ({x}, {y}): {got} against {want} ± {tolerance}"
                        );
                    } else {
                        assert_eq!(got, f64::INFINITY, "texel ({x}, {y}) covered");
                    }
                }
            }
        }
        assert!(checked[0] > 10_000 && checked[1] > 10_000, "{checked:?}");
    }
}
