//! Per-pixel classification against the shadow map (thesis §6.3.3): lit, shadowed, or potentially
//! incorrect (a shadow ray decides).

use super::ShadowMap;
use super::deltas::Deltas;
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

/// The texel under map coordinates `(x, y)` when it has all eight neighbours, `None` when the point falls
/// outside the map's interior.
#[inline]
fn texel(map: &ShadowMap, x: f32, y: f32) -> Option<(usize, usize)> {
    // The interior is `[1, res − 1)` on both axes (`res − 1` is exact: at most 16383), NaN outside. Inside
    // it truncation is the floor and fits an `i32`: one instruction each, where the saturating `as`
    // conversions (to `usize`: about fifteen instructions per coordinate on x86-64, a sixth of a pixel's
    // classification; to `i32`: about six) check for NaN and overflow again.
    let last = (map.resolution() - 1) as f32;
    if !(x >= 1.0 && y >= 1.0 && x < last && y < last) {
        return None;
    }
    // SAFETY: `x` and `y` are finite and in `[1, 16383)` (checked above), so they truncate to an `i32`.
    let (i, j) = unsafe { (x.to_int_unchecked::<i32>(), y.to_int_unchecked::<i32>()) };
    Some((i as usize, j as usize))
}

/// The shadow map's verdict alone for the receiver at `p` (no edge test): lit when it is at most the bias
/// behind the nearest surface the light sees, or off the map.
pub(super) fn shadow_map_only(map: &ShadowMap, p: Vec3, cos: f32, bias_texels: f32) -> Class {
    let q = map.project(p);
    match texel(map, q.x, q.y) {
        Some((i, j)) => verdict(map, q.z, map.depth(i, j), cos, bias_texels),
        None => Class::Lit,
    }
}

/// The map's verdict for a receiver at depth `d` over a texel of depth `s`: lit when it is at most the
/// bias behind it. A receiver within the constant part of the bias is lit without the slope's square root
/// (the slope-scaled part only adds to it).
#[inline]
fn verdict(map: &ShadowMap, d: f32, s: f32, cos: f32, bias_texels: f32) -> Class {
    if d <= s + map.texel_size() * bias_texels || d <= s + tolerances(map, cos, bias_texels).bias {
        Class::Lit
    } else {
        Class::Shadowed
    }
}

/// The soft-shadow classification of a receiver that faces all of the light (`cos = n·L` above the
/// sine of the light's angular radius): marked where the penumbra `mask` covers its texel, off the map or
/// over an empty texel; elsewhere no edge's penumbra reaches it and the map decides as for hard shadows.
pub(super) fn soft(map: &ShadowMap, mask: &[bool], p: Vec3, cos: f32, bias_texels: f32) -> Class {
    let q = map.project(p);
    match texel(map, q.x, q.y) {
        Some((i, j)) if !mask[j * map.resolution() + i] && map.depth(i, j).is_finite() => {
            verdict(map, q.z, map.depth(i, j), cos, bias_texels)
        }
        _ => Class::Marked,
    }
}

/// The selective classification of the receiver at `p` (`cos = n·L > 0`): where the map's neighbourhood
/// is smooth (`Δ ≤ edge`) the map decides; at a depth discontinuity the depths of the four texels whose
/// centres surround the receiver ([`ShadowMap::around`]: the map's samples nearest its ray, all it knows
/// there) decide when they agree: lit when none lies in front of the receiver by more than the constant
/// bias (nothing the map saw there can shade it: the occluder's own lit side next to its silhouette),
/// shadowed when all lie in front of its depth span within one texel, `[d̂, d]`, by more than the bias;
/// else the receiver is marked. (The thesis compares `[d̂, d]` with `[s − Δ, s + Δ]`, which also marks a
/// receiver at the nearest depth beside a deeper neighbour: on the crowd, 13% more marked pixels for the
/// same image. The nearest and farthest of all nine texels instead of these four also mark a receiver
/// whose texel touches the edge only on its far side: on the quick crowd 1.56% of the pixels against
/// 0.99%, with 0.002% and 0.003% of the image unlike the ray-traced one.)
/// Off the map or over an empty texel (geometry too thin for the map): marked. `deltas` holds the map's
/// depth at each smooth texel.
#[inline]
pub(super) fn selective(
    map: &ShadowMap,
    deltas: &Deltas,
    p: Vec3,
    cos: f32,
    bias_texels: f32,
) -> Class {
    let q = map.project(p);
    let Some((i, j)) = texel(map, q.x, q.y) else {
        return Class::Marked;
    };
    let d = q.z;
    // Most pixels: a smooth texel, decided by its depth alone (one read of the table).
    let smooth = deltas.smooth(i, j);
    if smooth.is_finite() {
        return verdict(map, d, smooth, cos, bias_texels);
    }
    let s = map.depth(i, j);
    if !s.is_finite() {
        return Class::Marked;
    }
    // Not smooth and not empty: an edge texel (`Δ` above `edge`).
    let (lo, hi) = map
        .around(q.x, q.y)
        .into_iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), t| {
            (lo.min(t), hi.max(t))
        });
    let tol = tolerances(map, cos, bias_texels);
    if d <= lo + map.texel_size() * bias_texels {
        Class::Lit
    } else if d - tol.reach - tol.bias > hi {
        Class::Shadowed
    } else {
        Class::Marked
    }
}

/// A surface with normal `nrm`: `Empty` when it is none (a zero normal), `FacingAway` when `n·L` is at
/// most `away` (the light, along `towards`, does not reach it), else `n·L`.
#[inline]
pub(super) fn facing(nrm: Vec3, towards: Vec3, away: f32) -> Result<f32, Class> {
    let cos = nrm.dot(towards);
    if nrm == Vec3::ZERO {
        Err(Class::Empty)
    } else if cos <= away {
        Err(Class::FacingAway)
    } else {
        Ok(cos)
    }
}
