//! Where a pass's shadow map is rendered: on the CPU's threads, or elsewhere with the same arithmetic.

use super::{GBuffer, Occluders, ShadowMap};
use crate::Result;
use glam::Vec3;

/// What a hard selective pass's classification takes besides the map and the G-buffer
/// ([`MapRenderer::classify_hard`]).
#[doc(hidden)]
#[derive(Clone, Copy, Debug)]
pub struct HardClassify {
    /// Unit direction towards the light.
    pub towards: Vec3,
    /// The constant depth bias, in texels.
    pub bias_texels: f32,
    /// The `Δ` threshold, in world units.
    pub edge: f32,
    /// The receivers' bounds across the light (x, y) the map was fitted to, where receivers facing the
    /// light outside them are to be reported.
    pub fitted: Option<(Vec3, Vec3)>,
    /// Whether the G-buffer is new to the renderer: none of its classifications in this pass ran yet.
    pub fresh: bool,
    /// Whether the pass runs on all threads.
    pub parallel: bool,
}

/// What renders a [`HardShadows`](super::HardShadows) pass's shadow map
/// ([`run_with`](super::HardShadows::run_with)): [`CpuMap`], or `gpu::GpuShadowMap` (feature `gpu`).
/// Every renderer gives the same map (the GPU's where its kernels round as the CPU's do, see
/// `gpu::GpuShadowMap`), so the pass's image does not depend on the choice, only its cost. Sealed: the
/// crate's renderers are the only ones.
pub trait MapRenderer: sealed::Sealed {
    /// Renders `occluders` into `map` (already aimed at the light) over the receivers' bounds, as
    /// [`ShadowMap`]'s own render does. With `classify_next` (a hard selective pass, which asks
    /// [`classify_hard`](Self::classify_hard) next, before it reads the map), a renderer may leave the
    /// map's depths and point nearest the light to be filled in there, with the classes.
    #[doc(hidden)]
    #[allow(clippy::too_many_arguments)] // each one thing the render reads, as `ShadowMap::render`'s
    fn render_map(
        &mut self,
        map: &mut ShadowMap,
        occluders: &(impl Occluders + ?Sized),
        receivers: (Vec3, Vec3),
        spread: f32,
        res: usize,
        parallel: bool,
        classify_next: bool,
    ) -> Result<()>;

    /// Whether the map is rendered on the GPU ([`ShadowStats::map_on_gpu`](super::ShadowStats)).
    #[doc(hidden)]
    fn on_gpu(&self) -> bool {
        false
    }

    /// Classifies every pixel of `gbuffer` against `map`, which this renderer rendered last, for a hard
    /// selective pass: each pixel's class (`classify::Class` as a byte) into `classes`, four pixels a
    /// word from the lowest byte. Returns whether a receiver facing the light lies outside
    /// `job.fitted`, or `None` where the CPU classifies instead (the default). Either way `map` is
    /// whole on return (see [`render_map`](Self::render_map)'s `classify_next`); on an error, empty.
    #[doc(hidden)]
    fn classify_hard(
        &mut self,
        _map: &mut ShadowMap,
        _gbuffer: &GBuffer,
        _job: &HardClassify,
        _classes: &mut Vec<u32>,
    ) -> Result<Option<bool>> {
        Ok(None)
    }
}

/// The shadow map rendered on the CPU, on all threads where the pass runs in parallel: what
/// [`HardShadows::run`](super::HardShadows::run) uses.
#[derive(Clone, Copy, Debug, Default)]
pub struct CpuMap;

impl MapRenderer for CpuMap {
    fn render_map(
        &mut self,
        map: &mut ShadowMap,
        occluders: &(impl Occluders + ?Sized),
        receivers: (Vec3, Vec3),
        spread: f32,
        res: usize,
        parallel: bool,
        _classify_next: bool,
    ) -> Result<()> {
        map.render(occluders, receivers, spread, res, parallel);
        Ok(())
    }
}

pub(crate) mod sealed {
    /// Keeps [`MapRenderer`](super::MapRenderer) to the crate's renderers.
    pub trait Sealed {}
    impl Sealed for super::CpuMap {}
    #[cfg(feature = "gpu")]
    impl Sealed for crate::gpu::GpuShadowMap {}
}
