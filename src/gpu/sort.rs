//! Portable GPU radix sort of (u32 key, u32 value) pairs (shaders/sort.wgsl, shaders/scan.wgsl):
//! reduce-then-scan, 4 bits per pass, stable, no subgroup operations.

use super::GpuContext;
use super::buffers::{GpuBuffer, ParamSlots, bind_group};
use super::scan::Scan;

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
    /// The scan of the digit histogram.
    scan: Scan,
    _scratch: Vec<GpuBuffer>,
}

impl RadixSort {
    /// A sorter for `n` pairs in `keys`/`vals` by their low `bits` bits, with ping-pong buffers of its own.
    pub fn new(ctx: &GpuContext, keys: &GpuBuffer, vals: &GpuBuffer, n: u32, bits: u32) -> Self {
        let keys2 = GpuBuffer::storage(ctx, "sort keys scratch", n as u64 * 4);
        let vals2 = GpuBuffer::storage(ctx, "sort vals scratch", n as u64 * 4);
        let mut sorter = Self::with_scratch(ctx, keys, vals, [&keys2, &vals2], n, bits);
        sorter._scratch.extend([keys2, vals2]);
        sorter
    }

    /// The same, ping-ponging through the caller's `scratch` (at least `4 n` bytes each, overwritten by
    /// every sort): buffers another phase of a build uses, so that the sort adds only its histogram.
    pub fn with_scratch(
        ctx: &GpuContext,
        keys: &GpuBuffer,
        vals: &GpuBuffer,
        [keys2, vals2]: [&GpuBuffer; 2],
        n: u32,
        bits: u32,
    ) -> Self {
        let blocks = n.div_ceil(256).max(1);
        // The histogram: 16 counts per block.
        let hist = GpuBuffer::storage(ctx, "sort histogram", 16 * blocks as u64 * 4);
        let scan = Scan::new(ctx, &hist, 16 * blocks);
        // One slot: each pass's digit comes from the device's pass slots.
        let params = ParamSlots::new(ctx, &[[n, 0, blocks, 0]]);
        let k = &ctx.kernels;
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
                    ctx.passes.binding(),
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
                    ctx.passes.binding(),
                ],
            ),
        ];
        let scratch = vec![hist];
        Self {
            n,
            bits,
            blocks,
            _params: params,
            sort_groups,
            scan,
            _scratch: scratch,
        }
    }

    /// Scratch memory held, in bytes (not the caller's scratch of [`with_scratch`](Self::with_scratch)).
    pub fn memory_bytes(&self) -> u64 {
        self._scratch.iter().map(|b| b.buffer().size()).sum::<u64>()
            + self.scan.memory_bytes()
            + self._params.memory_bytes()
    }

    /// Dispatches [`record`](Self::record) makes.
    pub fn dispatches(&self) -> u32 {
        if self.n < 2 || self.bits == 0 {
            return 0;
        }
        self.bits.div_ceil(4).next_multiple_of(2) * (2 + self.scan.dispatches())
    }

    /// Records the sort. An even number of passes leaves the result in the original buffers; an odd one
    /// in the scratch pair, so passes are always made even (a pass over zero bits is a stable no-op copy).
    pub fn record(&self, ctx: &GpuContext, pass: &mut wgpu::ComputePass<'_>) {
        if self.n < 2 || self.bits == 0 {
            return;
        }
        let k = &ctx.kernels;
        let passes = self.bits.div_ceil(4).next_multiple_of(2);
        debug_assert!(self.bits.div_ceil(4) as usize <= super::buffers::PASS_SLOTS);
        let real = self.bits.div_ceil(4) as usize;
        for p in 0..passes as usize {
            // Extra passes reuse the last real pass's parameters: a repeated stable pass is a no-op order.
            let slot = [0, ParamSlots::offset(p.min(real - 1))];
            let g = &self.sort_groups[p % 2];
            let (x, y) = ctx.groups(self.blocks * 256, 256);
            pass.set_pipeline(k.sort.pipeline("count"));
            pass.set_bind_group(0, g, &slot);
            pass.dispatch_workgroups(x, y, 1);
            self.scan.record(ctx, pass, None);
            pass.set_pipeline(k.sort.pipeline("scatter"));
            pass.set_bind_group(0, g, &slot);
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
