//! Ray packets through the two-level world: coherent rays (a tile of camera rays, shadow segments toward
//! one point) meet each entity's structure as one packet ([`MeshBvh::closest_hits_packet`], or the grid's
//! packets for a mesh kept as a grid).
//!
//! The top level is walked ray by ray to collect the entities any ray of the packet reaches; the entities
//! are then visited nearest first, and each one traces — as a packet, in its object space — the rays whose
//! closest hit so far still lies beyond its world box. Answers equal [`TraceWorld::cast_ray`] and
//! [`TraceWorld::occluded`] ray by ray: the same distance, and the same entity and triangle unless two are
//! hit at exactly that distance. Use it for batches of at least a few coherent rays; a packet of scattered
//! rays costs about what single rays cost plus the entity sort. Allocates nothing once the thread's list of
//! reached entities has grown to the most a packet reached.

use super::world::{Instance, nearer, with_scratch};
use super::{QueryFilter, RayHit, TraceWorld};
use crate::bvh::{Hit, MAX_PACKET, traverse};
use crate::geometry::{Ray, hit_limit};
use bevy_ecs::prelude::Entity;
use glam::Vec3;
use std::cell::RefCell;

thread_local! {
    /// The entities a packet's rays reach at the top level (entry distance, top-level slot), kept per
    /// thread so that a warm packet allocates nothing; it grows to the most a packet has reached.
    static REACHED: RefCell<Vec<(f32, u32)>> = const { RefCell::new(Vec::new()) };
}

impl TraceWorld {
    /// [`cast_ray`](Self::cast_ray) for every ray of `rays` (hits within `min(ray.tmax, max_t)`), traced as
    /// packets of up to [`MAX_PACKET`] consecutive rays: give camera rays in tiles (4×4 or 8×8, tile after
    /// tile). `out` must be as long as `rays`. Single-threaded; the batched [`RayQueue`](super::RayQueue)
    /// spreads packets over threads.
    ///
    /// ```
    /// use kinetrace::ecs::{QueryFilter, TraceWorld};
    /// use kinetrace::Ray;
    /// use glam::Vec3;
    /// let world = TraceWorld::default(); // normally the plugin's resource
    /// let tile: Vec<Ray> = (0..64)
    ///     .map(|i| Ray::new(Vec3::Z * 5.0, Vec3::new((i % 8) as f32 * 0.01, (i / 8) as f32 * 0.01, -1.0)))
    ///     .collect();
    /// let mut hits = vec![None; tile.len()];
    /// world.cast_packet(&tile, 100.0, &QueryFilter::default(), &mut hits);
    /// assert!(hits.iter().all(Option::is_none)); // nothing in an empty world
    /// ```
    pub fn cast_packet(
        &self,
        rays: &[Ray],
        max_t: f32,
        filter: &QueryFilter,
        out: &mut [Option<RayHit>],
    ) {
        assert_eq!(rays.len(), out.len(), "one output per ray");
        for (rays, out) in rays.chunks(MAX_PACKET).zip(out.chunks_mut(MAX_PACKET)) {
            let mut world = [Ray::new(Vec3::ZERO, Vec3::X); MAX_PACKET];
            for (w, r) in world.iter_mut().zip(rays) {
                *w = r.clipped(max_t);
            }
            let world = &world[..rays.len()];
            let mut best = [None::<(Entity, Hit)>; MAX_PACKET];
            self.packet_entities(world, filter, |e, inst, object, idx, tmax| {
                let mut hits = [None; MAX_PACKET];
                let hits = &mut hits[..object.len()];
                inst.closest_hits_packet(object, hits);
                for (&i, h) in idx.iter().zip(hits.iter()) {
                    if let Some(h) = h
                        && nearer(h.t, e, &best[i])
                    {
                        best[i] = Some((e, *h));
                        tmax[i] = h.t;
                    }
                }
            });
            for (i, o) in out.iter_mut().enumerate() {
                *o = best[i].map(|(e, h)| self.instances[&e].world_hit(e, &world[i], &h));
            }
        }
    }

    /// [`occluded`](Self::occluded) for every segment `(from, to)`, as packets of up to [`MAX_PACKET`]:
    /// give shadow segments toward one light (or line-of-sight checks toward one point) together.
    pub fn occluded_packet(
        &self,
        segments: &[(Vec3, Vec3)],
        filter: &QueryFilter,
        out: &mut [bool],
    ) {
        assert_eq!(segments.len(), out.len(), "one output per segment");
        for (segs, out) in segments.chunks(MAX_PACKET).zip(out.chunks_mut(MAX_PACKET)) {
            let mut world = [Ray::new(Vec3::ZERO, Vec3::X); MAX_PACKET];
            for (w, &(from, to)) in world.iter_mut().zip(segs) {
                *w = Ray::segment(from, to);
            }
            let world = &world[..segs.len()];
            out.fill(false);
            self.packet_entities(world, filter, |_, inst, object, idx, tmax| {
                let mut hit = [false; MAX_PACKET];
                let hit = &mut hit[..object.len()];
                inst.any_hits_packet(object, hit);
                for (&i, &h) in idx.iter().zip(hit.iter()) {
                    if h {
                        // An occluded segment needs nothing more: no box is reached below −∞.
                        out[i] = true;
                        tmax[i] = f32::NEG_INFINITY;
                    }
                }
            });
        }
    }

    /// Visits the accepted entities that some ray of `rays` (up to [`MAX_PACKET`], world space) reaches,
    /// nearest first. For each, `visit(entity, instance, object_rays, indices, bounds)` traces the rays that
    /// still reach the entity's box — transformed to its object space with their current bound — and
    /// lowers `bounds[i]` of ray `i` when it found something nearer (−∞ ends the ray). The reached entities
    /// are gathered in the thread's [`REACHED`] list.
    fn packet_entities(
        &self,
        rays: &[Ray],
        filter: &QueryFilter,
        mut visit: impl FnMut(Entity, &Instance, &[Ray], &[usize], &mut [f32; MAX_PACKET]),
    ) {
        with_scratch(&REACHED, |scratch| {
            // Top level, ray by ray: each reached entity with the nearest entry of any ray into its box.
            // Each ray's slack for the whole scene (see `traverse`): the entities' boxes are tested
            // against its bound moved outward by it, as every traversal tests boxes.
            let world = self.tlas.bounds();
            let mut slack = [0.0f32; MAX_PACKET];
            for (s, r) in slack.iter_mut().zip(rays) {
                *s = r.hit_slack(&world);
            }
            for (r, &ray_slack) in rays.iter().zip(&slack).filter(|(r, _)| r.is_valid()) {
                traverse(self.tlas.nodes(), r, &mut (), |slots, _| {
                    for s in slots {
                        let p = self.tlas.prim_indices()[s];
                        let t = r
                            .intersect_aabb(
                                &self.tlas_bounds[p as usize],
                                hit_limit(r.tmax, ray_slack),
                            )
                            .unwrap_or(f32::INFINITY);
                        scratch.push((t, p));
                    }
                    false
                });
            }
            scratch.sort_unstable_by(|a, b| a.1.cmp(&b.1).then(a.0.total_cmp(&b.0)));
            scratch.dedup_by_key(|x| x.1);
            scratch.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let mut tmax = [f32::NEG_INFINITY; MAX_PACKET];
            for (t, r) in tmax.iter_mut().zip(rays) {
                if r.is_valid() {
                    *t = r.tmax;
                }
            }
            let mut object = [Ray::new(Vec3::ZERO, Vec3::X); MAX_PACKET];
            let mut idx = [0usize; MAX_PACKET];
            for &(_, p) in scratch.iter() {
                let e = self.tlas_entities[p as usize];
                let inst = &self.instances[&e];
                if !filter.accepts(e, inst.layers) {
                    continue;
                }
                let mut n = 0;
                for (i, r) in rays.iter().enumerate() {
                    let limit = hit_limit(tmax[i], slack[i]);
                    if tmax[i] >= r.tmin && r.intersect_aabb(&inst.world_bounds, limit).is_some() {
                        object[n] = inst.object_ray(r, tmax[i]);
                        idx[n] = i;
                        n += 1;
                    }
                }
                if n == 0 {
                    continue;
                }
                visit(e, inst, &object[..n], &idx[..n], &mut tmax);
            }
        });
    }
}
