//! Following an app's own transform component, so that nobody writes a copy system into [`TraceTransform`].

use super::systems::top_level_system;
use super::{KinetracePlugin, TraceMesh, TraceSystems, TraceTransform};
use bevy_ecs::prelude::*;
use glam::Affine3A;
use std::fmt;
use std::sync::Arc;

impl KinetracePlugin {
    /// Makes the app's own transform component `T` place traceable entities: the plugin copies
    /// `to_affine(&t)` into [`TraceTransform`] whenever `T` is inserted or changed, or the entity gets a
    /// [`TraceMesh`], and puts it back at the identity when `T` is removed. Use it instead of writing that
    /// copy system by hand; `to_affine` can be a method of a type you do not own (such as bevy's
    /// `GlobalTransform::affine`). Follow one component per entity: with two, which copy lands last is unspecified.
    ///
    /// The copy runs in [`TraceSystems::TopLevel`] before the top level is updated, so a write to `T`
    /// ordered before that set counts the same frame, exactly like a write to [`TraceTransform`]. Cost: one
    /// change-filtered pass over the traceable entities with a `T` per frame; only entities whose matrix
    /// actually changed touch the top level.
    ///
    /// ```
    /// use bevy_ecs::prelude::*;
    /// use glam::{Affine3A, Quat, Vec3};
    /// use kinetrace::ecs::*;
    /// use kinetrace::{Ray, scenes};
    ///
    /// /// The app's own transform: a position and a heading.
    /// #[derive(Component)]
    /// struct Place {
    ///     at: Vec3,
    ///     yaw: f32,
    /// }
    ///
    /// impl Place {
    ///     fn affine(&self) -> Affine3A {
    ///         Affine3A::from_rotation_translation(Quat::from_rotation_y(self.yaw), self.at)
    ///     }
    /// }
    ///
    /// let mut world = World::new();
    /// let mut schedule = Schedule::default();
    /// KinetracePlugin::default()
    ///     .sync_transforms(Place::affine)
    ///     .build(&mut world, &mut schedule);
    /// let ball = world
    ///     .spawn((TraceMesh(scenes::icosphere(2)), Place { at: Vec3::new(0.0, 0.0, 10.0), yaw: 0.0 }))
    ///     .id();
    /// let ray = Ray::new(Vec3::new(3.0, 0.0, 0.0), Vec3::Z);
    /// let cast = |world: &World| world.resource::<TraceWorld>().cast_ray(&ray, 100.0, &QueryFilter::default());
    /// schedule.run(&mut world);
    /// world.clear_trackers();
    /// assert!(cast(&world).is_none()); // the ball is at x = 0
    ///
    /// world.get_mut::<Place>(ball).unwrap().at.x = 3.0; // gameplay moves its own component only
    /// schedule.run(&mut world);
    /// let hit = cast(&world).expect("the ball moved into the ray");
    /// assert_eq!(hit.entity, ball);
    /// assert!((hit.distance - 9.0).abs() < 0.05); // the unit sphere's surface, 10 m away
    /// ```
    pub fn sync_transforms<T: Component>(mut self, to_affine: fn(&T) -> Affine3A) -> Self {
        self.transform_sources.push(TransformSource::new(to_affine));
        self
    }
}

/// A transform component of the app that the plugin copies into [`TraceTransform`] each frame, with the
/// function that turns it into an object-to-world matrix. Made by
/// [`KinetracePlugin::sync_transforms`](super::KinetracePlugin::sync_transforms), which is where to read
/// what it does and costs.
#[derive(Clone)]
pub struct TransformSource {
    component: &'static str,
    install: Arc<dyn Fn(&mut Schedule) + Send + Sync>,
}

impl TransformSource {
    /// Follows component `T`, converted with `to_affine`.
    pub fn new<T: Component>(to_affine: fn(&T) -> Affine3A) -> Self {
        Self {
            component: std::any::type_name::<T>(),
            install: Arc::new(move |schedule: &mut Schedule| {
                schedule.add_systems(
                    sync_transforms(to_affine)
                        .in_set(TraceSystems::TopLevel)
                        .before(top_level_system),
                );
            }),
        }
    }

    /// Adds the copy system to `schedule`.
    pub(super) fn install(&self, schedule: &mut Schedule) {
        (self.install)(schedule)
    }
}

impl fmt::Debug for TransformSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_tuple("TransformSource")
            .field(&self.component)
            .finish()
    }
}

/// Traceable entities whose `T` is new or changed, or that just became traceable.
type SourceChanged<T> = (With<TraceMesh>, Or<(Changed<T>, Added<TraceMesh>)>);
/// Their `T` and the transform it sets.
type Followed<'w, 's, T> =
    Query<'w, 's, (&'static T, &'static mut TraceTransform), SourceChanged<T>>;
/// Transforms of entities without a `T` (those that just lost theirs among them).
type Orphans<'w, 's, T> = Query<'w, 's, &'static mut TraceTransform, Without<T>>;

/// The system that copies `T` into [`TraceTransform`]: for traceable entities whose `T` was inserted or
/// changed, or that became traceable while having a `T`; and back to the identity (where an entity without
/// a transform of its own stands) for those that lost their `T`. Writes only what differs, so an unchanged
/// matrix costs the top level nothing.
fn sync_transforms<T: Component>(
    to_affine: fn(&T) -> Affine3A,
) -> impl FnMut(Followed<T>, RemovedComponents<T>, Orphans<T>) {
    move |mut changed, mut removed, mut orphans| {
        for (source, mut target) in &mut changed {
            target.set_if_neq(TraceTransform(to_affine(source)));
        }
        for e in removed.read() {
            if let Ok(mut target) = orphans.get_mut(e) {
                target.set_if_neq(TraceTransform::default());
            }
        }
    }
}
