//! Stable LSD radix sort of key–value pairs: the sort of the LBVH builder.
//!
//! 11-bit digits (2048 buckets, an 8 KiB histogram that stays in L1), one counting pass for all digits, then
//! one scatter pass per digit; digits that are equal across all keys are skipped. Cost: `⌈bits / 11⌉` passes
//! over keys and values, O(n) extra memory.

const DIGIT_BITS: u32 = 11;
const BUCKETS: usize = 1 << DIGIT_BITS;

/// Sorts `keys` (and `vals` along with them) by the low `bits` bits of the keys, stably: pairs with equal
/// keys keep their order. `keys` and `vals` must have the same length. Moves 16-byte pairs; where the key
/// and the value fit one `u64` together, [`sort_by_bits`] on packed words moves half as many bytes.
pub(crate) fn sort_pairs(keys: &mut [u64], vals: &mut [u32], bits: u32) {
    assert_eq!(keys.len(), vals.len(), "one value per key");
    let mut pairs: Vec<(u64, u32)> = keys.iter().copied().zip(vals.iter().copied()).collect();
    sort_by_bits(&mut pairs, bits, |p| p.0);
    for (i, (k, v)) in pairs.into_iter().enumerate() {
        keys[i] = k;
        vals[i] = v;
    }
}

/// Sorts `items` stably by the low `bits` bits of `key(item)`.
pub(crate) fn sort_by_bits<T: Copy + Default>(
    items: &mut Vec<T>,
    bits: u32,
    key: impl Fn(&T) -> u64,
) {
    let n = items.len();
    if n < 2 || bits == 0 {
        return;
    }
    let passes = bits.div_ceil(DIGIT_BITS) as usize;
    let mut hist = vec![[0u32; BUCKETS]; passes];
    for x in items.iter() {
        let k = key(x);
        for (p, h) in hist.iter_mut().enumerate() {
            h[((k >> (p as u32 * DIGIT_BITS)) as usize) & (BUCKETS - 1)] += 1;
        }
    }
    let mut out = vec![T::default(); n];
    for (p, h) in hist.iter_mut().enumerate() {
        if h.iter().any(|&c| c as usize == n) {
            continue; // every key has the same digit here
        }
        let mut sum = 0u32;
        for c in h.iter_mut() {
            let x = *c;
            *c = sum;
            sum += x;
        }
        let shift = p as u32 * DIGIT_BITS;
        for x in items.iter() {
            let d = ((key(x) >> shift) as usize) & (BUCKETS - 1);
            let at = h[d] as usize;
            h[d] += 1;
            out[at] = *x;
        }
        std::mem::swap(items, &mut out);
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
}
