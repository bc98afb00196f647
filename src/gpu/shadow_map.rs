//! The shadow map of a [`HardShadows`](crate::shadows::HardShadows) pass rendered on the GPU
//! (shaders/shadow_map.wgsl), texel for texel the map the CPU renders.

use super::GpuContext;
use super::buffers::{GpuBuffer, Readback, STORAGE, bind_group};
use crate::Result;
use crate::shadows::{
    self, GBuffer, HardClassify, MapRenderer, Occluders, ShadowMap, ToLight, unkey,
};
use glam::Vec3;

/// Renders [`HardShadows`](crate::shadows::HardShadows)' shadow maps on the GPU, and classifies a hard
/// selective pass's pixels against the map there (thesis §6.3: both are nearly free on a GPU): give it
/// to [`HardShadows::run_with`](crate::shadows::HardShadows::run_with).
///
/// The kernels take each corner into light space and rasterise every triangle with the CPU's operations
/// in the CPU's order (divisions rounded as the CPU rounds), so where the context compiles them without
/// contraction ([`GpuContext::contraction_free`]: Vulkan) each texel holds the depth the CPU map holds
/// (a zero's sign aside) and the pass's classification, rays and image are the CPU pass's; elsewhere
/// (Metal, DX12) up to the rounding of fused operations. Triangles that would need subnormal
/// arithmetic, which a GPU may flush to zero, cover nothing on either side (see the CPU rasteriser's
/// largest area). Use it where the GPU is free and the CPU is not: the map is the pass's one cost
/// proportional to the triangles (on the CPU, about 4–5 ms a pass for the 696k-triangle crowd on a 2-core
/// Intel VM, `bench shadows`). Costs per pass: the occluders uploaded, 36 bytes a triangle plus 68 a group
/// and 32 of parameters a submission; one submission and at most one blocking wait (two of each for an area
/// light's map, whose extent waits for the point nearest the light); 4 bytes a texel read back, straight
/// into the map. The classification (shaders/shadow_classify.wgsl: `classify::selective`'s operations in
/// its order, square roots and divisions rounded as the CPU rounds them, so each pixel gets the CPU's
/// class; off with [`set_classify`](Self::set_classify)) runs in the map's submission, after it, and its
/// results come back in the map's wait (twice where the pass fits its map twice, the G-buffer uploaded
/// once); it adds per pass the G-buffer uploaded, 24 bytes a pixel, 112 of parameters, and a byte a pixel
/// read back, which the CPU turns into the visibility and the list of marked pixels (about 1.2 ms for 1024²
/// pixels on 2 cores, against about 5 ms classifying). Its buffers grow to the largest scene, map and image
/// seen and are kept (a warm render allocates none; wgpu's command encoders and bind groups are made per
/// render). A GPU error (a map or scene larger than the device's buffers, say) is the pass's error; one
/// while rendering leaves the pass no map (0 × 0).
///
/// ```no_run
/// use kinetrace::gpu::{GpuContext, GpuShadowMap};
/// use kinetrace::shadows::{GBuffer, HardShadows, ShadowSettings};
/// use glam::Vec3;
/// # fn main() -> kinetrace::Result<()> {
/// let gpu = GpuContext::new()?;
/// let mut on_gpu = GpuShadowMap::new(&gpu);
/// let ground = vec![[Vec3::new(-9.0, 0.0, -9.0), Vec3::new(9.0, 0.0, -9.0), Vec3::new(0.0, 0.0, 9.0)]];
/// let mut g = GBuffer::new(1, 1);
/// g.set(0, Vec3::ZERO, Vec3::Y);
/// let mut pass = HardShadows::new();
/// let no_occluder = |_: Vec3, _: Vec3| false;
/// let lit = pass.run_with(&ShadowSettings::default(), &ground, &g, no_occluder, &mut on_gpu)?;
/// assert_eq!(lit[0], 1.0);
/// # Ok(()) }
/// ```
pub struct GpuShadowMap {
    ctx: GpuContext,
    corners: GpuBuffer,
    starts: GpuBuffer,
    to_light: GpuBuffer,
    depth: GpuBuffer,
    state: GpuBuffer,
    large: GpuBuffer,
    args: GpuBuffer,
    params: GpuBuffer,
    /// Bound for the arguments while `map_large` reads them as its dispatch's sizes (a buffer may not be
    /// both in one dispatch).
    stand_in: GpuBuffer,
    /// Each group's first triangle (then the count), its first byte (then the total), and its transform
    /// into light space, as uploaded.
    first: Vec<u32>,
    bytes: Vec<u64>,
    transforms: Vec<[f32; 16]>,
    /// Workgroups per dimension the large triangles' indirect dispatch folds at (`fold_groups` in the
    /// kernels): the device's limit, at most 65,535.
    max_groups: u32,
    /// The hard selective classification's G-buffer (12 bytes a pixel each), classes (a byte a pixel),
    /// flags and parameters.
    positions: GpuBuffer,
    normals: GpuBuffer,
    classes: GpuBuffer,
    flags: GpuBuffer,
    classify_params: GpuBuffer,
    /// Whether hard selective passes classify their pixels here ([`set_classify`](Self::set_classify)).
    classify: bool,
    /// The map's commands, recorded for a hard selective pass whose classification follows: they go in
    /// its submission, and the map is read back with the classes. The only map classified here (none
    /// when the map was left empty, failed, or was read back at once).
    pending: Option<wgpu::CommandEncoder>,
}

/// Words of the kernels' state: the nearest point's key and the count of triangles listed as large.
const STATE_WORDS: usize = 2;

/// The word of the classification's parameters that holds the nearest point's key, copied from the
/// state (`top` in shaders/shadow_classify.wgsl's `ClassifyParams`), and its byte.
const TOP_WORD: usize = 19;
const TOP_AT: u64 = TOP_WORD as u64 * 4;

impl GpuShadowMap {
    /// Empty buffers on `ctx`'s device; they grow on the first render.
    pub fn new(ctx: &GpuContext) -> Self {
        let storage = |label| GpuBuffer::storage(ctx, label, 256);
        Self {
            ctx: ctx.clone(),
            corners: storage("shadow map corners"),
            starts: storage("shadow map groups"),
            to_light: storage("shadow map transforms"),
            depth: storage("shadow map depths"),
            state: storage("shadow map state"),
            large: storage("shadow map large triangles"),
            args: GpuBuffer::new(
                ctx,
                "shadow map dispatch args",
                12,
                STORAGE | wgpu::BufferUsages::INDIRECT,
            ),
            params: storage("shadow map params"),
            stand_in: storage("shadow map stand-in"),
            first: Vec::new(),
            bytes: Vec::new(),
            transforms: Vec::new(),
            max_groups: ctx.max_groups().min(0xffff),
            positions: storage("shadow classification positions"),
            normals: storage("shadow classification normals"),
            classes: storage("shadow classification classes"),
            flags: storage("shadow classification flags"),
            classify_params: storage("shadow classification params"),
            classify: ctx.contraction_free(),
            pending: None,
        }
    }

    /// Whether hard selective passes also classify their pixels on the GPU, against the map still there:
    /// the G-buffer uploaded (24 bytes a pixel) and a byte a pixel read back, in the map's submission
    /// and wait, instead of the CPU's pass over the G-buffer (about 5 ms for 1024² pixels on 2 cores). Off,
    /// the CPU classifies against the map read back. On by default where the kernels round as the CPU
    /// does ([`GpuContext::contraction_free`]: Vulkan), so the classes, and the image, are the same;
    /// where they may fuse (Metal, DX12) the CPU classifies unless this turns it on. The CPU classifies
    /// anyway a G-buffer past the device's buffers and an edge threshold beyond `f32`. On a device that
    /// flushes subnormals, a receiver whose normal is far from unit length (about 10³⁶ and more), whose
    /// tangent plane's slope then needs a subnormal, may be classified otherwise.
    pub fn set_classify(&mut self, on_gpu: bool) {
        self.classify = on_gpu;
    }

    /// Test hook (feature `testing`): the large triangles' dispatch folds at `groups` workgroups per
    /// dimension (at least 1, at most the device's limit), so that tests reach its second and third
    /// dimensions without millions of large triangles.
    #[cfg(feature = "testing")]
    pub fn limit_workgroups(&mut self, groups: u32) {
        self.max_groups = groups.clamp(1, self.ctx.max_groups().min(0xffff));
    }

    /// Uploads `occluders` (a mebibyte a task across threads where `parallel`) and their transforms into
    /// `map`'s light space; returns the triangle count.
    fn upload(
        &mut self,
        map: &ShadowMap,
        occluders: &(impl Occluders + ?Sized),
        parallel: bool,
    ) -> Result<u32> {
        let ctx = &self.ctx;
        let light = map.light();
        self.first.clear();
        self.transforms.clear();
        let mut n = 0u64;
        for g in 0..occluders.groups() {
            let (tris, place) = occluders.group(g);
            self.first.push(n as u32);
            let to = ToLight::new(light, place, occluders.closed(g));
            let [x, y, z] = [to.m.x_axis, to.m.y_axis, to.m.z_axis];
            let t = to.t;
            self.transforms.push([
                x.x, x.y, x.z, 0.0, y.x, y.y, y.z, 0.0, z.x, z.y, z.z, 0.0, t.x, t.y, t.z, to.cull,
            ]);
            n += tris.len() as u64;
        }
        ctx.check_storage("shadow-map triangles", n * 36)?;
        ctx.check_threads("shadow-map triangles", n, 256)?;
        self.first.push(n as u32);
        let limit = ctx.storage_limit();
        self.corners.ensure_within(ctx, n * 36, limit);
        self.large.ensure_within(ctx, n * 4, limit);
        self.starts.ensure(ctx, self.first.len() as u64 * 4);
        self.to_light.ensure(ctx, self.transforms.len() as u64 * 64);
        self.bytes.clear();
        self.bytes.extend(self.first.iter().map(|&t| t as u64 * 36));
        let corners = |g: usize| bytemuck::cast_slice(occluders.group(g).0);
        ctx.write_buffer_parts(self.corners.buffer(), 0, &self.bytes, corners, parallel);
        self.starts.write(ctx, &self.first);
        self.to_light.write(ctx, &self.transforms);
        Ok(n as u32)
    }

    /// Writes the kernels' parameters: `n` triangles onto a map of `res` texels a side over `map`'s frame.
    fn set_params(&self, map: &ShadowMap, n: u32, res: usize) {
        let (.., corner, per_texel, _) = map.frame();
        let words = [
            n,
            self.transforms.len() as u32,
            res as u32,
            self.max_groups,
            corner.x.to_bits(),
            corner.y.to_bits(),
            per_texel.to_bits(),
            0,
        ];
        self.params.write(&self.ctx, &words);
    }

    /// Records the nearest point's reduction over `n` triangles (the state cleared first).
    fn record_top(&self, enc: &mut wgpu::CommandEncoder, group: &wgpu::BindGroup, n: u32) {
        enc.clear_buffer(self.state.buffer(), 0, None);
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("kinetrace shadow map top"),
            timestamp_writes: None,
        });
        pass.set_bind_group(0, group, &[]);
        pass.set_pipeline(self.ctx.kernels.shadow_map.pipeline("map_top"));
        let (x, y) = self.ctx.groups(n, 256);
        pass.dispatch_workgroups(x, y, 1);
    }

    /// Records into `enc` the read-back of the map of `texels` texels (its nearest point's key, then
    /// each texel's depth), submits it and blocks until `map` holds it, with `also` of the words after
    /// them (the parts `more`, at most two, reads back as well). An error leaves no map (0 × 0).
    fn read_map<R>(
        &self,
        map: &mut ShadowMap,
        mut enc: wgpu::CommandEncoder,
        texels: usize,
        more: &[(&wgpu::Buffer, usize)],
        also: impl FnOnce(&[u32]) -> R,
    ) -> Result<R> {
        // At most two more parts (no allocation: a fixed array, its unused slots never read).
        let mut parts = [
            (self.state.buffer(), 1),
            (self.depth.buffer(), texels),
            (self.state.buffer(), 0),
            (self.state.buffer(), 0),
        ];
        parts[2..2 + more.len()].copy_from_slice(more);
        let back = Readback::<u32>::record_parts(&self.ctx, &mut enc, &parts[..2 + more.len()]);
        self.ctx.submit(enc);
        let read = back.wait_with(&self.ctx, |words| {
            // A stored depth is its key complemented; 0 is an empty texel.
            let depth = &words[1..1 + texels];
            map.take_rendered(shadows::nearest(words[0]), |k| match depth[k] {
                0 => f32::INFINITY,
                d => unkey(!d),
            });
            also(&words[1 + texels..])
        });
        if read.is_err() {
            map.clear(0);
        }
        read
    }

    /// The kernels' bind group, with `args` bound for the dispatch arguments.
    fn bind(&self, args: &GpuBuffer) -> wgpu::BindGroup {
        bind_group(
            &self.ctx,
            &self.ctx.kernels.shadow_map.layout,
            &[
                self.corners.binding(),
                self.starts.binding(),
                self.to_light.binding(),
                self.depth.binding(),
                self.state.binding(),
                self.large.binding(),
                args.binding(),
                self.params.binding(),
            ],
        )
    }
}

impl MapRenderer for GpuShadowMap {
    fn on_gpu(&self) -> bool {
        true
    }

    fn render_map(
        &mut self,
        map: &mut ShadowMap,
        occluders: &(impl Occluders + ?Sized),
        receivers: (Vec3, Vec3),
        spread: f32,
        res: usize,
        parallel: bool,
        classify_next: bool,
    ) -> Result<()> {
        debug_assert!(
            self.pending.is_none(),
            "a map left for a classification never asked"
        );
        self.pending = None;
        let n = self.upload(map, occluders, parallel)?;
        let texels = (res * res) as u64;
        self.ctx.check_storage("shadow map", texels * 4)?;
        self.depth
            .ensure_within(&self.ctx, texels * 4, self.ctx.storage_limit());
        self.state.ensure(&self.ctx, STATE_WORDS as u64 * 4);
        // The point nearest the light: an area light's map first needs it to know its extent.
        let nearest = if spread > 0.0 && n > 0 {
            self.set_params(map, n, res);
            let mut enc = self.ctx.encoder();
            self.record_top(&mut enc, &self.bind(&self.args), n);
            let top = Readback::<u32>::record(&self.ctx, &mut enc, self.state.buffer(), 1);
            self.ctx.submit(enc);
            Some(top.wait(&self.ctx)?[0])
        } else {
            None
        };
        if !map.fit(receivers, spread, nearest.map(shadows::nearest), res, n > 0) {
            return Ok(());
        }
        self.set_params(map, n, res);
        let (group, reading_args) = (self.bind(&self.args), self.bind(&self.stand_in));
        let mut enc = self.ctx.encoder();
        if nearest.is_some() {
            // The nearest point is in the state already: only the large triangles' count starts afresh.
            enc.clear_buffer(self.state.buffer(), 4, Some(4));
        } else {
            self.record_top(&mut enc, &group, n);
        }
        enc.clear_buffer(self.depth.buffer(), 0, Some(texels * 4));
        {
            let k = &self.ctx.kernels.shadow_map;
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("kinetrace shadow map"),
                timestamp_writes: None,
            });
            pass.set_bind_group(0, &group, &[]);
            pass.set_pipeline(k.pipeline("map_small"));
            let (x, y) = self.ctx.groups(n, 256);
            pass.dispatch_workgroups(x, y, 1);
            pass.set_pipeline(k.pipeline("map_plan"));
            pass.dispatch_workgroups(1, 1, 1);
            pass.set_pipeline(k.pipeline("map_large"));
            pass.set_bind_group(0, &reading_args, &[]);
            pass.dispatch_workgroups_indirect(self.args.buffer(), 0);
        }
        if classify_next && self.classify {
            self.pending = Some(enc);
            return Ok(());
        }
        self.read_map(map, enc, texels as usize, &[], |_| ())
    }

    fn classify_hard(
        &mut self,
        map: &mut ShadowMap,
        gbuffer: &GBuffer,
        job: &HardClassify,
        classes: &mut Vec<u32>,
    ) -> Result<Option<bool>> {
        let ctx = &self.ctx;
        let pixels = gbuffer.positions.len();
        let words = pixels.div_ceil(4);
        let bytes = pixels as u64 * 12;
        // The CPU classifies what the kernel cannot: a G-buffer past the device's buffers or dispatch,
        // and an edge threshold beyond f32 (where the CPU's `Δ ≤ ∞` holds next to empty texels).
        let fits = ctx
            .check_storage("shadow classification G-buffer", bytes)
            .is_ok()
            && ctx
                .check_threads("shadow classification", words as u64, 256)
                .is_ok();
        // Only a map kept for it (rendered with `classify_next` while classifying here): the CPU
        // classifies any other, read back already.
        let Some(mut enc) = self.pending.take() else {
            return Ok(None);
        };
        let texels = map.resolution() * map.resolution();
        if !fits || !job.edge.is_finite() {
            // The CPU classifies, against the map read back now.
            self.read_map(map, enc, texels, &[], |_| ())?;
            return Ok(None);
        }
        let limit = ctx.storage_limit();
        if job.fresh {
            self.positions.ensure_within(ctx, bytes, limit);
            self.normals.ensure_within(ctx, bytes, limit);
            for (buffer, data) in [
                (&self.positions, &gbuffer.positions),
                (&self.normals, &gbuffer.normals),
            ] {
                let whole = |_| bytemuck::cast_slice(data);
                ctx.write_buffer_parts(buffer.buffer(), 0, &[0, bytes], whole, job.parallel);
            }
        }
        self.classes.ensure_within(ctx, words as u64 * 4, limit);
        self.flags.ensure(ctx, 4);
        let (u, v, t, corner, per_texel, _) = map.frame();
        let (lo, hi) = job.fitted.unwrap_or((Vec3::ZERO, Vec3::ZERO));
        let f = |x: f32| x.to_bits();
        let params: [u32; 28] = [
            f(u.x),
            f(u.y),
            f(u.z),
            0,
            f(v.x),
            f(v.y),
            f(v.z),
            0,
            f(t.x),
            f(t.y),
            f(t.z),
            0,
            f(lo.x),
            f(lo.y),
            f(hi.x),
            f(hi.y),
            f(corner.x),
            f(corner.y),
            f(per_texel),
            // Word TOP_WORD, the nearest point's key: copied from the map's state below, where it may
            // only now be.
            0,
            f(map.texel_size()),
            f(job.bias_texels),
            f(job.edge),
            f((map.resolution() - 1) as f32),
            pixels as u32,
            map.resolution() as u32,
            job.fitted.is_some() as u32,
            0,
        ];
        self.classify_params.write(ctx, &params);
        let kernels = &ctx.kernels.shadow_classify;
        let group = bind_group(
            ctx,
            &kernels.layout,
            &[
                self.depth.binding(),
                self.positions.binding(),
                self.normals.binding(),
                self.classes.binding(),
                self.flags.binding(),
                self.classify_params.binding(),
            ],
        );
        // After the map's commands (one submission and one wait for both).
        enc.copy_buffer_to_buffer(
            self.state.buffer(),
            0,
            self.classify_params.buffer(),
            TOP_AT,
            4,
        );
        enc.clear_buffer(self.flags.buffer(), 0, Some(4));
        if words > 0 {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("kinetrace shadow classification"),
                timestamp_writes: None,
            });
            pass.set_bind_group(0, &group, &[]);
            pass.set_pipeline(kernels.pipeline("classify_hard"));
            let (x, y) = ctx.groups(words as u32, 256);
            pass.dispatch_workgroups(x, y, 1);
        }
        let take = |w: &[u32]| {
            classes.clear();
            classes.extend_from_slice(&w[1..]);
            Some(w[0] != 0)
        };
        let more = [(self.flags.buffer(), 1), (self.classes.buffer(), words)];
        self.read_map(map, enc, texels, &more, take)
    }
}
