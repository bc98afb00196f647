//! Linear-blend skinning on the CPU, the reference of the GPU kernel (shaders/skin.wgsl).

use crate::{Error, Result, parallel};
use glam::{Mat4, Vec3};

/// Per-vertex joint indices and weights, four each (glTF's `JOINTS_0` / `WEIGHTS_0`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SkinWeights {
    /// Joint indices into the skin's matrix palette.
    pub joints: Vec<[u16; 4]>,
    /// Weights, summing to 1 per vertex.
    pub weights: Vec<[f32; 4]>,
}

impl SkinWeights {
    /// Checks that there is one entry per vertex and that every joint exists in a palette of
    /// `joint_count`; errors name the first offending vertex.
    pub fn check(&self, vertex_count: usize, joint_count: usize) -> Result<()> {
        if self.joints.len() != vertex_count || self.weights.len() != vertex_count {
            return Err(Error::VertexCountMismatch {
                expected: vertex_count,
                got: self.joints.len().min(self.weights.len()),
            });
        }
        if let Some(v) = self
            .joints
            .iter()
            .position(|j| j.iter().any(|&j| j as usize >= joint_count))
        {
            return Err(Error::InvalidOption(format!(
                "vertex {v} uses joint {:?}, but the skin has {joint_count} joints",
                self.joints[v]
            )));
        }
        Ok(())
    }
}

/// `out[v] = Σ_k w_k · (M[j_k] · rest[v])` for every vertex, on all threads. Checks sizes and joint indices
/// first (see [`SkinWeights::check`]). Cost: 4 matrix–point products per vertex; no allocation.
pub fn skin_positions(
    rest: &[Vec3],
    skin: &SkinWeights,
    matrices: &[Mat4],
    out: &mut [Vec3],
) -> Result<()> {
    skin.check(rest.len(), matrices.len())?;
    if out.len() != rest.len() {
        return Err(Error::VertexCountMismatch {
            expected: rest.len(),
            got: out.len(),
        });
    }
    parallel::fill(true, out, 4096, |v| {
        let p = rest[v];
        let (j, w) = (skin.joints[v], skin.weights[v]);
        (0..4).fold(Vec3::ZERO, |acc, k| {
            acc + matrices[j[k] as usize].transform_point3(p) * w[k]
        })
    });
    Ok(())
}
