//! `bevy_ecs` integration: components to make entities traceable, a plugin whose systems keep their trees
//! current each frame, an immediate query parameter ([`SpatialRays`]), batched queries ([`RayQueue`] →
//! [`RayResults`]), shape casts, closest points, overlaps and containment across all entities (immediate on
//! [`SpatialRays`], batched through [`ShapeQueue`] → [`ShapeResults`]) and collision contacts between entities
//! that opt in ([`Collider`] → [`Contacts`], [`CollisionStarted`] / [`CollisionEnded`]), and sound paths
//! from [`SoundSource`]s to [`Listener`]s ([`SoundPaths`]).
//!
//! Change detection decides the work: an untouched mesh costs nothing; a moved entity only updates the top
//! level; a deformed mesh ([`VertexPositions`] or [`TraceSkin`] changed) is refitted and rebuilt when the
//! [`RebuildPolicy`] says so (Lauterbach's 0.40 by default, or the adaptive cost model, which may also build
//! on the GPU); a new index buffer means a rebuild. The top level over the entities' world boxes is refitted
//! while the set of entities stays the same and rebuilt when entities come or go or the same policy says so
//! after a refit (see [`TopLevelStats`]). [`TraceStats::meshes`] and [`TraceStats::top_level`] say what was
//! done and why.
//!
//! A complete program on bare `bevy_ecs` — what the main loop must do each frame is run the schedule and
//! clear the world's change trackers (the plugin updates its messages itself):
//!
//! ```
//! use bevy_ecs::prelude::*;
//! use glam::{Affine3A, Vec3};
//! use kinetrace::ecs::*;
//! use kinetrace::{Ray, scenes};
//!
//! #[derive(Resource, Default)]
//! struct Seen(Vec<f32>);
//!
//! fn spin(mut q: Query<&mut TraceTransform>, stats: Res<TraceStats>) {
//!     for mut t in &mut q {
//!         t.0 = Affine3A::from_rotation_y(stats.frame as f32 * 0.1);
//!     }
//! }
//!
//! fn look(rays: SpatialRays, mut queue: ResMut<RayQueue>, results: Res<RayResults>, mut seen: ResMut<Seen>) {
//!     let ray = Ray::new(Vec3::new(0.0, 0.0, -5.0), Vec3::Z);
//!     if let Some(hit) = rays.cast_ray(&ray, 100.0, &QueryFilter::default()) {
//!         seen.0.push(hit.distance);
//!     }
//!     queue.shadow(7, Vec3::new(0.0, 5.0, 0.0), Vec3::new(0.0, -5.0, 0.0), QueryFilter::default());
//!     let _ = &results.shadows; // last batch's answers, readable after TraceSystems::Queries
//! }
//!
//! let mut world = World::new();
//! let mut schedule = Schedule::default();
//! KinetracePlugin::default().build(&mut world, &mut schedule);
//! world.init_resource::<Seen>();
//! schedule.add_systems((spin.before(TraceSystems::TopLevel), look.after(TraceSystems::TopLevel).before(TraceSystems::Queries)));
//! world.spawn((TraceMesh(scenes::icosphere(2)), MotionHint::Rigid));
//!
//! for _frame in 0..3 {
//!     schedule.run(&mut world);
//!     world.clear_trackers(); // so that next frame's Changed<_> and RemovedComponents see only new changes
//! }
//! assert_eq!(world.resource::<Seen>().0.len(), 3);
//! assert!((world.resource::<Seen>().0[0] - 4.0).abs() < 0.05); // the unit sphere's surface
//! assert_eq!(world.resource::<RayResults>().shadows, vec![(7, true)]);
//! ```

mod animation;
mod batch;
mod collide;
mod components;
mod config;
mod filter;
#[cfg(feature = "gpu")]
mod gpu_collide;
pub mod gpu_frame;
#[cfg(feature = "gpu")]
mod gpu_policy;
mod gpu_queries;
mod maintain;
mod params;
mod planned;
mod plugin;
mod point_batches;
mod ray_crsh;
mod ray_kinds;
mod shape_batch;
mod shape_queries;
mod sound;
mod stats;
mod systems;
mod top_level;
mod transform_sync;
mod world;
mod world_interleaved;
mod world_packets;

pub use crate::adaptive::{Build, Device, Prediction, Verdict};
pub use animation::{AnimationClock, AnimationPlayer};
pub use batch::{RayQueue, RayRequest, RayResults, ShadowRequest};
pub use collide::{
    Collider, CollisionEnded, CollisionLayers, CollisionSettings, CollisionStarted, ContactPair,
    Contacts,
};
pub use components::*;
pub use config::{
    Decision, Latency, Policy, PolicyInput, RebuildPolicy, TraceConfig, TraceMode,
    lauterbach_policy,
};
pub use filter::{QueryFilter, RayHit};
pub use gpu_frame::{GpuOnly, ResidentStats};
pub use gpu_queries::GpuQueries;
pub use params::SpatialRays;
#[doc(hidden)]
pub use planned::{CostScript, ScriptedCost};
#[allow(deprecated)] // the old name, re-exported until it is removed
pub use plugin::TraceSet;
pub use plugin::{KinetracePlugin, Plugin, TraceSystems};
pub use point_batches::{PointBatches, PointOrder};
pub use shape_batch::{
    ClosestPointRequest, ContainsRequest, OverlapRequest, ShapeCastRequest, ShapeQueue,
    ShapeResults,
};
pub use shape_queries::{NearestPoint, ShapeHit};
pub use sound::{AcousticSurface, Listener, SoundPair, SoundPaths, SoundSettings, SoundSource};
pub use stats::{
    MeshAction, MeshStats, RebuildReason, TopLevelAction, TopLevelReason, TopLevelStats, TraceStats,
};
// Structure choice (issue 12): which structure answers a mesh's rays.
pub use crate::grid::{ChoiceReason, StructureKind};
pub use config::{Structure, TraceStructure};
pub use ray_kinds::{
    MIN_TRIED_RAYS, RayBatch, RequestKind, SORTED_PACKET, SecondaryRays, SecondaryStrategy,
};
pub use stats::{OptionStats, PlannedOption, StructureStats, StructureWhy};
pub use transform_sync::TransformSource;
pub use world::{TraceWorld, WorldOccluders};
