//! The sorted order of a secondary batch on the GPU (feature `gpu`): keys in WGSL
//! (`shaders/raysort_keys.wgsl`, the layouts of [`key`](super::key)), then the crate's stable radix sort
//! twice — by key, then by a 1-bit invalid flag that moves the trimmed rays behind the valid ones.
//!
//! When to use it: batches whose rays already live on the GPU or are large enough that one upload and a
//! read-back cost less than the CPU key pass and sort (measure with `bench raysort`). Cost: one upload of 48
//! bytes per ray, an origin-bounds pass (global atomics), a key pass, 8 radix passes for 32-bit keys plus 2
//! for the flag, and a read-back of 16 bytes per ray. Unlike [`sort_rays`](super::sort_rays) it sorts
//! the rays themselves, not the chunks of equal key: no compression.
//!
//! The answer equals [`sort_rays`](super::sort_rays)'s whenever the keys are equal (both sorts are stable
//! over request order). The key needs no `acos` or `atan2` (WGSL's may be 4096 ulps off), only division
//! and square root, which WGSL does not round correctly either, so a ray whose direction or origin cell
//! lies within rounding of a step boundary can land one step away.

use super::{KeyLayout, RayKind, SecondaryRay, SortedRays};
use crate::Result;
use crate::gpu::GpuContext;
use crate::gpu::buffers::{GpuBuffer, ParamSlots, bind_group};
use crate::gpu::sort::RadixSort;

/// One ray as `shaders/raysort_keys.wgsl` reads it (48 bytes).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuRay {
    /// Start point.
    origin: [f32; 3],
    /// Light index of a shadow ray (0 for reflection rays).
    light: u32,
    /// Direction as [`Ray::dir`](crate::Ray::dir) holds it.
    dir: [f32; 3],
    /// Range start.
    tmin: f32,
    /// Range end.
    tmax: f32,
    /// 0 shadow, 1 reflection.
    kind: u32,
    _pad: [u32; 2],
}
const _: () = assert!(std::mem::size_of::<GpuRay>() == 48);

impl GpuRay {
    fn new(r: &SecondaryRay) -> Self {
        let (light, kind) = match r.kind {
            RayKind::Shadow { light } => (light, 0),
            RayKind::Reflection => (0, 1),
        };
        Self {
            origin: r.ray.origin.to_array(),
            light,
            dir: r.ray.dir().to_array(),
            tmin: r.ray.tmin,
            tmax: r.ray.tmax,
            kind,
            _pad: [0; 2],
        }
    }
}

/// Sorts `rays` on the GPU and reads the order back, blocking; `Error::InvalidOption` for a layout over 32
/// bits, `Error::Gpu`-family errors from the device. Same contract as [`sort_rays`](super::sort_rays):
/// valid rays by key (stable), then the invalid ones in request order; tags stay with their rays through
/// `order` (the request index).
pub fn sort_rays_gpu(
    ctx: &GpuContext,
    rays: &[SecondaryRay],
    layout: &KeyLayout,
) -> Result<SortedRays> {
    layout.validate()?;
    if rays.is_empty() {
        return Ok(SortedRays::default());
    }
    let n = rays.len() as u32;
    let packed: Vec<GpuRay> = rays.iter().map(GpuRay::new).collect();
    let input = GpuBuffer::storage(ctx, "raysort rays", n as u64 * 48);
    input.write(ctx, &packed);
    let keys = GpuBuffer::storage(ctx, "raysort keys", n as u64 * 4);
    let vals = GpuBuffer::storage(ctx, "raysort order", n as u64 * 4);
    let info = GpuBuffer::storage(ctx, "raysort info", n as u64 * 8);
    let bounds = GpuBuffer::storage(ctx, "raysort bounds", 24);
    bounds.write(ctx, &[u32::MAX, u32::MAX, u32::MAX, 0, 0, 0]);
    let packed_layout = layout.light_bits << 24
        | layout.shadow_direction_bits << 16
        | layout.origin_bits << 8
        | layout.reflection_direction_bits;
    let params = ParamSlots::new(ctx, &[[n, packed_layout, 0, 0]]);
    let module = &ctx.kernels.raysort;
    let group = bind_group(
        ctx,
        &module.layout,
        &[
            input.binding(),
            keys.binding(),
            vals.binding(),
            info.binding(),
            bounds.binding(),
            params.binding(),
        ],
    );
    let key_bits = (layout.light_bits + 2 * layout.shadow_direction_bits)
        .max(3 * layout.origin_bits + 2 * layout.reflection_direction_bits);
    let by_key = RadixSort::new(ctx, &keys, &vals, n, key_bits);
    let by_flag = RadixSort::new(ctx, &keys, &vals, n, 1);
    let (x, y) = ctx.groups(n, 256);
    let mut enc = ctx.encoder();
    {
        let mut pass = enc.begin_compute_pass(&Default::default());
        let run = |pass: &mut wgpu::ComputePass<'_>, entry: &str| {
            pass.set_pipeline(module.pipeline(entry));
            pass.set_bind_group(0, &group, &[0]);
            pass.dispatch_workgroups(x, y, 1);
        };
        run(&mut pass, "origin_bounds");
        run(&mut pass, "ray_keys");
        by_key.record(ctx, &mut pass);
        run(&mut pass, "gather_invalid");
        by_flag.record(ctx, &mut pass);
        run(&mut pass, "gather_keys");
    }
    let order = crate::gpu::Readback::<u32>::record(ctx, &mut enc, vals.buffer(), rays.len());
    let sorted_keys = crate::gpu::Readback::<u32>::record(ctx, &mut enc, keys.buffer(), rays.len());
    ctx.submit(enc);
    let order = order.wait(ctx)?;
    let mut sorted_keys = sorted_keys.wait(ctx)?;
    let valid = order.partition_point(|&i| rays[i as usize].ray.is_valid());
    sorted_keys.truncate(valid);
    // The chunks the CPU sort would move: runs of equal key among the valid rays in request order.
    let mut by_request = vec![None; rays.len()];
    for (&i, &k) in order.iter().zip(&sorted_keys) {
        by_request[i as usize] = Some(k);
    }
    let mut chunks = 0;
    let mut last = None;
    for k in by_request.into_iter().flatten() {
        if last != Some(k) {
            chunks += 1;
            last = Some(k);
        }
    }
    Ok(SortedRays {
        order,
        keys: sorted_keys,
        chunks,
    })
}
