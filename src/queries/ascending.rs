//! Putting an overlap query's triangle indices in ascending order, the order its answer promises.
//!
//! The tree hands the triangles over in its own order. A comparison sort of the ~44 triangles a `bench
//! queries` sphere overlaps cost about 2,170 instructions a query (a seventh of the query), with
//! mispredicted branches on top. They lie close together in index order (a mesh's neighbouring triangles
//! mostly have neighbouring indices: 13 words of 64 indices on average there), so a bitmap over their
//! range, read back word by word, orders them in about 1,450 instructions and few mispredictions: the
//! sphere overlap row's thread CPU time fell by 5.5% (docs/BENCHMARKS.md).

use std::mem::MaybeUninit;

/// Most 64-bit words of the bitmap (2 KB on the stack, of which only the span's words are written):
/// indices spanning more than 16,384 values are sorted by comparison.
const WORDS: usize = 256;

/// Sorts `ids` ascending. Distinct indices whose range spans at most [`WORDS`] words and at most four
/// words per index go through a bitmap: each sets its bit, the set bits are read back in order (O(n +
/// span / 64), no allocation); anything else (repeated indices included) through `sort_unstable`.
pub(crate) fn sort_ascending(ids: &mut [u32]) {
    if ids.len() < 2 {
        return;
    }
    let (lo, hi) = ids
        .iter()
        .fold((u32::MAX, 0), |(lo, hi), &i| (lo.min(i), hi.max(i)));
    let span = ((hi - lo) / 64) as usize + 1;
    if span > WORDS || span > 4 * ids.len() {
        ids.sort_unstable();
        return;
    }
    let mut buffer = [MaybeUninit::<u64>::uninit(); WORDS];
    for word in &mut buffer[..span] {
        word.write(0);
    }
    // SAFETY: the loop above initialised the first `span` words (`span <= WORDS`); `u64` has no invalid
    // bit patterns or drop.
    let bits = unsafe { std::slice::from_raw_parts_mut(buffer.as_mut_ptr().cast::<u64>(), span) };
    for &i in ids.iter() {
        let d = i - lo;
        bits[(d / 64) as usize] |= 1 << (d % 64);
    }
    // A repeated index sets one bit for two entries: the bitmap cannot give them back.
    if bits.iter().map(|w| w.count_ones() as usize).sum::<usize>() != ids.len() {
        ids.sort_unstable();
        return;
    }
    let mut k = 0;
    for (w, &word) in bits.iter().enumerate() {
        let mut word = word;
        while word != 0 {
            ids[k] = lo + w as u32 * 64 + word.trailing_zeros();
            k += 1;
            word &= word - 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::SceneRng;

    /// Equal to `sort_unstable` on lists that take either path: clustered and spread indices, repeated
    /// ones, the ends of the `u32` range, a span of exactly [`WORDS`] words and one more.
    #[test]
    fn equals_a_comparison_sort() {
        let mut rng = SceneRng::new(5);
        let mut lists: Vec<Vec<u32>> = vec![
            vec![],
            vec![7],
            vec![u32::MAX, u32::MAX - 64, u32::MAX - 1],
            vec![5, 5, 1],
        ];
        // WORDS / 4 indices (the most words a bitmap may span per index), spanning WORDS words, then one
        // word more.
        for last in [64 * WORDS as u32 - 1, 64 * WORDS as u32] {
            let quarter = WORDS as u32 / 4;
            lists.push(
                (0..quarter - 1)
                    .map(|i| i * 7)
                    .chain([last])
                    .rev()
                    .collect(),
            );
        }
        for round in 0..3_000 {
            let n = 1 + round % 90;
            let base = (rng.next_u64() % 4_000_000_000) as u32;
            let width = [8u64, 200, 1_000, 4_096, 100_000][round % 5];
            let mut ids: Vec<u32> = (0..n)
                .map(|_| base.saturating_add((rng.next_u64() % width) as u32))
                .collect();
            if round % 3 != 0 {
                ids.sort_unstable();
                ids.dedup();
                // Shuffled back out of order (Fisher–Yates).
                for i in (1..ids.len()).rev() {
                    ids.swap(i, (rng.next_u64() % (i as u64 + 1)) as usize);
                }
            }
            lists.push(ids);
        }
        let mut bitmap_path = 0;
        for ids in lists {
            let mut expected = ids.clone();
            expected.sort_unstable();
            let mut got = ids.clone();
            sort_ascending(&mut got);
            assert_eq!(got, expected, "{ids:?}");
            let mut distinct = expected.clone();
            distinct.dedup();
            let span = expected.last().map_or(0, |&h| (h - expected[0]) / 64 + 1) as usize;
            bitmap_path += usize::from(
                distinct.len() == ids.len() && ids.len() > 1 && span <= WORDS.min(4 * ids.len()),
            );
        }
        assert!(bitmap_path > 1_000, "{bitmap_path}");
    }
}
