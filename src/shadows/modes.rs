//! Each mode's classification of a run of neighbouring pixels ([`RunTest`]), in lanes of any width
//! ([`lanes`]): the lanes' verdicts where they settle a pixel, the mode's scalar test
//! ([`classify`]) pixel by pixel where they do not. One type per mode, so that each mode's loop is its
//! own, with its test inlined.

use super::ShadowMap;
use super::classify::{self, Class};
use super::deltas::Deltas;
use super::lanes::{self, Lanes, Run, Verdicts};
use glam::Vec3;

/// A mode's verdicts on a run of pixels.
pub(super) trait RunTest: Sync {
    /// The verdicts on `px`'s pixels.
    fn verdicts<L: Lanes>(&self, px: &Run<L>) -> Verdicts;
}

/// What every mode's scalar test reads: the direction towards the light, the `n · L` at or below which
/// a surface does not face it, and the constant bias in texels.
#[derive(Clone, Copy)]
pub(super) struct Light {
    pub towards: Vec3,
    pub away: f32,
    pub bias: f32,
}

impl Light {
    /// A pixel with no surface or one facing away from the light, else its `n · L`.
    #[inline(always)]
    fn facing(&self, nrm: Vec3) -> Result<f32, Class> {
        classify::facing(nrm, self.towards, self.away)
    }
}

/// A ray per pixel: every pixel facing the light marked.
pub(super) struct MarkFacing(pub Light);

impl RunTest for MarkFacing {
    #[inline(always)]
    fn verdicts<L: Lanes>(&self, px: &Run<L>) -> Verdicts {
        lanes::mark_facing(px, self.0.away)
    }
}

/// The shadow map alone: its depth decides every pixel facing the light.
pub(super) struct MapOnly<'a> {
    pub map: &'a ShadowMap,
    pub light: Light,
}

impl RunTest for MapOnly<'_> {
    #[inline(always)]
    fn verdicts<L: Lanes>(&self, px: &Run<L>) -> Verdicts {
        let Self { map, light } = *self;
        let decided = lanes::decide(map, map.depths(), px, light.away, light.bias);
        lanes::or_each(
            px,
            decided.verdicts,
            decided.rest,
            #[inline(always)]
            |p, nrm| match light.facing(nrm) {
                Ok(cos) => classify::shadow_map_only(map, p, cos, light.bias),
                Err(c) => c,
            },
        )
    }
}

/// Selective soft shadows: marked where a penumbra may fall (`mask`) or the surface sees only part of
/// the light's disc (`n · L` at most `horizon`), else as the map says.
pub(super) struct Soft<'a> {
    pub map: &'a ShadowMap,
    pub mask: &'a [bool],
    pub horizon: f32,
    pub light: Light,
}

impl RunTest for Soft<'_> {
    #[inline(always)]
    fn verdicts<L: Lanes>(&self, px: &Run<L>) -> Verdicts {
        let Self {
            map,
            mask,
            horizon,
            light,
        } = *self;
        lanes::each(
            px,
            #[inline(always)]
            |p, nrm| match light.facing(nrm) {
                Ok(cos) if cos <= horizon => Class::Marked,
                Ok(cos) => classify::soft(map, mask, p, cos, light.bias),
                Err(c) => c,
            },
        )
    }
}

/// Selective hard shadows: the map decides over smooth texels (`deltas`), the receiver's tangent plane
/// at edge texels, a ray where neither can.
pub(super) struct Selective<'a> {
    pub map: &'a ShadowMap,
    pub deltas: &'a Deltas,
    pub light: Light,
}

impl RunTest for Selective<'_> {
    #[inline(always)]
    fn verdicts<L: Lanes>(&self, px: &Run<L>) -> Verdicts {
        let Self { map, deltas, light } = *self;
        let decided = lanes::decide(map, deltas.table(), px, light.away, light.bias);
        // At shadow edges in lanes too; what is left (off the map, a normal that is not finite) is
        // marked by the scalar test.
        let edges = lanes::edges(map, px, &decided, light.bias);
        let rest = decided.rest & !decided.edge;
        lanes::or_each(
            px,
            decided.verdicts | edges,
            rest,
            #[inline(always)]
            |p, nrm| match light.facing(nrm) {
                Ok(cos) => classify::selective(map, deltas, p, nrm, cos, light.bias),
                Err(c) => c,
            },
        )
    }
}
