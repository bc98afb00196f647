//! Animation: skeletons and poses, keyframed clips with glTF's interpolation rules, glTF loading,
//! linear-blend skinning, and a procedural skinned humanoid.

mod clip;
mod glb_export;
mod gltf_load;
mod humanoid;
mod pose;
mod skin;

pub use clip::{Channel, Clip, Interpolation, Property};
pub use glb_export::character_to_glb;
pub use gltf_load::{GltfMesh, load_gltf, load_gltf_slice};
pub use humanoid::{CharacterAsset, MorphTargets, humanoid};
pub use pose::{Joint, Skeleton, Transform};
pub use skin::{SkinWeights, skin_positions};
