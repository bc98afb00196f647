//! The geometry sound is traced through: one [`MeshBvh`], or the two-level scene the ray queries use (a
//! top-level tree over instances, each a mesh tree with a transform), plus each triangle's acoustic
//! surface.

use super::frustum::{Cull, box_distance};
use super::material::AcousticMaterial;
use crate::bvh::{Bvh, traverse, traverse_by};
use crate::geometry::{TriangleHit, TriangleRay, checked_inverse, hit_limit};
use crate::{Aabb, Error, MeshBvh, Ray, Result};
use glam::{Affine3A, Mat3A, Vec3};
use std::collections::HashMap;

/// No surface: a zero-area triangle, which neither reflects nor occludes.
pub(crate) const NO_SURFACE: u32 = u32::MAX;

/// A plane `normal · x = offset` (unit normal) with one material: the coplanar triangles of one material
/// merged, so a wall of two triangles reflects as one (thesis §6.1.3, merging of neighbouring coplanar
/// triangles). Coplanar triangles that do not touch merge too: both mirror the sound alike, and sub-frusta
/// through a gap between them hit something else, so no merged block spans it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Surface {
    pub normal: Vec3,
    pub offset: f32,
    pub material: u32,
}

/// One mesh placed in a two-level [`SoundScene`]: its object-space tree, the transform to world space and
/// the index of its material (every triangle of an instance shares it).
#[derive(Clone, Copy, Debug)]
pub struct SoundInstance<'a> {
    /// The mesh's tree, in object space.
    pub bvh: &'a MeshBvh,
    /// Object to world space; finite and invertible.
    pub transform: Affine3A,
    /// Index of the instance's material in the scene's materials.
    pub material: u32,
}

/// An instance as traversal needs it.
struct Placed<'a> {
    bvh: &'a MeshBvh,
    /// `None`: the identity (the tree is in world space).
    xf: Option<Xf>,
    /// Index of the instance's slot 0 in [`SoundScene::facets`].
    first: usize,
}

/// One triangle as tracing reads it, made once per scene so no test transforms a vertex or recomputes
/// a normal: world-space corners, the unnormalised normal `(b − a) × (c − a)` and the surface.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Facet {
    pub corners: [Vec3; 3],
    pub normal: Vec3,
    /// [`NO_SURFACE`] for a zero-area triangle.
    pub surface: u32,
}

/// A transform with what traversing its tree needs.
#[derive(Clone, Copy)]
struct Xf {
    to_world: Affine3A,
    to_object: Affine3A,
    /// `|M|`, the linear part's entries made non-negative: maps a box's half-extents to its world box's.
    abs: Mat3A,
}

impl Xf {
    fn new(to_world: Affine3A) -> Result<Self> {
        let m = to_world.matrix3;
        Ok(Self {
            to_world,
            to_object: checked_inverse(&to_world)?,
            abs: Mat3A::from_cols(m.x_axis.abs(), m.y_axis.abs(), m.z_axis.abs()),
        })
    }

    /// A lower bound of the world distance from `p` to the object-space box `b`: the distance to the world
    /// box around the transformed box (its centre mapped, its half-extents through `|M|`; exact for a
    /// transform without rotation), less a relative 1e-6 for rounding. About 40 flops, against 8 corners.
    #[inline]
    fn distance(&self, p: Vec3, b: &Aabb) -> f32 {
        let centre = self.to_world.transform_point3((b.min + b.max) * 0.5);
        let half = self.abs * ((b.max - b.min) * 0.5);
        let world = Aabb {
            min: centre - half,
            max: centre + half,
        };
        box_distance(p, &world) * (1.0 - 1e-6)
    }
}

impl Placed<'_> {
    /// Triangle `slot` in world space: the same arithmetic as transforming the mesh's vertices, so a
    /// copy of the world triangles gives bit-identical corners.
    fn world_triangle(&self, slot: usize) -> [Vec3; 3] {
        let t = self.bvh.slot_triangles()[slot];
        match self.xf {
            None => t,
            Some(x) => t.map(|p| x.to_world.transform_point3(p)),
        }
    }
}

/// Where a ray meets a scene: the hit and the surface hit.
pub(crate) struct SceneHit {
    pub hit: TriangleHit,
    pub surface: u32,
}

/// A scene ready for [`propagate`](super::propagate): the trees the ray queries use, each triangle's
/// material, and the coplanar surfaces.
///
/// Make one from a single world-space tree ([`new`](Self::new)) or, without copying any triangle, from
/// the top-level tree and the instances of a two-level scene ([`instanced`](Self::instanced)); both trace
/// the same world triangles with the same arithmetic, so they find the same paths. Building one groups the
/// triangles into surfaces in O(n) (a hash on the quantised world plane and the material) and keeps each
/// triangle's world corners and normal (52 bytes a triangle), so tracing never transforms a vertex; make a
/// new one after a tree is refitted, rebuilt or moved. Triangles whose unit normals agree to about 1e-4 and whose
/// plane offsets agree to 1e-4 of the scene's size share a surface.
pub struct SoundScene<'a> {
    /// The top-level tree (primitive `i` is `instances[i]`); `None`: one instance, traversed directly.
    top: Option<&'a Bvh>,
    /// `None`: an instance left out (it neither reflects nor occludes).
    instances: Vec<Option<Placed<'a>>>,
    /// Every slot of every instance (leaf order, instance after instance) in world space with its surface.
    facets: Vec<Facet>,
    pub(crate) surfaces: Vec<Surface>,
    pub(crate) materials: Vec<AcousticMaterial>,
}

/// Groups triangles into [`Surface`]s by quantised plane and material.
struct Grouping {
    size: f32,
    keys: HashMap<(i32, i32, i32, i32, u32), u32>,
    surfaces: Vec<Surface>,
}

impl Grouping {
    /// The triangle as a [`Facet`], its surface found or made.
    fn facet(&mut self, corners: [Vec3; 3], material: u32) -> Facet {
        let [a, b, c] = corners;
        let cross = (b - a).cross(c - a);
        Facet {
            corners,
            normal: cross,
            surface: self.surface(a, cross.normalize_or_zero(), material),
        }
    }

    /// The surface of a triangle with corner `a` and unit normal `normal` (zero: none).
    fn surface(&mut self, a: Vec3, normal: Vec3, material: u32) -> u32 {
        if normal == Vec3::ZERO {
            return NO_SURFACE;
        }
        let offset = normal.dot(a);
        let q = |x: f32| (x * 1e4).round() as i32;
        let key = (
            q(normal.x),
            q(normal.y),
            q(normal.z),
            q(offset / self.size),
            material,
        );
        let surfaces = &mut self.surfaces;
        *self.keys.entry(key).or_insert_with(|| {
            surfaces.push(Surface {
                normal,
                offset,
                material,
            });
            surfaces.len() as u32 - 1
        })
    }
}

impl<'a> SoundScene<'a> {
    /// Wraps `bvh` (world space); `triangle_materials[i]` is the index in `materials` of mesh triangle `i`.
    ///
    /// Errors: [`Error::InvalidOption`] when `triangle_materials` is not one entry per triangle or names a
    /// material that does not exist.
    pub fn new(
        bvh: &'a MeshBvh,
        triangle_materials: &[u32],
        materials: Vec<AcousticMaterial>,
    ) -> Result<Self> {
        let prims = bvh.bvh().prim_indices();
        if triangle_materials.len() != prims.len() {
            return Err(Error::InvalidOption(format!(
                "{} triangle materials for {} triangles",
                triangle_materials.len(),
                prims.len()
            )));
        }
        if let Some(i) = triangle_materials
            .iter()
            .position(|&m| m as usize >= materials.len())
        {
            return Err(Error::InvalidOption(format!(
                "triangle {i} names material {}, but there are {}",
                triangle_materials[i],
                materials.len()
            )));
        }
        let mut group = Grouping::new(bvh.bvh().bounds().extent().max_element());
        let facets = bvh
            .slot_triangles()
            .iter()
            .zip(prims)
            .map(|(t, &p)| group.facet(*t, triangle_materials[p as usize]))
            .collect();
        Ok(Self {
            top: None,
            instances: vec![Some(Placed {
                bvh,
                xf: None,
                first: 0,
            })],
            facets,
            surfaces: group.surfaces,
            materials,
        })
    }

    /// A two-level scene: `top` is a tree over the instances' world boxes whose primitive `i` is
    /// `instances[i]` (`None` leaves that primitive out). No tree is built: frusta and rays descend from
    /// `top` into each instance's tree with the inverse transform, as the ray queries do, and meet the
    /// triangles in world space, transformed once here. Cost: O(triangles) once to transform the
    /// triangles and group the surfaces.
    ///
    /// Errors: [`Error::InvalidOption`] when `instances` is not one entry per primitive of `top` or an
    /// instance names a material that does not exist; [`Error::InvalidTransform`] for a transform that is
    /// not finite or not invertible.
    pub fn instanced(
        top: &'a Bvh,
        instances: &[Option<SoundInstance<'a>>],
        materials: Vec<AcousticMaterial>,
    ) -> Result<Self> {
        if instances.len() != top.prim_indices().len() {
            return Err(Error::InvalidOption(format!(
                "{} instances for a top-level tree over {}",
                instances.len(),
                top.prim_indices().len()
            )));
        }
        let mut group = Grouping::new(top.bounds().extent().max_element());
        let mut facets = Vec::new();
        let mut placed = Vec::with_capacity(instances.len());
        for inst in instances {
            let Some(inst) = inst else {
                placed.push(None);
                continue;
            };
            if inst.material as usize >= materials.len() {
                return Err(Error::InvalidOption(format!(
                    "an instance names material {}, but there are {}",
                    inst.material,
                    materials.len()
                )));
            }
            let p = Placed {
                bvh: inst.bvh,
                xf: Some(Xf::new(inst.transform)?),
                first: facets.len(),
            };
            let slots = inst.bvh.slot_triangles().len();
            facets.extend((0..slots).map(|s| group.facet(p.world_triangle(s), inst.material)));
            placed.push(Some(p));
        }
        Ok(Self {
            top: Some(top),
            instances: placed,
            facets,
            surfaces: group.surfaces,
            materials,
        })
    }

    /// Number of coplanar surfaces the triangles were merged into.
    pub fn surface_count(&self) -> usize {
        self.surfaces.len()
    }

    /// Number of triangles traced (zero-area ones included).
    pub fn triangle_count(&self) -> usize {
        self.facets.len()
    }

    /// Every triangle as tracing reads it, for tests' brute-force oracles.
    #[cfg(test)]
    pub(crate) fn facets(&self) -> &[Facet] {
        &self.facets
    }

    /// Calls `f(placed)` for every instance whose world box `enter(box, bound)` accepts, nearest key first;
    /// `f` returns the new bound and whether to stop.
    fn instances_by<K: PartialOrd + Copy + Default>(
        &self,
        bound: K,
        enter: impl Fn(&Aabb, K) -> Option<K>,
        mut f: impl FnMut(&Placed<'a>, K) -> (K, bool),
    ) {
        let Some(top) = self.top else {
            if let Some(p) = &self.instances[0] {
                f(p, bound);
            }
            return;
        };
        traverse_by(
            top.nodes(),
            bound,
            &mut (),
            |n, b| enter(&n.aabb(), b),
            |slots, b| {
                for s in slots {
                    if let Some(p) = &self.instances[top.prim_indices()[s] as usize] {
                        let (nb, stop) = f(p, *b);
                        *b = nb;
                        if stop {
                            return true;
                        }
                    }
                }
                false
            },
        );
    }

    /// Frustum traversal: calls `tri(state, facet)` for every triangle with a surface in a leaf the
    /// frustum may overlap within `bound(state)` of its apex (re-read after every leaf).
    pub(crate) fn frustum_leaves<S>(
        &self,
        cull: &Cull,
        state: &mut S,
        mut tri: impl FnMut(&mut S, &Facet),
        bound: impl Fn(&S) -> f32,
    ) {
        let start = bound(state);
        self.instances_by(
            start,
            |b, d| {
                let e = box_distance(cull.apex, b);
                (e <= d && cull.may_overlap(b)).then_some(e)
            },
            |p, d| {
                let local = match p.xf {
                    None => *cull,
                    Some(x) => cull.in_object_space(&x.to_world, &x.to_object),
                };
                traverse_by(
                    p.bvh.bvh().nodes(),
                    d,
                    &mut (),
                    |n, d| {
                        let b = n.aabb();
                        let e = match p.xf {
                            None => box_distance(local.apex, &b),
                            Some(x) => x.distance(cull.apex, &b),
                        };
                        (e <= d && local.may_overlap(&b)).then_some(e)
                    },
                    |slots, d| {
                        for facet in &self.facets[p.first + slots.start..p.first + slots.end] {
                            if facet.surface != NO_SURFACE {
                                tri(state, facet);
                            }
                        }
                        *d = bound(state);
                        false
                    },
                );
                (bound(state), false)
            },
        );
    }

    /// The nearest triangle with a surface within the ray's range, or, with `any`, the first one found.
    pub(crate) fn hit(&self, ray: &Ray, any: bool) -> Option<SceneHit> {
        if !ray.is_valid() {
            return None;
        }
        let tr = TriangleRay::new(ray);
        let mut best: Option<SceneHit> = None;
        // Instances' boxes against the best `t` moved outward as every ray traversal moves it (see
        // `traverse`), so that the hit kept does not depend on the order the top level is visited in.
        let slack = self.top.map_or(0.0, |top| ray.hit_slack(&top.bounds()));
        self.instances_by(
            ray.tmax,
            |b, t| ray.intersect_aabb(b, hit_limit(t, slack)),
            |p, tmax| {
                let local = match p.xf {
                    None => *ray,
                    Some(x) => Ray::with_range(
                        x.to_object.transform_point3(ray.origin),
                        x.to_object.transform_vector3(ray.dir()),
                        ray.tmin,
                        tmax,
                    ),
                };
                let mut stop = false;
                let mut t = tmax;
                traverse(p.bvh.bvh().nodes(), &local, &mut (), |slots, tmax| {
                    for facet in &self.facets[p.first + slots.start..p.first + slots.end] {
                        if facet.surface == NO_SURFACE {
                            continue;
                        }
                        let [a, b, c] = facet.corners;
                        if let Some(hit) = tr.intersect(a, b, c, ray.tmin, *tmax) {
                            *tmax = hit.t;
                            best = Some(SceneHit {
                                hit,
                                surface: facet.surface,
                            });
                            if any {
                                stop = true;
                                return true;
                            }
                        }
                    }
                    t = *tmax;
                    false
                });
                (t, stop)
            },
        );
        best
    }
}

impl Grouping {
    fn new(size: f32) -> Self {
        Self {
            size: size.max(1e-6),
            keys: HashMap::new(),
            surfaces: Vec::new(),
        }
    }
}
