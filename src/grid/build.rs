//! Per-frame grid build: resolution from λ, triangles binned by their grown boxes (optionally only into the
//! cells they overlap), a counting sort into one compact cell → triangle array, macrocell occupancy.
//!
//! The counting sort runs over slabs of z-layers of cells, one slab per task: every task reads all
//! triangles' cell ranges and counts (then writes) only its own cells, so no two tasks touch the same cell,
//! no atomics are needed, and the result does not depend on the thread count. Buffers are kept between
//! frames: once they have grown to the largest mesh seen, a rebuild allocates nothing.

use super::UniformGrid;
use crate::bvh::{is_collapsed, query_corners};
use crate::geometry::Aabb;
use crate::{Mesh, Result, parallel};
use glam::{DVec3, UVec3, Vec3};

/// Largest number of cells on one axis.
pub const MAX_RESOLUTION: u32 = 1024;

/// The build lowers λ (by 4× per try) until the references are at most this many per triangle, which bounds
/// the grid's memory for inputs where many large triangles overlap most cells.
pub const MAX_REFS_PER_TRIANGLE: u64 = 32;

/// Triangles per parallel task for the per-triangle passes.
const CHUNK: usize = 4096;

impl UniformGrid {
    /// Rebuilds the grid over `mesh` (any triangle count, any positions), reusing the buffers: no allocation
    /// once they have grown. O(N + cells + references).
    pub fn rebuild(&mut self, mesh: &Mesh) -> Result<()> {
        self.rebuild_from(mesh.indices(), mesh.positions())
    }

    /// [`rebuild`](Self::rebuild) over `mesh`'s triangles at new vertex `positions` (a deformed frame),
    /// without making a new [`Mesh`]: what the ECS does every frame for a mesh kept as a grid. Same cost, no
    /// allocation once warm. Errors: [`Error::VertexCountMismatch`](crate::Error::VertexCountMismatch) when
    /// `positions` is not as long as the mesh's, [`Error::NonFiniteVertex`](crate::Error::NonFiniteVertex);
    /// the grid is unchanged then.
    pub fn rebuild_deformed(&mut self, mesh: &Mesh, positions: &[Vec3]) -> Result<()> {
        if positions.len() != mesh.positions().len() {
            return Err(crate::Error::VertexCountMismatch {
                expected: mesh.positions().len(),
                got: positions.len(),
            });
        }
        crate::mesh::check_positions(positions)?;
        self.rebuild_from(mesh.indices(), positions)
    }

    /// The rebuild over checked `indices` into checked `positions`.
    fn rebuild_from(&mut self, indices: &[u32], positions: &[Vec3]) -> Result<()> {
        self.options.check()?;
        let par = self.options.parallel;
        let n = indices.len() / 3;
        self.tris.resize(n, [Vec3::ZERO; 3]);
        // One pass writes the corners and gathers each chunk's box and live count (reduced in chunk order).
        self.chunk_sums
            .resize(n.div_ceil(CHUNK).max(1), (Aabb::EMPTY, 0));
        parallel::fill_chunks_with(
            par,
            &mut self.tris,
            CHUNK,
            &mut self.chunk_sums,
            |c, ts, sum| {
                let (mut b, mut k) = (Aabb::EMPTY, 0);
                for (j, t) in ts.iter_mut().enumerate() {
                    *t = query_corners(crate::mesh::triangle(positions, indices, c * CHUNK + j));
                    if !is_collapsed(t) {
                        b = b.union(&Aabb::from_triangle(t[0], t[1], t[2]));
                        k += 1;
                    }
                }
                *sum = (b, k);
            },
        );
        let (box_, live) = self.chunk_sums[..n.div_ceil(CHUNK)]
            .iter()
            .fold((Aabb::EMPTY, 0u64), |(a, i), (b, j)| (a.union(b), i + j));
        let mut lambda = self.options.lambda as f64;
        let mut before = None;
        loop {
            self.set_resolution(&box_, lambda * live as f64);
            let refs = self.bin();
            // Stop once within the bound, or when a smaller budget no longer changes the grid.
            if refs <= MAX_REFS_PER_TRIANGLE * live
                || self.res == UVec3::ONE
                || before == Some(self.res)
            {
                break;
            }
            before = Some(self.res);
            lambda *= 0.25;
        }
        self.sort();
        self.mark_macrocells();
        Ok(())
    }

    /// Chooses cells per axis (about `cells` in all, shaped like `b`), the grid box, the margin and the far
    /// limit. An empty `b` gives one cell and an empty box.
    fn set_resolution(&mut self, b: &Aabb, cells: f64) {
        if b.is_empty() {
            self.bounds = Aabb::EMPTY;
            self.res = UVec3::ONE;
            self.cell = Vec3::ZERO;
            self.inv_cell = Vec3::ZERO;
            self.margin = 0.0;
            self.far_limit = f32::INFINITY;
            return;
        }
        // Flat boxes get a thickness of 1/1000 of their longest edge, so the volume is never zero; in f64,
        // where the volume of any finite f32 box neither overflows nor underflows.
        let e = b.extent().as_dvec3();
        let e = e.max(DVec3::splat(e.max_element() * 1e-3));
        self.res = cells_per_axis(e, cells);
        let half = e.as_vec3() * 0.5;
        let c = b.center();
        let cell = (half * 2.0) / self.res.as_vec3();
        let scale = c.abs().max_element() + half.max_element() * 2.0 + half.length() * 2.0;
        self.margin = 0.01 * cell.min_element() + 32.0 * f32::EPSILON * scale;
        self.far_limit = self.margin / (8.0 * f32::EPSILON);
        self.bounds = Aabb::new(c - half - self.margin, c + half + self.margin);
        self.cell = self.bounds.extent() / self.res.as_vec3();
        self.inv_cell = self.res.as_vec3() / self.bounds.extent();
    }

    /// Each triangle's cell range (its box grown by the margin); returns the total number of references
    /// (summed per chunk in the same pass, then in chunk order).
    fn bin(&mut self) -> u64 {
        let par = self.options.parallel;
        let n = self.tris.len();
        self.ranges.resize(n, [UVec3::ONE, UVec3::ZERO]);
        let mut ranges = std::mem::take(&mut self.ranges);
        let mut sums = std::mem::take(&mut self.chunk_sums);
        let (grid, m) = (&*self, self.margin);
        parallel::fill_chunks_with(par, &mut ranges, CHUNK, &mut sums, |c, rs, sum| {
            let mut refs = 0;
            for (r, t) in rs.iter_mut().zip(&grid.tris[c * CHUNK..]) {
                *r = if is_collapsed(t) || grid.bounds.is_empty() {
                    [UVec3::ONE, UVec3::ZERO]
                } else {
                    let b = Aabb::from_triangle(t[0], t[1], t[2]);
                    [grid.cell_of(b.min - m), grid.cell_of(b.max + m)]
                };
                refs += range_cells(r);
            }
            sum.1 = refs;
        });
        let total = sums[..n.div_ceil(CHUNK)].iter().map(|s| s.1).sum();
        self.ranges = ranges;
        self.chunk_sums = sums;
        total
    }

    /// The counting sort: per-cell counts, prefix sums (each cell's end), then triangles written in reverse
    /// order at their cells' ends, leaving each cell's start behind and its triangles ascending.
    fn sort(&mut self) {
        let par = self.options.parallel;
        let (rx, ry, rz) = (self.res.x, self.res.y, self.res.z);
        let sxy = (rx * ry) as usize;
        let cells = sxy * rz as usize;
        // Taken out while the passes read the rest of the grid; put back at the end (no allocation).
        let mut cell_start = std::mem::take(&mut self.cell_start);
        let mut refs = std::mem::take(&mut self.refs);
        cell_start.clear();
        cell_start.resize(cells + 1, 0);
        let grid = &*self;
        let slab_grain = (rz as usize / (2 * parallel::threads())).max(1) as u32;
        let starts = &mut cell_start[..cells];
        for_slabs(
            par,
            slab_grain,
            0,
            rz,
            sxy,
            starts,
            &mut [],
            0,
            &|z0, z1, counts, _, _| {
                for (t, r) in grid.ranges.iter().enumerate() {
                    grid.each_binned_cell(t, r, z0, z1, |c| counts[c] += 1);
                }
            },
        );
        let mut sum = 0u32;
        for c in starts.iter_mut() {
            sum += *c;
            *c = sum;
        }
        cell_start[cells] = sum;
        // Every entry is written below: only entries past the old length need a value.
        refs.resize(sum as usize, 0);
        for_slabs(
            par,
            slab_grain,
            0,
            rz,
            sxy,
            &mut cell_start[..cells],
            &mut refs,
            0,
            &|z0, z1, ends, refs, base| {
                for (t, r) in grid.ranges.iter().enumerate().rev() {
                    grid.each_binned_cell(t, r, z0, z1, |c| {
                        ends[c] -= 1;
                        refs[(ends[c] - base) as usize] = t as u32;
                    });
                }
            },
        );
        self.cell_start = cell_start;
        self.refs = refs;
    }

    /// Calls `f` with the slab-local index of every cell of triangle `t`'s range `r` in z-layers `z0..z1`
    /// that the triangle is binned into: every cell of the range, or with
    /// [`GridOptions::overlap_test`](super::GridOptions::overlap_test) only the cells it overlaps.
    #[inline]
    fn each_binned_cell(&self, t: usize, r: &[UVec3; 2], z0: u32, z1: u32, f: impl FnMut(usize)) {
        let (rx, sxy) = (self.res.x, (self.res.x * self.res.y) as usize);
        if !(self.options.overlap_test && needs_overlap_test(r)) || r[1].z < z0 || r[0].z >= z1 {
            return each_cell(r, z0, z1, rx, sxy, |_| true, f);
        }
        // Half a cell grown by the margin, plus 1/1024 of it so that `f64` rounding in the test (about
        // 1e-15 of the coordinates, against a margin of at least 4e-6 of them) can never drop a cell the
        // triangle reaches within the margin.
        let cell = self.cell.as_dvec3();
        let half = cell * 0.5 + f64::from(self.margin) * (1.0 + 1.0 / 1024.0);
        let origin = self.bounds.min.as_dvec3() + cell * 0.5;
        let sat = CellSat::new(&self.tris[t], half);
        each_cell(
            r,
            z0,
            z1,
            rx,
            sxy,
            |c| sat.overlaps(origin + c.as_dvec3() * cell),
            f,
        );
    }

    /// Which `M³` blocks of cells hold any reference: per row of cells, one comparison of the prefix sums
    /// at the ends of each run of `M` cells (a run holds references exactly when they differ).
    fn mark_macrocells(&mut self) {
        let m = self.options.macrocell;
        let (r, mr) = (self.res, (self.res + (m - 1)) / m);
        self.macro_res = mr;
        self.macro_full.clear();
        self.macro_full.resize((mr.x * mr.y * mr.z) as usize, false);
        for z in 0..r.z {
            for y in 0..r.y {
                let row = self.cell_index(UVec3::new(0, y, z));
                let block = (mr.x * (y / m + mr.y * (z / m))) as usize;
                for mx in 0..mr.x {
                    let (x0, x1) = (mx * m, ((mx + 1) * m).min(r.x));
                    if self.cell_start[row + x1 as usize] > self.cell_start[row + x0 as usize] {
                        self.macro_full[block + mx as usize] = true;
                    }
                }
            }
        }
    }
}

/// The separating-axis test of one triangle against equal axis-aligned boxes at many centres
/// (Akenine-Möller 2001), with everything that does not depend on the centre computed once: per axis the
/// triangle's projected interval and the box's projected radius. The box's own three axes are left out:
/// the cells tested come from the triangle's grown box, so those axes separate nothing that matters (a
/// cell they would drop is only kept, never lost).
struct CellSat {
    /// The triangle's normal and the nine cross products of its edges with the coordinate axes.
    axes: [DVec3; 10],
    /// Per axis: the triangle's projection interval, grown by the box's projected radius.
    lo: [f64; 10],
    hi: [f64; 10],
}

impl CellSat {
    fn new(t: &[Vec3; 3], half: DVec3) -> Self {
        let v = t.map(Vec3::as_dvec3);
        let e = [v[1] - v[0], v[2] - v[1], v[0] - v[2]];
        let mut axes = [e[0].cross(e[1]); 10];
        for (i, a) in [DVec3::X, DVec3::Y, DVec3::Z].into_iter().enumerate() {
            for (j, e) in e.iter().enumerate() {
                axes[1 + 3 * i + j] = a.cross(*e);
            }
        }
        let (mut lo, mut hi) = ([0.0; 10], [0.0; 10]);
        for (k, a) in axes.iter().enumerate() {
            let p = v.map(|x| x.dot(*a));
            let r = half.dot(a.abs());
            lo[k] = p[0].min(p[1]).min(p[2]) - r;
            hi[k] = p[0].max(p[1]).max(p[2]) + r;
        }
        Self { axes, lo, hi }
    }

    /// Whether the triangle and the box centred at `c` overlap on every axis (a vanishing axis has a
    /// zero-width interval around 0 and never separates).
    #[inline]
    fn overlaps(&self, c: DVec3) -> bool {
        (0..10).all(|k| {
            let d = self.axes[k].dot(c);
            self.lo[k] <= d && d <= self.hi[k]
        })
    }
}

/// Cells per axis for a box of extent `e` (all positive) and a budget of about `cells`: the same edge length
/// on every axis, `(cells / volume)^(1/3)` per unit. An axis thinner than one cell gets one cell and the
/// budget is spread over the others again, so a flat box of `cells` cells is `√cells × √cells × 1`, not a
/// grid sized for a thickness it does not have. Each axis has 1 to [`MAX_RESOLUTION`] cells.
fn cells_per_axis(e: DVec3, cells: f64) -> UVec3 {
    let cells = cells.max(1.0);
    let mut free = [true; 3];
    loop {
        let dims = free.iter().filter(|&&f| f).count();
        if dims == 0 {
            return UVec3::ONE;
        }
        let volume: f64 = (0..3).filter(|&i| free[i]).map(|i| e[i]).product();
        let k = (cells / volume).powf(1.0 / dims as f64);
        let thin = std::array::from_fn::<bool, 3, _>(|i| free[i] && e[i] * k < 1.0);
        if thin == [false; 3] {
            let res = DVec3::from_array(std::array::from_fn(
                |i| if free[i] { e[i] * k } else { 1.0 },
            ));
            return res
                .round()
                .clamp(DVec3::ONE, DVec3::splat(MAX_RESOLUTION as f64))
                .as_uvec3();
        }
        for i in 0..3 {
            free[i] &= !thin[i];
        }
    }
}

/// Number of cells in an inclusive cell range (0 for an unbinned triangle).
#[inline]
fn range_cells(r: &[UVec3; 2]) -> u64 {
    if r[0].x > r[1].x {
        return 0;
    }
    let d = (r[1] - r[0] + 1).as_u64vec3();
    d.x * d.y * d.z
}

/// Whether a triangle binned into cell range `r` can miss some of its cells: only when the range is more
/// than one cell wide on at least two axes. A range one cell wide on two axes is a column of cells, and a
/// triangle (connected, spanning its box on the third axis) reaches every cell of its column.
#[inline]
fn needs_overlap_test(r: &[UVec3; 2]) -> bool {
    let wide = r[1].cmpgt(r[0]);
    (wide.x as u8 + wide.y as u8 + wide.z as u8) >= 2
}

/// Calls `f` with the slab-local index of every cell of range `r` in z-layers `z0..z1` (`sxy` cells a layer)
/// for which `keep` (given the cell's coordinates) holds.
#[inline]
fn each_cell(
    r: &[UVec3; 2],
    z0: u32,
    z1: u32,
    rx: u32,
    sxy: usize,
    mut keep: impl FnMut(UVec3) -> bool,
    mut f: impl FnMut(usize),
) {
    let (lo, hi) = (r[0], r[1]);
    if lo.x > hi.x || hi.z < z0 || lo.z >= z1 {
        return;
    }
    // Exclusive ranges and running indices: an inclusive range's exhaustion flag was a visible share of
    // the build (callgrind).
    let mut layer = (lo.z.max(z0) - z0) as usize * sxy + (lo.y * rx + lo.x) as usize;
    for z in lo.z.max(z0)..hi.z.min(z1 - 1) + 1 {
        let mut row = layer;
        for y in lo.y..hi.y + 1 {
            for (i, x) in (lo.x..hi.x + 1).enumerate() {
                if keep(UVec3::new(x, y, z)) {
                    f(row + i);
                }
            }
            row += rx as usize;
        }
        layer += sxy;
    }
}

/// Runs `f(z0, z1, starts, refs, base)` over slabs of at most `grain` z-layers, in parallel when asked.
/// `starts` holds the slab's cells; `refs`, when not empty, the slab's references, which begin at absolute
/// position `base`, and `starts` then holds each cell's end (so a slab's references end at its last cell's).
#[allow(clippy::too_many_arguments)]
fn for_slabs<F>(
    par: bool,
    grain: u32,
    z0: u32,
    z1: u32,
    sxy: usize,
    starts: &mut [u32],
    refs: &mut [u32],
    base: u32,
    f: &F,
) where
    F: Fn(u32, u32, &mut [u32], &mut [u32], u32) + Sync,
{
    if !par || z1 - z0 <= grain {
        f(z0, z1, starts, refs, base);
        return;
    }
    let mid = (z0 + z1) / 2;
    let (sa, sb) = starts.split_at_mut((mid - z0) as usize * sxy);
    let cut = if refs.is_empty() {
        0
    } else {
        sa.last().map_or(base, |&e| e) - base
    };
    let (ra, rb) = refs.split_at_mut(cut as usize);
    parallel::join(
        true,
        || for_slabs(par, grain, z0, mid, sxy, sa, ra, base, f),
        || for_slabs(par, grain, mid, z1, sxy, sb, rb, base + cut, f),
    );
}
