//! Selective ray-traced shadows, hard and soft (thesis §6.3): a shadow map from the light decides most
//! pixels, and shadow rays only the pixels it may get wrong.
//!
//! Per frame, [`HardShadows::run`] takes the camera's primary hits (a [`GBuffer`]), the scene's triangles
//! ([`Occluders`]: in world space, or each mesh's with its transform, e.g. `TraceWorld::occluders`) and a
//! shadow-ray query ([`ShadowRays`]: a closure `occluded(from, to)`, e.g.
//! `TraceWorld::occluded` or [`MeshBvh::any_hit`](crate::MeshBvh::any_hit), or a batched one in
//! [`Packets`], e.g. `TraceWorld::occluded_packet`, or in [`Interleaved`], e.g.
//! `TraceWorld::occluded_interleaved`), and writes a visibility per pixel:
//!
//! 1. the shadow map: the triangles rasterised orthographically along the light over the footprint of the
//!    pixels' surfaces ([`ShadowMap`]; in a selective pass, a closed mesh's only where they face the
//!    light, [`ShadowSettings::closed_culling`]). The footprint is first taken from a sample of the image's rows
//!    (every 16th, and those around where the last pass found its extremes); step 2, which reads every
//!    pixel anyway, checks that each lies within it, and where the sample missed part of it the exact
//!    footprint is found, the map rendered and step 2 run again ([`ShadowStats::refitted`]): the same
//!    map and image either way, for a pass over the G-buffer less in a moving scene whose extremes stay
//!    near where they were;
//! 2. classification of every pixel: `Δ`, the largest depth difference between the pixel's texel and its
//!    eight neighbours, flags shadow edges, where the receiver's own surface within one texel (the
//!    thesis's `d̂`, here its tangent plane extended to the four texels whose centres surround it) is
//!    compared with those texels' depths: where some may shade it (one lies in front of the plane by
//!    more than the constant bias) and some may not, the pixel is *potentially incorrect* and marked (a
//!    one-sided, per-direction form of the thesis's `[s − Δ, s + Δ]` overlap over the nine texels, which
//!    also marks the occluder's own lit side at its silhouette and receivers a texel away from the edge;
//!    see `classify::selective`). `Δ` is computed for every texel beforehand, in
//!    one vectorised pass over the map, and pixels are visited row by row in bands of 8 rows (the
//!    G-buffer read as it lies), eight at a time in SIMD lanes with AVX2 (else four), edges too (bit for
//!    bit the pixel-by-pixel test, which decides what the lanes leave: off the map, broken normals).
//!    Soft shadows (a disc light, [`ShadowSettings::light_angle`] above 0) mark
//!    instead the pixels under the penumbra mask — every edge texel splatted with the light's disc, as wide
//!    as a shadow can spread from it — and those near the light's horizon;
//! 3. compaction of the marked pixels into a dense list (fused with step 2: each band of image rows lists
//!    its own, in parallel, and the lists are concatenated);
//! 4. shadow rays for the marked pixels only, in parallel: one towards a point-like light, or
//!    [`ShadowSettings::samples`] over the disc ([`LightDisc`]), in batches of up to [`PACKET`] rays of
//!    neighbouring pixels (packets, when the query traces them as such);
//! 5. the composite: the map's verdict where it was trusted, the fraction of rays that reach the light
//!    where not.
//!
//! [`ShadowMode`] switches between the shadow map alone (always hard), the selective pipeline and rays for
//! every pixel (the reference the selective image is measured against). Its cost is the map
//! (O(triangles + texels)), O(pixels) classification (plus O(texels + edge texels · splat area) for the
//! penumbra mask), and rays for the marked pixels only (0.6–2.4% of them on the crowd for hard shadows).
//! On the CPU the map and the classification (eight pixels at a time with AVX2, else four, bound by its
//! scattered reads of the map and the G-buffer's 24 bytes a pixel; see [`dispatch`](crate::dispatch)) cost
//! under a quarter of hard shadow rays that mostly escape to the sky on a crowd of 16 × 2,880 triangles,
//! and the marked rays graze silhouettes at several times an average shadow ray's cost, so there
//! selective hard shadows take about 3.5× less CPU than a ray per pixel traced the faster of two ways
//! (single rays walked four at a time, interleaved, rather than packets of 8 × 8 pixels; same query and
//! threads on both sides; 3.5× on a 2-core Intel VM, 3.8× on a 2-core AMD EPYC one; see the `shadows`
//! bench suite in docs/BENCHMARKS.md). On a crowd of 700k triangles, smaller than a texel, the map and
//! classification alone cost an eighth to a sixth of a ray per pixel but 2.4% of the pixels are marked
//! and their rays graze dense geometry (0.8–1 µs of CPU each, several times an average ray of the
//! reference): 3.2–3.3× less CPU on the AMD machine, 2.8× on the Intel one, whose rays are cheaper
//! against the map and the classification. Moving the map off the CPU's threads helps most there (the
//! thesis renders it on the GPU, where rasterisation is nearly free):
//! [`HardShadows::run_with`] a `gpu::GpuShadowMap` renders the same map, texel for texel, on the GPU,
//! and classifies a hard selective pass's pixels there too, each as the CPU would, in one submission
//! and one wait (what that saves on a hardware GPU is not measured yet: the uploads of 36 bytes a
//! triangle and 24 a pixel and the read-backs of 4 bytes a texel and 1 a pixel stay on the CPU's side;
//! on a software adapter it is slower than the CPU); soft shadows, 16 rays a pixel, gain about 3.5× and
//! 1.7× (quick and full crowd). Use it for soft shadows, where shadow rays are expensive (dense
//! occluders, many triangles over the receivers) or where the map is rendered anyway; use the shadow map
//! alone where aliased hard edges are acceptable. A warm pass (same sizes) allocates nothing of its own.
//! Directional lights only; surfaces facing away from all of the light are in shadow without a ray. Not
//! covered: point lights, and conservative rasterisation of thin triangles (triangles edge-on to the
//! light cover no texel; receivers over empty texels are marked instead); the soft mask assumes every
//! receiver as deep as the deepest, so occluders high above the receivers mark wide areas (the thesis's
//! caveat), and smooth surfaces that shade part of the disc without a depth edge (a slope below the
//! light's horizon) are missed.

mod classify;
mod deltas;
mod lanes;
mod modes;
mod occluders;
mod penumbra;
mod rays;
mod renderer;
mod shadow_map;

use occluders::Culling;
pub use occluders::Occluders;
pub use penumbra::LightDisc;
pub use rays::{Interleaved, PACKET, Packets, ShadowRays};
#[cfg(feature = "gpu")]
pub(crate) use renderer::HardClassify;
pub use renderer::{CpuMap, MapRenderer};
pub use shadow_map::ShadowMap;
#[cfg(feature = "gpu")]
pub(crate) use shadow_map::{ToLight, nearest, unkey};

use crate::{Error, Result, parallel};
use classify::Class;
use deltas::Deltas;
use glam::{Vec3, Vec4};
use lanes::{Lanes, Run};
use std::time::{Duration, Instant};

/// Which pixels get shadow rays.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ShadowMode {
    /// None: the shadow map decides every pixel (fast, aliased at shadow edges).
    ShadowMap,
    /// Only the pixels the shadow map may get wrong (thesis §6.3).
    #[default]
    Selective,
    /// Every pixel facing the light: exact, the reference.
    RayTraced,
}

/// How a [`HardShadows`] pass runs.
#[derive(Clone, Copy, Debug)]
pub struct ShadowSettings {
    /// Which pixels get shadow rays.
    pub mode: ShadowMode,
    /// Direction from the scene towards the (directional) light; any non-zero length.
    pub towards_light: Vec3,
    /// Shadow-map texels per side (≥ 4).
    pub map_resolution: usize,
    /// Constant depth bias in texels, added to the slope-scaled bias.
    pub bias_texels: f32,
    /// Depth difference, in texels, above which the eight-neighbourhood is a shadow edge (`Δ` threshold).
    pub edge_texels: f32,
    /// Shadow rays start this far off the surface along its normal (world units).
    pub normal_offset: f32,
    /// Shadow rays end this far towards the light (world units): beyond the scene.
    pub ray_length: f32,
    /// Run the map, classification and rays on all threads (feature `parallel`).
    pub parallel: bool,
    /// Angular radius of the light in radians, at most 0.5: 0 is a point-like sun (hard shadows); above 0
    /// the light is a disc of directions and shadows are soft — pixels in the penumbra mask get
    /// [`samples`](Self::samples) rays.
    pub light_angle: f32,
    /// Shadow rays per pixel that gets rays when the light has an area ([`light_angle`](Self::light_angle)
    /// above 0), 1 to 1024, along [`LightDisc`]'s pattern; the thesis shows 16.
    pub samples: u32,
    /// In a selective pass, leave out of the shadow map the triangles of closed groups
    /// ([`Occluders::closed`]) that face away from the light: about half of them, and never the first
    /// surface a line from the light meets on a closed surface facing outwards. The map changes only
    /// where that first surface is lost: where the rasteriser's rounding drops a texel centre from both
    /// triangles along a shared edge (it is not watertight; a face behind used to fill the pinhole), and
    /// where skinning folds a surface over itself at a bent joint, turning a few triangles inside out.
    /// Such a texel is deeper or empty, a depth edge the classification sends rays to, so the image
    /// barely moves: on the full crowd (64 closed characters of 10,880 triangles, `bench shadows`, rows
    /// "all faces" and "culled") the map took 6.5 → 5.2 ms and the pass 6% less CPU, 89 of the map's 1M
    /// texels were deeper (by up to 6 texel sides) and one pixel of the image changed (0.021% of the
    /// pixels unlike the ray-traced image either way). The shadow map alone
    /// ([`ShadowMode::ShadowMap`]) would show those pinholes as specks of light, so it keeps every face.
    /// Shadow rays meet every triangle either way. Default on; off, every triangle counts.
    pub closed_culling: bool,
}

impl Default for ShadowSettings {
    fn default() -> Self {
        Self {
            mode: ShadowMode::Selective,
            towards_light: Vec3::Y,
            map_resolution: 1024,
            bias_texels: 1.0,
            edge_texels: 1.5,
            normal_offset: 1e-3,
            ray_length: 100.0,
            parallel: true,
            light_angle: 0.0,
            samples: 16,
            closed_culling: true,
        }
    }
}

/// The camera's primary hits, one per pixel, row by row: what a renderer has before shading.
#[derive(Clone, Debug, Default)]
pub struct GBuffer {
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// The hit point under each pixel (world space).
    pub positions: Vec<Vec3>,
    /// The unit surface normal there, facing the camera; `Vec3::ZERO` where the pixel shows no surface.
    /// The selective pass extends the surface along its tangent plane to the shadow-map texels around
    /// the pixel: give the geometric normal, or a shading normal close to it.
    pub normals: Vec<Vec3>,
}

impl GBuffer {
    /// A `width × height` buffer with no surface anywhere (fill it with [`set`](Self::set)).
    pub fn new(width: usize, height: usize) -> Self {
        let mut g = Self::default();
        g.resize(width, height);
        g
    }

    /// Resizes to `width × height` and clears every pixel to "no surface" (no allocation when not larger).
    pub fn resize(&mut self, width: usize, height: usize) {
        (self.width, self.height) = (width, height);
        self.positions.clear();
        self.positions.resize(width * height, Vec3::ZERO);
        self.normals.clear();
        self.normals.resize(width * height, Vec3::ZERO);
    }

    /// Records the surface under pixel `i` (row-major index).
    pub fn set(&mut self, i: usize, position: Vec3, normal: Vec3) {
        self.positions[i] = position;
        self.normals[i] = normal;
    }
}

/// What the last pass did.
#[derive(Clone, Copy, Debug, Default)]
pub struct ShadowStats {
    /// Pixels in the image.
    pub pixels: usize,
    /// Pixels showing a surface that faces the light (the ones a shadow could fall on).
    pub facing: usize,
    /// Pixels that got a shadow ray (the marked, potentially incorrect pixels in selective mode).
    pub rays: usize,
    /// Whether the receivers' bounds over the sample of image rows the map was first fitted to missed an
    /// extreme (or could not tell: a receiver facing the light at a non-finite position), so the map was
    /// rendered and every pixel classified a second time, over the exact bounds.
    pub refitted: bool,
    /// Whether the shadow map was rendered on the GPU ([`HardShadows::run_with`] a `GpuShadowMap`).
    pub map_on_gpu: bool,
    /// Whether the pixels were classified on the GPU too (a hard selective pass with a `GpuShadowMap`
    /// that classifies, see `GpuShadowMap::set_classify`).
    pub classified_on_gpu: bool,
    /// Time rendering the shadow map (on the GPU: uploading, rendering and reading it back; where the
    /// GPU classifies too, uploading the occluders and recording the map's commands: they are submitted,
    /// run and read back with the classification, in its time).
    pub map_time: Duration,
    /// Time classifying and compacting (on the GPU: uploading the G-buffer, classifying, reading the
    /// classes back and listing the marked pixels; with the map's rendering and read-back, which share
    /// its submission and wait).
    pub classify_time: Duration,
    /// Time tracing shadow rays and compositing.
    pub trace_time: Duration,
    /// Triangles of closed groups, whose faces away from the light the map left out
    /// ([`ShadowSettings::closed_culling`]: selective passes only; 0 in the other modes or with it
    /// off).
    pub closed_triangles: usize,
}

impl ShadowStats {
    /// Fraction of all pixels that got a shadow ray (the thesis's "% of pixels ray traced").
    pub fn ray_fraction(&self) -> f64 {
        self.rays as f64 / self.pixels.max(1) as f64
    }
}

/// Image rows one worker classifies at a time (and composites: the band's marked pixels are its own list),
/// row by row; its marked pixels are then listed in blocks of `BAND × BAND` pixels, whose rays make the
/// packets.
const BAND: usize = 8;

/// The receivers' bounds a map is first fitted to come from every this many image rows (and the last).
const SAMPLE_ROWS: usize = 16;

/// One band of pixels' share of a pass's classification.
#[derive(Clone, Debug, Default)]
struct Chunk {
    /// Its marked pixels, block by block (see [`in_blocks`]).
    marked: Vec<u32>,
    /// The other order of `marked` ([`in_blocks`]'s room).
    scratch: Vec<u32>,
    /// Where they start in the pass's dense list of marked pixels.
    start: usize,
    /// Its pixels showing a surface that faces the light.
    facing: usize,
    /// Whether one of its receivers lies outside the bounds the classification checks them against.
    outside: bool,
}

/// One hard-shadow pass, kept between frames so a warm pass does not allocate (see the module docs).
#[derive(Clone, Debug, Default)]
pub struct HardShadows {
    map: ShadowMap,
    /// The map's `Δ` per texel (hard selective passes).
    deltas: Deltas,
    /// Per band of [`BAND`] image rows, its marked pixels.
    chunks: Vec<Chunk>,
    /// Indices of the pixels that get shadow rays (dense), and the fraction of each one's rays that reach
    /// the light.
    marked: Vec<u32>,
    lit: Vec<f32>,
    /// Soft shadows: per texel, whether a penumbra may reach it.
    mask: Vec<bool>,
    /// Each pixel's class as the renderer's classification gave it (a byte a pixel, four a word), where
    /// it classified (`MapRenderer::classify_hard`).
    classes: Vec<u32>,
    visibility: Vec<f32>,
    /// The image rows [`Self::receivers`] last read (a sample, or every row when the sample missed an
    /// extreme), and each one's bounds.
    rows: Vec<usize>,
    bounds: Vec<(Vec3, Vec3)>,
    /// The bands of [`BAND`] rows that held the last pass's extreme receivers (lowest x, y and z across
    /// and along the light, highest x and y): sampled again, with their neighbours, by the next pass.
    extremes: Vec<usize>,
    stats: ShadowStats,
}

impl HardShadows {
    /// An empty pass; buffers grow on the first [`run`](Self::run).
    pub fn new() -> Self {
        Self::default()
    }

    /// Computes the visibility of the light at every pixel of `gbuffer`; `occluders` are every triangle
    /// ([`Occluders`]: in world space, or in groups placed by transforms such as `TraceWorld::occluders`;
    /// used for the shadow map, the ray-traced mode does not read them) and `rays` says whether anything
    /// lies on a segment (a closure `occluded(from, to)`, or a batched query in [`Packets`], which gets
    /// neighbouring pixels' rays together, or in [`Interleaved`], which gets up to [`PACKET`] rays
    /// across blocks to walk several at once). Returns the visibility (also in
    /// [`visibility`](Self::visibility)). Errors: a zero or non-finite light direction, a map resolution
    /// below 4 or above 16384, negative or non-finite tolerances, or a G-buffer whose arrays do not hold
    /// `width × height` pixels.
    pub fn run(
        &mut self,
        settings: &ShadowSettings,
        occluders: &(impl Occluders + ?Sized),
        gbuffer: &GBuffer,
        rays: impl ShadowRays,
    ) -> Result<&[f32]> {
        self.run_with(settings, occluders, gbuffer, rays, &mut CpuMap)
    }

    /// [`run`](Self::run) with the shadow map rendered by `renderer`: [`CpuMap`] (what `run` does), or
    /// the GPU (`gpu::GpuShadowMap`, feature `gpu`), which renders the same map. Also errors when the
    /// renderer fails (a GPU error).
    pub fn run_with(
        &mut self,
        settings: &ShadowSettings,
        occluders: &(impl Occluders + ?Sized),
        gbuffer: &GBuffer,
        rays: impl ShadowRays,
        renderer: &mut impl MapRenderer,
    ) -> Result<&[f32]> {
        let towards = validate(settings, gbuffer)?;
        let par = settings.parallel;
        let n = gbuffer.width * gbuffer.height;
        let s = settings;
        let soft = s.light_angle > 0.0;
        let (mut map_time, mut classify_time) = (Duration::ZERO, Duration::ZERO);
        // The map is fitted to the receivers' bounds over a sample of the image's rows first; the
        // classification, which reads every pixel anyway, checks that none lies outside them, and only
        // where one does (the sample missed an extreme) are the exact bounds found, the map fitted to
        // them and every pixel classified again: the same map and image as a fit to the exact bounds,
        // for a twentieth of a pass over the G-buffer.
        let mut sampled = None;
        if s.mode != ShadowMode::RayTraced {
            let t = Instant::now();
            self.map.aim(towards);
            let bounds = self.receivers(gbuffer, towards, par, false);
            self.fit_map(s, occluders, bounds, renderer)?;
            map_time += t.elapsed();
            sampled = Some(bounds);
        }
        let t = Instant::now();
        let mut classified = self.classify(s, gbuffer, towards, sampled, renderer, true)?;
        classify_time += t.elapsed();
        let refitted = classified.outside;
        let mut fit = sampled.unwrap_or(NO_BOUNDS);
        if refitted {
            let t = Instant::now();
            fit = self.receivers(gbuffer, towards, par, true);
            self.fit_map(s, occluders, fit, renderer)?;
            map_time += t.elapsed();
            let t = Instant::now();
            // The G-buffer is new to the renderer unless its classification ran the first time (the
            // first fit may have left it nothing to classify against: no receiver in the sample).
            let fresh = !classified.by_renderer;
            classified = self.classify(s, gbuffer, towards, None, renderer, fresh)?;
            classify_time += t.elapsed();
        }
        if sampled.is_some() {
            self.note_extremes(fit);
        }
        let t = Instant::now();
        self.marked.clear();
        let mut facing = 0;
        for chunk in &mut self.chunks {
            chunk.start = self.marked.len();
            self.marked.extend_from_slice(&chunk.marked);
            facing += chunk.facing;
        }
        classify_time += t.elapsed();
        let t2 = Instant::now();
        self.lit.resize(self.marked.len(), 0.0);
        let shoot = rays::Shoot {
            width: gbuffer.width,
            positions: &gbuffer.positions,
            normals: &gbuffer.normals,
            offset: s.normal_offset,
            length: s.ray_length,
            towards,
            disc: LightDisc::new(towards, s.light_angle, if soft { s.samples } else { 1 }),
            soft,
        };
        rays::trace(par, &self.marked, &mut self.lit, shoot, &rays);
        let lit = &self.lit;
        let chunk = BAND * gbuffer.width;
        parallel::fill_chunks_with(
            par,
            &mut self.visibility,
            chunk,
            &mut self.chunks,
            |c, vis, out| {
                for (&i, &l) in out.marked.iter().zip(&lit[out.start..]) {
                    vis[i as usize - c * chunk] = l;
                }
            },
        );
        self.stats = ShadowStats {
            pixels: n,
            facing,
            rays: self.marked.len(),
            refitted,
            map_on_gpu: s.mode != ShadowMode::RayTraced && renderer.on_gpu(),
            classified_on_gpu: classified.by_renderer,
            map_time,
            classify_time,
            trace_time: t2.elapsed(),
            closed_triangles: {
                let culled = Culling::of(occluders, s);
                (0..culled.groups())
                    .filter(|&g| culled.closed(g))
                    .map(|g| culled.group(g).0.len())
                    .sum()
            },
        };
        Ok(&self.visibility)
    }

    /// Renders the map over the receivers' bounds `receivers` (see [`Self::receivers`]), with the penumbra
    /// mask a soft selective pass classifies against.
    fn fit_map(
        &mut self,
        s: &ShadowSettings,
        occluders: &(impl Occluders + ?Sized),
        receivers: (Vec3, Vec3),
        renderer: &mut impl MapRenderer,
    ) -> Result<()> {
        let soft = s.light_angle > 0.0;
        let rendered = renderer.render_map(
            &mut self.map,
            &Culling::of(occluders, s),
            receivers,
            s.light_angle.tan(),
            s.map_resolution,
            s.parallel,
            s.mode == ShadowMode::Selective && !soft,
        );
        if rendered.is_err() {
            // A renderer's error (the GPU's) leaves no map behind: none half-written, and none of the
            // resolution asked for (which may be the error).
            self.map.clear(0);
            return rendered;
        }
        if s.mode == ShadowMode::Selective && soft {
            let edge = s.edge_texels * self.map.texel_size();
            // The deepest receiver's depth: top − its lowest `p · towards`.
            let deepest = self.map.project(Vec3::ZERO).z - receivers.0.z;
            penumbra::mask(&self.map, s.light_angle, edge, deepest, &mut self.mask);
        }
        Ok(())
    }

    /// Classifies every pixel against the last map as the mode says (visibility and each band's marked
    /// pixels); with the receivers' bounds `fitted` the map was fitted to, also says whether a receiver
    /// lies outside them (see [`lanes::outside`]): a map fitted to every pixel's bounds would differ. A
    /// hard selective pass is classified by `renderer` where it can (the GPU's, against the map it
    /// rendered; `fresh`: the G-buffer is new to it), else on the CPU, against the map's smooth texels
    /// found first.
    fn classify(
        &mut self,
        s: &ShadowSettings,
        g: &GBuffer,
        towards: Vec3,
        fitted: Option<(Vec3, Vec3)>,
        renderer: &mut impl MapRenderer,
        fresh: bool,
    ) -> Result<Classified> {
        let soft = s.light_angle > 0.0;
        let hard_selective = s.mode == ShadowMode::Selective && !soft;
        if hard_selective {
            let edge = s.edge_texels * self.map.texel_size();
            let job = renderer::HardClassify {
                towards,
                bias_texels: s.bias_texels,
                edge,
                fitted,
                fresh,
                parallel: s.parallel,
            };
            if let Some(outside) =
                renderer.classify_hard(&mut self.map, g, &job, &mut self.classes)?
            {
                let into = Classification {
                    par: s.parallel,
                    px: Pixels {
                        g,
                        towards,
                        map: None,
                        within: None,
                    },
                    visibility: &mut self.visibility,
                    chunks: &mut self.chunks,
                };
                into.take_classes(&self.classes);
                return Ok(Classified {
                    outside,
                    by_renderer: true,
                });
            }
            self.deltas.find(&self.map, edge, s.parallel);
        }
        let (map, mask, deltas) = (&self.map, &self.mask, &self.deltas);
        // Surfaces that see part of the light's disc: n·L above −sin(angle); all of it above +sin(angle).
        // The shadow map alone is hard: it shades everything at or below n·L = 0.
        let horizon = s.light_angle.sin();
        let away = if s.mode == ShadowMode::ShadowMap {
            0.0
        } else {
            -horizon
        };
        let light = modes::Light {
            towards,
            away,
            bias: s.bias_texels,
        };
        // Only a soft map depends on the deepest receiver (`ShadowMap::render`): a hard one is not
        // checked along the light.
        let deepest = |b: (Vec3, Vec3)| if soft { b.0.z } else { f32::NEG_INFINITY };
        let px = Pixels {
            g,
            towards,
            // Every mode but the ray-traced one reads the positions across the map.
            map: (s.mode != ShadowMode::RayTraced).then_some(map),
            within: fitted.map(|b| (b.0.truncate().extend(deepest(b)), b.1)),
        };
        let into = Classification {
            par: s.parallel,
            px,
            visibility: &mut self.visibility,
            chunks: &mut self.chunks,
        };
        // One classification per mode, each its own loop (the test inlined, no dispatch per pixel). The
        // hard modes settle most pixels a run at a time ([`lanes::decide`]); the rest, pixel by pixel.
        match s.mode {
            ShadowMode::RayTraced => into.each_run(modes::MarkFacing(light)),
            ShadowMode::ShadowMap => into.each_run(modes::MapOnly { map, light }),
            ShadowMode::Selective if soft => into.each_run(modes::Soft {
                map,
                mask,
                horizon,
                light,
            }),
            ShadowMode::Selective => into.each_run(modes::Selective { map, deltas, light }),
        }
        Ok(Classified {
            outside: self.chunks.iter().any(|c| c.outside),
            by_renderer: false,
        })
    }

    /// The last pass's visibility per pixel: 1 lit, 0 in shadow (also where the surface faces away from the
    /// light), the fraction of the disc's samples that reach it for soft shadows; 1 where there is no
    /// surface.
    pub fn visibility(&self) -> &[f32] {
        &self.visibility
    }

    /// The bounds of the pixels whose surface faces the light (lower corner above the upper where none
    /// does): x and y across the light the map is aimed at, z along it (`p · towards`), in parallel over
    /// rows — with `every_row`, over the whole image; else over a sample of it: its first and last rows,
    /// every [`SAMPLE_ROWS`]th, and the bands of [`BAND`] rows around those that held the last pass's
    /// extremes (where, in a moving scene, they most likely are again), which the classification checks
    /// every pixel against. Keeps each row's bounds for [`Self::note_extremes`].
    fn receivers(
        &mut self,
        g: &GBuffer,
        towards: Vec3,
        par: bool,
        every_row: bool,
    ) -> (Vec3, Vec3) {
        let (w, h) = (g.width, g.height);
        let map = &self.map;
        // At most every SAMPLE_ROWS-th row, the last, and three bands around each of five extremes, or
        // every row: room for all, so that a warm pass allocates nothing whichever rows it reads.
        let most = (h.div_ceil(SAMPLE_ROWS) + 1 + 5 * 3 * BAND).max(h);
        self.rows.clear();
        self.rows.reserve(most);
        self.bounds.reserve(most.saturating_sub(self.bounds.len()));
        if every_row {
            self.rows.extend(0..h);
        } else {
            self.rows
                .extend((0..h).step_by(SAMPLE_ROWS).chain(h.checked_sub(1)));
            for &band in &self.extremes {
                let near = band.saturating_sub(1) * BAND..((band + 2) * BAND).min(h);
                self.rows.extend(near);
            }
        }
        let rows = &self.rows;
        self.bounds.resize(rows.len(), NO_BOUNDS);
        parallel::fill(par, &mut self.bounds, 1, |k| {
            crate::dispatch::widest(
                #[inline(always)]
                || {
                    let mut receivers = lanes::Receivers::new();
                    let row = rows[k] * w..(rows[k] + 1) * w;
                    for (_, four) in lanes::fours(g, row, towards, Some(map)) {
                        receivers.add(map, &four);
                    }
                    receivers.bounds()
                },
            )
        });
        self.bounds.iter().fold(NO_BOUNDS, |a, &b| union(a, b))
    }

    /// Remembers the bands of [`BAND`] rows that hold the extremes of the receivers' bounds `fit` the map
    /// was last fitted to (see [`Self::extremes`]): those of the first rows [`Self::receivers`] last read
    /// that reach them.
    fn note_extremes(&mut self, fit: (Vec3, Vec3)) {
        self.extremes.clear();
        self.extremes.reserve(5);
        let lowest = [(0, fit.0.x), (0, fit.0.y), (0, fit.0.z)];
        let highest = [(1, fit.1.x), (1, fit.1.y)];
        for (k, (side, at)) in lowest.into_iter().chain(highest).enumerate() {
            let axis = k % 3;
            let holds = |b: &(Vec3, Vec3)| [b.0, b.1][side][axis] == at;
            if let Some(row) = self.bounds.iter().position(holds) {
                self.extremes.push(self.rows[row] / BAND);
            }
        }
    }

    /// Indices of the pixels the last pass sent shadow rays for, in the order they were traced: band by
    /// band of 8 image rows, within a band 8 × 8 block by block from the left, within a block row by row.
    pub fn marked(&self) -> &[u32] {
        &self.marked
    }

    /// What the last pass did.
    pub fn stats(&self) -> ShadowStats {
        self.stats
    }

    /// The last shadow map (empty after a ray-traced pass).
    pub fn shadow_map(&self) -> &ShadowMap {
        &self.map
    }
}

/// The image's pixels as the classification visits them: the G-buffer's, in bands of [`BAND`] rows,
/// each band row by row, lit from `towards`; with `map`, their positions are read across it (once for
/// every test, [`lanes::Run::new`]), and with `within` too, their receivers checked against those bounds
/// ([`lanes::outside`]).
#[derive(Clone, Copy)]
struct Pixels<'a> {
    g: &'a GBuffer,
    towards: Vec3,
    map: Option<&'a ShadowMap>,
    within: Option<(Vec3, Vec3)>,
}

/// What one classification of a pass found out besides the pixels' classes.
#[derive(Clone, Copy)]
struct Classified {
    /// A receiver lies outside the bounds the map was fitted to.
    outside: bool,
    /// The renderer classified (the GPU), not the CPU.
    by_renderer: bool,
}

/// One classification of every pixel: the pixels, on all threads or not, and where their verdicts go.
struct Classification<'a> {
    par: bool,
    px: Pixels<'a>,
    visibility: &'a mut Vec<f32>,
    chunks: &'a mut Vec<Chunk>,
}

impl Classification<'_> {
    /// Classifies every pixel with `test`, a run of neighbouring pixels of one image row at a time (in the
    /// widest lanes the CPU has, [`lanes::widest`]), into the visibility and the bands' lists
    /// ([`bands`](Self::bands)), and with `px.within` checks their receivers against those bounds.
    fn each_run(self, test: impl modes::RunTest) {
        lanes::widest(EachRun { into: self, test })
    }

    /// Takes each pixel's class from `classes` (a byte a pixel, four a word from the lowest byte, as
    /// `MapRenderer::classify_hard` gives them) into the visibility and the bands' lists, as
    /// [`each_run`](Self::each_run) would from the classes it finds.
    fn take_classes(self, classes: &[u32]) {
        self.bands::<Vec4>(
            #[inline(always)]
            |i, len| {
                let mut v = lanes::Verdicts::default();
                for k in 0..len {
                    let code = classes[(i + k) / 4] >> (8 * ((i + k) % 4)) & 0xff;
                    v.set(k, Class::from_code(code as u8));
                }
                (v, 0)
            },
        );
    }

    /// Runs over every pixel in runs of up to [`L::N`](Lanes::N) of one image row (in parallel over
    /// bands of [`BAND`] rows), `verdicts(first, len)` giving the run's verdicts and the lanes whose
    /// receivers lie outside the fitted bounds: writes the map's verdict into `visibility` (0 for a
    /// marked pixel, until its rays are in) and lists each band's marked pixels in its chunk, block by
    /// block ([`in_blocks`]: neighbouring marked pixels stay together, so their rays make coherent
    /// packets), with its count of pixels facing the light and whether one of its receivers lies outside.
    /// Generic over `verdicts`, so each mode's loop has its test inlined (mark it `#[inline(always)]`:
    /// the loop runs in [`Lanes::compiled`]).
    fn bands<L: Lanes>(
        self,
        verdicts: impl Fn(usize, usize) -> (lanes::Verdicts, lanes::Bits) + Sync,
    ) {
        let Self {
            par,
            px,
            visibility,
            chunks,
        } = self;
        let g = px.g;
        let (w, n) = (g.width, g.width * g.height);
        let chunk = BAND * w;
        visibility.resize(n, 1.0);
        chunks.resize_with(n.div_ceil(chunk.max(1)), Chunk::default);
        parallel::fill_chunks_with(par, visibility, chunk, chunks, |c, vis, out| {
            L::compiled(
                #[inline(always)]
                || {
                    out.marked.clear();
                    out.facing = 0;
                    let mut outside = 0;
                    let rows = vis.len() / w;
                    // Where each row's marked pixels start in the band's list, and where the last ends.
                    let mut starts = [0; BAND + 1];
                    for (y, start) in starts.iter_mut().enumerate().take(rows) {
                        *start = out.marked.len();
                        let row = c * chunk + y * w;
                        for i in (row..row + w).step_by(L::N) {
                            let (at, len) = (i - c * chunk, (row + w - i).min(L::N));
                            let (v, off) = verdicts(i, len);
                            outside |= off;
                            lanes::write_visibility(v.lit, &mut vis[at..at + len]);
                            out.facing += v.facing.count_ones() as usize;
                            let mut marked = v.marked;
                            while marked != 0 {
                                out.marked.push(i as u32 + marked.trailing_zeros());
                                marked &= marked - 1;
                            }
                        }
                    }
                    starts[rows] = out.marked.len();
                    out.outside = outside != 0;
                    in_blocks(
                        &mut out.marked,
                        &mut out.scratch,
                        c * chunk,
                        &starts[..=rows],
                        w,
                    );
                },
            )
        });
    }
}

/// A classification by `test` ([`Classification::each_run`]), in whichever lanes [`lanes::widest`] picks.
struct EachRun<'a, T> {
    into: Classification<'a>,
    test: T,
}

impl<T: modes::RunTest> lanes::WithLanes for EachRun<'_, T> {
    type Output = ();

    fn run<L: Lanes>(self) {
        let Self { into, test } = self;
        let px = into.px;
        let g = px.g;
        into.bands::<L>(
            #[inline(always)]
            |i, len| {
                let run = Run::<L>::new(
                    &g.positions[i..i + len],
                    &g.normals[i..i + len],
                    px.towards,
                    px.map,
                );
                let outside = match (px.map, px.within) {
                    (Some(map), Some(fitted)) => lanes::outside(map, &run, fitted),
                    _ => 0,
                };
                (test.verdicts(&run), outside)
            },
        );
    }
}

/// Reorders the marked pixels `marked` of the band whose first pixel is `band`, listed row by row (row
/// `y`'s from `starts[y]` to `starts[y + 1]`, ascending; the image `width` pixels wide), into block order: [`BAND`] × [`BAND`]
/// blocks from the left, within a block row by row. The classification reads the G-buffer row by row
/// (a block at a time it read sixteen strided streams of 96 bytes, about a fifth slower) and the rays
/// want the block order (neighbouring pixels' rays make packets). `scratch` holds the other order; a
/// merge of the rows, O(marked + width), no allocation once both have room.
fn in_blocks(
    marked: &mut Vec<u32>,
    scratch: &mut Vec<u32>,
    band: usize,
    starts: &[usize],
    width: usize,
) {
    if marked.is_empty() {
        return;
    }
    scratch.clear();
    scratch.reserve(marked.len());
    let mut next: [usize; BAND] = std::array::from_fn(|y| starts.get(y).copied().unwrap_or(0));
    for end in (BAND..width + BAND).step_by(BAND) {
        for (y, at) in next.iter_mut().enumerate().take(starts.len() - 1) {
            let row = band + y * width;
            while *at < starts[y + 1] && (marked[*at] as usize) < row + end {
                scratch.push(marked[*at]);
                *at += 1;
            }
        }
    }
    std::mem::swap(marked, scratch);
}

/// Bounds holding nothing: the lower corner above the upper.
const NO_BOUNDS: (Vec3, Vec3) = (Vec3::MAX, Vec3::MIN);

/// Bounds `b` grown by the receiver at `p` with normal `nrm` when it faces the light (`n · towards` above
/// 0) and has a place across `map`: its coordinates across the map and `p · towards`, when all three are
/// finite (a non-finite one, from a broken G-buffer, would make every texel of the map NaN). The
/// receivers' sampled rows add pixels four at a time ([`lanes::Receivers`]) and only the odd ones here.
fn receiver(b: (Vec3, Vec3), map: &ShadowMap, towards: Vec3, p: Vec3, nrm: Vec3) -> (Vec3, Vec3) {
    let q = map.across(p).extend(p.dot(towards));
    if nrm.dot(towards) > 0.0 && q.is_finite() {
        (b.0.min(q), b.1.max(q))
    } else {
        b
    }
}

/// The smallest bounds holding `a` and `b`.
fn union(a: (Vec3, Vec3), b: (Vec3, Vec3)) -> (Vec3, Vec3) {
    (a.0.min(b.0), a.1.max(b.1))
}

/// Checks the settings and the G-buffer; returns the unit light direction.
fn validate(s: &ShadowSettings, g: &GBuffer) -> Result<Vec3> {
    let bad = |m: String| Err(Error::InvalidShadowInput(m));
    let towards = s.towards_light.normalize_or_zero();
    if towards == Vec3::ZERO || !towards.is_finite() {
        return bad(format!("light direction {:?}", s.towards_light));
    }
    if !(4..=16384).contains(&s.map_resolution) {
        return bad(format!("map resolution {} (4 to 16384)", s.map_resolution));
    }
    if !(0.0..=0.5).contains(&s.light_angle) || !(1..=1024).contains(&s.samples) {
        return bad(format!(
            "light angle {} rad (0 to 0.5), {} samples (1 to 1024)",
            s.light_angle, s.samples
        ));
    }
    for (what, x) in [
        ("bias_texels", s.bias_texels),
        ("edge_texels", s.edge_texels),
        ("normal_offset", s.normal_offset),
        ("ray_length", s.ray_length),
    ] {
        if !(x.is_finite() && x >= 0.0) {
            return bad(format!("{what} = {x}"));
        }
    }
    let n = g.width * g.height;
    if g.positions.len() != n || g.normals.len() != n || n > u32::MAX as usize {
        return bad(format!(
            "G-buffer of {}×{} holds {} positions and {} normals",
            g.width,
            g.height,
            g.positions.len(),
            g.normals.len()
        ));
    }
    Ok(towards)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng, rngs::SmallRng};

    /// A band's marked pixels, listed row by row, come out block by block, within a block row by row —
    /// the order of sorting them by (block, row, column), on images whose width is and is not a multiple
    /// of the block, with bands of fewer rows than [`BAND`] (the image's last) — and a second band of
    /// the same size reorders without growing either buffer.
    #[test]
    fn marked_pixels_come_out_block_by_block() {
        let mut r = SmallRng::seed_from_u64(3);
        for (width, rows, band) in [(37, BAND, 2), (64, BAND, 0), (21, 3, 5), (8, 1, 1)] {
            let first = band * BAND * width;
            let mut listed = Vec::new();
            let mut starts = vec![0; rows + 1];
            for (y, start) in starts.iter_mut().enumerate().take(rows) {
                *start = listed.len();
                let row = (first + y * width) as u32;
                listed.extend(
                    (0..width as u32)
                        .filter(|_| r.random_bool(0.4))
                        .map(|x| row + x),
                );
            }
            starts[rows] = listed.len();
            let mut expected = listed.clone();
            let at = |i: u32| {
                let (y, x) = ((i as usize - first) / width, (i as usize - first) % width);
                (x / BAND, y, x)
            };
            expected.sort_by_key(|&i| at(i));
            let (mut marked, mut scratch) = (Vec::new(), Vec::new());
            let mut room = None;
            for _ in 0..2 {
                marked.clear();
                marked.extend_from_slice(&listed);
                in_blocks(&mut marked, &mut scratch, first, &starts, width);
                assert_eq!(marked, expected, "{width} wide, {rows} rows");
                let mut now = [marked.capacity(), scratch.capacity()];
                now.sort();
                assert!(room.is_none_or(|r| r == now), "{room:?} → {now:?}");
                room = Some(now);
            }
        }
    }
}
