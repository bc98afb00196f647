//! Validated triangle meshes.

use crate::bvh::MAX_PRIMITIVES;
use crate::geometry::Aabb;
use crate::{Error, Result};
use glam::Vec3;
use std::sync::Arc;

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
}

impl Mesh {
    /// Checks and wraps `positions` and `indices` (three per triangle, counter-clockwise is not required).
    ///
    /// Errors name the first offending entry: [`Error::NonFiniteVertex`], [`Error::IndexOutOfRange`],
    /// [`Error::IndexCountNotMultipleOfThree`], [`Error::TooManyPrimitives`].
    pub fn new(positions: impl Into<Arc<[Vec3]>>, indices: impl Into<Arc<[u32]>>) -> Result<Self> {
        let positions = positions.into();
        let indices = indices.into();
        check_positions(&positions)?;
        check_indices(&indices, positions.len())?;
        Ok(Self { positions, indices })
    }

    /// Vertex positions.
    pub fn positions(&self) -> &[Vec3] {
        &self.positions
    }

    /// Triangle indices, three per triangle.
    pub fn indices(&self) -> &[u32] {
        &self.indices
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
        })
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
