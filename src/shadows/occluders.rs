//! What a shadow map is rendered from: groups of triangles, each placed in world space by its own
//! transform (or already there).

use glam::{Affine3A, Vec3};

/// The occluders of a [`HardShadows`](super::HardShadows) pass: groups of triangles, each with the affine
/// transform that places it in world space (`None`: in world space already).
///
/// A slice or `Vec` of world-space triangles is one group. A scene of placed meshes is better given as one
/// group per mesh — [`TraceWorld::occluders`](crate::ecs::TraceWorld::occluders) does so for the ECS world
/// — so the map projects each mesh's own triangles through its transform and the light at once instead of
/// having them copied into world space every frame (on a crowd of 700k triangles, 25 MB each way and
/// 3–4 ms a frame on 2 cores). The map is then the same up to rounding: a transform composed with the
/// light rounds differently from the two applied in turn.
pub trait Occluders: Sync {
    /// How many groups.
    fn groups(&self) -> usize;

    /// Group `g` (below [`groups`](Self::groups)): its triangles, and the transform that places them in
    /// world space (`None`: they are in world space).
    fn group(&self, g: usize) -> (&[[Vec3; 3]], Option<Affine3A>);

    /// Whether group `g`'s triangles form a closed surface facing outwards, as
    /// [`Mesh::is_closed`](crate::Mesh::is_closed) finds for the mesh they come from (in its winding):
    /// then a selective pass's shadow map leaves out those facing away from the light, about half of
    /// them, which the light never meets first on such a surface (see
    /// [`ShadowSettings::closed_culling`](super::ShadowSettings::closed_culling): the map a fifth faster
    /// on a crowd of skinned characters, what it changes, and why the shadow map alone keeps every face).
    /// By default `false`: every triangle counts, as for a shadow ray.
    /// [`TraceWorld::occluders`](crate::ecs::TraceWorld::occluders) says it of every closed mesh.
    fn closed(&self, g: usize) -> bool {
        let _ = g;
        false
    }

    /// Triangles in all groups.
    fn triangle_count(&self) -> usize {
        (0..self.groups()).map(|g| self.group(g).0.len()).sum()
    }
}

/// Triangles in world space (a slice, a `Vec`, an array): one group.
impl<T: AsRef<[[Vec3; 3]]> + Sync + ?Sized> Occluders for T {
    fn groups(&self) -> usize {
        1
    }

    fn group(&self, _: usize) -> (&[[Vec3; 3]], Option<Affine3A>) {
        (self.as_ref(), None)
    }
}

/// `of`'s groups, closed where `of` says so in a pass that culls ([`Culling::of`]).
pub(super) struct Culling<'a, O: ?Sized> {
    of: &'a O,
    on: bool,
}

impl<'a, O: ?Sized> Culling<'a, O> {
    /// `occluders` as a pass with settings `s` renders them: closed groups only in a selective pass with
    /// [`ShadowSettings::closed_culling`](super::ShadowSettings::closed_culling) on.
    pub(super) fn of(occluders: &'a O, s: &super::ShadowSettings) -> Self {
        Self {
            of: occluders,
            on: s.closed_culling && s.mode == super::ShadowMode::Selective,
        }
    }
}

impl<O: Occluders + ?Sized> Occluders for Culling<'_, O> {
    fn groups(&self) -> usize {
        self.of.groups()
    }

    fn group(&self, g: usize) -> (&[[Vec3; 3]], Option<Affine3A>) {
        self.of.group(g)
    }

    fn closed(&self, g: usize) -> bool {
        self.on && self.of.closed(g)
    }

    fn triangle_count(&self) -> usize {
        self.of.triangle_count()
    }
}
