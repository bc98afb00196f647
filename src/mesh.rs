//! Validated triangle meshes.

use crate::bvh::MAX_PRIMITIVES;
use crate::geometry::Aabb;
use crate::{Error, Result};
use glam::Vec3;
use std::sync::{Arc, OnceLock};

/// An indexed triangle mesh whose input has been checked: every coordinate finite, every index in range,
/// whole triangles only. Degenerate triangles (repeated or collinear vertices) are legal.
///
/// Positions and indices sit behind `Arc`s, so cloning a mesh is cheap and meshes can be shared between
/// entities and threads.
///
/// ```
/// use kinetrace::{Mesh, Error};
/// use glam::Vec3;
/// let mesh = Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![0, 1, 2])?;
/// assert_eq!(mesh.triangle_count(), 1);
/// let bad = Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![0, 1, 3]);
/// assert!(matches!(bad, Err(Error::IndexOutOfRange { position: 2, index: 3, .. })));
/// # Ok::<(), Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct Mesh {
    positions: Arc<[Vec3]>,
    indices: Arc<[u32]>,
    /// Identity of the topology: fresh for every [`Mesh::new`], kept by clones and
    /// [`Mesh::with_positions`].
    topology: u64,
    /// [`Mesh::is_closed`], found once per topology (shared as `topology` is).
    closed: Arc<OnceLock<bool>>,
}

/// Source of [`Mesh::topology`] identities (never reused, unlike an index buffer's address).
static NEXT_TOPOLOGY: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

impl Mesh {
    /// Checks and wraps `positions` and `indices` (three per triangle, counter-clockwise is not required).
    ///
    /// Errors name the first offending entry: [`Error::NonFiniteVertex`], [`Error::IndexOutOfRange`],
    /// [`Error::IndexCountNotMultipleOfThree`], [`Error::TooManyPrimitives`]. No positions and no indices
    /// make an empty mesh, which every query misses; triangles that repeat an index or have collinear
    /// corners are kept and never hit.
    ///
    /// Any finite coordinate is accepted, but ray queries are exact (watertight, matching brute force)
    /// only while coordinates relative to the ray's origin stay below about 1e18: the triangle test
    /// multiplies two of them, and past `sqrt(f32::MAX)` ≈ 1.8e19 the products overflow. Beyond that a
    /// ray may miss a triangle it touches; it never reports one it does not (`tests/bad_input.rs`).
    /// Closest-point, shape-cast and containment queries decide in `f64` and stay exact there (tested at
    /// 1e30).
    pub fn new(positions: impl Into<Arc<[Vec3]>>, indices: impl Into<Arc<[u32]>>) -> Result<Self> {
        let positions = positions.into();
        let indices = indices.into();
        check_positions(&positions)?;
        check_indices(&indices, positions.len())?;
        let topology = NEXT_TOPOLOGY.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        Ok(Self {
            positions,
            indices,
            topology,
            closed: Arc::default(),
        })
    }

    /// Vertex positions.
    pub fn positions(&self) -> &[Vec3] {
        &self.positions
    }

    /// Triangle indices, three per triangle.
    pub fn indices(&self) -> &[u32] {
        &self.indices
    }

    /// Identity of this mesh's topology: the same for clones and [`with_positions`](Self::with_positions)
    /// copies, different for every mesh made by [`Mesh::new`] (ids are never reused).
    pub(crate) fn topology(&self) -> u64 {
        self.topology
    }

    /// The shared index buffer.
    pub(crate) fn indices_arc(&self) -> Arc<[u32]> {
        self.indices.clone()
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// The three corners of triangle `i`.
    #[inline]
    pub fn triangle(&self, i: usize) -> [Vec3; 3] {
        triangle(&self.positions, &self.indices, i)
    }

    /// A copy of this mesh with new vertex positions (same topology), checked for finiteness.
    pub fn with_positions(&self, positions: impl Into<Arc<[Vec3]>>) -> Result<Self> {
        let positions = positions.into();
        if positions.len() != self.positions.len() {
            return Err(Error::VertexCountMismatch {
                expected: self.positions.len(),
                got: positions.len(),
            });
        }
        check_positions(&positions)?;
        Ok(Self {
            positions,
            indices: self.indices.clone(),
            topology: self.topology,
            closed: self.closed.clone(),
        })
    }

    /// Whether the mesh is a closed surface facing outwards: every edge of a triangle (corners in index
    /// order) is met exactly once more, the other way round, in another triangle; no triangle repeats an
    /// index; and each part — the triangles joined through their edges — encloses a positive volume by
    /// its winding. Several closed parts (interpenetrating or not, as a character made of capsules) are
    /// one closed surface, but one part turned inside out, or a hollow shell, is not. Edges pair by
    /// index only: copies of a vertex at one position (a seam, a hard edge, a closed mouth) leave the
    /// mesh open, since a deformation may pull them apart. A line from outside first crosses a closed
    /// surface at a triangle whose winding faces where the line comes from, which lets a shadow map
    /// leave out the triangles facing away from the light
    /// ([`Occluders::closed`](crate::shadows::Occluders::closed)).
    ///
    /// Found at the first call, once per topology: clones and [`with_positions`](Self::with_positions)
    /// copies share the answer, the volumes' signs taken from the positions of the first copy asked
    /// (posing or skinning does not turn a surface inside out; mirror a mesh through its transform, not
    /// its positions). One sort of the edges, 16 bytes an edge, and a union–find over the triangles:
    /// about 0.2 s a million triangles on one core (an icosphere of 1.3M: 244 ms on a 2-core Intel VM).
    ///
    /// ```
    /// use kinetrace::scenes;
    /// assert!(scenes::icosphere(2).is_closed());
    /// assert!(!scenes::folded_sheet(8, 0.0).is_closed()); // an open sheet
    /// ```
    pub fn is_closed(&self) -> bool {
        *self
            .closed
            .get_or_init(|| closed_outwards(&self.positions, &self.indices))
    }

    /// Bounds of every triangle, in triangle order.
    pub fn triangle_bounds(&self) -> Vec<Aabb> {
        (0..self.triangle_count())
            .map(|i| {
                let [a, b, c] = self.triangle(i);
                Aabb::from_triangle(a, b, c)
            })
            .collect()
    }
}

/// Corners of triangle `i` of an index buffer that has already been checked.
#[inline]
pub(crate) fn triangle(positions: &[Vec3], indices: &[u32], i: usize) -> [Vec3; 3] {
    let t = &indices[3 * i..3 * i + 3];
    [
        positions[t[0] as usize],
        positions[t[1] as usize],
        positions[t[2] as usize],
    ]
}

/// [`Mesh::is_closed`] for an index buffer that has already been checked: every edge met exactly twice,
/// once each way, by triangles that repeat no index, and each part (triangles joined through their
/// edges) enclosing a positive signed volume (summed in `f64` about one of its corners). One sort of
/// the edges and a union–find over the triangles.
fn closed_outwards(positions: &[Vec3], indices: &[u32]) -> bool {
    if indices.is_empty() {
        return false;
    }
    // Each edge as its two corners, lower first, and its triangle with the edge's way in the top bit.
    let mut edges = Vec::with_capacity(indices.len());
    for (i, t) in indices.chunks_exact(3).enumerate() {
        if t[0] == t[1] || t[1] == t[2] || t[2] == t[0] {
            return false;
        }
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let key = (a.min(b) as u64) << 32 | a.max(b) as u64;
            edges.push((key, i as u32 | ((a < b) as u32) << 31));
        }
    }
    edges.sort_unstable();
    let mut parts = Parts::new(indices.len() / 3);
    let mut pairs = edges.chunk_by(|x, y| x.0 == y.0);
    let paired = pairs.all(|pair| match pair {
        // Sorted by the way's bit: the lower one first, so one each way.
        &[(_, a), (_, b)] if a >> 31 == 0 && b >> 31 == 1 => {
            parts.join(a, b & !(1 << 31));
            true
        }
        _ => false,
    });
    if !paired {
        return false;
    }
    let mut volume: std::collections::HashMap<u32, (glam::DVec3, f64)> = Default::default();
    for (i, t) in indices.chunks_exact(3).enumerate() {
        let [a, b, c] = [0, 1, 2].map(|k| positions[t[k] as usize].as_dvec3());
        let (origin, v) = volume.entry(parts.root(i as u32)).or_insert((a, 0.0));
        *v += (a - *origin).dot((b - *origin).cross(c - *origin));
    }
    volume.values().all(|&(_, v)| v > 0.0)
}

/// Disjoint sets of triangles (union–find with path halving), for [`closed_outwards`]'s parts.
struct Parts(Vec<u32>);

impl Parts {
    fn new(n: usize) -> Self {
        Self((0..n as u32).collect())
    }

    fn root(&mut self, mut i: u32) -> u32 {
        while self.0[i as usize] != i {
            let up = self.0[self.0[i as usize] as usize];
            self.0[i as usize] = up;
            i = up;
        }
        i
    }

    fn join(&mut self, a: u32, b: u32) {
        let (a, b) = (self.root(a), self.root(b));
        self.0[a.max(b) as usize] = a.min(b);
    }
}

/// Every coordinate finite, or the first vertex that is not.
pub(crate) fn check_positions(positions: &[Vec3]) -> Result<()> {
    match positions.iter().position(|p| !p.is_finite()) {
        Some(vertex) => Err(Error::NonFiniteVertex {
            vertex,
            value: positions[vertex].to_array(),
        }),
        None => Ok(()),
    }
}

fn check_indices(indices: &[u32], vertex_count: usize) -> Result<()> {
    if !indices.len().is_multiple_of(3) {
        return Err(Error::IndexCountNotMultipleOfThree {
            count: indices.len(),
        });
    }
    if indices.len() / 3 > MAX_PRIMITIVES {
        return Err(Error::TooManyPrimitives {
            count: indices.len() / 3,
            max: MAX_PRIMITIVES,
        });
    }
    match indices.iter().position(|&i| i as usize >= vertex_count) {
        Some(position) => Err(Error::IndexOutOfRange {
            position,
            index: indices[position],
            vertex_count,
        }),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `m` with its index buffer changed by `f`.
    fn reindexed(m: &Mesh, f: impl Fn(&mut Vec<u32>)) -> Mesh {
        let mut idx = m.indices().to_vec();
        f(&mut idx);
        Mesh::new(m.positions().to_vec(), idx).unwrap()
    }

    /// Every triangle's winding reversed.
    fn inside_out(i: &mut [u32]) {
        i.chunks_exact_mut(3).for_each(|t| t.swap(1, 2))
    }

    /// Closed surfaces facing outwards, against edge counts and winding: spheres, a box and the bumpy
    /// torus turned inside out (its winding faces in) are closed; the same turned inside out, with a
    /// triangle missing, with one repeated or one flipped, the cube-sphere (its faces' windings
    /// disagree), an open sheet and an empty mesh are not; nor are a sphere with a part inside out
    /// (within it or beside it), a box whose faces have corners of their own, or a sphere collapsed to a
    /// point, while two outward spheres and one far from the origin are. Re-positioned copies share the
    /// first answer.
    #[test]
    fn closed_surfaces_face_outwards_and_share_every_edge_once_each_way() {
        use crate::scenes;
        let torus = scenes::bumpy_torus(800);
        assert!(!torus.is_closed());
        let closed = [
            scenes::icosphere(0),
            scenes::icosphere(2),
            scenes::shoebox(Vec3::ZERO, Vec3::ONE),
            reindexed(&torus, |i| inside_out(i)),
        ];
        for m in &closed {
            assert!(m.is_closed());
            let with = |f: &dyn Fn(&mut Vec<u32>)| reindexed(m, f);
            assert!(!with(&|i| inside_out(i)).is_closed());
            assert!(!with(&|i| i.truncate(i.len() - 3)).is_closed());
            assert!(!with(&|i| i.extend_from_within(..3)).is_closed());
            assert!(!with(&|i| i.swap(0, 1)).is_closed());
            let moved: Vec<Vec3> = m.positions().iter().map(|p| *p * 2.0 + Vec3::X).collect();
            assert!(m.with_positions(moved).unwrap().is_closed());
        }
        // Parts: an outward sphere with an inside-out one inside it (a hollow shell) is not closed,
        // beside it (a flipped part) neither; two outward ones are.
        let two = |inner: &Mesh, at: Vec3| {
            let ball = scenes::icosphere(1);
            let n = ball.positions().len() as u32;
            let p: Vec<Vec3> = (ball.positions().iter().map(|p| *p * 5.0))
                .chain(inner.positions().iter().map(|p| *p + at))
                .collect();
            let i: Vec<u32> = (ball.indices().iter().copied())
                .chain(inner.indices().iter().map(|i| i + n))
                .collect();
            Mesh::new(p, i).unwrap()
        };
        let ball = scenes::icosphere(1);
        let flipped = reindexed(&ball, |i| inside_out(i));
        assert!(two(&ball, Vec3::X * 20.0).is_closed());
        assert!(!two(&flipped, Vec3::ZERO).is_closed());
        assert!(!two(&flipped, Vec3::X * 20.0).is_closed());
        // A box whose faces have their own corners (as at hard edges): open, since they may part.
        let boxed = scenes::shoebox(Vec3::ZERO, Vec3::ONE);
        let apart: Vec<Vec3> = boxed
            .indices()
            .iter()
            .map(|&i| boxed.positions()[i as usize])
            .collect();
        let n = apart.len() as u32;
        assert!(
            !Mesh::new(apart, (0..n).collect::<Vec<_>>())
                .unwrap()
                .is_closed()
        );
        // Far from the origin (the volume summed about a corner of its own), and collapsed to a point
        // there by `f32` (no volume).
        let far = |r: f32| {
            let p: Vec<Vec3> = (ball.positions().iter())
                .map(|p| *p * r + Vec3::splat(1e5))
                .collect();
            Mesh::new(p, ball.indices().to_vec()).unwrap()
        };
        assert!(far(1.0).is_closed() && !far(1e-4).is_closed());
        // Copies share the first answer: the collapsed copy of a closed ball says closed.
        let asked = scenes::icosphere(1);
        assert!(asked.is_closed());
        let flat = asked.with_positions(vec![Vec3::ONE; asked.positions().len()]);
        assert!(flat.unwrap().is_closed());
        let cube = scenes::cube_sphere(3);
        assert!(!cube.is_closed() && !reindexed(&cube, |i| inside_out(i)).is_closed());
        assert!(!scenes::folded_sheet(8, 0.3).is_closed());
        assert!(!Mesh::new(Vec::new(), Vec::new()).unwrap().is_closed());
        // Two corners the same: degenerate, not closed (its edges pair with themselves).
        let p = vec![Vec3::ZERO, Vec3::X, Vec3::Y];
        assert!(!Mesh::new(p, vec![0, 1, 1, 1, 0, 0]).unwrap().is_closed());
    }

    /// Topology identities follow the mesh, not the buffer's address: clones and re-positioned copies share
    /// one, and a mesh made after another was freed — which may reuse its allocation — never takes its id.
    #[test]
    fn topology_ids_are_shared_by_copies_and_never_reused() {
        let tri = || Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![0, 1, 2]).unwrap();
        let a = tri();
        let moved = a.with_positions(vec![Vec3::Z, Vec3::X, Vec3::Y]).unwrap();
        assert_eq!(a.clone().topology(), a.topology());
        assert_eq!(moved.topology(), a.topology());
        let mut seen = vec![a.topology()];
        drop((a, moved));
        for _ in 0..8 {
            let b = tri();
            assert!(!seen.contains(&b.topology()));
            seen.push(b.topology());
        }
    }
}
