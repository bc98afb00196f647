//! Sound propagation as an ECS query: [`SoundSource`] and [`Listener`] entities, per-entity
//! [`AcousticSurface`] materials, and the [`SoundPaths`] resource the plugin refreshes every
//! [`SoundSettings::every`] frames during [`TraceSystems::Queries`](super::TraceSystems::Queries).
//!
//! What an update does: it traces through the two-level scene the ray queries use ([`TraceWorld`]: the
//! top-level tree over the entities and each entity's own tree with its transform, so moved entities and
//! deformed, refitted meshes are current) with [`SoundScene::instanced`], building no tree (each triangle
//! is transformed to world space once per update, not once per test); it merges coplanar surfaces of the entities the settings' layer mask accepts and traces each
//! source–listener pair with [`propagate`](crate::sound::propagate) on all threads. The answer is the
//! direct call's on one world-space tree of the same triangles (up to float rounding of the merged
//! surfaces' planes; tested).
//!
//! Cost per update: O(triangles) to merge surfaces (a world transform and a hash per triangle), plus the
//! propagation itself, which dominates (see [`crate::sound`]). Frames between updates cost nothing.
//! Propagation allocates its frusta.

use super::{QueryFilter, TraceErrorMessage, TraceStats, TraceWorld};
use crate::Result;
use crate::sound::{
    AcousticMaterial, SoundConfig, SoundInstance, SoundPath, SoundScene, propagate,
};
use bevy_ecs::prelude::*;
use glam::Vec3;

/// A point sound source at a world position. Its paths to every [`Listener`] are in [`SoundPaths`].
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct SoundSource(pub Vec3);

/// A listener at a world position.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct Listener(pub Vec3);

/// The acoustic material of a traceable entity's every triangle; entities without one use
/// [`SoundSettings::default_material`].
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct AcousticSurface(pub AcousticMaterial);

/// How sound is traced (a resource the plugin inserts with these defaults).
#[derive(Resource, Clone, Debug)]
pub struct SoundSettings {
    /// The propagation settings.
    pub config: SoundConfig,
    /// Update every this many frames (1: every frame; 0 counts as 1). Paths stay as last computed between
    /// updates. Default 1.
    pub every: u64,
    /// Material of entities with no [`AcousticSurface`]. Default: 10 % absorption in every band.
    pub default_material: AcousticMaterial,
    /// Which entities reflect and occlude sound (a [`QueryLayers`](super::QueryLayers) mask; 0: all).
    pub layers: u32,
}

impl Default for SoundSettings {
    fn default() -> Self {
        Self {
            config: SoundConfig::default(),
            every: 1,
            default_material: AcousticMaterial {
                absorption: [0.1; crate::sound::BANDS],
            },
            layers: 0,
        }
    }
}

/// The specular paths of one source–listener pair.
#[derive(Clone, Debug, PartialEq)]
pub struct SoundPair {
    /// The [`SoundSource`] entity.
    pub source: Entity,
    /// The [`Listener`] entity.
    pub listener: Entity,
    /// Paths by order, then delay; [`SoundPath::surfaces`] name the update's merged surfaces.
    pub paths: Vec<SoundPath>,
    /// Frusta traced for this pair.
    pub frusta: u64,
}

/// Every source–listener pair's paths, from the last update.
#[derive(Resource, Clone, Debug, Default)]
pub struct SoundPaths {
    /// One entry per pair, sources in query order, then listeners.
    pub pairs: Vec<SoundPair>,
    /// The [`TraceStats::frame`] of the last update (0: none yet).
    pub frame: u64,
    /// Updates run so far.
    pub updates: u64,
    /// Triangles the last update traced through.
    pub triangles: usize,
}

impl SoundPaths {
    /// The paths from `source` to `listener`, if both existed at the last update.
    pub fn between(&self, source: Entity, listener: Entity) -> Option<&[SoundPath]> {
        self.pairs
            .iter()
            .find(|p| p.source == source && p.listener == listener)
            .map(|p| p.paths.as_slice())
    }
}

/// The materials of the last update, kept so a warm update reuses their buffers.
#[derive(Default)]
pub(crate) struct SoundState {
    palette: Vec<AcousticMaterial>,
}

impl SoundState {
    /// The two-level scene over the traceable entities the settings accept: one instance per top-level
    /// primitive (`None` for those left out), each entity's tree with its transform and material.
    fn scene<'w>(
        &mut self,
        world: &'w TraceWorld,
        settings: &SoundSettings,
        material_of: impl Fn(Entity) -> Option<AcousticMaterial>,
    ) -> Result<SoundScene<'w>> {
        let palette = &mut self.palette;
        palette.clear();
        let filter = QueryFilter {
            layers: settings.layers,
            ..Default::default()
        };
        // Top-level primitive `i` is entity `tlas_entities[i]`.
        let instances: Vec<Option<SoundInstance>> = world
            .tlas_entities
            .iter()
            .map(|&e| {
                let inst = &world.instances[&e];
                filter.accepts(e, inst.layers).then(|| {
                    let m = material_of(e).unwrap_or(settings.default_material);
                    let material = match palette.iter().position(|p| *p == m) {
                        Some(i) => i,
                        None => {
                            palette.push(m);
                            palette.len() - 1
                        }
                    } as u32;
                    SoundInstance {
                        bvh: &inst.bvh,
                        transform: inst.transform,
                        material,
                    }
                })
            })
            .collect();
        SoundScene::instanced(&world.tlas, &instances, palette.clone())
    }
}

/// Whether this frame is an update frame under `settings.every`.
pub(crate) fn sound_due(
    settings: Res<SoundSettings>,
    stats: Res<TraceStats>,
    paths: Res<SoundPaths>,
) -> bool {
    paths.updates == 0 || stats.frame >= paths.frame + settings.every.max(1)
}

/// Refreshes [`SoundPaths`]; an error (a bad setting or non-finite position) is sent as a
/// [`TraceErrorMessage`] naming the source, and leaves that pair out.
#[allow(clippy::too_many_arguments)] // a system: each parameter is one thing it reads
pub(crate) fn sound_system(
    settings: Res<SoundSettings>,
    world: Res<TraceWorld>,
    stats: Res<TraceStats>,
    sources: Query<(Entity, &SoundSource)>,
    listeners: Query<(Entity, &Listener)>,
    surfaces: Query<&AcousticSurface>,
    mut out: ResMut<SoundPaths>,
    mut state: Local<SoundState>,
    mut errors: MessageWriter<TraceErrorMessage>,
) {
    let out = &mut *out;
    out.frame = stats.frame;
    out.updates += 1;
    out.pairs.clear();
    let state = &mut *state;
    let scene = state.scene(&world, &settings, |e| surfaces.get(e).ok().map(|s| s.0));
    out.triangles = scene.as_ref().map_or(0, SoundScene::triangle_count);
    let mut report = |entity, error| {
        errors.write(TraceErrorMessage { entity, error });
    };
    let scene = match scene {
        Ok(s) => s,
        Err(error) => {
            for (entity, _) in &sources {
                report(entity, error.clone());
            }
            return;
        }
    };
    for (source, s) in &sources {
        for (listener, l) in &listeners {
            match propagate(&scene, s.0, l.0, &settings.config) {
                Ok(found) => out.pairs.push(SoundPair {
                    source,
                    listener,
                    paths: found.paths,
                    frusta: found.frusta,
                }),
                Err(error) => report(source, error),
            }
        }
    }
}
