//! Installing the crate into a user's world and schedule.

use super::systems::*;
use super::*;
use bevy_ecs::message::{MessageRegistry, message_update_system};
use bevy_ecs::prelude::*;

/// Something that installs resources and systems into a `bevy_ecs` world and schedule: the small plugin
/// trait of an app built on bare `bevy_ecs` (no `bevy_app`).
pub trait Plugin {
    /// Adds the plugin's resources to `world` and its systems to `schedule`.
    fn build(&self, world: &mut World, schedule: &mut Schedule);
}

/// The per-frame phases, in order. Put your systems in or around them: animation clocks in
/// [`Animate`](Self::Animate), transform writes before [`TopLevel`](Self::TopLevel), gameplay that reads
/// queries after [`Queries`](Self::Queries).
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TraceSet {
    /// Sample animations into joint matrices (your systems, or the glTF animation player).
    Animate,
    /// Linear-blend skinning into [`VertexPositions`].
    Skin,
    /// Scene characterisation of changed meshes (reserved for the adaptive policy).
    Characterize,
    /// Refit or rebuild changed meshes.
    Maintain,
    /// Follow transforms; refit or rebuild the top level.
    TopLevel,
    /// Answer the batched requests of [`RayQueue`].
    Queries,
}

/// Adds ray queries over every entity with a [`TraceMesh`].
///
/// The plugin's systems run one after another, so a schedule made mostly of them is best served by
/// `bevy_ecs::schedule::SingleThreadedExecutor` (set with `Schedule::set_executor`): bevy's default
/// multi-threaded executor spent about 0.1 ms per frame waking threads in our measurements, the
/// single-threaded one about 1 µs (docs/BENCHMARKS.md). Batched queries use all threads either way.
///
/// Resources: [`TraceConfig`], [`TraceWorld`], [`RayQueue`], [`RayResults`], [`TraceStats`]; message
/// [`TraceErrorMessage`]. With [`update_messages`](Self::update_messages) (the default) the plugin also
/// runs bevy's `message_update_system` once per frame, before [`TraceSet::Animate`]; turn it off when your
/// loop already does.
#[derive(Clone, Debug)]
pub struct KinetracePlugin {
    /// The settings, inserted as the [`TraceConfig`] resource.
    pub config: TraceConfig,
    /// Run `message_update_system` (see above).
    pub update_messages: bool,
}

impl Default for KinetracePlugin {
    fn default() -> Self {
        Self {
            config: TraceConfig::default(),
            update_messages: true,
        }
    }
}

impl Plugin for KinetracePlugin {
    fn build(&self, world: &mut World, schedule: &mut Schedule) {
        world.insert_resource(self.config.clone());
        world.init_resource::<TraceWorld>();
        world.init_resource::<RayQueue>();
        world.init_resource::<RayResults>();
        world.init_resource::<TraceStats>();
        MessageRegistry::register_message::<TraceErrorMessage>(world);
        schedule.configure_sets(
            (
                TraceSet::Animate,
                TraceSet::Skin,
                TraceSet::Characterize,
                TraceSet::Maintain,
                TraceSet::TopLevel,
                TraceSet::Queries,
            )
                .chain(),
        );
        if self.update_messages {
            schedule.add_systems(message_update_system.before(begin_frame));
        }
        schedule.add_systems((
            begin_frame.before(TraceSet::Animate),
            skin_system.in_set(TraceSet::Skin),
            maintain_system.in_set(TraceSet::Maintain),
            top_level_system.in_set(TraceSet::TopLevel),
            queries_system.in_set(TraceSet::Queries),
        ));
    }
}
