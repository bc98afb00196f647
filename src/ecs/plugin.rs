//! Installing the crate into a user's world and schedule.

use super::maintain::maintain_system;
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
pub enum TraceSystems {
    /// Sample animations into joint matrices (your systems, or the glTF animation player).
    Animate,
    /// Linear-blend skinning into [`VertexPositions`].
    Skin,
    /// Scene characterisation of meshes that changed enough to matter (profiles in [`TraceWorld::profile`]).
    Characterize,
    /// Refit or rebuild changed meshes.
    Maintain,
    /// Follow transforms; refit or rebuild the top level.
    TopLevel,
    /// Answer the batched requests of [`RayQueue`]; test colliders ([`Contacts`]).
    Queries,
}

/// The old name of [`TraceSystems`], from before bevy 0.17 named system sets `…Systems`; removed in the
/// next release. Being an alias of the enum, it still names the variants (`TraceSet::TopLevel`) and works
/// in `in_set`, `before` and `after` and in patterns; only the new name appears in the docs.
#[deprecated(
    since = "0.1.0",
    note = "renamed to `TraceSystems`, after bevy's `…Systems` convention"
)]
pub type TraceSet = TraceSystems;

/// Adds ray queries over every entity with a [`TraceMesh`].
///
/// The plugin's systems run one after another, so a schedule made mostly of them is best served by
/// `bevy_ecs::schedule::SingleThreadedExecutor` (set with `Schedule::set_executor`): bevy's default
/// multi-threaded executor spent about 0.1 ms per frame waking threads in our measurements, the
/// single-threaded one about 1 µs (docs/BENCHMARKS.md). Batched queries use all threads either way.
///
/// Resources: [`TraceConfig`], [`TraceWorld`], [`RayQueue`], [`RayResults`], [`TraceStats`], [`Contacts`],
/// [`CollisionSettings`], [`SoundSettings`], [`SoundPaths`]; messages [`TraceErrorMessage`], [`CollisionStarted`], [`CollisionEnded`]. With
/// [`update_messages`](Self::update_messages) (the default) the plugin also runs bevy's `message_update_system` once per frame, before [`TraceSystems::Animate`]; turn it off when your
/// loop already does.
#[derive(Clone, Debug)]
pub struct KinetracePlugin {
    /// The settings, inserted as the [`TraceConfig`] resource.
    pub config: TraceConfig,
    /// Run `message_update_system` (see above).
    pub update_messages: bool,
    /// The app's transform components followed into [`TraceTransform`] (add them with
    /// [`sync_transforms`](Self::sync_transforms)).
    pub transform_sources: Vec<TransformSource>,
}

impl Default for KinetracePlugin {
    fn default() -> Self {
        Self {
            config: TraceConfig::default(),
            update_messages: true,
            transform_sources: Vec::new(),
        }
    }
}

impl Plugin for KinetracePlugin {
    /// [`try_build`](KinetracePlugin::try_build), logging a failure (batched queries then run on the CPU).
    fn build(&self, world: &mut World, schedule: &mut Schedule) {
        if let Err(e) = self.try_build(world, schedule) {
            log::error!("kinetrace: {e}; batched queries run on the CPU");
        }
    }
}

impl KinetracePlugin {
    /// Installs the plugin; in a GPU mode also creates the GPU device. Fails only for
    /// [`TraceMode::GpuRequired`] without a usable GPU, with [`Error::NoGpu`](crate::Error::NoGpu) — after
    /// installing everything else, so the app still runs on the CPU if the caller chooses to go on.
    pub fn try_build(&self, world: &mut World, schedule: &mut Schedule) -> crate::Result<()> {
        world.insert_resource(self.config.clone());
        world.init_resource::<TraceWorld>();
        world.init_resource::<RayQueue>();
        world.init_resource::<RayResults>();
        world.init_resource::<super::SecondaryRays>();
        world.init_resource::<super::PointBatches>();
        world.init_resource::<super::ShapeQueue>();
        world.init_resource::<super::ShapeResults>();
        world.init_resource::<TraceStats>();
        world.init_resource::<super::AnimationClock>();
        world.init_resource::<Contacts>();
        world.init_resource::<CollisionSettings>();
        world.init_resource::<super::collide::CollisionState>();
        world.init_resource::<super::SoundSettings>();
        world.init_resource::<super::SoundPaths>();
        MessageRegistry::register_message::<TraceErrorMessage>(world);
        MessageRegistry::register_message::<CollisionStarted>(world);
        MessageRegistry::register_message::<CollisionEnded>(world);
        world.remove_resource::<GpuQueries>();
        schedule.configure_sets(
            (
                TraceSystems::Animate,
                TraceSystems::Skin,
                TraceSystems::Characterize,
                TraceSystems::Maintain,
                TraceSystems::TopLevel,
                TraceSystems::Queries,
            )
                .chain(),
        );
        if self.update_messages {
            schedule.add_systems(message_update_system.before(begin_frame));
        }
        schedule.add_systems((
            begin_frame.before(TraceSystems::Animate),
            super::animation::animate_system.in_set(TraceSystems::Animate),
            skin_system.in_set(TraceSystems::Skin),
            characterize_system.in_set(TraceSystems::Characterize),
            maintain_system.in_set(TraceSystems::Maintain),
            top_level_system.in_set(TraceSystems::TopLevel),
            queries_system.in_set(TraceSystems::Queries),
            // Before the rays, whose system hands both timings to the adaptive policy.
            super::shape_batch::shape_queries_system
                .before(queries_system)
                .in_set(TraceSystems::Queries),
            super::collide::collide_system
                .run_if(super::collide::collisions_needed)
                .in_set(TraceSystems::Queries),
            super::sound::sound_system
                .run_if(any_with_component::<super::SoundSource>)
                .run_if(super::sound::sound_due)
                .in_set(TraceSystems::Queries),
        ));
        #[cfg(feature = "gpu")]
        schedule.add_systems((
            super::gpu_frame::resident_frame_system
                .run_if(super::gpu_frame::resident_on)
                .in_set(TraceSystems::Queries),
            super::gpu_queries::gpu_counters_system.after(TraceSystems::Queries),
        ));
        for source in &self.transform_sources {
            source.install(schedule);
        }
        self.start_gpu(world)
    }

    #[cfg(feature = "gpu")]
    fn start_gpu(&self, world: &mut World) -> crate::Result<()> {
        if self.config.mode == TraceMode::Cpu {
            return Ok(());
        }
        match crate::gpu::GpuContext::with_options(&gpu_options(&self.config)) {
            Ok(ctx) => {
                log::info!("kinetrace: batched queries on {}", ctx.adapter_name());
                world.insert_resource(GpuQueries::new(ctx));
                Ok(())
            }
            Err(e) if self.config.mode == TraceMode::GpuRequired => Err(e),
            Err(e) => {
                log::warn!("kinetrace: {e}; batched queries run on the CPU");
                Ok(())
            }
        }
    }

    #[cfg(not(feature = "gpu"))]
    fn start_gpu(&self, _world: &mut World) -> crate::Result<()> {
        match self.config.mode {
            TraceMode::GpuRequired => Err(crate::Error::NoGpu(
                "kinetrace was built without the gpu feature".into(),
            )),
            TraceMode::GpuWhenAvailable => {
                log::warn!(
                    "kinetrace: built without the gpu feature; batched queries run on the CPU"
                );
                Ok(())
            }
            TraceMode::Cpu => Ok(()),
        }
    }
}

/// The adapter rule of the configured mode: [`TraceMode::GpuWhenAvailable`] refuses software adapters unless
/// the configuration or `KINETRACE_ALLOW_SOFTWARE_GPU=1` allows them; [`TraceMode::GpuRequired`] takes any.
#[cfg(feature = "gpu")]
fn gpu_options(config: &TraceConfig) -> crate::gpu::GpuOptions {
    use crate::gpu::{ALLOW_SOFTWARE_ENV, software_allowed};
    let allowed = software_allowed(
        config.allow_software_gpu,
        std::env::var(ALLOW_SOFTWARE_ENV).ok().as_deref(),
    );
    crate::gpu::GpuOptions {
        hardware_only: config.mode == TraceMode::GpuWhenAvailable && !allowed,
        limits: None,
    }
}
