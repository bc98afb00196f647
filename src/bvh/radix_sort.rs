//! Stable LSD radix sort of key–value pairs: the sort of the LBVH builder.
//!
//! 11-bit digits (2048 buckets, an 8 KiB histogram that stays in L1), one counting pass for all digits, then
//! one scatter pass per digit; digits that are equal across all keys are skipped; on all threads each pass
//! after the first counts its digit again per chunk. Cost: `⌈bits / 11⌉` passes
//! over keys and values, O(n) extra memory.

const DIGIT_BITS: u32 = 11;
const BUCKETS: usize = 1 << DIGIT_BITS;

/// Sorts `keys` (and `vals` along with them) by the low `bits` bits of the keys, stably: pairs with equal
/// keys keep their order. `keys` and `vals` must have the same length. Moves 16-byte pairs; where the key
/// and the value fit one `u64` together, [`sort_by_bits`] on packed words moves half as many bytes.
pub(crate) fn sort_pairs(keys: &mut [u64], vals: &mut [u32], bits: u32) {
    assert_eq!(keys.len(), vals.len(), "one value per key");
    let mut pairs: Vec<(u64, u32)> = keys.iter().copied().zip(vals.iter().copied()).collect();
    sort_by_bits(&mut pairs, bits, false, |p| p.0);
    for (i, (k, v)) in pairs.into_iter().enumerate() {
        keys[i] = k;
        vals[i] = v;
    }
}

/// Sorts `items` stably by the low `bits` bits of `key(item)`; with `parallel` (and the `parallel`
/// feature) each pass counts and scatters in chunks on all threads: every chunk's items go to the places
/// its digit counts and the counts of the chunks before it give them, so the result is the one stable
/// order whatever the thread count. Below [`PARALLEL_ITEMS`] items it runs on one thread.
pub(crate) fn sort_by_bits<T: Copy + Default + Send + Sync>(
    items: &mut Vec<T>,
    bits: u32,
    parallel: bool,
    key: impl Fn(&T) -> u64 + Sync + Send,
) {
    sort_by_bits_with(items, &mut RadixScratch::default(), bits, parallel, key);
}

/// The buffers of one sort, kept by callers that sort every frame so that a warm sort allocates nothing.
#[derive(Clone, Debug, Default)]
pub(crate) struct RadixScratch<T> {
    /// The scatter target, swapped with the items each pass.
    out: Vec<T>,
    /// Per chunk, per pass, digit counts.
    hist: Vec<Vec<[u32; BUCKETS]>>,
    /// Per chunk, the next place of each digit.
    at: Vec<[u32; BUCKETS]>,
}

/// [`sort_by_bits`] with its buffers in `scratch`.
pub(crate) fn sort_by_bits_with<T: Copy + Default + Send + Sync>(
    items: &mut Vec<T>,
    scratch: &mut RadixScratch<T>,
    bits: u32,
    parallel: bool,
    key: impl Fn(&T) -> u64 + Sync + Send,
) {
    let n = items.len();
    if n < 2 || bits == 0 {
        return;
    }
    let passes = bits.div_ceil(DIGIT_BITS) as usize;
    let chunks = if parallel && n >= PARALLEL_ITEMS {
        4 * crate::parallel::threads()
    } else {
        1
    };
    let chunk = n.div_ceil(chunks);
    let chunks = n.div_ceil(chunk);
    let range = |c: usize| c * chunk..((c + 1) * chunk).min(n);
    // Per chunk, per pass, the count of each digit among the chunk's items in the current order.
    let RadixScratch { out, hist, at } = scratch;
    hist.resize_with(chunks, Vec::new);
    for h in hist.iter_mut() {
        h.clear();
        h.resize(passes, [0; BUCKETS]);
    }
    crate::parallel::for_each_mut(parallel, hist, |c, h| {
        for x in &items[range(c)] {
            let k = key(x);
            for (p, h) in h.iter_mut().enumerate() {
                h[((k >> (p as u32 * DIGIT_BITS)) as usize) & (BUCKETS - 1)] += 1;
            }
        }
    });
    // A digit every key shares is skipped (totals do not depend on the order).
    let mut skip = [false; 64usize.div_ceil(DIGIT_BITS as usize)];
    for (p, s) in skip.iter_mut().enumerate().take(passes) {
        *s = (0..BUCKETS).any(|d| hist.iter().map(|h| h[p][d] as usize).sum::<usize>() == n);
    }
    out.clear();
    out.resize(n, T::default());
    at.resize(chunks, [0; BUCKETS]);
    let mut moved = false;
    for p in (0..passes).filter(|&p| !skip[p]) {
        if moved && chunks > 1 {
            // A pass moved items between chunks: count this digit again, chunk by chunk.
            crate::parallel::for_each_mut(parallel, hist, |c, h| {
                h[p] = [0; BUCKETS];
                for x in &items[range(c)] {
                    h[p][((key(x) >> (p as u32 * DIGIT_BITS)) as usize) & (BUCKETS - 1)] += 1;
                }
            });
        }
        moved = true;
        // Where each chunk's first item of each digit goes: digits in order, chunks in order within one.
        let mut sum = 0u32;
        for d in 0..BUCKETS {
            for (a, h) in at.iter_mut().zip(hist.iter()) {
                a[d] = sum;
                sum += h[p][d];
            }
        }
        let shift = p as u32 * DIGIT_BITS;
        let dst = Scatter(out.as_mut_ptr());
        let src = &items[..];
        crate::parallel::for_each_mut(parallel, at, |c, a| {
            for x in &src[range(c)] {
                let d = ((key(x) >> shift) as usize) & (BUCKETS - 1);
                // SAFETY: the chunks' ranges of places are disjoint and each lies within `out` (the
                // counts sum to n), so every place is written once, by one chunk.
                unsafe { dst.write(a[d] as usize, *x) };
                a[d] += 1;
            }
        });
        std::mem::swap(items, out);
    }
}

/// Below this many items a sort runs on one thread: per-chunk counts would cost more than they save.
const PARALLEL_ITEMS: usize = 1 << 15;

/// The scatter target the chunks of one pass share; each writes only its own places.
struct Scatter<T>(*mut T);

// SAFETY: chunks write disjoint places (see `sort_by_bits`); `T: Send` moves values across threads.
unsafe impl<T: Send> Sync for Scatter<T> {}
unsafe impl<T: Send> Send for Scatter<T> {}

impl<T> Scatter<T> {
    /// Writes `x` at place `i`.
    ///
    /// # Safety
    /// `i` lies within the target and no other thread writes it during the pass.
    unsafe fn write(&self, i: usize, x: T) {
        unsafe { self.0.add(i).write(x) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_stable_std_sort() {
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        for (n, bits) in [
            (0, 30),
            (1, 30),
            (2, 63),
            (3, 30),
            (1023, 30),
            (1025, 63),
            (5000, 12),
        ] {
            let keys: Vec<u64> = (0..n)
                .map(|_| {
                    s ^= s << 13;
                    s ^= s >> 7;
                    s ^= s << 17;
                    ((s % 97) * (s >> 40)) & ((1u64 << bits) - 1)
                })
                .collect();
            let mut expect: Vec<(u64, u32)> = keys.iter().copied().zip(0..).collect();
            expect.sort_by_key(|&(k, _)| k);
            let (mut k, mut v) = (keys.clone(), (0..n as u32).collect::<Vec<_>>());
            sort_pairs(&mut k, &mut v, bits);
            let got: Vec<(u64, u32)> = k.into_iter().zip(v).collect();
            assert_eq!(got, expect, "n={n} bits={bits}");
        }
    }

    /// The chunked pass on all threads gives the stable order bit for bit, as one thread does: packed
    /// code–index words past the parallel threshold, with long runs of equal keys and a digit that
    /// every key shares (skipped).
    #[test]
    fn all_threads_sort_as_one_thread_does() {
        let mut s = 0x2545_f491_4f6c_dd1du64;
        for n in [PARALLEL_ITEMS, 3 * PARALLEL_ITEMS + 17] {
            let words: Vec<u64> = (0..n as u64)
                .map(|i| {
                    s ^= s << 13;
                    s ^= s >> 7;
                    s ^= s << 17;
                    (((s % 4099) | 1 << 25) << 32) | i
                })
                .collect();
            let mut expect = words.clone();
            expect.sort_by_key(|&w| w >> 32);
            let (mut one, mut all) = (words.clone(), words);
            sort_by_bits(&mut one, 30, false, |&w| w >> 32);
            sort_by_bits(&mut all, 30, true, |&w| w >> 32);
            assert_eq!(one, expect, "one thread, n={n}");
            assert_eq!(all, expect, "all threads, n={n}");
        }
    }
}
