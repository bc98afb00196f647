//! The coherent ray-space hierarchy (CRSH, seed 002) through the two-level world: a hierarchy of
//! sphere–cone nodes over a batch of sorted world rays; each top node is tested against every mesh's
//! world bounding sphere (the per-BLAS spheres), then against the spheres of that mesh's triangles in
//! world space, the survivors go down the hierarchy, and each ray meets its survivors in the exact
//! watertight test — in the mesh's object space, as the BVH path tests them, so distances are the same.
//!
//! Cost: the world spheres of every triangle of every mesh (O(triangles) per batch), then one sphere test
//! per triangle of each reached mesh per top node: O(rays / s^D · triangles). The planner keeps it only
//! where that beats the BVH ([`SecondaryStrategy::Crsh`](super::SecondaryStrategy)).

use super::world::{Instance, nearer};
use super::{QueryFilter, TraceWorld};
use crate::bvh::Hit;
use crate::geometry::Ray;
use crate::raysort::RayHierarchy;
use crate::raysort::cone::bounding_sphere;
use crate::raysort::trace::exact_hit;
use crate::{Result, parallel};
use bevy_ecs::prelude::Entity;
use glam::Vec3;

/// One mesh as the hierarchy sees it: its world sphere and its triangles' (slot order).
struct MeshSpheres<'a> {
    entity: Entity,
    inst: &'a Instance,
    sphere: (Vec3, f32),
    triangles: Vec<(Vec3, f32)>,
}

/// For each of `rays` (valid world rays in hierarchy order, with their filters) the closest hit, or for
/// `any` some hit, as (entity, object-space hit). `Error::InvalidOption` for a hierarchy shape out of
/// range (see [`RayHierarchy::build`]).
pub(super) fn trace(
    world: &TraceWorld,
    rays: &[Ray],
    filters: &[&QueryFilter],
    any: bool,
    branching: usize,
    depth: usize,
) -> Result<Vec<Option<(Entity, Hit)>>> {
    let h = RayHierarchy::build(rays, branching, depth, true)?;
    let meshes: Vec<MeshSpheres> = (world.tlas_entities.iter())
        .map(|&e| (e, &world.instances[&e]))
        .filter(|(_, inst)| !inst.world_bounds.is_empty())
        .map(|(entity, inst)| {
            let t = inst.transform;
            let triangles = (inst.bvh.slot_triangles().iter())
                .map(|tri| bounding_sphere(&tri.map(|p| t.transform_point3(p))))
                .collect();
            MeshSpheres {
                entity,
                inst,
                sphere: bounding_sphere(&inst.world_bounds.corners()),
                triangles,
            }
        })
        .collect();
    let per_top = branching.pow(depth as u32);
    let mut out = vec![None; rays.len()];
    parallel::fill_chunks(true, &mut out, per_top, |top, out| {
        let walk = Walk {
            h: &h,
            rays,
            filters,
            any,
            base: top * per_top,
        };
        let node = &h.level(depth)[top];
        for m in &meshes {
            if node.hits_sphere(m.sphere.0, m.sphere.1) {
                let everything: Vec<u32> = (0..m.triangles.len() as u32).collect();
                walk.descend(m, depth, top, &everything, out);
            }
        }
    });
    Ok(out)
}

/// The traversal of one top node's subtree.
struct Walk<'a> {
    h: &'a RayHierarchy,
    rays: &'a [Ray],
    filters: &'a [&'a QueryFilter],
    any: bool,
    /// Hierarchy position of the top node's first ray (`out[0]`).
    base: usize,
}

impl Walk<'_> {
    /// Tests node `j` of level `k` against mesh `m`'s triangles `candidates` and takes the survivors
    /// down; at level 1, to the exact tests of the node's rays.
    fn descend(
        &self,
        m: &MeshSpheres,
        k: usize,
        j: usize,
        candidates: &[u32],
        out: &mut [Option<(Entity, Hit)>],
    ) {
        let survivors = (self.h).survivors(k, j, candidates, |t| m.triangles[t as usize]);
        if survivors.is_empty() {
            return;
        }
        for child in self.h.children(k, j, self.rays.len()) {
            if k == 1 {
                self.exact(m, child, &survivors, &mut out[child - self.base]);
            } else {
                self.descend(m, k - 1, child, &survivors, out);
            }
        }
    }

    /// The exact tests of hierarchy ray `i` against mesh `m`'s triangles `candidates`, in object space,
    /// within the ray's nearest hit so far (`found`, updated when one is nearer).
    fn exact(
        &self,
        m: &MeshSpheres,
        i: usize,
        candidates: &[u32],
        found: &mut Option<(Entity, Hit)>,
    ) {
        if !self.filters[i].accepts(m.entity, m.inst.layers) || (self.any && found.is_some()) {
            return;
        }
        let world_ray = &self.rays[i];
        let tmax = found.map_or(world_ray.tmax, |(_, h)| h.t);
        let ray = m.inst.object_ray(world_ray, tmax);
        let (tris, prims) = (m.inst.bvh.slot_triangles(), m.inst.bvh.bvh().prim_indices());
        let best = exact_hit(&ray, tmax, candidates, self.any, &mut 0, |s| {
            (prims[s as usize], tris[s as usize])
        });
        if let Some(h) = best
            && nearer(h.t, m.entity, found)
        {
            *found = Some((m.entity, h));
        }
    }
}
