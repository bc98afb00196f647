//! `Δ` for every texel of the shadow map at once, before classification: the largest depth difference
//! between a texel and its eight neighbours (thesis §6.3.3), the edge test of every pixel over it.
//!
//! Computed row by row from three rows of the map, a loop the compiler vectorises, it replaces nine
//! scattered reads and eight differences per pixel with one read per pixel. A first attempt skipped the
//! test over 8 × 8-texel tiles whose depth range (with a one-texel border) stayed within the edge
//! threshold; it skipped nothing on the crowd, because a receiver plane seen at an angle by the light (the
//! ground under a low sun) changes depth by about a texel per texel, so no tile of it stays within 1.5
//! texels, while each texel's `Δ` does.

use super::ShadowMap;
use crate::parallel;

/// Rows of the map one worker handles at a time.
const ROWS: usize = 16;

/// Per texel of the last map, row by row, its depth and its `Δ` side by side (one cache line serves both
/// reads of a pixel); `Δ` is infinite on the map's border (no texel there has all eight neighbours) and
/// next to an empty texel. Costs one pass over the map, in parallel over bands of rows; kept between
/// frames, so a warm pass of the same resolution does not allocate.
#[derive(Clone, Debug, Default)]
pub(super) struct Deltas {
    res: usize,
    texels: Vec<[f32; 2]>,
}

impl Deltas {
    /// Computes `Δ` for every texel of `map`.
    pub(super) fn find(&mut self, map: &ShadowMap, par: bool) {
        let res = map.resolution();
        let depth = map.depths();
        self.res = res;
        self.texels.resize(res * res, [f32::INFINITY; 2]);
        parallel::fill_chunks(par, &mut self.texels, ROWS * res, |band, out| {
            for (r, row) in out.chunks_mut(res).enumerate() {
                let j = band * ROWS + r;
                for (t, &s) in row.iter_mut().zip(&depth[j * res..(j + 1) * res]) {
                    *t = [s, f32::INFINITY];
                }
                if j == 0 || j + 1 == res {
                    continue;
                }
                let rows = [j - 1, j, j + 1].map(|y| &depth[y * res..(y + 1) * res]);
                let windows = rows[0]
                    .windows(3)
                    .zip(rows[1].windows(3))
                    .zip(rows[2].windows(3));
                for (d, ((a, b), c)) in row[1..res - 1].iter_mut().zip(windows) {
                    let s = b[1];
                    // A finite s makes an empty neighbour's difference infinite, never NaN; over an
                    // empty texel the value is never read.
                    let diff = |n: f32| (n - s).abs();
                    let (top, bottom) = (
                        diff(a[0]).max(diff(a[1])).max(diff(a[2])),
                        diff(c[0]).max(diff(c[1])).max(diff(c[2])),
                    );
                    d[1] = top.max(bottom).max(diff(b[0])).max(diff(b[2]));
                }
            }
        });
    }

    /// Texel `(i, j)`'s depth and `Δ` (meaningful where the texel is interior and its depth finite).
    pub(super) fn at(&self, i: usize, j: usize) -> [f32; 2] {
        self.texels[j * self.res + i]
    }
}
