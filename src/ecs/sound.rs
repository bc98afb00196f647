//! Sound propagation as an ECS query: [`SoundSource`] and [`Listener`] entities, per-entity
//! [`AcousticSurface`] materials, and the [`SoundPaths`] resource the plugin refreshes every
//! [`SoundSettings::every`] frames during [`TraceSystems::Queries`](super::TraceSystems::Queries).
//!
//! What an update does: it gathers the world-space triangles of every traceable entity the settings' layer
//! mask accepts from the trees the ray queries use ([`TraceWorld`], so moved entities and deformed,
//! refitted meshes are current), refits a world-space tree over them (rebuilt when the triangle count
//! changes or the refit degraded it past the thesis's 0.40), merges coplanar surfaces and traces each
//! source–listener pair with [`propagate`](crate::sound::propagate) on all threads. The answer is the
//! direct call's on the same world-space geometry.
//!
//! Cost per update: O(triangles) to gather, refit and merge surfaces (about 1 ms per 20k triangles), plus
//! the propagation itself, which dominates (see [`crate::sound`]). Frames between updates cost nothing.
//! The gather and refit reuse their buffers once warm; propagation allocates its frusta.

use super::{QueryFilter, TraceErrorMessage, TraceStats, TraceWorld};
use crate::bvh::BuildOptions;
use crate::sound::{AcousticMaterial, SoundConfig, SoundPath, SoundScene, propagate};
use crate::{Mesh, MeshBvh, Result};
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

/// The world-space tree kept between updates, and its buffers.
#[derive(Default)]
pub(crate) struct SoundState {
    bvh: Option<MeshBvh>,
    /// Three vertices per triangle, world space.
    positions: Vec<Vec3>,
    /// Material index per triangle, into `palette`.
    materials: Vec<u32>,
    palette: Vec<AcousticMaterial>,
}

/// The thesis's rebuild threshold on the refit degradation metric (§4.1.5).
const REBUILD_ABOVE: f32 = 0.40;

impl SoundState {
    /// Gathers the accepted entities' world triangles and materials, and refits or rebuilds the tree.
    fn update(
        &mut self,
        world: &TraceWorld,
        settings: &SoundSettings,
        material_of: impl Fn(Entity) -> Option<AcousticMaterial>,
    ) -> Result<()> {
        let (positions, materials, palette) =
            (&mut self.positions, &mut self.materials, &mut self.palette);
        positions.clear();
        materials.clear();
        palette.clear();
        let filter = QueryFilter {
            layers: settings.layers,
            ..Default::default()
        };
        world.for_each_world_mesh(&filter, |e, tris| {
            let m = material_of(e).unwrap_or(settings.default_material);
            let index = match palette.iter().position(|p| *p == m) {
                Some(i) => i,
                None => {
                    palette.push(m);
                    palette.len() - 1
                }
            } as u32;
            for t in tris {
                positions.extend(t);
                materials.push(index);
            }
        });
        let refitted = match self.bvh.as_mut() {
            Some(bvh) if 3 * bvh.slot_triangles().len() == self.positions.len() => {
                bvh.refit(&self.positions)? <= REBUILD_ABOVE
            }
            _ => false,
        };
        if !refitted {
            let indices: Vec<u32> = (0..self.positions.len() as u32).collect();
            let mesh = Mesh::new(self.positions.clone(), indices)?;
            self.bvh = Some(MeshBvh::build(&mesh, &BuildOptions::default())?);
        }
        Ok(())
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
    let scene = state
        .update(&world, &settings, |e| surfaces.get(e).ok().map(|s| s.0))
        .and_then(|()| {
            let bvh = state.bvh.as_ref().expect("updated");
            out.triangles = bvh.slot_triangles().len();
            SoundScene::new(bvh, &state.materials, state.palette.clone())
        });
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
