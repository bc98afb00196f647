//! Exclusive prefix sums of a u32 buffer in place (shaders/scan.wgsl): each workgroup scans 256 elements
//! and writes its total one level up, the totals are scanned the same way, and the offsets are added back
//! down. Used by the radix sort (digit histograms) and by the binned SAH builder (partition flags).

use super::GpuContext;
use super::buffers::{GpuBuffer, ParamSlots, bind_group};

/// The levels of a scan over a fixed element count. Cost: about 1.004 passes over the data up and one down,
/// 2 dispatches per level (one level per factor of 256 elements); scratch of 4 bytes per 256 elements.
pub(crate) struct Scan {
    _params: ParamSlots,
    /// Per level: bind group (data, block totals) and element count, the data itself first.
    levels: Vec<(wgpu::BindGroup, u32)>,
    _sums: Vec<GpuBuffer>,
}

impl Scan {
    /// A scan of the first `n` elements of `data`.
    pub fn new(ctx: &GpuContext, data: &GpuBuffer, n: u32) -> Self {
        let mut sizes = vec![n.max(1)];
        while *sizes.last().unwrap() > 1 {
            sizes.push(sizes.last().unwrap().div_ceil(256));
        }
        let sums: Vec<GpuBuffer> = sizes[1..]
            .iter()
            .map(|&s| GpuBuffer::storage(ctx, "scan level", s as u64 * 4))
            .collect();
        let slots: Vec<[u32; 4]> = sizes.iter().map(|&s| [s, 0, 0, 0]).collect();
        let params = ParamSlots::new(ctx, &slots);
        let k = &ctx.kernels;
        let levels = (0..sizes.len() - 1)
            .map(|l| {
                let below = if l == 0 { data } else { &sums[l - 1] };
                let g = bind_group(
                    ctx,
                    &k.scan.layout,
                    &[below.binding(), sums[l].binding(), params.binding()],
                );
                (g, sizes[l])
            })
            .collect();
        Self {
            _params: params,
            levels,
            _sums: sums,
        }
    }

    /// Scratch memory held, in bytes.
    pub fn memory_bytes(&self) -> u64 {
        self._sums.iter().map(|b| b.buffer().size()).sum::<u64>() + self._params.memory_bytes()
    }

    /// Dispatches recorded per scan.
    pub fn dispatches(&self) -> u32 {
        (2 * self.levels.len()).saturating_sub(1) as u32
    }

    /// Records the scan. With `indirect = Some((args, offset))`, level `l`'s dispatches take their
    /// workgroup counts from the triple at `offset + 12·l` of `args` (zero to skip the scan).
    pub fn record(
        &self,
        ctx: &GpuContext,
        pass: &mut wgpu::ComputePass<'_>,
        indirect: Option<(&wgpu::Buffer, u64)>,
    ) {
        let k = &ctx.kernels;
        let dispatch = |pass: &mut wgpu::ComputePass<'_>, l: usize, size: u32| match indirect {
            Some((args, at)) => pass.dispatch_workgroups_indirect(args, at + 12 * l as u64),
            None => {
                let (x, y) = ctx.groups(size, 256);
                pass.dispatch_workgroups(x, y, 1);
            }
        };
        for (l, (g, size)) in self.levels.iter().enumerate() {
            pass.set_pipeline(k.scan.pipeline("scan_blocks"));
            pass.set_bind_group(0, g, &[ParamSlots::offset(l)]);
            dispatch(pass, l, *size);
        }
        for (l, (g, size)) in self.levels.iter().enumerate().rev().skip(1) {
            pass.set_pipeline(k.scan.pipeline("add_offsets"));
            pass.set_bind_group(0, g, &[ParamSlots::offset(l)]);
            dispatch(pass, l, *size);
        }
    }
}
