//! Continuous collision of meshes: a tree over each triangle's swept box between last frame's and this
//! frame's vertex positions, traversed like the discrete trees, with the 15 elementary tests of
//! [`ccd::triangle_pair_toi`] on the overlapping leaves (thesis §6.2.3).

use super::bvtt::{Bvtt, PairStats};
use super::ccd::{self, Feature};
use super::narrow::{NarrowPhase, slot_pairs};
use super::{PairQuery, run};
use crate::bvh::{BuildOptions, Bvh, Node, next_topology_id, refit_nodes, slot_indices};
use crate::geometry::Aabb;
use crate::mesh::check_positions;
use crate::{Error, Mesh, Result};
use glam::{Affine3A, Vec3};

/// The first contact of two moving triangles within the frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Impact {
    /// Triangle of the first mesh (for a mesh against itself, the smaller index).
    pub triangle_a: u32,
    /// Triangle of the second mesh.
    pub triangle_b: u32,
    /// When, as a fraction of the frame: 0 at last frame's positions, 1 at this frame's.
    pub t: f32,
    /// Which vertex–face or edge–edge test found it (relative to `triangle_a` and `triangle_b`).
    pub feature: Feature,
    /// Where, at time `t`, in the frame the positions were given in.
    pub point: Vec3,
}

/// A mesh's motion over one frame, for continuous collision queries: its triangles at the last and the
/// current positions (both in world space, so that rigid motion is swept too) and a tree over the boxes
/// that hold both.
///
/// Build once; each frame call [`update`](Self::update) with the new pair of positions (a refit: O(n), no
/// allocation). Memory: 72 bytes of corners and 12 of indices per triangle, plus the tree.
#[derive(Clone, Debug)]
pub struct SweptMesh {
    bvh: Bvh,
    /// Corners at the start and the end of the frame, per slot.
    tris: Vec<[[Vec3; 3]; 2]>,
    slot_indices: Vec<[u32; 3]>,
    vertex_count: usize,
    topology: u64,
}

impl SweptMesh {
    /// The swept tree of `mesh`'s triangles moving from `prev` to `curr` (vertex positions, as many as the
    /// mesh has).
    ///
    /// Errors: [`Error::VertexCountMismatch`] or [`Error::NonFiniteVertex`] for bad positions, and the
    /// build's errors.
    pub fn build(
        mesh: &Mesh,
        prev: &[Vec3],
        curr: &[Vec3],
        options: &BuildOptions,
    ) -> Result<Self> {
        let n = mesh.positions().len();
        check(n, prev)?;
        check(n, curr)?;
        let boxes: Vec<Aabb> = mesh
            .indices()
            .chunks_exact(3)
            .map(|t| swept_box(&[t[0], t[1], t[2]], prev, curr))
            .collect();
        let bvh = Bvh::build(&boxes, options)?;
        let slot_indices = slot_indices(&bvh, mesh.indices());
        let tris = slot_indices
            .iter()
            .map(|t| corners(t, prev, curr))
            .collect();
        Ok(SweptMesh {
            bvh,
            tris,
            slot_indices,
            vertex_count: n,
            topology: next_topology_id(),
        })
    }

    /// Moves to the next frame's motion, from `prev` to `curr` (usually last call's `curr` and the new
    /// positions), refitting the tree; returns its degradation metric (see [`Bvh::refit`]).
    ///
    /// Errors: as [`build`](Self::build); the tree is then unchanged.
    pub fn update(&mut self, prev: &[Vec3], curr: &[Vec3]) -> Result<f32> {
        check(self.vertex_count, prev)?;
        check(self.vertex_count, curr)?;
        let (tris, idx) = (&mut self.tris, &self.slot_indices);
        Ok(refit_nodes(self.bvh.nodes_mut(), |slot| {
            tris[slot] = corners(&idx[slot], prev, curr);
            swept_box(&idx[slot], prev, curr).lanes()
        }))
    }

    /// The tree over the swept boxes.
    pub fn bvh(&self) -> &Bvh {
        &self.bvh
    }

    /// Changes with every build, stays through updates (see [`crate::MeshBvh::topology_id`]).
    pub fn topology_id(&self) -> u64 {
        self.topology
    }
}

fn check(expected: usize, positions: &[Vec3]) -> Result<()> {
    if positions.len() != expected {
        return Err(Error::VertexCountMismatch {
            expected,
            got: positions.len(),
        });
    }
    check_positions(positions)
}

fn corners(t: &[u32; 3], prev: &[Vec3], curr: &[Vec3]) -> [[Vec3; 3]; 2] {
    [t.map(|i| prev[i as usize]), t.map(|i| curr[i as usize])]
}

/// The box of a triangle at both ends of the frame: with linear motion, it holds the triangle at every
/// time in between.
fn swept_box(t: &[u32; 3], prev: &[Vec3], curr: &[Vec3]) -> Aabb {
    let [a, b] = corners(t, prev, curr);
    Aabb::from_triangle(a[0], a[1], a[2]).union(&Aabb::from_triangle(b[0], b[1], b[2]))
}

/// Continuous tests of two swept meshes, or of one against itself.
struct Continuous<'a> {
    a: &'a SweptMesh,
    b: &'a SweptMesh,
    itself: bool,
}

impl NarrowPhase for Continuous<'_> {
    type Out = Impact;

    #[inline]
    fn leaves(
        &self,
        la: &Node,
        lb: &Node,
        same: bool,
        stats: &mut PairStats,
        out: &mut Vec<Impact>,
    ) {
        let (pa, pb) = (self.a.bvh.prim_indices(), self.b.bvh.prim_indices());
        let itself = self.itself.then_some((&self.a.slot_indices[..], pa));
        slot_pairs(la, lb, same, itself, stats, |sa, sb| {
            if let Some(hit) = ccd::triangle_pair_toi(&self.a.tris[sa], &self.b.tris[sb]) {
                out.push(Impact {
                    triangle_a: pa[sa],
                    triangle_b: pb[sb],
                    t: hit.t,
                    feature: hit.feature,
                    point: hit.point,
                });
            }
        });
    }

    #[inline]
    fn key(i: &Impact) -> (u32, u32) {
        (i.triangle_a, i.triangle_b)
    }
}

impl PairQuery {
    /// First contacts between the moving triangles of `a` and `b` within the frame (one per touching
    /// pair, the earliest of its 15 elementary tests), written to `out` sorted by triangle pair.
    ///
    /// Cost: the traversal of the swept trees plus 15 cubic root isolations per pair of triangles in
    /// overlapping leaves — several times a discrete query; use it for what moves fast enough to tunnel.
    pub fn swept(&mut self, a: &SweptMesh, b: &SweptMesh, out: &mut Vec<Impact>) -> PairStats {
        let bvtt = Bvtt::pair(a.bvh.nodes(), b.bvh.nodes(), &Affine3A::IDENTITY);
        let narrow = Continuous {
            a,
            b,
            itself: false,
        };
        self.impacts_of(&bvtt, &narrow, (a.topology, b.topology), out)
    }

    /// First contacts between non-adjacent moving triangles of one mesh (triangles sharing a vertex are
    /// skipped), `triangle_a < triangle_b`.
    pub fn swept_itself(&mut self, m: &SweptMesh, out: &mut Vec<Impact>) -> PairStats {
        let bvtt = Bvtt::itself(m.bvh.nodes());
        let narrow = Continuous {
            a: m,
            b: m,
            itself: true,
        };
        self.impacts_of(&bvtt, &narrow, (m.topology, m.topology), out)
    }

    fn impacts_of(
        &mut self,
        bvtt: &Bvtt<'_>,
        narrow: &Continuous<'_>,
        trees: (u64, u64),
        out: &mut Vec<Impact>,
    ) -> PairStats {
        let (parallel, starts, chunks) = (self.parallel, &mut self.starts, &mut self.impacts);
        run(parallel, starts, chunks, bvtt, narrow, trees, None, out)
    }
}
