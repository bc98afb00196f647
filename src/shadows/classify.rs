//! Per-pixel classification against the shadow map (thesis §6.3.3): lit, shadowed, or potentially
//! incorrect (a shadow ray decides).

use super::ShadowMap;
use glam::Vec3;

/// What the shadow map says about one pixel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub(super) enum Class {
    /// No surface under the pixel.
    Empty,
    /// The surface faces away from the light: in its own (attached) shadow, no ray needed.
    FacingAway,
    /// The shadow map's answer is trusted: lit.
    Lit,
    /// The shadow map's answer is trusted: shadowed.
    Shadowed,
    /// A potentially incorrect pixel: a shadow ray decides.
    Marked,
}

/// Depth tolerances in world units for one receiver, from its slope towards the light.
struct Tolerances {
    /// Slope-scaled bias: a receiver no more than this behind the map's depth counts as the surface itself.
    bias: f32,
    /// How much nearer the light the receiver gets within one texel (diagonal): `d − d̂`.
    reach: f32,
}

/// How far the receiver's own surface can move in depth across one texel: `w·√2·tan θ`, `cos θ = n·L`
/// (the orthographic form of the thesis's `d̂ = d·sin β / sin(α + β)`), `cos θ` kept above 1/64 so a
/// grazing receiver gets a large but finite reach.
fn tolerances(map: &ShadowMap, cos: f32, bias_texels: f32) -> Tolerances {
    let cos = cos.max(1.0 / 64.0);
    let tan = (1.0 - cos * cos).max(0.0).sqrt() / cos;
    let w = map.texel_size();
    let reach = w * std::f32::consts::SQRT_2 * tan;
    Tolerances {
        bias: w * bias_texels + reach,
        reach,
    }
}

/// The shadow map's depth under a point and `Δ`, the largest depth difference to its eight neighbours
/// (infinite next to an empty texel or outside the map); `None` when the point falls outside the map.
fn sample(map: &ShadowMap, x: f32, y: f32) -> Option<(f32, f32)> {
    let res = map.resolution();
    // Truncation is the floor here: anything below 1 (NaN included) is off the map's interior.
    if !(x >= 1.0 && y >= 1.0) {
        return None;
    }
    let (i, j) = (x as usize, y as usize);
    if i >= res - 1 || j >= res - 1 {
        return None;
    }
    let s = map.depth(i, j);
    let mut delta = 0f32;
    for (di, dj) in [
        (0, 0),
        (1, 0),
        (2, 0),
        (0, 1),
        (2, 1),
        (0, 2),
        (1, 2),
        (2, 2),
    ] {
        let n = map.depth(i + di - 1, j + dj - 1);
        delta = delta.max(if n.is_finite() && s.is_finite() {
            (n - s).abs()
        } else {
            f32::INFINITY
        });
    }
    Some((s, delta))
}

/// The shadow map's verdict alone for the receiver at `p` (no edge test): lit when it is at most the bias
/// behind the nearest surface the light sees, or off the map.
pub(super) fn shadow_map_only(map: &ShadowMap, p: Vec3, cos: f32, bias_texels: f32) -> Class {
    let q = map.project(p);
    match sample(map, q.x, q.y) {
        Some((s, _)) if q.z > s + tolerances(map, cos, bias_texels).bias => Class::Shadowed,
        _ => Class::Lit,
    }
}

/// The selective classification of the receiver at `p` (`cos = n·L > 0`): where the map's neighbourhood
/// is smooth (`Δ ≤ edge`) the map decides; at a depth discontinuity the
/// receiver is marked when its depth span within one texel, `[d̂, d]`, overlaps the occluders' span
/// `[s − Δ, s + Δ]`, else the map decides. Off the map or over an empty texel (geometry too thin for the
/// map): marked.
pub(super) fn selective(map: &ShadowMap, p: Vec3, cos: f32, bias_texels: f32, edge: f32) -> Class {
    let q = map.project(p);
    let Some((s, delta)) = sample(map, q.x, q.y).filter(|(s, _)| s.is_finite()) else {
        return Class::Marked;
    };
    let tol = tolerances(map, cos, bias_texels);
    let d = q.z;
    if delta <= edge {
        if d <= s + tol.bias {
            Class::Lit
        } else {
            Class::Shadowed
        }
    } else if d - tol.reach - tol.bias <= s + delta && d + tol.bias >= s - delta {
        Class::Marked
    } else if d > s {
        Class::Shadowed
    } else {
        Class::Lit
    }
}
