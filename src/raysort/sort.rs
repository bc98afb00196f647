//! The sorted order of a batch (Garanzha & Loop): trim the rays no query can answer, compress runs of equal
//! key into chunks, radix-sort the chunks by key, decompress the chunks into ray order.
//!
//! Stable (rays of equal key keep their request order) and a permutation. Cost: one key per ray (in parallel
//! with the `parallel` feature), then O(n) compression and decompression and a radix sort of the chunks only:
//! batches in coherent request order have far fewer chunks than rays.

use super::{KeyLayout, SecondaryRay};
use crate::bvh::radix_sort::sort_pairs;
use crate::geometry::Aabb;
use crate::{Result, parallel};

/// A batch's sorted order.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SortedRays {
    /// Request index of the ray at each sorted position: the valid rays by key, then the trimmed (invalid,
    /// see [`Ray::is_valid`](crate::Ray::is_valid)) rays in request order.
    pub order: Vec<u32>,
    /// Key of each valid sorted ray (`order[..keys.len()]`), non-decreasing.
    pub keys: Vec<u32>,
    /// Runs of equal key in request order that the radix sort moved as one.
    pub chunks: usize,
}

impl SortedRays {
    /// The number of valid rays, which come first in [`order`](Self::order).
    pub fn valid(&self) -> usize {
        self.keys.len()
    }
}

/// Sorts `rays` by their keys under `layout`; `Error::InvalidOption` for a layout over 32 bits.
pub fn sort_rays(rays: &[SecondaryRay], layout: &KeyLayout, parallel: bool) -> Result<SortedRays> {
    layout.validate()?;
    // Trim: the valid rays, in request order.
    let (valid, trimmed): (Vec<u32>, Vec<u32>) =
        (0..rays.len() as u32).partition(|&i| rays[i as usize].ray.is_valid());
    let origins = valid.iter().fold(Aabb::EMPTY, |mut b, &i| {
        b.grow(rays[i as usize].ray.origin);
        b
    });
    let mut keys = vec![0u32; valid.len()];
    parallel::fill(parallel, &mut keys, 4096, |j| {
        layout.key(&rays[valid[j] as usize], &origins)
    });
    // Compress: chunk key and the chunk's first position in `valid`; sizes follow from the starts.
    let mut chunk_keys = Vec::new();
    let mut chunk_base = Vec::new();
    for (j, &k) in keys.iter().enumerate() {
        if j == 0 || keys[j - 1] != k {
            chunk_keys.push(k as u64);
            chunk_base.push(j as u32);
        }
    }
    let chunks = chunk_keys.len();
    let chunk_end = |c: usize| chunk_base.get(c + 1).map_or(valid.len(), |&b| b as usize);
    let mut sorted_chunks: Vec<u32> = (0..chunks as u32).collect();
    sort_pairs(&mut chunk_keys, &mut sorted_chunks, 32);
    // Decompress: each sorted chunk's rays, in order.
    let mut order = Vec::with_capacity(rays.len());
    let mut sorted_keys = Vec::with_capacity(valid.len());
    for (&c, &k) in sorted_chunks.iter().zip(&chunk_keys) {
        let c = c as usize;
        let range = chunk_base[c] as usize..chunk_end(c);
        sorted_keys.extend(std::iter::repeat_n(k as u32, range.len()));
        order.extend_from_slice(&valid[range]);
    }
    order.extend_from_slice(&trimmed);
    Ok(SortedRays {
        order,
        keys: sorted_keys,
        chunks,
    })
}
