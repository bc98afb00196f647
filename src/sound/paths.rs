//! Sound paths: what a frustum containing the listener yields, checked leg by leg with exact rays.
//!
//! Discrete frustum tracing decides each reflection by a sub-frustum's centre ray, so a frustum can reach
//! past the edge of its reflector (grazing angles, thesis §6.1.7) or past an occluder its centre ray missed.
//! A candidate path is therefore validated the way image-source methods validate theirs: from the listener
//! back towards each image source, the nearest hit must be the named reflector, and the last leg to the
//! source must be free. Paths found are then exact (delay and direction to float rounding); sampling only
//! ever loses paths, never invents one. Cost: one ray per leg of each candidate. A reflection within
//! [`EDGE_MARGIN`] (barycentric) of a triangle's edge is refused: a leg through an edge of a closed mesh
//! could otherwise reach the inside of the mesh.

use super::frustum::Frustum;
use super::material::BANDS;
use super::scene::SoundScene;
use crate::Ray;
use glam::Vec3;

/// One propagation path from a source to the listener.
#[derive(Clone, Debug, PartialEq)]
pub struct SoundPath {
    /// Number of specular reflections (0: the direct path).
    pub order: u32,
    /// Reflecting surfaces, first reflection first (ids of coplanar same-material triangle groups).
    pub surfaces: Vec<u32>,
    /// Path length in scene units (metres for [`SoundConfig::speed_of_sound`](super::SoundConfig)).
    pub length: f32,
    /// Travel time, `length / speed_of_sound`, in seconds.
    pub delay: f32,
    /// Unit direction from the listener towards where the sound arrives from.
    pub direction: Vec3,
    /// Energy per band relative to the source's energy at 1 unit: the product of the reflectances over
    /// the squared length (spherical spreading).
    pub attenuation: [f32; BANDS],
}

/// Relative offset of a leg's start along its segment, so a leg never hits the reflector it starts on.
const LEG_START: f32 = 1e-5;

/// Smallest barycentric weight a reflection point may have: paths reflecting this close to a triangle's
/// edge are dropped (also on a shared edge inside a surface, which loses a path of measure zero).
const EDGE_MARGIN: f32 = 1e-6;

/// The path `f` carries to `listener`, if `f` contains it and the path survives validation.
pub(crate) fn path_to(
    scene: &SoundScene,
    f: &Frustum,
    source: Vec3,
    listener: Vec3,
    speed: f32,
) -> Option<SoundPath> {
    if !f.contains(listener) {
        return None;
    }
    // Image sources: images[k] is the source mirrored in the first k reflectors.
    let mut images = vec![source];
    for &s in &f.chain {
        let pl = scene.surfaces[s as usize];
        let last = *images.last().expect("starts with the source");
        images.push(last - 2.0 * (pl.normal.dot(last) - pl.offset) * pl.normal);
    }
    let mut at = listener;
    let mut arrival = None;
    for (k, &s) in f.chain.iter().enumerate().rev() {
        let to = images[k + 1];
        let found = scene.hit(&Ray::with_range(at, to - at, LEG_START, 1.0), false)?;
        let hit = found.hit;
        // The named reflector, hit inside a triangle: a leg through a triangle's edge may be entering a
        // closed mesh through its edge (measure zero, but exactly what symmetric scenes produce).
        let inside = hit.u.min(hit.v).min(1.0 - hit.u - hit.v) > EDGE_MARGIN;
        if found.surface != s || !inside {
            return None;
        }
        let p = at + (to - at) * hit.t;
        arrival.get_or_insert(p);
        at = p;
    }
    let start = if f.chain.is_empty() { 0.0 } else { LEG_START };
    if scene
        .hit(&Ray::with_range(at, source - at, start, 1.0), true)
        .is_some()
    {
        return None;
    }
    let length = images.last().expect("non-empty").distance(listener);
    let direction = (arrival.unwrap_or(source) - listener).normalize_or_zero();
    let spread = 1.0 / (length * length);
    Some(SoundPath {
        order: f.chain.len() as u32,
        surfaces: f.chain.clone(),
        length,
        delay: length / speed,
        direction,
        attenuation: f.gain.map(|g| g * spread),
    })
}
