//! Hybrid builder (Lauterbach thesis §5.3): LBVH for the top `k` levels, binned SAH below.
//!
//! The LBVH levels split the scene quickly along the Morton curve where a top-down SAH build has the least
//! parallelism and the most work; below them each of the (at most 2^k) subtrees is finished with binned SAH,
//! which repairs LBVH's weakness on small detail in a large box. The thesis used 6 LBVH levels.
//!
//! When to use: rebuilds of large, unevenly distributed meshes where SAH quality matters but a full SAH
//! build costs too much. Cost: an LBVH pass plus SAH on subtrees of about `n / 2^k` primitives each, built
//! in parallel.

use super::build_sah::BinnedSah;
use super::layout::Slot;
use super::{BuildInput, MortonBits, build_lbvh, topdown};

/// Builds into the whole tree's root `slot`.
pub(crate) fn build(
    input: &BuildInput,
    slot: Slot<'_>,
    bits: MortonBits,
    levels: usize,
    bins: u32,
) -> usize {
    let sah = BinnedSah { bins };
    let finish = |s: Slot<'_>, depth: usize| topdown::build(input, &sah, s, depth);
    build_lbvh::build(input, slot, bits, Some((levels, &finish)))
}
