//! Per-pixel classification against the shadow map (thesis §6.3.3): lit, shadowed, or potentially
//! incorrect (a shadow ray decides).

use super::ShadowMap;
use super::deltas::Deltas;
use glam::{Vec2, Vec3};

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

impl Class {
    /// The class whose code (`as u8`) is `code`, as the GPU's classification writes it
    /// (shaders/shadow_classify.wgsl); a code that is none: marked (a ray decides).
    #[inline(always)]
    pub(super) fn from_code(code: u8) -> Class {
        match code {
            0 => Class::Empty,
            1 => Class::FacingAway,
            2 => Class::Lit,
            3 => Class::Shadowed,
            _ => Class::Marked,
        }
    }
}

/// The slope-scaled bias, in world units, of a receiver with `cos = n·L`: a receiver no more than this
/// behind the map's depth counts as the surface itself. The constant bias plus how far the receiver's
/// own surface can move in depth across one texel (diagonal), `w·√2·tan θ`, `cos θ = n·L` (the
/// orthographic form of the thesis's `d − d̂`, `d̂ = d·sin β / sin(α + β)`), `cos θ` kept above 1/64 so a
/// grazing receiver gets a large but finite bias.
fn slope_bias(map: &ShadowMap, cos: f32, bias_texels: f32) -> f32 {
    let cos = cos.max(1.0 / 64.0);
    let tan = (1.0 - cos * cos).max(0.0).sqrt() / cos;
    let w = map.texel_size();
    w * bias_texels + w * std::f32::consts::SQRT_2 * tan
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
    if d <= s + map.texel_size() * bias_texels || d <= s + slope_bias(map, cos, bias_texels) {
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

/// The selective classification of the receiver at `p` (unit normal `nrm`, `cos = n·L > 0`): where the
/// map's neighbourhood is smooth (`Δ ≤ edge`) the map decides; at a depth discontinuity the depths of the
/// four texels whose centres surround the receiver ([`ShadowMap::around`]: the map's samples nearest its
/// ray, all it knows there) are compared with the receiver's tangent plane at those centres — where its
/// own surface would put them ([`slope`]) — less the constant bias: lit when none lies in front of the
/// plane (nothing the map saw there can shade it: the occluder's own lit side next to its silhouette, a
/// convex surface curving away from the light), shadowed when all do, else the receiver is marked.
/// (The thesis compares the receiver's span within a texel, `[d̂, d]`, with `[s − Δ, s + Δ]`; the plane
/// is that span taken along each texel's direction rather than its widest. The span as the nearest and
/// farthest of the four instead marked the lit side of every slope towards the light: on the full crowd
/// 3.99% of the pixels against 2.38%, with 0.005% and 0.021% of the image unlike the ray-traced one.)
/// Off the map, over an empty texel (geometry too thin for the map) or under a normal that is not finite:
/// marked. `deltas` holds the map's depth at each smooth texel.
#[inline(always)]
pub(super) fn selective(
    map: &ShadowMap,
    deltas: &Deltas,
    p: Vec3,
    nrm: Vec3,
    cos: f32,
    bias_texels: f32,
) -> Class {
    let q = map.project(p);
    let Some((i, j)) = texel(map, q.x, q.y) else {
        return Class::Marked;
    };
    if !cos.is_finite() {
        // A broken normal (not finite): no slope to bias by nor plane to compare with, so a ray
        // decides, as in the ray-traced mode.
        return Class::Marked;
    }
    let d = q.z;
    // Most pixels: a smooth texel, decided by its depth alone (one read of the table).
    let smooth = deltas.smooth(i, j);
    if smooth.is_finite() {
        return verdict(map, d, smooth, cos, bias_texels);
    }
    if !map.depth(i, j).is_finite() {
        return Class::Marked;
    }
    // Not smooth and not empty: an edge texel (`Δ` above `edge`).
    let (depths, first) = map.around(q.x, q.y);
    let slope = slope(map, nrm, cos);
    if !slope.is_finite() {
        // A finite normal far from unit length can still overflow the slope: no plane to compare
        // with either.
        return Class::Marked;
    }
    let bias = map.texel_size() * bias_texels;
    let mut front = 0;
    for (k, s) in depths.into_iter().enumerate() {
        let at = first + Vec2::new((k & 1) as f32, (k >> 1) as f32);
        // An empty texel (infinitely deep) lies in front of nothing.
        front += (s < d + slope.x * at.x + slope.y * at.y - bias) as u32;
    }
    match front {
        0 => Class::Lit,
        4 => Class::Shadowed,
        _ => Class::Marked,
    }
}

/// How the depth of the receiver's tangent plane (unit normal `nrm`, `cos = n·L`) changes per texel
/// across the map, along its two axes: `w · (n·u, n·v) / cos`, `cos` kept above 1/64 as in
/// [`slope_bias`] (a grazing receiver's plane steep but finite).
#[inline]
fn slope(map: &ShadowMap, nrm: Vec3, cos: f32) -> Vec2 {
    map.across(nrm) * (map.texel_size() / cos.max(1.0 / 64.0))
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
