//! The order of a batch of query points along a Morton curve through their box ([`MortonOrder`]).

use crate::bvh::radix_sort::{RadixScratch, sort_by_bits_with};
use crate::geometry::{Aabb, morton30_cube};
use glam::Vec3;

/// The order of a batch of query points along a Morton curve through their box: answered in this order,
/// neighbouring queries follow one another and walk the same nodes while they are in cache. Keep one and
/// reuse it.
///
/// When to use: many point queries (closest points, containment) against a mesh too large for the cache,
/// asked in no particular order. The plugin's batched closest points use it as a planned option
/// ([`PointBatches`](crate::ecs::PointBatches)). Cost: one pass for the points' box, a 30-bit code per
/// point and the LBVH builder's radix sort of (code, index) words (three passes); no allocation once grown
/// to the largest batch.
///
/// ```
/// use kinetrace::queries::MortonOrder;
/// use glam::Vec3;
/// let points = [Vec3::new(9.0, 9.0, 9.0), Vec3::ZERO, Vec3::new(8.0, 9.0, 9.0), Vec3::splat(0.5)];
/// let mut order = MortonOrder::default();
/// order.sort(points.len(), |i| points[i]);
/// let visited: Vec<usize> = order.indices().collect();
/// assert_eq!(visited, [1, 3, 2, 0]);
/// ```
#[derive(Clone, Debug, Default)]
pub struct MortonOrder {
    /// Words `code << 32 | index`, sorted by code.
    keyed: Vec<u64>,
    radix: RadixScratch<u64>,
}

impl MortonOrder {
    /// Orders the `n` points `point(0..n)` along the curve through their box, in cubic cells (1,024 along
    /// its longest side); non-finite points (which no query answers) come first, equal codes in index
    /// order. At most `u32::MAX` points.
    pub fn sort(&mut self, n: usize, point: impl Fn(usize) -> Vec3) {
        let bounds = (0..n)
            .map(&point)
            .filter(|p| p.is_finite())
            .fold(Aabb::EMPTY, |mut b, p| {
                b.grow(p);
                b
            });
        self.keyed.clear();
        self.keyed.extend((0..n).map(|i| {
            let p = point(i);
            let code = if p.is_finite() {
                morton30_cube(p, &bounds)
            } else {
                0
            };
            u64::from(code) << 32 | i as u64
        }));
        // Stable: equal codes stay in index order.
        sort_by_bits_with(&mut self.keyed, &mut self.radix, 30, false, |&w| w >> 32);
    }

    /// The points' indices in the order of the last [`sort`](Self::sort).
    pub fn indices(&self) -> impl ExactSizeIterator<Item = usize> + '_ {
        self.keyed.iter().map(|&w| w as u32 as usize)
    }

    /// The index of the `k`-th point in that order.
    #[inline]
    pub fn index(&self, k: usize) -> usize {
        self.keyed[k] as u32 as usize
    }
}
