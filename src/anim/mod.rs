//! Animation: skeletons and poses, keyframed clips with glTF's interpolation rules, linear-blend skinning,
//! and a procedural skinned humanoid.

mod clip;
mod humanoid;
mod pose;
mod skin;

pub use clip::{Channel, Clip, Interpolation, Property};
pub use humanoid::{CharacterAsset, humanoid};
pub use pose::{Joint, Skeleton, Transform};
pub use skin::{SkinWeights, skin_positions};
