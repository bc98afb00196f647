//! `Δ` for every texel of the shadow map at once, before classification: the largest depth difference
//! between a texel and its eight neighbours (thesis §6.3.3), the edge test of every pixel over it.
//!
//! Computed row by row from three rows of the map, a loop the compiler vectorises, it replaces nine
//! scattered reads and eight differences per pixel with one read per pixel: the table holds the depth of
//! each smooth texel (`Δ` at most the edge threshold) and NaN at the others, so most pixels read 4 bytes
//! of it and nothing else, and the few over an edge texel read the depths around them from the map
//! (`ShadowMap::around`). A table of `[depth, Δ]` pairs read twice the bytes at every pixel. A first attempt
//! skipped the test over 8 × 8-texel tiles whose depth range (with a one-texel border) stayed within the
//! edge threshold; it skipped nothing on the crowd, because a receiver plane seen at an angle by the light (the
//! ground under a low sun) changes depth by about a texel per texel, so no tile of it stays within 1.5
//! texels, while each texel's `Δ` does.

use super::ShadowMap;
use crate::parallel;

/// Rows of the map one worker handles at a time.
const ROWS: usize = 16;

/// The largest depth difference between the middle texel of three consecutive rows' three texels (`a`,
/// `b`, `c`: the rows above, through and below) and its eight neighbours. A finite middle depth makes an
/// empty neighbour's difference infinite; an empty middle's difference from an empty neighbour is NaN,
/// which counts as none (so a texel with nothing around it is smooth and empty).
#[inline(always)]
fn delta(a: &[f32], b: &[f32], c: &[f32]) -> f32 {
    let s = b[1];
    // `if d > m { d } else { m }` from 0, not `f32::max`: a NaN `d` leaves `m`, and it is one SIMD
    // instruction where `f32::max` takes four.
    let max = |m: f32, n: f32| {
        let d = (n - s).abs();
        if d > m { d } else { m }
    };
    [a[0], a[1], a[2], b[0], b[2], c[0], c[1], c[2]]
        .into_iter()
        .fold(0.0, max)
}

/// Per texel of the last map, row by row, its depth where it is smooth — `Δ` at most the edge threshold —
/// and NaN where not (on the map's border, where no texel has all eight neighbours, next to an empty
/// texel, at a depth discontinuity); infinite where smooth and empty. Costs one pass over the map, in
/// parallel over bands of rows; kept between frames, so a warm pass of the same resolution does not
/// allocate.
#[derive(Clone, Debug, Default)]
pub(super) struct Deltas {
    res: usize,
    smooth: Vec<f32>,
}

impl Deltas {
    /// Finds the smooth texels of `map`: `Δ` at most `edge`.
    pub(super) fn find(&mut self, map: &ShadowMap, edge: f32, par: bool) {
        let res = map.resolution();
        let depth = map.depths();
        self.res = res;
        self.smooth.resize(res * res, f32::NAN);
        parallel::fill_chunks(par, &mut self.smooth, ROWS * res, |band, out| {
            crate::dispatch::widest(
                #[inline(always)]
                || {
                    for (r, row) in out.chunks_mut(res).enumerate() {
                        let j = band * ROWS + r;
                        if j == 0 || j + 1 == res {
                            row.fill(f32::NAN);
                            continue;
                        }
                        (row[0], row[res - 1]) = (f32::NAN, f32::NAN);
                        let rows = [j - 1, j, j + 1].map(|y| &depth[y * res..(y + 1) * res]);
                        let windows = rows[0]
                            .windows(3)
                            .zip(rows[1].windows(3))
                            .zip(rows[2].windows(3));
                        for (t, ((a, b), c)) in row[1..res - 1].iter_mut().zip(windows) {
                            *t = if delta(a, b, c) <= edge {
                                b[1]
                            } else {
                                f32::NAN
                            };
                        }
                    }
                },
            )
        });
    }

    /// Every texel's [`smooth`](Self::smooth) value, row by row.
    pub(super) fn table(&self) -> &[f32] {
        &self.smooth
    }

    /// Texel `(i, j)`'s depth where it is smooth, else NaN (see [`Deltas`]).
    #[inline]
    pub(super) fn smooth(&self, i: usize, j: usize) -> f32 {
        self.smooth[j * self.res + i]
    }
}
