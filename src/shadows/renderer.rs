//! Where a pass's shadow map is rendered: on the CPU's threads, or elsewhere with the same arithmetic.

use super::{Occluders, ShadowMap};
use crate::Result;
use glam::Vec3;

/// What renders a [`HardShadows`](super::HardShadows) pass's shadow map
/// ([`run_with`](super::HardShadows::run_with)): [`CpuMap`], or `gpu::GpuShadowMap` (feature `gpu`).
/// Every renderer gives the same map (the GPU's where its kernels round as the CPU's do, see
/// `gpu::GpuShadowMap`), so the pass's image does not depend on the choice, only its cost. Sealed: the
/// crate's renderers are the only ones.
pub trait MapRenderer: sealed::Sealed {
    /// Renders `occluders` into `map` (already aimed at the light) over the receivers' bounds, as
    /// [`ShadowMap`]'s own render does.
    #[doc(hidden)]
    fn render_map(
        &mut self,
        map: &mut ShadowMap,
        occluders: &(impl Occluders + ?Sized),
        receivers: (Vec3, Vec3),
        spread: f32,
        res: usize,
        parallel: bool,
    ) -> Result<()>;

    /// Whether the map is rendered on the GPU ([`ShadowStats::map_on_gpu`](super::ShadowStats)).
    #[doc(hidden)]
    fn on_gpu(&self) -> bool {
        false
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
