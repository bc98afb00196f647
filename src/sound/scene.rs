//! The geometry sound is traced through: a [`MeshBvh`] plus, per triangle, its acoustic surface.

use super::material::AcousticMaterial;
use crate::{Error, MeshBvh, Result};
use glam::Vec3;
use std::collections::HashMap;

/// No surface: a zero-area triangle, which neither reflects nor occludes.
pub(crate) const NO_SURFACE: u32 = u32::MAX;

/// A plane `normal · x = offset` (unit normal) with one material: the coplanar triangles of one material
/// merged, so a wall of two triangles reflects as one (thesis §6.1.3, merging of neighbouring coplanar
/// triangles).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Surface {
    pub normal: Vec3,
    pub offset: f32,
    pub material: u32,
}

/// A scene ready for [`propagate`](super::propagate): the tree the ray queries use, each triangle's
/// material, and the coplanar surfaces.
///
/// Building one groups the triangles into surfaces in O(n) (a hash on the quantised plane and the
/// material); make a new one after the tree is refitted or rebuilt. Triangles whose unit normals agree to
/// about 1e-4 and whose plane offsets agree to 1e-4 of the scene's size share a surface.
pub struct SoundScene<'a> {
    pub(crate) bvh: &'a MeshBvh,
    /// Surface of each slot (leaf order), [`NO_SURFACE`] for zero-area triangles.
    pub(crate) slot_surface: Vec<u32>,
    /// Surface of each mesh triangle.
    pub(crate) prim_surface: Vec<u32>,
    pub(crate) surfaces: Vec<Surface>,
    pub(crate) materials: Vec<AcousticMaterial>,
}

impl<'a> SoundScene<'a> {
    /// Wraps `bvh`; `triangle_materials[i]` is the index in `materials` of mesh triangle `i`.
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
        let size = bvh.bvh().bounds().extent().max_element().max(1e-6);
        let mut keys: HashMap<(i32, i32, i32, i32, u32), u32> = HashMap::new();
        let mut surfaces = Vec::new();
        let mut slot_surface = Vec::with_capacity(prims.len());
        let mut prim_surface = vec![NO_SURFACE; prims.len()];
        for (slot, [a, b, c]) in bvh.slot_triangles().iter().enumerate() {
            let normal = (*b - *a).cross(*c - *a).normalize_or_zero();
            let prim = prims[slot] as usize;
            if normal == Vec3::ZERO {
                slot_surface.push(NO_SURFACE);
                continue;
            }
            let offset = normal.dot(*a);
            let material = triangle_materials[prim];
            let q = |x: f32| (x * 1e4).round() as i32;
            let key = (
                q(normal.x),
                q(normal.y),
                q(normal.z),
                q(offset / size),
                material,
            );
            let id = *keys.entry(key).or_insert_with(|| {
                surfaces.push(Surface {
                    normal,
                    offset,
                    material,
                });
                surfaces.len() as u32 - 1
            });
            slot_surface.push(id);
            prim_surface[prim] = id;
        }
        Ok(Self {
            bvh,
            slot_surface,
            prim_surface,
            surfaces,
            materials,
        })
    }

    /// Number of coplanar surfaces the triangles were merged into.
    pub fn surface_count(&self) -> usize {
        self.surfaces.len()
    }
}
