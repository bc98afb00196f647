//! The shadow map's rasteriser: a triangle's nearest depth written into the texels whose centres it
//! covers, a triangle at a time ([`rasterise`]) or a band's binned triangles [`LANES`] at a time
//! ([`rasterise_band`]), bit for bit alike.

use super::{LANES, fill_lanes};
use glam::Vec3;

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
pub(super) fn rasterise(t: &[Vec3; 3], row0: usize, res: usize, out: &mut [f32]) {
    let rows = out.len() / res;
    let (lo, hi) = (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]));
    let (y0, y1) = centres(lo.y, hi.y, res);
    let (y0, y1) = (y0.max(row0), y1.min(row0 + rows - 1));
    let (x0, x1) = centres(lo.x, hi.x, res);
    if y1 < y0 || x1 < x0 {
        return;
    }
    // Edge k's weight is a_k x + b_k y + c_k, normalised so the three sum to 1 (barycentrics).
    let area = area([t[0].x, t[1].x, t[2].x], [t[0].y, t[1].y, t[2].y]);
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
        let z_row = row_depth(&e, [t[0].z, t[1].z, t[2].z], cy);
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

/// Twice the signed area of the triangle with corners `x`, `y` across the map: positive where its
/// winding runs counter-clockwise there, as [`rasterise`] normalises its edge weights by and the placing
/// pass culls by (`shaders/shadow_map.wgsl`'s `area`, the same operations).
#[inline(always)]
pub(super) fn area(x: [f32; 3], y: [f32; 3]) -> f32 {
    (x[1] - x[0]) * (y[2] - y[0]) - (y[1] - y[0]) * (x[2] - x[0])
}

/// [`lane_span`] of the bounds of a triangle's corners' coordinates `c` along one axis.
#[inline(always)]
pub(super) fn lane_bounds(c: [f32; 3], n: usize) -> (i32, i32) {
    lane_span(c[0].min(c[1]).min(c[2]), c[0].max(c[1]).max(c[2]), n)
}

/// The depth at `x = 0` along the row through `cy` of the plane through the corners' depths `z`, by the
/// edge weights `e` (`a x + b y + c` each): the corners' depths blended by the weights' parts that do not
/// change along the row, summed in corner order (as `shaders/shadow_map.wgsl` sums them).
#[inline(always)]
fn row_depth(e: &[(f32, f32, f32); 3], z: [f32; 3], cy: f32) -> f32 {
    ((e[0].1 * cy + e[0].2) * z[0] + (e[1].1 * cy + e[1].2) * z[1]) + (e[2].1 * cy + e[2].2) * z[2]
}

/// Rasterises a band's binned triangles `tris` (corners in texels across the map, `z` their
/// `p · towards`, whose depth is `top − z`) into `out`, rows `row0..` of a `res`-wide map, [`LANES`]
/// at a time: a triangle whose bounds hold at most two texel centres (93% of the covering triangles of
/// the 696k-triangle crowd hold one, 7% two) is tested and its depth computed in lanes, with
/// [`rasterise`]'s operations in its order, and any wider one goes through `rasterise`; the texels are
/// written triangle by triangle in the band's order, so the map is bit for bit `rasterise`'s, one
/// triangle at a time. Branch-free but for the wider triangles: one at a time, each triangle's loops
/// and coverage tests mispredicted so often that the crowd's 164k covering triangles took 47 ns of CPU
/// each, against about 16 in lanes (2-core Intel VM).
#[inline(always)]
pub(super) fn rasterise_band(
    tris: &[[Vec3; 3]],
    top: f32,
    row0: usize,
    res: usize,
    out: &mut [f32],
) {
    for block in tris.chunks(LANES) {
        rasterise_lanes(block, top, row0, res, out);
    }
}

/// [`rasterise_band`] for up to [`LANES`] triangles.
#[inline(always)]
fn rasterise_lanes(block: &[[Vec3; 3]], top: f32, row0: usize, res: usize, out: &mut [f32]) {
    // Lanes past the triangles are NaN and cover nothing. Depth for `z`.
    let mut p = [[[f32::NAN; LANES]; 3]; 3];
    fill_lanes(
        &mut p,
        block,
        #[inline(always)]
        |z| top - z,
    );
    // Per lane, the candidate centres (the bounds' first, and their last where there are two) as the
    // texel each falls in within `out` and the depth to write there (infinite where not covered, into
    // texel 0: no change); and whether the triangle has more candidates than the lanes take.
    let mut at = [[0i32; LANES]; 2];
    let mut depth = [[f32::INFINITY; LANES]; 2];
    let mut wide = [false; LANES];
    let rows = (row0 as i32, (row0 + out.len() / res) as i32 - 1);
    for l in 0..LANES {
        // Indexed in place (no per-lane copies), so the loop runs as vector operations.
        let [x, y, z] = [0, 1, 2].map(|a| [p[0][a][l], p[1][a][l], p[2][a][l]]);
        let (x0, x1) = lane_bounds(x, res);
        let (y0, y1) = lane_bounds(y, res);
        let (y0, y1) = (y0.max(rows.0), y1.min(rows.1));
        let covers = (x0 <= x1) & (y0 <= y1);
        // One candidate, or two side by side: (x0, y0) and (x1, y1).
        let (one, two) = ((x1 - x0) + (y1 - y0) == 0, (x1 - x0) + (y1 - y0) == 1);
        wide[l] = covers & !one & !two;
        let area = (x[1] - x[0]) * (y[2] - y[0]) - (y[1] - y[0]) * (x[2] - x[0]);
        let flat = (area == 0.0) | !area.is_finite() | (area.abs() >= MAX_AREA);
        let per_area = 1.0 / area;
        let coef = |i: usize, j: usize| {
            let (ea, eb) = ((y[i] - y[j]) * per_area, (x[j] - x[i]) * per_area);
            (ea, eb, -(ea * x[i] + eb * y[i]))
        };
        let e = [coef(1, 2), coef(2, 0), coef(0, 1)];
        let dz = e[0].0 * z[0] + e[1].0 * z[1] + e[2].0 * z[2];
        for (k, (i, j), wanted) in [(0, (x0, y0), one | two), (1, (x1, y1), two)] {
            let (cx, cy) = (i as f32 + 0.5, j as f32 + 0.5);
            let inside = (e[0].0 * cx + e[0].1 * cy + e[0].2 >= 0.0)
                & (e[1].0 * cx + e[1].1 * cy + e[1].2 >= 0.0)
                & (e[2].0 * cx + e[2].1 * cy + e[2].2 >= 0.0);
            let hit = covers & wanted & !flat & inside;
            depth[k][l] = if hit {
                dz * cx + row_depth(&e, z, cy)
            } else {
                f32::INFINITY
            };
            at[k][l] = if hit {
                (j - rows.0) * res as i32 + i
            } else {
                0
            };
        }
    }
    for (l, t) in block.iter().enumerate() {
        if wide[l] {
            rasterise(&t.map(|q| q.truncate().extend(top - q.z)), row0, res, out);
            continue;
        }
        for (at, depth) in at.iter().zip(&depth) {
            let d = &mut out[at[l] as usize];
            *d = d.min(depth[l]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec2;
    use rand::{Rng, SeedableRng, rngs::SmallRng};

    /// Rows of the map one worker rasterises at a time, as the map's.
    const BAND_ROWS: usize = super::super::BAND_ROWS;

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

    /// [`rasterise_band`] writes the map [`rasterise`] writes triangle by triangle, bit for bit: tiny
    /// triangles (one or two candidate centres: the lanes) with corners and edges exactly on texel
    /// centres, flat ones, ones past `MAX_AREA`, pairs sharing an edge through a centre, triangles
    /// across band boundaries and off the map, mixed with wider ones (through `rasterise`) in blocks
    /// that leave a partial one.
    #[test]
    fn band_lanes_rasterise_as_one_triangle_at_a_time() {
        let mut r = SmallRng::seed_from_u64(11);
        let res: usize = 80;
        let on_grid = |r: &mut SmallRng, scale: f32| {
            Vec2::new(
                r.random_range(-2..res as i32 + 2) as f32,
                r.random_range(-2..82) as f32,
            ) * scale
                + Vec2::splat(0.5)
        };
        let mut tris = Vec::new();
        for k in 0..6_000 {
            let o = match k % 3 {
                // A corner on a centre, or half a texel off one.
                0 => on_grid(&mut r, 1.0),
                1 => on_grid(&mut r, 1.0) + Vec2::splat(0.5),
                _ => Vec2::new(r.random_range(-3.0..83.0), r.random_range(-3.0..83.0)),
            };
            let size = [0.6, 1.0, 1.4, 2.0, 6.0][k % 5];
            let mut corner = |snap: bool| {
                let d = Vec2::new(r.random_range(-size..size), r.random_range(-size..size));
                let d = if snap { d.round() } else { d };
                (o + d).extend(r.random_range(-5.0..5.0))
            };
            let snap = k % 4 == 0;
            let t = [corner(snap), corner(snap), corner(snap)];
            tris.push(t);
            if k % 7 == 0 {
                // Its neighbour across an edge, which may run through a centre.
                tris.push([t[1], t[0], corner(snap)]);
            }
            if k % 101 == 0 {
                // Flat: a repeated corner, and three on a line.
                tris.push([t[0], t[1], t[0]]);
                let m = (t[0] + t[1]) * 0.5;
                tris.push([t[0], m, t[1]]);
            }
            if k % 503 == 0 {
                // Past `MAX_AREA`, covering nothing (however near the light): over the whole map, and
                // with one candidate centre on it (a corner's), inside.
                tris.push([-1e20, 1e20, 0.0].map(|x| Vec3::new(x, x.abs() - 1e20, 50.0)));
                let corner = [(-1e19, -1e19), (0.9, -1e19), (0.9, 1.4)];
                tris.push(corner.map(|(x, y)| Vec3::new(x, y, 50.0)));
            }
        }
        // A partial block of three at the end.
        tris.truncate(tris.len() / LANES * LANES - LANES + 3);
        // Both ways are taken often: a triangle with one or two candidate centres in a band goes
        // through the lanes, one with more through `rasterise`.
        let mut ways = [0; 2];
        for band in 0..res.div_ceil(BAND_ROWS) {
            let rows = (
                (band * BAND_ROWS) as f32,
                ((band + 1) * BAND_ROWS - 1) as f32,
            );
            for t in &tris {
                let (lo, hi) = (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]));
                let (x, y) = (span(lo.x, hi.x, res), span(lo.y, hi.y, res));
                let y = (y.0.max(rows.0), y.1.min(rows.1));
                if x.0 <= x.1 && y.0 <= y.1 {
                    ways[((x.1 - x.0) + (y.1 - y.0) > 1.0) as usize] += 1;
                }
            }
        }
        assert!(
            ways.iter().all(|&n| n > 1_000),
            "{ways:?}: in lanes, one at a time"
        );
        let top = 2.5;
        let (mut lanes, mut one) = (
            vec![f32::INFINITY; res * res],
            vec![f32::INFINITY; res * res],
        );
        for (band, (a, b)) in (lanes.chunks_mut(BAND_ROWS * res))
            .zip(one.chunks_mut(BAND_ROWS * res))
            .enumerate()
        {
            rasterise_band(&tris, top, band * BAND_ROWS, res, a);
            for t in &tris {
                rasterise(
                    &t.map(|q| q.truncate().extend(top - q.z)),
                    band * BAND_ROWS,
                    res,
                    b,
                );
            }
        }
        let bits = |d: &[f32]| d.iter().map(|d| d.to_bits()).collect::<Vec<_>>();
        assert!(bits(&lanes) == bits(&one), "the lanes' map differs");
        let covered = one.iter().filter(|d| d.is_finite()).count();
        assert!(covered > res * res / 2, "{covered} texels covered");
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
            // Through the lanes (the wider triangles through `rasterise`), corners given as the map's
            // `p · towards` from a top of 0: depth `0 − (−z)`, `z` exactly.
            let binned: Vec<_> = (tris.iter())
                .map(|t| t.map(|v| v.truncate().extend(-v.z)))
                .collect();
            let mut depth = vec![f32::INFINITY; res * res];
            for (band, out) in depth.chunks_mut(BAND_ROWS * res).enumerate() {
                rasterise_band(&binned, 0.0, band * BAND_ROWS, res, out);
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
