//! A uniform grid over a mesh's triangles, rebuilt from scratch every frame, with single-ray 3D-DDA and
//! frustum-packet traversal (Wald, Ize, Kensler, Knoll & Parker, "Ray Tracing Animated Scenes using Coherent
//! Grid Traversal", SIGGRAPH 2006; digest 001).
//!
//! **When to use it.** A grid costs one linear pass per frame whatever the motion — explosions, debris,
//! triangle soups that change every frame — where a refitted BVH degrades and a rebuilt one costs a sort.
//! It is at its best for coherent rays (camera tiles, shadow rays toward one light) traced as packets
//! ([`UniformGrid::closest_hits_packet`]), and at its worst when a few triangles are spread over a large box
//! (teapot in a stadium) or for scattered single rays, where the BVH wins.
//!
//! **What it costs.** Build: O(N + refs) with no allocation once the buffers have grown (about λ·N cells of
//! 4 bytes, plus 4 bytes per triangle reference, plus 36 bytes of corners and 12 of cell range per
//! triangle). Query: one cell step per cell crossed, each triangle tested at most once per ray or packet
//! while it stays in the mailbox.
//!
//! **Triangle–cell overlap test** ([`GridOptions::overlap_test`], off by default). Binning by boxes lists a
//! large or diagonal triangle in cells of its box that it never touches; the test keeps only the cells the
//! triangle reaches (within the margin). Measured in `bench grid --quick` (2-core VM, one thread): 19–27% fewer
//! references on the crowd and the 200k surface (2% on the explosion's small triangles), queries 0–16% faster,
//! the build 1.2–2.6× slower. A grid rebuilt every frame and queried by a few thousand rays loses more in the
//! build than it gains in the queries, hence off by default; turn it on for large query batches per build.
//! Under the ECS's planner (`Structure::Auto` with the adaptive policy) it is planned per mesh from the
//! measured rebuild and query seconds ([`Choice::overlap`](crate::adaptive::Choice::overlap)).
//!
//! **Answers.** The same watertight triangle test as the BVH and the same closest-hit rule: smallest `t`, and
//! among triangles hit at exactly that `t` the lowest index the traversal tested. Triangles are binned by
//! their boxes grown by a margin ([`UniformGrid::margin`]) that covers the rounding of the cell walk, so a
//! ray never slips past a triangle at a cell boundary; rays whose origin is so far away that rounding could
//! exceed that margin are answered by testing every triangle (see [`UniformGrid::is_far`]).

mod build;
pub mod choice;
mod dda;
mod packet;

pub use choice::{ChoiceInput, ChoiceReason, StructureChoice, StructureKind, choose_structure};
pub use packet::{MAX_PACKET, PACKET_SPREAD_LIMIT, PACKET_START_CELLS};

use crate::bvh::Hit;
use crate::geometry::Aabb;
use crate::{Error, Result};
use glam::{UVec3, Vec3};

/// Parameters of a [`UniformGrid`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridOptions {
    /// Cells per triangle, λ: the grid has about λ·N cells, shaped like the mesh's box. The paper's optimum
    /// is 5; smaller values build faster and suit very large meshes (paper §4.4).
    pub lambda: f32,
    /// Macrocell edge M in cells: an `M³` block of cells is skipped by packets when all of it is empty.
    /// The paper's value is 6.
    pub macrocell: u32,
    /// Build on all threads (the result is the same either way).
    pub parallel: bool,
    /// Bin a triangle only into the cells it overlaps (a separating-axis test per cell in `f64`, against
    /// the cell grown by the [margin](UniformGrid::margin)) instead of every cell of its box. Fewer
    /// references for large or diagonal triangles, at the price of the test in the build: triangles whose
    /// box is one cell wide on two axes skip it (they reach every cell of their box anyway).
    pub overlap_test: bool,
}

impl Default for GridOptions {
    fn default() -> Self {
        Self {
            lambda: 5.0,
            macrocell: 6,
            parallel: true,
            overlap_test: false,
        }
    }
}

impl GridOptions {
    fn check(&self) -> Result<()> {
        if !(self.lambda.is_finite() && self.lambda > 0.0) {
            return Err(Error::InvalidOption(format!(
                "grid lambda must be finite and positive, got {}",
                self.lambda
            )));
        }
        if self.macrocell == 0 {
            return Err(Error::InvalidOption(
                "grid macrocell must be at least 1".into(),
            ));
        }
        Ok(())
    }
}

/// A uniform grid of cells, each listing the triangles whose (slightly grown) boxes overlap it, in one
/// compact array sorted by cell. See the [module docs](self) for when to use it and what it costs.
///
/// ```
/// use kinetrace::{Mesh, Ray, grid::{GridOptions, UniformGrid}};
/// use glam::Vec3;
/// let mesh = Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![0, 1, 2])?;
/// let mut grid = UniformGrid::build(&mesh, &GridOptions::default())?;
/// let ray = Ray::new(Vec3::new(0.2, 0.2, 1.0), -Vec3::Z);
/// assert_eq!(grid.closest_hit(&ray).map(|h| (h.primitive, h.t)), Some((0, 1.0)));
/// // Next frame: rebuild in place, reusing the buffers.
/// grid.rebuild(&mesh.with_positions(vec![Vec3::Z, Vec3::X + Vec3::Z, Vec3::Y + Vec3::Z])?)?;
/// assert_eq!(grid.closest_hit(&Ray::new(Vec3::new(0.2, 0.2, 3.0), -Vec3::Z)).map(|h| h.t), Some(2.0));
/// # Ok::<(), kinetrace::Error>(())
/// ```
#[derive(Clone, Debug, Default)]
pub struct UniformGrid {
    options: GridOptions,
    /// The grid's box: the mesh's non-degenerate triangles' box grown by the margin (empty for no triangles).
    bounds: Aabb,
    /// Cells per axis (each at least 1).
    res: UVec3,
    /// Cell edge lengths and their reciprocals.
    cell: Vec3,
    inv_cell: Vec3,
    /// How far triangle boxes are grown before binning (see [`UniformGrid::margin`]).
    margin: f32,
    /// Origins farther than this (in the measure of [`UniformGrid::is_far`]) are answered by brute force.
    far_limit: f32,
    /// Corners of each triangle in mesh order; zero-area triangles collapsed to one point, which no ray hits.
    tris: Vec<[Vec3; 3]>,
    /// Each triangle's inclusive cell range, `lo > hi` on x for triangles that are not binned.
    ranges: Vec<[UVec3; 2]>,
    /// `cell_start[c]..cell_start[c + 1]` is cell `c`'s run in `refs`; cells are numbered `x + rx·(y + ry·z)`.
    cell_start: Vec<u32>,
    /// Triangle indices, grouped by cell, ascending within a cell.
    refs: Vec<u32>,
    /// Macrocells per axis and which of them hold any reference.
    macro_res: UVec3,
    macro_full: Vec<bool>,
    /// Per build chunk: its triangles' box and live count, then its reference count (reused scratch).
    chunk_sums: Vec<(Aabb, u64)>,
}

impl UniformGrid {
    /// An empty grid with these options, to [`rebuild`](Self::rebuild) every frame.
    pub fn new(options: GridOptions) -> Result<Self> {
        options.check()?;
        Ok(Self {
            options,
            bounds: Aabb::EMPTY,
            res: UVec3::ONE,
            ..Default::default()
        })
    }

    /// Builds the grid over `mesh`'s triangles. Errors: [`Error::InvalidOption`] for a λ that is not finite
    /// and positive or a zero macrocell size.
    pub fn build(mesh: &crate::Mesh, options: &GridOptions) -> Result<Self> {
        let mut g = Self::new(*options)?;
        g.rebuild(mesh)?;
        Ok(g)
    }

    /// The options the grid was made with.
    pub fn options(&self) -> &GridOptions {
        &self.options
    }

    /// Turns the [triangle–cell overlap test](GridOptions::overlap_test) on or off from the next
    /// [`rebuild`](Self::rebuild) on, keeping the grid's buffers (what a planner that switches it per
    /// frame needs). O(1).
    pub fn set_overlap_test(&mut self, on: bool) {
        self.options.overlap_test = on;
    }

    /// Cells per axis.
    pub fn resolution(&self) -> UVec3 {
        self.res
    }

    /// The grid's box (empty when the mesh has no triangle with area).
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// Number of triangle references over all cells (a triangle counts once per cell it is binned into).
    pub fn reference_count(&self) -> usize {
        self.refs.len()
    }

    /// The triangles binned into cell `c` (ascending), or none for a cell outside the grid.
    pub fn cell_triangles(&self, c: UVec3) -> &[u32] {
        if c.cmpge(self.res).any() || self.cell_start.is_empty() {
            return &[];
        }
        self.cell_refs(self.cell_index(c))
    }

    /// Number of triangles the grid was built over.
    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }

    /// How far every triangle's box is grown before binning: 1% of the smallest cell edge plus 32 units of
    /// rounding (`f32::EPSILON`) of the grid's largest coordinate and diagonal. It bounds the rounding error
    /// of the cell walk and of the triangle test for every ray that is not [far](Self::is_far).
    pub fn margin(&self) -> f32 {
        self.margin
    }

    /// True when a ray from `origin` is so far from the grid that the rounding of its walk could exceed the
    /// [margin](Self::margin) (more than about 10⁴ cells away); such rays test every triangle instead.
    #[inline]
    pub fn is_far(&self, origin: Vec3) -> bool {
        origin.abs().max_element() + (origin - self.bounds.center()).length() > self.far_limit
    }

    /// The cell `c` of `p` on every axis, clamped into the grid: `floor` of the cell coordinate, taken as
    /// the truncation of its non-negative part (the same cells; `floor` is a library call on baseline
    /// x86-64 and was a sixth of the build).
    #[inline]
    fn cell_of(&self, p: Vec3) -> UVec3 {
        let c = (p - self.bounds.min) * self.inv_cell;
        c.max(Vec3::ZERO).as_uvec3().min(self.res - 1)
    }

    /// Linear index of cell `c`.
    #[inline]
    fn cell_index(&self, c: UVec3) -> usize {
        (c.x + self.res.x * (c.y + self.res.y * c.z)) as usize
    }

    /// The triangles of cell `i`.
    #[inline]
    fn cell_refs(&self, i: usize) -> &[u32] {
        &self.refs[self.cell_start[i] as usize..self.cell_start[i + 1] as usize]
    }

    /// The hit record for triangle `p` (normal as the BVH computes it).
    #[inline]
    fn hit(&self, t: f32, p: u32, u: f32, v: f32) -> Hit {
        let [a, b, c] = self.tris[p as usize];
        Hit {
            t,
            primitive: p,
            u,
            v,
            normal: (b - a).cross(c - a).normalize_or_zero(),
        }
    }
}

/// A direct-mapped cache of the triangles a ray or packet has tested (mailboxing, paper §3.3): a triangle
/// found here is not tested again. A collision only costs a repeated test, never a missed one.
struct Mailbox<const N: usize>([u32; N]);

impl<const N: usize> Mailbox<N> {
    fn new() -> Self {
        Self([u32::MAX; N])
    }

    /// True when `p` was seen; records it otherwise.
    #[inline]
    fn seen(&mut self, p: u32) -> bool {
        let slot = &mut self.0[p as usize % N];
        let seen = *slot == p;
        *slot = p;
        seen
    }
}
