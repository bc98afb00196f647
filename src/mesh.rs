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

    /// Whether the mesh is a closed surface facing outwards: every edge `a → b` of a triangle (corners in
    /// index order) is met exactly once more, as `b → a` in another triangle, no triangle repeats an
    /// index, and the volume it encloses, by the corners' winding, is positive. Several closed parts
    /// (interpenetrating or not, as a character made of capsules) are one closed surface. A line from
    /// outside then first crosses such a surface at a triangle whose winding faces where the line comes
    /// from, so a shadow map leaves out the triangles facing away from the light (see
    /// [`Occluders::closed`](crate::shadows::Occluders::closed)).
    ///
    /// Found once per topology, O(triangles · log triangles) with one allocation, and kept by clones and
    /// [`with_positions`](Self::with_positions) copies: the volume's sign is taken from the positions of
    /// the first copy asked (posing or skinning a closed surface does not turn it inside out).
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

/// [`Mesh::is_closed`] for an index buffer that has already been checked: every directed edge once, its
/// reverse once, no repeated index, and a positive signed volume (summed in `f64`).
fn closed_outwards(positions: &[Vec3], indices: &[u32]) -> bool {
    if indices.is_empty() {
        return false;
    }
    let mut edges = Vec::with_capacity(indices.len());
    for t in indices.chunks_exact(3) {
        if t[0] == t[1] || t[1] == t[2] || t[2] == t[0] {
            return false;
        }
        for k in 0..3 {
            edges.push((t[k] as u64) << 32 | t[(k + 1) % 3] as u64);
        }
    }
    // `a → b` as `a · 2³² + b`: its reverse is the two halves swapped.
    edges.sort_unstable();
    let once = edges.windows(2).all(|w| w[0] != w[1]);
    let paired = || (edges.iter()).all(|&e| edges.binary_search(&e.rotate_right(32)).is_ok());
    let volume = || {
        let at = |i: u32| positions[i as usize].as_dvec3();
        (indices.chunks_exact(3))
            .map(|t| at(t[0]).dot(at(t[1]).cross(at(t[2]))))
            .sum::<f64>()
    };
    once && paired() && volume() > 0.0
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
    /// disagree), an open sheet and an empty mesh are not; re-positioned copies keep the answer.
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
