//! The sorted order of a batch (Garanzha & Loop): trim the rays no query can answer, compress runs of equal
//! key into chunks, radix-sort the chunks by key, decompress the chunks into ray order.
//!
//! Stable (rays of equal key keep their request order) and a permutation. Cost: one key per ray (in parallel
//! with the `parallel` feature), then O(n) compression and decompression and a radix sort of the chunks only
//! (three 11-bit passes over 8-byte words: key and chunk number packed): batches in coherent request order
//! have far fewer chunks than rays. [`SortedRays::sort`] with a kept [`SortScratch`] allocates nothing once
//! its buffers have grown to the batch; [`sort_rays`] allocates them afresh.
//!
//! [`SortedRays::sort_above`] sorts on the key's high bits only, for callers that read nothing below them
//! (sorted runs cut their packets on the bits above [`RUN_LOW_BITS`](super::RUN_LOW_BITS)): rays of equal
//! high bits keep their request order, which in a camera's pixel order is already coherent, the chunks of
//! equal high bits in request order are longer, and the radix sort needs fewer passes (two 11-bit passes for
//! 22 bits).

use super::{KeyLayout, SecondaryRay};
use crate::bvh::prefetch;
use crate::bvh::radix_sort::{RadixScratch, sort_by_bits_with};
use crate::geometry::Aabb;
use crate::{Result, parallel};

/// A batch's sorted order.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SortedRays {
    /// Request index of the ray at each sorted position: the valid rays by key, then the trimmed (invalid,
    /// see [`Ray::is_valid`](crate::Ray::is_valid)) rays in request order.
    pub order: Vec<u32>,
    /// Key of each valid sorted ray (`order[..keys.len()]`), non-decreasing; with the bits below the sort's
    /// (see [`SortedRays::sort_above`]) cleared.
    pub keys: Vec<u32>,
    /// Runs of equal (sorted) key bits in request order that the radix sort moved as one.
    pub chunks: usize,
}

/// The working buffers of [`SortedRays::sort`]; keep one beside the [`SortedRays`] of a per-frame batch.
#[derive(Clone, Debug, Default)]
pub struct SortScratch {
    /// Request index of each valid ray, in request order.
    valid: Vec<u32>,
    /// Key of each valid ray, in request order.
    keys: Vec<u32>,
    /// Per chunk, its key (high 32 bits) and its number (low 32 bits); sorted by key.
    chunks: Vec<u64>,
    /// Per chunk number, its first position in `valid`; then `valid.len()`.
    starts: Vec<u32>,
    radix: RadixScratch<u64>,
}

impl SortedRays {
    /// The number of valid rays, which come first in [`order`](Self::order).
    pub fn valid(&self) -> usize {
        self.keys.len()
    }

    /// Sorts `rays` by their keys under `layout` into `self`, reusing its buffers and `scratch`'s.
    /// `Error::InvalidOption` for a layout over 32 bits.
    pub fn sort(
        &mut self,
        rays: &[SecondaryRay],
        layout: &KeyLayout,
        parallel: bool,
        scratch: &mut SortScratch,
    ) -> Result<()> {
        self.sort_above(rays, layout, 0, parallel, scratch)
    }

    /// [`sort`](Self::sort) on the keys' bits above their low `low_bits` only (clamped to 32: request
    /// order), stable: rays whose keys agree there keep their request order, and [`keys`](Self::keys)
    /// hold the keys with those low bits cleared. Cheaper than the full sort where the caller reads no
    /// low bit: fewer radix passes (`⌈(32 − low_bits) / 11⌉`) over fewer, longer chunks.
    pub fn sort_above(
        &mut self,
        rays: &[SecondaryRay],
        layout: &KeyLayout,
        low_bits: u32,
        parallel: bool,
        scratch: &mut SortScratch,
    ) -> Result<()> {
        layout.validate()?;
        let low = low_bits.min(32);
        // The key with its low bits cleared (a u64 shift: 32 clears all).
        let high = |k: u32| ((k as u64 >> low) << low) as u32;
        let s = scratch;
        // Trim: the valid rays, in request order, and their origins' bounds.
        s.valid.clear();
        let mut origins = Aabb::EMPTY;
        for (i, r) in rays.iter().enumerate() {
            if r.ray.is_valid() {
                s.valid.push(i as u32);
                origins.grow(r.ray.origin);
            }
        }
        s.keys.clear();
        s.keys.resize(s.valid.len(), 0);
        let valid = &s.valid;
        parallel::fill(parallel, &mut s.keys, 4096, |j| {
            // The pass above has pushed the batch's rays out of L2 (64 bytes a ray): ask for a ray's line a
            // dozen keys ahead (the keys' share of the sorted runs' samples 14% -> 10% at 1024²).
            if let Some(&ahead) = valid.get(j + PREFETCH_AHEAD) {
                prefetch(std::ptr::from_ref(&rays[ahead as usize]));
            }
            high(layout.key(&rays[valid[j] as usize], &origins))
        });
        // Compress: one word per run of equal key.
        s.chunks.clear();
        s.starts.clear();
        let mut last = None;
        for (j, &k) in s.keys.iter().enumerate() {
            if last != Some(k) {
                last = Some(k);
                s.chunks.push((k as u64) << 32 | s.starts.len() as u64);
                s.starts.push(j as u32);
            }
        }
        s.starts.push(s.valid.len() as u32);
        sort_by_bits_with(&mut s.chunks, &mut s.radix, 32 - low, parallel, |&w| {
            (w >> 32) >> low
        });
        // Decompress: each sorted chunk's rays, in order; then the trimmed rays.
        self.order.clear();
        self.keys.clear();
        for &w in &s.chunks {
            let c = w as u32 as usize;
            let range = s.starts[c] as usize..s.starts[c + 1] as usize;
            self.keys
                .extend(std::iter::repeat_n((w >> 32) as u32, range.len()));
            self.order.extend_from_slice(&s.valid[range]);
        }
        if s.valid.len() < rays.len() {
            let trimmed = (0..rays.len() as u32).filter(|&i| !rays[i as usize].ray.is_valid());
            self.order.extend(trimmed);
        }
        self.chunks = s.chunks.len();
        Ok(())
    }
}

/// Rays ahead of the one being keyed whose cache line the key pass asks for.
const PREFETCH_AHEAD: usize = 12;

/// Sorts `rays` by their keys under `layout`; `Error::InvalidOption` for a layout over 32 bits. Allocates
/// its buffers: per frame, keep a [`SortedRays`] and a [`SortScratch`] and call [`SortedRays::sort`].
pub fn sort_rays(rays: &[SecondaryRay], layout: &KeyLayout, parallel: bool) -> Result<SortedRays> {
    let mut sorted = SortedRays::default();
    sorted.sort(rays, layout, parallel, &mut SortScratch::default())?;
    Ok(sorted)
}
