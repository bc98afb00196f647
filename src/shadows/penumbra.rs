//! Soft shadows of an area light (thesis §6.3.3): the light's sample directions, and the penumbra mask —
//! the shadow map's edge texels splatted with the light's shape, sized by how far a shadow can spread
//! from them.

use super::ShadowMap;
use glam::Vec3;
use std::f32::consts::TAU;

/// A disc-shaped light of angular radius `angle` around the unit direction `towards`, sampled with
/// `samples` directions per pixel: stratified over a ⌈√samples⌉² grid on the unit square, jittered per
/// pixel and sample by a hash of both (so any two passes over the same pixel use the same pattern), mapped
/// onto the disc (area-uniform) and tilted off `towards` by up to `tan(angle)`.
///
/// [`HardShadows`](super::HardShadows)'s soft mode samples it; use it to build a reference with the same
/// rays. A direction costs a hash, a `sin_cos` and a normalisation.
#[derive(Clone, Copy, Debug)]
pub struct LightDisc {
    towards: Vec3,
    /// The disc's axes, each `tan(angle)` long.
    u: Vec3,
    v: Vec3,
    samples: u32,
    grid: u32,
}

impl LightDisc {
    /// The light around `towards` (unit) of angular radius `angle` (radians), `samples` (≥ 1) per pixel.
    pub fn new(towards: Vec3, angle: f32, samples: u32) -> Self {
        let u = towards.any_orthonormal_vector();
        let tan = angle.tan();
        Self {
            towards,
            u: u * tan,
            v: towards.cross(u) * tan,
            samples,
            grid: (samples as f32).sqrt().ceil().max(1.0) as u32,
        }
    }

    /// Sample directions per pixel.
    pub fn samples(&self) -> u32 {
        self.samples
    }

    /// Direction `k` (below [`samples`](Self::samples)) of pixel `pixel`'s pattern: unit, towards the light.
    pub fn direction(&self, pixel: u32, k: u32) -> Vec3 {
        let h = hash((pixel as u64) << 32 | k as u64);
        let jitter = |bits: u64| (bits & 0xff_ffff) as f32 / (1u32 << 24) as f32;
        let g = self.grid as f32;
        let a = ((k % self.grid) as f32 + jitter(h)) / g;
        let b = ((k / self.grid % self.grid) as f32 + jitter(h >> 32)) / g;
        let (sin, cos) = (TAU * b).sin_cos();
        let r = a.sqrt();
        (self.towards + self.u * (r * cos) + self.v * (r * sin)).normalize()
    }
}

/// SplitMix64's finaliser: a well-mixed 64-bit hash of `x`.
fn hash(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Marks in `mask` (one flag per texel of `map`, row by row) every texel a penumbra may reach: each edge
/// texel (`Δ` above `edge`, or next to an empty texel) is splatted with a disc — the light's shape seen
/// along its centre direction — whose radius is how far the shadow of an occluder at the edge's nearest
/// depth `s` spreads on a receiver as deep as `deepest`: `(deepest − s)·tan(angle)`, plus the edge's own
/// texel diagonal. Conservative (every receiver is assumed as deep as the deepest); the thesis notes that
/// occluders near the light then mark large areas. Cost: O(texels + edge texels · splat area).
pub(super) fn mask(map: &ShadowMap, angle: f32, edge: f32, deepest: f32, mask: &mut Vec<bool>) {
    let res = map.resolution();
    mask.clear();
    mask.resize(res * res, false);
    let per_depth = angle.tan() / map.texel_size();
    for j in 1..res.saturating_sub(1) {
        for i in 1..res - 1 {
            let rows = map.rows3(i, j);
            let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
            for n in rows.iter().flat_map(|r| r.iter()) {
                (lo, hi) = (lo.min(*n), hi.max(*n));
            }
            if !lo.is_finite() || hi - lo <= edge {
                continue;
            }
            let r = (deepest - lo).max(0.0) * per_depth + std::f32::consts::SQRT_2;
            let reach = r.ceil() as usize;
            let (x0, x1) = (i.saturating_sub(reach), (i + reach).min(res - 1));
            let (y0, y1) = (j.saturating_sub(reach), (j + reach).min(res - 1));
            for y in y0..=y1 {
                let dy = y as f32 - j as f32;
                for x in x0..=x1 {
                    let dx = x as f32 - i as f32;
                    if dx * dx + dy * dy <= (r + 1.0) * (r + 1.0) {
                        mask[y * res + x] = true;
                    }
                }
            }
        }
    }
}
