//! Animation: skinning (more of it — glTF loading, clips, procedural characters — builds on this).

mod skin;

pub use skin::{SkinWeights, skin_positions};
