//! The shadow rays of a pass: the query a caller gives ([`ShadowRays`]), and the loop that sends the
//! marked pixels' rays to it in packets.

use super::{BAND, LightDisc};
use crate::parallel;
use glam::Vec3;

/// The shadow-ray query a [`HardShadows`](super::HardShadows) pass asks: whether anything lies on a
/// segment, one at a time or for a batch of segments at once.
///
/// Any `Fn(Vec3, Vec3) -> bool + Sync` closure is one (a ray at a time, e.g. `TraceWorld::occluded` or
/// [`MeshBvh::any_hit`](crate::MeshBvh::any_hit)); wrap a batched query in [`Packets`] to have the pass's
/// rays traced as packets (e.g. `TraceWorld::occluded_packet`), or in [`Interleaved`] for a query that
/// walks several single rays at once (e.g. `TraceWorld::occluded_interleaved`). The pass sends batches
/// of at most [`PACKET`] segments; for packets, all from pixels of one 8 × 8 block of the image (so a
/// packet's rays lie close together): for hard shadows, the block's marked pixels' parallel rays towards
/// the light (a whole block's where every pixel gets a ray; often a single ray in the selective pass,
/// whose marked pixels are sparse); for soft ones, a few pixels' rays over the light's disc. An
/// [`Interleaved`] query's batches run across blocks ([`batches_by_block`](Self::batches_by_block)).
pub trait ShadowRays: Sync {
    /// Whether anything lies on the segment from `from` to `to`.
    fn occluded(&self, from: Vec3, to: Vec3) -> bool;

    /// [`occluded`](Self::occluded) for every segment, into `out` (as long as `segments`). By default one
    /// segment at a time.
    fn occluded_all(&self, segments: &[(Vec3, Vec3)], out: &mut [bool]) {
        for (o, &(from, to)) in out.iter_mut().zip(segments) {
            *o = self.occluded(from, to);
        }
    }

    /// Whether each batch holds the rays of one 8 × 8 block of pixels only (the default: what packets
    /// need); false lets a batch run across blocks, up to [`PACKET`] rays ([`Interleaved`]).
    fn batches_by_block(&self) -> bool {
        true
    }
}

impl<F: Fn(Vec3, Vec3) -> bool + Sync> ShadowRays for F {
    fn occluded(&self, from: Vec3, to: Vec3) -> bool {
        self(from, to)
    }
}

/// A batched shadow-ray query, `f(segments, out)` setting `out[i]` when anything lies on segment `i`:
/// use it when the query traces packets of coherent rays faster than single rays (a BVH's packet
/// traversal amortises every node visit over the packet's rays).
#[derive(Clone, Copy, Debug)]
pub struct Packets<F>(pub F);

impl<F: Fn(&[(Vec3, Vec3)], &mut [bool]) + Sync> ShadowRays for Packets<F> {
    fn occluded(&self, from: Vec3, to: Vec3) -> bool {
        let mut out = [false];
        (self.0)(&[(from, to)], &mut out);
        out[0]
    }

    fn occluded_all(&self, segments: &[(Vec3, Vec3)], out: &mut [bool]) {
        (self.0)(segments, out)
    }
}

/// A batched shadow-ray query, `f(segments, out)` setting `out[i]` when anything lies on segment `i`,
/// given batches of up to [`PACKET`] segments across blocks of pixels: use it for a query that walks
/// several single rays at once, interleaved (e.g. `TraceWorld::occluded_interleaved`), where the selective
/// pass's sparse marked pixels would give it one or two rays a block.
#[derive(Clone, Copy, Debug)]
pub struct Interleaved<F>(pub F);

impl<F: Fn(&[(Vec3, Vec3)], &mut [bool]) + Sync> ShadowRays for Interleaved<F> {
    fn occluded(&self, from: Vec3, to: Vec3) -> bool {
        Packets(&self.0).occluded(from, to)
    }

    fn occluded_all(&self, segments: &[(Vec3, Vec3)], out: &mut [bool]) {
        (self.0)(segments, out)
    }

    fn batches_by_block(&self) -> bool {
        false
    }
}

/// Most segments in one batch given to [`ShadowRays::occluded_all`]; also the marked pixels one worker
/// takes at a time.
pub const PACKET: usize = 64;

/// How the rays of one pixel leave its surface.
#[derive(Clone, Copy)]
pub(super) struct Shoot<'a> {
    /// The image's width in pixels, and its surfaces.
    pub width: usize,
    pub positions: &'a [Vec3],
    pub normals: &'a [Vec3],
    /// Rays start this far off the surface along the normal, and are this long.
    pub offset: f32,
    pub length: f32,
    /// Towards the light's centre; with `soft`, the rays go along `disc`'s directions instead.
    pub towards: Vec3,
    pub disc: LightDisc,
    pub soft: bool,
}

/// Up to [`PACKET`] segments waiting for the query, each with the slot of the pixel it belongs to, all
/// from pixels of one block.
struct Batch {
    segments: [(Vec3, Vec3); PACKET],
    owner: [u8; PACKET],
    len: usize,
    block: (usize, usize),
}

impl Batch {
    /// Traces the waiting segments and counts, per pixel slot, those that reach the light.
    fn flush(&mut self, rays: &impl ShadowRays, reach: &mut [u32; PACKET]) {
        let n = self.len;
        if n == 0 {
            return;
        }
        let mut hit = [false; PACKET];
        rays.occluded_all(&self.segments[..n], &mut hit[..n]);
        for (&o, &h) in self.owner[..n].iter().zip(&hit[..n]) {
            reach[o as usize] += !h as u32;
        }
        self.len = 0;
    }
}

/// For each pixel of `marked` (listed block by block), the fraction of its rays that reach the light, into
/// `lit`: in parallel over runs of [`PACKET`] pixels, whose rays go to `rays` in batches of up to
/// [`PACKET`] from one `BAND × BAND` block of pixels of an image `width` pixels wide (rays far apart
/// make poor packets: they share few nodes), or across blocks where `rays` does not batch by block. A
/// direction below the surface is blocked by the surface itself (no ray). No allocation.
pub(super) fn trace(
    par: bool,
    marked: &[u32],
    lit: &mut [f32],
    shoot: Shoot,
    rays: &impl ShadowRays,
) {
    let samples = shoot.disc.samples();
    let by_block = rays.batches_by_block();
    let block = |i: u32| {
        let i = i as usize;
        if by_block {
            (i / shoot.width / BAND, i % shoot.width / BAND)
        } else {
            (0, 0)
        }
    };
    parallel::fill_chunks(par, lit, PACKET, |c, lit| {
        let ids = &marked[c * PACKET..c * PACKET + lit.len()];
        let mut reach = [0u32; PACKET];
        let mut batch = Batch {
            segments: [(Vec3::ZERO, Vec3::ZERO); PACKET],
            owner: [0; PACKET],
            len: 0,
            block: (usize::MAX, usize::MAX),
        };
        for (slot, &i) in ids.iter().enumerate() {
            if block(i) != batch.block {
                batch.flush(rays, &mut reach);
                batch.block = block(i);
            }
            let (p, nrm) = (shoot.positions[i as usize], shoot.normals[i as usize]);
            let from = p + nrm * shoot.offset;
            for k in 0..samples {
                let dir = if shoot.soft {
                    shoot.disc.direction(i, k)
                } else {
                    shoot.towards
                };
                if dir.dot(nrm) > 0.0 {
                    batch.segments[batch.len] = (from, from + dir * shoot.length);
                    batch.owner[batch.len] = slot as u8;
                    batch.len += 1;
                    if batch.len == PACKET {
                        batch.flush(rays, &mut reach);
                    }
                }
            }
        }
        batch.flush(rays, &mut reach);
        for (l, r) in lit.iter_mut().zip(reach) {
            *l = r as f32 / samples as f32;
        }
    });
}
