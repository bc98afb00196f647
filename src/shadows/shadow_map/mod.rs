//! The shadow map of a directional light: the scene's triangles rasterised orthographically along the
//! light into a square depth map that just covers them.

mod raster;

use super::Occluders;
use crate::parallel;
use glam::{Affine3A, Mat3A, Vec2, Vec3, Vec3A};
use raster::{area, lane_bounds, rasterise_band};

/// Rows of the map one worker rasterises at a time (each band visits only the triangles binned to it).
const BAND_ROWS: usize = 32;

/// A depth map seen from a directional light: depth is the distance along the light's rays from the plane
/// through the scene's point nearest the light, so 0 is nearest and `f32::INFINITY` marks an empty texel.
///
/// Use it through [`HardShadows`](super::HardShadows); on its own it answers "what does the light see
/// nearest at this point". Rendering costs one pass over the triangles, in parallel chunks, that places
/// each across the map (finding the point nearest the light on the way) and sorts those that cover a
/// texel centre (of a closed group, only those facing the light: [`Occluders::closed`]), projected, into
/// bands of 32 rows, chunk by chunk (an area light's map first finds the nearest point in a pass of its
/// own: how far it widens depends on it); then, in parallel over bands,
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
/// does. One form for both: no branch per point. And which of its triangles the map keeps ([`faces`]).
#[derive(Clone, Copy)]
pub(crate) struct ToLight {
    pub(crate) m: Mat3A,
    pub(crate) t: Vec3A,
    /// 0: every triangle; ±1: only those whose area across the map (corners in texels, the rasteriser's
    /// `area`) has this sign — a closed group's faces towards the light, its transform mirroring it or not.
    pub(crate) cull: f32,
}

impl ToLight {
    /// For a group placed by `place` (`None`: in world space) under the light transform `light`, keeping
    /// only its faces towards the light where it is `closed` ([`Occluders::closed`]).
    pub(crate) fn new(light: Mat3A, place: Option<Affine3A>, closed: bool) -> Self {
        // The light's axes are right-handed (`u × v = towards`), so a triangle whose winding faces the
        // light has a positive area across the map; a mirroring transform turns its winding over. A
        // transform that flattens the group (or is not finite) culls nothing.
        let det = place.map_or(1.0, |a| a.matrix3.determinant());
        let cull = match closed {
            true if det > 0.0 => 1.0,
            true if det < 0.0 => -1.0,
            _ => 0.0,
        };
        match place {
            None => Self {
                m: light,
                t: Vec3A::splat(-0.0),
                cull,
            },
            Some(a) => Self {
                m: light * a.matrix3,
                t: light * a.translation,
                cull,
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
        self.bins.clear();
        self.bins.resize(count + 1, 0);
        self.covering.clear();
        let mut top = 0;
        for block in tris.chunks(LANES) {
            let (reach, nearest, q) = reach_lanes(block, to, map);
            top = top.max(nearest);
            // The lanes that cover a centre, one by one. (Every lane written to spare room and kept by
            // counting it, without a branch per lane, was as fast while a quarter of the crowd's
            // triangles covered one; with its closed characters' faces away from the light left out,
            // an eighth do, and the map is about a tenth faster this way.)
            let mut lanes = 0u32;
            for (l, &[b0, b1]) in reach[..block.len()].iter().enumerate() {
                lanes |= ((b0 <= b1) as u32) << l;
            }
            while lanes != 0 {
                let l = lanes.trailing_zeros() as usize;
                lanes &= lanes - 1;
                let [b0, b1] = reach[l];
                let corners = [0, 1, 2].map(|k| Vec3::new(q[k][0][l], q[k][1][l], q[k][2][l]));
                self.covering.push((corners, [b0, b1]));
                for b in b0..=b1 {
                    self.bins[b as usize + 1] += 1;
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
            (tris, ToLight::new(light, place, occluders.closed(g)))
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
                    for p in &placed {
                        rasterise_band(p.band(band), this.top, band * BAND_ROWS, res, out);
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

/// Writes `tris` (at most [`LANES`]) into `p` lane by lane, `z` as `depth(z)`; the lanes past them
/// keep what `p` held. (In place: an array returned by value made the full crowd's map about a sixth
/// slower.)
#[inline(always)]
fn fill_lanes(p: &mut Lanes, tris: &[[Vec3; 3]], depth: impl Fn(f32) -> f32) {
    for (l, t) in tris.iter().enumerate() {
        for (pk, c) in p.iter_mut().zip(t) {
            (pk[0][l], pk[1][l], pk[2][l]) = (c.x, c.y, depth(c.z));
        }
    }
}

/// For up to [`LANES`] triangles `tris` taken into light space by `to`: per triangle the first and last
/// band of [`BAND_ROWS`] rows of `map` whose texel centres its bounds may cover (`[1, 0]` when none, or
/// when a corner is not finite, see [`in_light`]), and the largest [`key`] of its finite triangles'
/// `p · towards` (0 when none), and the triangles' corners across the map in texels, with their
/// `p · towards` (lanes past the triangles NaN), which the caller keeps for the few that cover a centre (a
/// quarter of a detailed scene's triangles): a second pass that projected those again cost 7% of the
/// placing. The operations of [`ToLight::apply`], [`in_light`] and [`ShadowMap::project`] in their order,
/// lane by lane: bit for bit a triangle at a time.
#[inline(always)]
fn reach_lanes(
    tris: &[[Vec3; 3]],
    to: ToLight,
    map: &ShadowMap,
) -> ([[u32; 2]; LANES], u32, Lanes) {
    // Lanes past the triangles are NaN.
    let mut p = [[[f32::NAN; LANES]; 3]; 3];
    fill_lanes(
        &mut p,
        tris,
        #[inline(always)]
        |z| z,
    );
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
        for (k, qk) in q.iter_mut().enumerate() {
            (qk[0][l], qk[1][l]) = (x[k], y[k]);
        }
        let ((x0, x1), (y0, y1)) = (lane_bounds(x, map.res), lane_bounds(y, map.res));
        let covers = finite & (x0 <= x1) & (y0 <= y1) & faces(to.cull, x, y);
        let band = |y: i32| y as u32 / BAND_ROWS as u32;
        reach[l] = if covers { [band(y0), band(y1)] } else { [1, 0] };
        let nearest = key(z[0]).max(key(z[1])).max(key(z[2]));
        top[l] = if finite { nearest } else { 0 };
    }
    (reach, top.into_iter().fold(0, u32::max), q)
}

/// Whether the triangle with corners `x`, `y` across the map (in texels) is kept under `cull`
/// ([`ToLight::cull`]): always where it is 0, else where its [`area`] — the one `rasterise` computes —
/// has `cull`'s sign (a triangle seen edge-on covers nothing either way).
#[inline(always)]
fn faces(cull: f32, x: [f32; 3], y: [f32; 3]) -> bool {
    cull == 0.0 || area(x, y) * cull > 0.0
}

#[cfg(test)]
mod tests {
    use super::raster::rasterise;
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

    /// A closed group culls by the sign of its transform's determinant — its faces towards the light
    /// (+1), or, mirrored, the other winding (−1) — and culls nothing where the transform flattens it
    /// (a zero determinant) or is not finite (a NaN or infinite matrix: no sign to trust), nor where the
    /// group is not closed.
    #[test]
    fn closed_groups_cull_by_their_transforms_handedness_and_broken_ones_not_at_all() {
        let light = Mat3A::from_rotation_x(0.3);
        let with = |m: Mat3A| Some(Affine3A::from_mat3_translation(m.into(), Vec3::ONE));
        let scaled = |d: Vec3| with(Mat3A::from_diagonal(d));
        for (place, cull) in [
            (None, 1.0),
            (scaled(Vec3::new(2.0, 3.0, 0.5)), 1.0),
            (scaled(Vec3::new(-2.0, 3.0, 0.5)), -1.0),
            (scaled(Vec3::new(-1.0, -1.0, -1.0)), -1.0),
            (scaled(Vec3::new(1.0, 0.0, 1.0)), 0.0),
            (scaled(Vec3::new(1.0, f32::NAN, 1.0)), 0.0),
            (scaled(Vec3::new(1.0, f32::INFINITY, 1.0)), 0.0),
            (with(Mat3A::from_cols(Vec3A::X, Vec3A::NAN, Vec3A::Z)), 0.0),
        ] {
            assert_eq!(ToLight::new(light, place, true).cull, cull, "{place:?}");
            assert_eq!(ToLight::new(light, place, false).cull, 0.0, "{place:?}");
        }
    }

    /// Groups of triangles said to be closed or not ([`Occluders::closed`]).
    struct Claimed(Vec<(Vec<[Vec3; 3]>, Option<Affine3A>)>, bool);

    impl Occluders for Claimed {
        fn groups(&self) -> usize {
            self.0.len()
        }
        fn group(&self, g: usize) -> (&[[Vec3; 3]], Option<Affine3A>) {
            (&self.0[g].0, self.0[g].1)
        }
        fn closed(&self, _: usize) -> bool {
            self.1
        }
    }

    /// Closed groups (icospheres: [`Mesh::is_closed`](crate::Mesh::is_closed)) leave out their faces
    /// away from the light, under a rotation and scale, under a mirroring transform (which turns their
    /// winding over) and in world space, at several turns and resolutions, in parallel or not. A subset of
    /// the triangles, so every texel lies at least as deep as in the map of all faces; and the same
    /// but for pinholes, where rounding drops a centre from both faces along a shared edge (the
    /// rasteriser is not watertight) and a face behind had filled it: under one texel in a thousand
    /// (none in these maps; 179 in 9.3M covered texels over 40 random turns of twelve finer spheres).
    /// The same spheres turned inside out and said to be closed (a wrong claim) keep their far sides
    /// instead: deeper wherever the spheres cover the map, which shows that faces are left out, and
    /// which.
    #[test]
    fn closed_groups_render_as_all_their_faces_but_pinholes_without_those_away_from_the_light() {
        let sphere = crate::scenes::icosphere(4);
        assert!(sphere.is_closed());
        let outwards: Vec<[Vec3; 3]> = (0..sphere.triangle_count())
            .map(|i| sphere.triangle(i))
            .collect();
        let inwards: Vec<[Vec3; 3]> = outwards.iter().map(|t| [t[0], t[2], t[1]]).collect();
        let at = |scale: Vec3, turn: glam::Quat, to: Vec3| {
            Affine3A::from_scale_rotation_translation(scale, turn, to)
        };
        let places = [
            Some(at(
                Vec3::new(8.0, 5.0, 6.0),
                glam::Quat::from_rotation_y(0.4),
                Vec3::new(30.0, 6.0, 40.0),
            )),
            // Mirrored (a negative determinant).
            Some(at(
                Vec3::new(-7.0, 6.0, 7.0),
                glam::Quat::from_rotation_x(0.7),
                Vec3::new(65.0, 8.0, 62.0),
            )),
            None,
        ];
        // The world-space group: the sphere placed by hand.
        let world = at(
            Vec3::splat(9.0),
            glam::Quat::IDENTITY,
            Vec3::new(45.0, 10.0, 20.0),
        );
        let claimed = |tris: &[[Vec3; 3]], closed: bool, turn: f32| {
            let spin = Affine3A::from_rotation_z(turn);
            let groups = places.iter().map(|&place| match place {
                Some(a) => (tris.to_vec(), Some(a * spin)),
                None => (
                    tris.iter()
                        .map(|t| t.map(|p| (world * spin).transform_point3(p)))
                        .collect(),
                    None,
                ),
            });
            Claimed(groups.collect(), closed)
        };
        let towards = Vec3::new(0.3, 1.0, 0.2).normalize();
        let (mut covered, mut pinholes) = (0, 0);
        for (parallel, res, turn) in [
            (true, 256, 0.0),
            (false, 256, 0.0),
            (true, 512, 1.3),
            (true, 384, 2.2),
        ] {
            let render = |occluders: &Claimed| {
                let (mut map, receivers) = aimed(towards);
                map.render(occluders, receivers, 0.0, res, parallel);
                map
            };
            let what = format!("parallel {parallel}, {res}², turned {turn}");
            let all = render(&claimed(&outwards, false, turn));
            let culled = render(&claimed(&outwards, true, turn));
            for (c, a) in culled.depths().iter().zip(all.depths()) {
                assert!(c >= a, "{what}: a culled map's texel {c} nearer than {a}");
                pinholes += (c != a) as usize;
                covered += a.is_finite() as usize;
            }
            // Inside out, said to be closed: the far sides.
            let far = render(&claimed(&inwards, true, turn));
            assert_eq!(
                far.top, all.top,
                "{what}: the nearest point counts every triangle"
            );
            let (mut deeper, mut here) = (0, 0);
            for (f, a) in far.depths().iter().zip(all.depths()) {
                assert!(
                    f >= a,
                    "{what}: a far side {f} nearer than the near side {a}"
                );
                deeper += (f > a) as usize;
                here += a.is_finite() as usize;
            }
            assert!(
                here > 3000 && deeper > here * 9 / 10,
                "{what}: {deeper} of {here} texels deeper"
            );
        }
        assert!(
            pinholes * 1000 < covered,
            "{pinholes} pinholes in {covered} covered texels"
        );
    }
}
