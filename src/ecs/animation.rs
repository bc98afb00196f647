//! Playing character clips: joint matrices for [`TraceSkin`] each frame, in [`TraceSystems::Animate`].

use super::TraceSkin;
use crate::anim::{CharacterAsset, Transform};
use bevy_ecs::prelude::*;
use glam::Mat4;
use std::sync::Arc;

/// Seconds to advance animations by this frame (1/60 by default). Set it from your clock each frame.
#[derive(Resource, Clone, Copy, Debug)]
pub struct AnimationClock {
    /// Frame time in seconds.
    pub delta: f32,
}

impl Default for AnimationClock {
    fn default() -> Self {
        Self { delta: 1.0 / 60.0 }
    }
}

/// Plays one clip of a character on an entity with a [`TraceSkin`] (see [`AnimationPlayer::bundle`]).
#[derive(Component, Clone, Debug)]
pub struct AnimationPlayer {
    /// The character.
    pub asset: Arc<CharacterAsset>,
    /// Index of the clip playing.
    pub clip: usize,
    /// Time into the clip, seconds.
    pub time: f32,
    /// Playback speed (1 = real time).
    pub speed: f32,
    /// Wrap at the end (else hold the last pose).
    pub looping: bool,
}

impl AnimationPlayer {
    /// Components for an animated, traceable instance of `asset` playing `clip` from `time`: the mesh, the
    /// skin and the player (add a [`TraceTransform`](super::TraceTransform) to place it).
    pub fn bundle(
        asset: &Arc<CharacterAsset>,
        clip: usize,
        time: f32,
    ) -> (super::TraceMesh, TraceSkin, AnimationPlayer) {
        (
            super::TraceMesh(asset.mesh.clone()),
            TraceSkin {
                weights: asset.weights.clone(),
                joint_matrices: vec![Mat4::IDENTITY; asset.skeleton.joints.len()],
                morphs: asset.morphs.clone(),
                morph_weights: asset
                    .morphs
                    .as_ref()
                    .map_or_else(Vec::new, |m| m.default_weights.clone()),
            },
            AnimationPlayer {
                asset: asset.clone(),
                clip,
                time,
                speed: 1.0,
                looping: true,
            },
        )
    }
}

/// Advances every player and writes its skin's joint matrices (reusing their memory).
pub(crate) fn animate_system(
    mut players: Query<(&mut AnimationPlayer, &mut TraceSkin)>,
    clock: Option<Res<AnimationClock>>,
    mut pose: Local<Vec<Transform>>,
) {
    let dt = clock.map_or(AnimationClock::default().delta, |c| c.delta);
    for (mut player, mut skin) in &mut players {
        let asset = player.asset.clone();
        let Some(clip) = asset.clips.get(player.clip) else {
            continue;
        };
        let mut t = player.time + dt * player.speed;
        if clip.duration > 0.0 {
            t = if player.looping {
                t.rem_euclid(clip.duration)
            } else {
                t.clamp(0.0, clip.duration)
            };
        }
        player.time = t;
        pose.clear();
        pose.extend(asset.skeleton.joints.iter().map(|j| j.rest));
        clip.sample(t, &mut pose);
        let n = asset.skeleton.joints.len();
        skin.joint_matrices.resize(n, Mat4::IDENTITY);
        asset
            .skeleton
            .skin_matrices(&pose, &mut skin.joint_matrices);
        if let Some(m) = &asset.morphs {
            skin.morph_weights.clear();
            skin.morph_weights.extend_from_slice(&m.default_weights);
            clip.sample_weights(t, &mut skin.morph_weights);
        }
    }
}
