//! Joint transforms and skeletons.

use glam::{Mat4, Quat, Vec3};

/// A joint's local transform: translation, rotation, scale (glTF's TRS).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transform {
    /// Translation.
    pub translation: Vec3,
    /// Rotation (unit quaternion).
    pub rotation: Quat,
    /// Scale.
    pub scale: Vec3,
}

impl Default for Transform {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Transform {
    /// No change.
    pub const IDENTITY: Transform = Transform {
        translation: Vec3::ZERO,
        rotation: Quat::IDENTITY,
        scale: Vec3::ONE,
    };

    /// A pure translation.
    pub fn from_translation(t: Vec3) -> Self {
        Self {
            translation: t,
            ..Self::IDENTITY
        }
    }

    /// As a matrix (scale, then rotation, then translation).
    pub fn matrix(&self) -> Mat4 {
        Mat4::from_scale_rotation_translation(self.scale, self.rotation, self.translation)
    }
}

/// One joint: its name, its parent (always an earlier joint), its rest transform.
#[derive(Clone, Debug, PartialEq)]
pub struct Joint {
    /// Name, for lookups and messages.
    pub name: String,
    /// Parent joint index; `None` for a root.
    pub parent: Option<usize>,
    /// Local transform in the rest pose.
    pub rest: Transform,
}

/// A joint hierarchy with its inverse bind matrices (mesh space → joint space at bind time).
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Skeleton {
    /// Joints, parents before children.
    pub joints: Vec<Joint>,
    /// One per joint.
    pub inverse_bind: Vec<Mat4>,
    /// World transform of whatever the root joints hang from (glTF nodes above the skin's joints).
    pub root: Mat4,
}

impl Skeleton {
    /// The rest pose: every joint's rest transform.
    pub fn rest_pose(&self) -> Vec<Transform> {
        self.joints.iter().map(|j| j.rest).collect()
    }

    /// Skinning matrices (joint world × inverse bind) of a pose, into `out` (one per joint). Cost: one matrix
    /// product per joint; no allocation.
    pub fn skin_matrices(&self, pose: &[Transform], out: &mut [Mat4]) {
        debug_assert!(pose.len() == self.joints.len() && out.len() == self.joints.len());
        for (i, j) in self.joints.iter().enumerate() {
            let local = pose[i].matrix();
            out[i] = match j.parent {
                Some(p) => out[p] * local,
                None => self.root * local,
            };
        }
        for (m, ib) in out.iter_mut().zip(&self.inverse_bind) {
            *m *= *ib;
        }
    }
}
