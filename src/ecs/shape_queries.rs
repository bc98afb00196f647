//! Shape casts, closest points, overlaps and containment across every entity of the two-level scene.
//!
//! Each query walks the top level in world space and asks each accepted entity's tree in the frame where
//! the answer stays exact:
//!
//! - an entity placed by a *similarity* (rotation, translation and uniform scale — every rigid body, and
//!   most scaled ones) gets the query carried into its mesh's frame: spheres stay spheres, boxes stay boxes,
//!   times of impact are unchanged (the direction goes through the same map), distances scale back by the
//!   scale factor;
//! - an entity under a non-uniform scale or a shear, where a sphere would turn into an ellipsoid, is
//!   answered in the world on its triangles carried through the transform (exact, about twice the cost per
//!   box and triangle visited);
//! - containment needs no shape: the point goes into the mesh's frame for any invertible transform (its
//!   coordinates are rounded to `f32` there, so a point within an `f32` ulp of the surface of a transformed
//!   entity may be classed either way; untransformed entities are exact).
//!
//! A transform counts as a similarity when its axes are orthogonal and of equal length, and preserve
//! handedness, to a relative `1e-5` (what an `f32` rotation matrix reaches).

use super::{QueryFilter, TraceWorld, world::Instance};
use crate::bvh::traverse_by;
use crate::queries::{CastHit, Feature, Frame, PointHit, Shape, Sweep, box_dist2, sort_ascending};
use bevy_ecs::entity::Entity;
use glam::{Affine3A, Mat3, Quat, Vec2, Vec3};

/// Where a swept shape first touches an entity, in world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShapeHit {
    /// The entity touched.
    pub entity: Entity,
    /// Time of impact in units of the cast's direction (world units for a unit direction); 0 when the
    /// shape starts in contact.
    pub distance: f32,
    /// World-space contact point on the entity's surface.
    pub point: Vec3,
    /// Unit world-space normal at the contact, from the surface towards the shape (for a start in contact,
    /// the way out).
    pub normal: Vec3,
    /// Triangle index in the entity's mesh.
    pub triangle: u32,
    /// Barycentric weights of the triangle's second and third corners at the contact.
    pub barycentrics: Vec2,
    /// Face, edge or corner of the triangle at the contact.
    pub feature: Feature,
}

/// The point of an entity's surface nearest to a query point, in world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NearestPoint {
    /// The entity.
    pub entity: Entity,
    /// World-space nearest point.
    pub point: Vec3,
    /// World distance from the query point.
    pub distance: f32,
    /// Triangle index in the entity's mesh.
    pub triangle: u32,
    /// Barycentric weights of the triangle's second and third corners.
    pub barycentrics: Vec2,
    /// Face, edge or corner of the triangle.
    pub feature: Feature,
}

/// Sorts one entity's `(entity, triangle)` pairs by triangle. Up to 256 go through a stack buffer of `u32`s:
/// sorting the 16-byte pairs themselves cost twice as much (4.4 k instructions for the ~43 triangles of a
/// `bench queries` sphere overlap, 18% of the ECS row). The buffer is left uninitialised: zeroing its 1 KB
/// cost 390 instructions a query (3.1 M of the row's 20.8 M sort), for the ~43 entries used.
fn sort_triangles(run: &mut [(Entity, u32)]) {
    use std::mem::MaybeUninit;
    const BUFFER: usize = 256;
    if run.len() > BUFFER {
        run.sort_unstable_by_key(|&(_, t)| t);
        return;
    }
    let mut buffer = [MaybeUninit::<u32>::uninit(); BUFFER];
    for (slot, &(_, t)) in buffer.iter_mut().zip(run.iter()) {
        slot.write(t);
    }
    // SAFETY: the loop above wrote the first `run.len()` entries (`run.len() <= BUFFER`), and `u32` has no
    // invalid bit patterns or drop.
    let tris =
        unsafe { std::slice::from_raw_parts_mut(buffer.as_mut_ptr().cast::<u32>(), run.len()) };
    sort_ascending(tris);
    for (pair, &t) in run.iter_mut().zip(tris.iter()) {
        pair.1 = t;
    }
}

/// How an entity's transform lets a query through.
enum Placement {
    /// `transform = translation · scale · rotation`: the query goes into the mesh's frame (the rotation,
    /// which only a box needs, is taken from the transform by [`into_mesh`]).
    Similar { scale: f32 },
    /// Anything else: the query stays in the world, the triangles come out.
    General,
}

fn placement(inst: &Instance) -> Placement {
    match inst.similar_scale {
        Some(scale) => Placement::Similar { scale },
        None => Placement::General,
    }
}

/// The scale of `t` when it is a similarity (`translation · scale · rotation`, see the module docs), else
/// `None`. Kept with the instance's transform ([`Instance::similar_scale`]) and read from there by every
/// query, instead of three lengths, three dot products and a determinant per query and entity.
pub(super) fn similarity_scale(t: &Affine3A) -> Option<f32> {
    let m = t.matrix3;
    let cols = [m.x_axis, m.y_axis, m.z_axis];
    let lens = cols.map(|c| c.length());
    let s = (lens[0] + lens[1] + lens[2]) / 3.0;
    const TOL: f32 = 1e-5;
    let similar = s > 0.0
        && lens.iter().all(|l| (l / s - 1.0).abs() <= TOL)
        && [(0, 1), (1, 2), (2, 0)]
            .iter()
            .all(|&(i, j)| (cols[i].dot(cols[j]) / (s * s)).abs() <= TOL)
        && m.determinant() > 0.0;
    similar.then_some(s)
}

/// A world shape in the mesh's frame of an entity placed by a similarity of `scale`.
fn into_mesh(inst: &Instance, shape: &Shape, scale: f32) -> Shape {
    let p = |v: Vec3| inst.inverse.transform_point3(v);
    match *shape {
        Shape::Sphere { center, radius } => Shape::sphere(p(center), radius / scale),
        Shape::Capsule { a, b, radius } => Shape::capsule(p(a), p(b), radius / scale),
        Shape::Box {
            center,
            half,
            rotation: r,
        } => {
            let rotation = Quat::from_mat3(&(Mat3::from(inst.transform.matrix3) * (1.0 / scale)));
            Shape::cuboid(
                p(center),
                half / scale,
                (rotation.normalize().conjugate() * r).normalize(),
            )
        }
    }
}

impl Instance {
    /// A mesh-frame normal in the world.
    fn world_normal(&self, n: Vec3) -> Vec3 {
        (self.normal_matrix * glam::Vec3A::from(n))
            .normalize_or_zero()
            .into()
    }

    /// The first contact of the world `shape` swept along `dir` up to `max_t`.
    fn cast_shape(&self, e: Entity, shape: &Shape, dir: Vec3, max_t: f32) -> Option<ShapeHit> {
        let hit = |h: CastHit, mesh_frame: bool| ShapeHit {
            entity: e,
            distance: h.t,
            point: if mesh_frame {
                self.transform.transform_point3(h.point)
            } else {
                h.point
            },
            normal: if mesh_frame {
                self.world_normal(h.normal)
            } else {
                h.normal
            },
            triangle: h.primitive,
            barycentrics: Vec2::new(h.u, h.v),
            feature: h.feature,
        };
        match placement(self) {
            Placement::Similar { scale } => {
                let local = into_mesh(self, shape, scale);
                let d = self.inverse.transform_vector3(dir);
                let h = self.bvh.cast_shape_in(&local, d, max_t, Frame::Mesh)?;
                Some(hit(h, true))
            }
            Placement::General => {
                let frame = Frame::world(&self.transform);
                let h = self.bvh.cast_shape_in(shape, dir, max_t, frame)?;
                Some(hit(h, false))
            }
        }
    }

    /// The nearest point to the world point `p` within the world distance `max_distance`.
    fn closest_point(&self, e: Entity, p: Vec3, max_distance: f32) -> Option<NearestPoint> {
        let hit = |h: PointHit, point: Vec3, distance: f32| NearestPoint {
            entity: e,
            point,
            distance,
            triangle: h.primitive,
            barycentrics: Vec2::new(h.u, h.v),
            feature: h.feature,
        };
        match placement(self) {
            Placement::Similar { scale } => {
                let local = self.inverse.transform_point3(p);
                let h = self
                    .bvh
                    .closest_point_in(local, max_distance / scale, Frame::Mesh)?;
                let point = self.transform.transform_point3(h.point);
                Some(hit(h, point, h.distance * scale)).filter(|h| h.distance <= max_distance)
            }
            Placement::General => {
                let frame = Frame::world(&self.transform);
                let h = self.bvh.closest_point_in(p, max_distance, frame)?;
                Some(hit(h, h.point, h.distance))
            }
        }
    }

    /// Calls `found` with each triangle the world `shape` overlaps.
    fn overlapping(&self, shape: &Shape, found: impl FnMut(u32)) {
        match placement(self) {
            Placement::Similar { scale } => {
                let local = into_mesh(self, shape, scale);
                self.bvh.overlapping_each(&local, Frame::Mesh, found);
            }
            Placement::General => {
                let frame = Frame::world(&self.transform);
                self.bvh.overlapping_each(shape, frame, found);
            }
        }
    }
}

impl TraceWorld {
    /// The accepted entity of a top-level slot, if the filter accepts it.
    fn accepted(&self, slot: usize, filter: &QueryFilter) -> Option<(Entity, &Instance)> {
        let e = self.tlas_entities[self.tlas.prim_indices()[slot] as usize];
        let inst = &self.instances[&e];
        filter.accepts(e, inst.layers).then_some((e, inst))
    }

    /// Sweeps `shape` (in world space) along `dir` up to `max_t` (in units of `dir`) and returns its first
    /// contact with an accepted entity: the earliest time of impact, among equal times the lowest entity.
    /// The conventions are [`MeshBvh::cast_sphere`](crate::MeshBvh::cast_sphere)'s (start in contact:
    /// distance 0 and the way out). An entity placed by a rotation, translation and uniform scale is
    /// queried in its mesh's frame; one under a non-uniform scale or a shear in world space on its
    /// transformed triangles (exact either way; the second costs about twice as much per box and triangle).
    /// An invalid shape or direction hits nothing.
    ///
    /// Cost: a top-level traversal of the boxes grown by the shape, nearest first, and one mesh cast per
    /// entity whose grown box the sweep reaches before the best hit so far. No allocation.
    pub fn cast_shape(
        &self,
        shape: &Shape,
        dir: Vec3,
        max_t: f32,
        filter: &QueryFilter,
    ) -> Option<ShapeHit> {
        let sweep = Sweep::of(shape, dir, max_t)?;
        let mut best: Option<ShapeHit> = None;
        traverse_by(
            self.tlas.nodes(),
            sweep.ray.tmax,
            &mut (),
            |n, tmax| sweep.enter(&n.aabb(), tmax),
            |slots, tmax| {
                for s in slots {
                    let Some((e, inst)) = self.accepted(s, filter) else {
                        continue;
                    };
                    let Some(h) = inst.cast_shape(e, shape, dir, *tmax) else {
                        continue;
                    };
                    if best.is_none_or(|b| (h.distance, h.entity) < (b.distance, b.entity)) {
                        best = Some(h);
                        *tmax = h.distance * (1.0 + 4.0 * f32::EPSILON) + f32::MIN_POSITIVE;
                    }
                }
                false
            },
        );
        best
    }

    /// The nearest point of an accepted entity's surface to `p`, if one lies within `max_distance`
    /// (`f32::INFINITY` for no limit); among entities at the same distance the lowest. Exact in `f64` per
    /// triangle as [`MeshBvh::closest_point`](crate::MeshBvh::closest_point), the distance rounded to `f32`
    /// in the world.
    ///
    /// Cost: best-first over the top level by box distance, one mesh query per entity whose box is nearer
    /// than the best point so far. No allocation.
    pub fn closest_point(
        &self,
        p: Vec3,
        max_distance: f32,
        filter: &QueryFilter,
    ) -> Option<NearestPoint> {
        if !p.is_finite() || max_distance.is_nan() || max_distance < 0.0 {
            return None;
        }
        let q = p.as_dvec3();
        let mut best: Option<NearestPoint> = None;
        traverse_by(
            self.tlas.nodes(),
            f64::from(max_distance).powi(2),
            &mut (),
            |n, bound| Some(box_dist2(&n.aabb(), q)).filter(|&d| d <= bound),
            |slots, bound| {
                for s in slots {
                    let Some((e, inst)) = self.accepted(s, filter) else {
                        continue;
                    };
                    let limit = best.map_or(max_distance, |b| b.distance);
                    let Some(h) = inst.closest_point(e, p, limit) else {
                        continue;
                    };
                    if best.is_none_or(|b| (h.distance, h.entity) < (b.distance, b.entity)) {
                        best = Some(h);
                        // Entities at the same distance are still visited (ties go to the lowest).
                        *bound = f64::from(h.distance).powi(2) * (1.0 + 1e-6);
                    }
                }
                false
            },
        );
        best
    }

    /// Writes into `out` (cleared first) every `(entity, triangle)` that the closed world `shape` touches
    /// or overlaps on accepted entities, sorted by entity then triangle. Decided in `f64` per triangle as
    /// [`MeshBvh::overlapping`](crate::MeshBvh::overlapping).
    ///
    /// Cost: the top-level boxes that overlap the shape's box, one mesh overlap query per entity reached, a
    /// sort of the answer. No allocation once `out` has grown to the answer's size.
    pub fn overlaps(&self, shape: &Shape, filter: &QueryFilter, out: &mut Vec<(Entity, u32)>) {
        out.clear();
        if !shape.is_valid() {
            return;
        }
        let bounds = shape.bounds();
        // Entities met in ascending order (one, say), each with its run sorted, leave a sorted list.
        let mut last: Option<Entity> = None;
        let mut in_order = true;
        traverse_by(
            self.tlas.nodes(),
            (),
            &mut (),
            |n, _| n.aabb().overlaps(&bounds).then_some(()),
            |slots, _| {
                for s in slots {
                    if let Some((e, inst)) = self.accepted(s, filter) {
                        let start = out.len();
                        inst.overlapping(shape, |t| out.push((e, t)));
                        if out.len() > start {
                            sort_triangles(&mut out[start..]);
                            in_order &= last.is_none_or(|l| l < e);
                            last = Some(e);
                        }
                    }
                }
                false
            },
        );
        if !in_order {
            out.sort_unstable();
        }
    }

    /// Writes into `out` (cleared first, sorted) the accepted entities whose closed meshes hold `p`, by
    /// [`MeshBvh::contains_point`](crate::MeshBvh::contains_point) (winding number; points on the surface
    /// are inside) in each mesh's frame.
    ///
    /// Cost: the top-level boxes holding `p`, one containment ray per entity reached. No allocation once
    /// `out` has grown to the answer's size.
    pub fn containing(&self, p: Vec3, filter: &QueryFilter, out: &mut Vec<Entity>) {
        out.clear();
        if !p.is_finite() {
            return;
        }
        traverse_by(
            self.tlas.nodes(),
            (),
            &mut (),
            |n, _| n.aabb().contains_point(p).then_some(()),
            |slots, _| {
                for s in slots {
                    if let Some((e, inst)) = self.accepted(s, filter)
                        && inst.bvh.contains_point(inst.inverse.transform_point3(p))
                    {
                        out.push(e);
                    }
                }
                false
            },
        );
        out.sort_unstable();
    }

    /// Whether entity `e` holds `p` (see [`containing`](Self::containing)); `None` when `e` is not traceable.
    pub fn contains_point(&self, e: Entity, p: Vec3) -> Option<bool> {
        let inst = self.instances.get(&e)?;
        Some(p.is_finite() && inst.bvh.contains_point(inst.inverse.transform_point3(p)))
    }
}
