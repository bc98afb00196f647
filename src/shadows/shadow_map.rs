//! The shadow map of a directional light: the scene's triangles rasterised orthographically along the
//! light into a square depth map that just covers them.

use crate::parallel;
use glam::{Vec2, Vec3};

/// Rows of the map one worker rasterises at a time (every band visits every triangle's bounds).
const BAND_ROWS: usize = 32;

/// A depth map seen from a directional light: depth is the distance along the light's rays from the plane
/// through the scene's point nearest the light, so 0 is nearest and `f32::INFINITY` marks an empty texel.
///
/// Use it through [`HardShadows`](super::HardShadows); on its own it answers "what does the light see
/// nearest at this point". Rendering costs one pass over the triangles per band of 32 rows plus the
/// covered texels (O(bands · triangles + covered texels)), in parallel over bands; the buffers are kept,
/// so a warm map of the same resolution does not allocate.
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
    /// Triangles in map coordinates (x, y in texels, z = depth), kept between frames.
    projected: Vec<[Vec3; 3]>,
}

impl ShadowMap {
    /// Renders `triangles` (world space) as seen from a light in direction `towards` (unit, pointing from the
    /// scene to the light) into a `res × res` map that covers the `receivers` across the light, plus a
    /// margin of one texel so every receiver has its eight neighbours. A directional light's occluder of a
    /// receiver lies on the receiver's line towards the light, so it projects onto the same spot: fitting
    /// the map to the receivers (the pixels the camera sees) rather than the scene loses no shadow and
    /// spends every texel where it is looked at. No receivers or no triangles give an empty map.
    pub(super) fn render<'a>(
        &mut self,
        triangles: &[[Vec3; 3]],
        receivers: impl Iterator<Item = &'a Vec3>,
        towards: Vec3,
        res: usize,
        parallel: bool,
    ) {
        self.towards = towards;
        self.u = towards.any_orthonormal_vector();
        self.v = towards.cross(self.u);
        let (mut lo, mut hi) = (Vec2::splat(f32::MAX), Vec2::splat(f32::MIN));
        for p in receivers {
            let q = Vec2::new(p.dot(self.u), p.dot(self.v));
            lo = lo.min(q);
            hi = hi.max(q);
        }
        let mut top = f32::MIN;
        for [a, b, c] in triangles {
            top = top.max(a.dot(towards).max(b.dot(towards)).max(c.dot(towards)));
        }
        self.res = res;
        self.depth.clear();
        self.depth.resize(res * res, f32::INFINITY);
        if triangles.is_empty() || lo.x > hi.x {
            (self.corner, self.top, self.texel) = (Vec2::ZERO, 0.0, 1.0);
            return;
        }
        let extent = (hi - lo).max_element().max(f32::MIN_POSITIVE);
        // One texel of margin on each side.
        self.texel = extent / (res as f32 - 2.0).max(1.0);
        self.corner = lo - Vec2::splat(self.texel);
        self.top = top;
        let mut projected = std::mem::take(&mut self.projected);
        let this = &*self;
        projected.resize(triangles.len(), [Vec3::ZERO; 3]);
        parallel::fill(parallel, &mut projected, 4096, |i| {
            triangles[i].map(|p| this.project(p))
        });
        let mut depth = std::mem::take(&mut self.depth);
        parallel::fill_chunks(parallel, &mut depth, BAND_ROWS * res, |band, out| {
            let row0 = band * BAND_ROWS;
            for t in &projected {
                rasterise(t, row0, res, out);
            }
        });
        self.depth = depth;
        self.projected = projected;
    }

    /// Map coordinates of a world point: x and y in texels (texel `(i, j)` covers `[i, i+1) × [j, j+1)`),
    /// z its depth from the light.
    pub fn project(&self, p: Vec3) -> Vec3 {
        let q = (Vec2::new(p.dot(self.u), p.dot(self.v)) - self.corner) / self.texel;
        q.extend(self.top - p.dot(self.towards))
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
}

/// Writes the nearest depth of triangle `t` (map coordinates) into the texels of rows `row0..` whose centres
/// it covers, edges and corners included (a centre on a shared edge belongs to both triangles). Each row's
/// covered span is solved from the three edge functions, so the cost is the covered texels plus one step
/// per row. Triangles seen edge-on by the light cover nothing.
fn rasterise(t: &[Vec3; 3], row0: usize, res: usize, out: &mut [f32]) {
    let rows = out.len() / res;
    let (lo, hi) = (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]));
    // Most triangles miss a band: reject them with two comparisons.
    if hi.y < row0 as f32 || lo.y > (row0 + rows) as f32 {
        return;
    }
    // Texel centres are at i + 0.5.
    let first = |a: f32| (a - 0.5).ceil().max(0.0) as usize;
    let last = |a: f32, n: usize| (a - 0.5).floor().min(n as f32 - 1.0);
    let (y0, y1) = (first(lo.y).max(row0), last(hi.y, row0 + rows));
    let (x0, x1) = (first(lo.x), last(hi.x, res));
    if y1 < y0 as f32 || x1 < x0 as f32 {
        return;
    }
    let (y1, x1) = (y1 as usize, x1 as usize);
    // Edge k's weight is a_k x + b_k y + c_k, normalised so the three sum to 1 (barycentrics).
    let area = (t[1].x - t[0].x) * (t[2].y - t[0].y) - (t[1].y - t[0].y) * (t[2].x - t[0].x);
    if area == 0.0 || !area.is_finite() {
        return;
    }
    let coef = |a: Vec3, b: Vec3| {
        let (ea, eb) = ((a.y - b.y) / area, (b.x - a.x) / area);
        (ea, eb, -(ea * a.x + eb * a.y))
    };
    let e = [coef(t[1], t[2]), coef(t[2], t[0]), coef(t[0], t[1])];
    for y in y0..=y1 {
        let cy = y as f32 + 0.5;
        // The span of centres where all three weights are ≥ 0.
        let (mut from, mut to) = (x0 as f32, x1 as f32);
        for &(a, b, c) in &e {
            let r = b * cy + c; // weight = a·(x + 0.5) + r ≥ 0
            // One centre of slack each way: the exact test below decides.
            if a > 0.0 {
                from = from.max((-r / a - 0.5).ceil() - 1.0);
            } else if a < 0.0 {
                to = to.min((-r / a - 0.5).floor() + 1.0);
            } else if r < 0.0 {
                to = -1.0;
            }
        }
        if to < from {
            continue;
        }
        let row = &mut out[(y - row0) * res..(y - row0 + 1) * res];
        let from = from as usize;
        for (x, d) in row[from..=to as usize].iter_mut().enumerate() {
            let cx = (from + x) as f32 + 0.5;
            let w = e.map(|(a, b, c)| a * cx + b * cy + c);
            if w[0] >= 0.0 && w[1] >= 0.0 && w[2] >= 0.0 {
                *d = d.min(w[0] * t[0].z + w[1] * t[1].z + w[2] * t[2].z);
            }
        }
    }
}
