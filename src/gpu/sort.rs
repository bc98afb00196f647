//! Portable GPU radix sort of (u32 key, u32 value) pairs (shaders/sort.wgsl, shaders/scan.wgsl):
//! reduce-then-scan, 4 bits per pass, stable, no subgroup operations.

use super::GpuContext;
use super::buffers::{GpuBuffer, ParamSlots, bind_group, groups};

/// Sorts pairs held in two buffers in place, using a second pair of buffers and a histogram as scratch.
/// Cost per 4-bit pass: three dispatch groups over the keys (count, a scan of 16 counts per 256 keys,
/// scatter). Sizes are fixed at creation; make a new one for a different count.
pub(crate) struct RadixSort {
    n: u32,
    bits: u32,
    blocks: u32,
    _params: ParamSlots,
    /// [0]: A → B, [1]: B → A.
    sort_groups: [wgpu::BindGroup; 2],
    /// Scan levels: (bind group, element count), bottom (the histogram) first.
    scan_levels: Vec<(wgpu::BindGroup, u32)>,
    _scratch: Vec<GpuBuffer>,
}

impl RadixSort {
    /// A sorter for `n` pairs in `keys`/`vals` by their low `bits` bits.
    pub fn new(ctx: &GpuContext, keys: &GpuBuffer, vals: &GpuBuffer, n: u32, bits: u32) -> Self {
        let blocks = n.div_ceil(256).max(1);
        let keys2 = GpuBuffer::storage(ctx, "sort keys scratch", n as u64 * 4);
        let vals2 = GpuBuffer::storage(ctx, "sort vals scratch", n as u64 * 4);
        let passes = bits.div_ceil(4);
        // Histogram and scan levels: 16 counts per block, then one total per 256 of the level below.
        let mut sizes = vec![16 * blocks];
        while *sizes.last().unwrap() > 1 {
            sizes.push(sizes.last().unwrap().div_ceil(256));
        }
        let level_bufs: Vec<GpuBuffer> = sizes
            .iter()
            .map(|&s| GpuBuffer::storage(ctx, "sort scan level", s as u64 * 4))
            .collect();
        let mut slots: Vec<[u32; 4]> = (0..passes).map(|p| [n, 4 * p, blocks, 0]).collect();
        slots.extend(sizes.iter().map(|&s| [s, 0, 0, 0]));
        let params = ParamSlots::new(ctx, &slots);
        let k = &ctx.kernels;
        let hist = &level_bufs[0];
        let sort_groups = [
            bind_group(
                ctx,
                &k.sort.layout,
                &[
                    keys.binding(),
                    vals.binding(),
                    keys2.binding(),
                    vals2.binding(),
                    hist.binding(),
                    params.binding(),
                ],
            ),
            bind_group(
                ctx,
                &k.sort.layout,
                &[
                    keys2.binding(),
                    vals2.binding(),
                    keys.binding(),
                    vals.binding(),
                    hist.binding(),
                    params.binding(),
                ],
            ),
        ];
        let scan_levels = (0..sizes.len() - 1)
            .map(|l| {
                let g = bind_group(
                    ctx,
                    &k.scan.layout,
                    &[
                        level_bufs[l].binding(),
                        level_bufs[l + 1].binding(),
                        params.binding(),
                    ],
                );
                (g, sizes[l])
            })
            .collect();
        let mut scratch = level_bufs;
        scratch.extend([keys2, vals2]);
        Self {
            n,
            bits,
            blocks,
            _params: params,
            sort_groups,
            scan_levels,
            _scratch: scratch,
        }
    }

    /// Scratch memory held, in bytes.
    pub fn memory_bytes(&self) -> u64 {
        self._scratch.iter().map(|b| b.buffer().size()).sum()
    }

    /// Dispatches [`record`](Self::record) makes: per pass a count, the scan levels up and down, a scatter.
    pub fn dispatches(&self) -> u32 {
        if self.n < 2 || self.bits == 0 {
            return 0;
        }
        let levels = self.scan_levels.len() as u32;
        self.bits.div_ceil(4).next_multiple_of(2) * (2 + 2 * levels - 1)
    }

    /// Records the sort. An even number of passes leaves the result in the original buffers; an odd one
    /// in the scratch pair, so passes are always made even (a pass over zero bits is a stable no-op copy).
    pub fn record(&self, ctx: &GpuContext, pass: &mut wgpu::ComputePass<'_>) {
        if self.n < 2 || self.bits == 0 {
            return;
        }
        let k = &ctx.kernels;
        let passes = self.bits.div_ceil(4).next_multiple_of(2);
        let real = self.bits.div_ceil(4) as usize;
        for p in 0..passes as usize {
            // Extra passes reuse the last real pass's parameters: a repeated stable pass is a no-op order.
            let slot = ParamSlots::offset(p.min(real - 1));
            let g = &self.sort_groups[p % 2];
            let (x, y) = groups(self.blocks * 256, 256);
            pass.set_pipeline(k.sort.pipeline("count"));
            pass.set_bind_group(0, g, &[slot]);
            pass.dispatch_workgroups(x, y, 1);
            self.record_scan(ctx, pass);
            pass.set_pipeline(k.sort.pipeline("scatter"));
            pass.set_bind_group(0, g, &[slot]);
            pass.dispatch_workgroups(x, y, 1);
        }
    }

    /// Exclusive scan of the histogram, level by level up, then offsets added back down.
    fn record_scan(&self, ctx: &GpuContext, pass: &mut wgpu::ComputePass<'_>) {
        let k = &ctx.kernels;
        let real = self.bits.div_ceil(4) as usize;
        let slot = |l: usize| ParamSlots::offset(real + l);
        for (l, (g, size)) in self.scan_levels.iter().enumerate() {
            let (x, y) = groups(*size, 256);
            pass.set_pipeline(k.scan.pipeline("scan_blocks"));
            pass.set_bind_group(0, g, &[slot(l)]);
            pass.dispatch_workgroups(x, y, 1);
        }
        for (l, (g, size)) in self.scan_levels.iter().enumerate().rev().skip(1) {
            let (x, y) = groups(*size, 256);
            pass.set_pipeline(k.scan.pipeline("add_offsets"));
            pass.set_bind_group(0, g, &[slot(l)]);
            pass.dispatch_workgroups(x, y, 1);
        }
    }
}

/// Test hook (feature `testing`): sorts pairs on the GPU and reads them back, blocking. Stable; sorts by the
/// low `bits` bits of the keys.
#[cfg(feature = "testing")]
pub fn sort_pairs(
    ctx: &GpuContext,
    keys: &[u32],
    vals: &[u32],
    bits: u32,
) -> crate::Result<(Vec<u32>, Vec<u32>)> {
    assert_eq!(keys.len(), vals.len(), "one value per key");
    let n = keys.len() as u32;
    let kb = GpuBuffer::storage(ctx, "sort keys", n as u64 * 4);
    let vb = GpuBuffer::storage(ctx, "sort vals", n as u64 * 4);
    kb.write(ctx, keys);
    vb.write(ctx, vals);
    let sorter = RadixSort::new(ctx, &kb, &vb, n, bits);
    let mut enc = ctx.encoder();
    {
        let mut pass = enc.begin_compute_pass(&Default::default());
        sorter.record(ctx, &mut pass);
    }
    let rk = super::Readback::<u32>::record(ctx, &mut enc, kb.buffer(), keys.len());
    let rv = super::Readback::<u32>::record(ctx, &mut enc, vb.buffer(), vals.len());
    ctx.submit(enc);
    Ok((rk.wait(ctx)?, rv.wait(ctx)?))
}
