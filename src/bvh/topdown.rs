//! The top-down driver shared by the spatial-median and binned-SAH builders (and by the hybrid builder
//! below its LBVH levels): ask a [`SplitRule`] where to cut, recurse into both halves in parallel when they
//! are big enough, and fall back to balanced object-median cuts where a rule cannot split or a branch gets
//! deep.

use super::layout::Slot;
use super::{BuildInput, MAX_DEPTH, MAX_PRIMITIVES};
use crate::geometry::Aabb;
use crate::parallel;
use glam::{BVec3A, Vec3A, Vec4};

/// Below this many primitives a subtree is built on the current thread.
pub(crate) const PARALLEL_SUBTREE: usize = 2048;

/// From this depth on, only object-median cuts are made: they halve the count, so a subtree of at most
/// [`MAX_PRIMITIVES`] = 2^27 primitives adds at most 27 levels and no leaf is deeper than [`MAX_DEPTH`] - 1.
pub(crate) const BALANCED_DEPTH: usize = MAX_DEPTH - 1 - MAX_PRIMITIVES.trailing_zeros() as usize;

/// A primitive as the top-down builders move it: its box and its id in 32 bytes, so that a node's
/// primitives are one contiguous run of memory that binning and partitioning stream through, instead of
/// ids that each cost a random load of a box and a centroid.
///
/// The id sits in `min.w` as the bits of a normal float (bit 30 set: exponent 128..=143, since ids are
/// below 2^27), so the unused lane never holds a denormal, infinity or NaN that could slow down the SIMD
/// arithmetic done on the xyz lanes.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Prim {
    min: Vec4,
    max: Vec4,
}

const ID_TAG: u32 = 1 << 30;
const _: () = assert!(MAX_PRIMITIVES as u32 <= 1 << 27);

impl Prim {
    #[inline]
    fn new(id: u32, b: &Aabb) -> Self {
        Self {
            min: b.min.extend(f32::from_bits(id | ID_TAG)),
            max: b.max.extend(0.0),
        }
    }

    /// The primitive's id (its index in the build input).
    #[inline]
    pub fn id(&self) -> u32 {
        self.min.w.to_bits() & !ID_TAG
    }

    /// Smallest corner (the w lane is not part of it).
    #[inline]
    pub fn min(&self) -> Vec3A {
        Vec3A::from_vec4(self.min)
    }

    /// Largest corner.
    #[inline]
    pub fn max(&self) -> Vec3A {
        Vec3A::from_vec4(self.max)
    }

    /// The centroid, bit for bit [`Aabb::center`] of the box.
    #[inline]
    pub fn centroid(&self) -> Vec3A {
        (self.min() + self.max()) * 0.5
    }
}

/// A box in SIMD registers, for the builders' inner loops. [`Self::EMPTY`] is the identity of growing.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Box3A {
    pub min: Vec3A,
    pub max: Vec3A,
}

impl Box3A {
    pub const EMPTY: Box3A = Box3A {
        min: Vec3A::INFINITY,
        max: Vec3A::NEG_INFINITY,
    };

    /// Grows to hold the point.
    #[inline]
    pub fn grow(&mut self, p: Vec3A) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }

    /// Grows to hold the primitive's box.
    #[inline]
    pub fn grow_prim(&mut self, p: &Prim) {
        self.min = self.min.min(p.min());
        self.max = self.max.max(p.max());
    }

    #[inline]
    #[must_use]
    pub fn union(&self, o: &Box3A) -> Box3A {
        Box3A {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }

    #[inline]
    pub fn aabb(&self) -> Aabb {
        Aabb::new(self.min.into(), self.max.into())
    }
}

/// The centroid bounds of both sides of a partition, grown without branching on the side.
pub(crate) struct Sides([Box3A; 2]);

impl Sides {
    pub fn new() -> Self {
        Sides([Box3A::EMPTY; 2])
    }

    /// Adds centroid `c` to the left or the right side: eight SIMD min/max/selects, no branch.
    #[inline]
    pub fn add(&mut self, c: Vec3A, left: bool) {
        let mask = BVec3A::splat(left);
        let [l, r] = &mut self.0;
        l.min = l.min.min(Vec3A::select(mask, c, l.min));
        l.max = l.max.max(Vec3A::select(mask, c, l.max));
        r.min = r.min.min(Vec3A::select(mask, r.min, c));
        r.max = r.max.max(Vec3A::select(mask, r.max, c));
    }

    /// The cut with these sides' bounds.
    pub fn cut(self, left: usize) -> Cut {
        Cut {
            left,
            centroids: self.0.map(|b| Some(b.aabb())),
        }
    }
}

/// Where a rule cuts a node.
pub(crate) struct Cut {
    /// Number of primitives of the left child, `0 < left < len`; they come first.
    pub left: usize,
    /// The children's centroid bounds where the rule found them on the way (saves a pass in the child).
    pub centroids: [Option<Aabb>; 2],
}

/// Where to cut a node.
pub(crate) trait SplitRule: Sync {
    /// Reorders `prims` so that the left child's come first and says where the cut is, or returns `None`
    /// when the node should be a leaf. `centroids` is the bounds of the primitives' centroids when the
    /// caller knows them. Only called with `prims.len() >= 2`.
    fn split(&self, input: &BuildInput, prims: &mut [Prim], centroids: Option<Aabb>)
    -> Option<Cut>;
}

/// Builds the subtree of `slot` at `depth` with `rule`. Returns the number of nodes used.
///
/// Cost on top of the rule's: one gather of the subtree's boxes into 32-byte [`Prim`]s (parallel when asked),
/// and writing each id back into `slot.prims` at its leaf.
pub(crate) fn build<R: SplitRule>(
    input: &BuildInput,
    rule: &R,
    slot: Slot<'_>,
    depth: usize,
) -> usize {
    let mut prims = vec![Prim::default(); slot.prims.len()];
    parallel::fill(input.parallel, &mut prims, 1 << 14, |i| {
        let id = slot.prims[i];
        Prim::new(id, &input.bounds[id as usize])
    });
    build_node(input, rule, slot, &mut prims, None, depth)
}

fn build_node<R: SplitRule>(
    input: &BuildInput,
    rule: &R,
    slot: Slot<'_>,
    prims: &mut [Prim],
    centroids: Option<Aabb>,
    depth: usize,
) -> usize {
    let m = prims.len();
    if m == 1 {
        return leaf(slot, prims);
    }
    let cut = if depth >= BALANCED_DEPTH {
        ObjectMedian.split(input, prims, centroids)
    } else {
        rule.split(input, prims, centroids)
    };
    let cut = match cut {
        Some(c) => c,
        None if m <= input.max_leaf => return leaf(slot, prims),
        None => ObjectMedian
            .split(input, prims, None)
            .expect("object median always cuts"),
    };
    let par = input.parallel && m >= PARALLEL_SUBTREE;
    let (lp, rp) = prims.split_at_mut(cut.left);
    let [lc, rc] = cut.centroids;
    slot.split(cut.left, par, [(lp, lc), (rp, rc)], |child, (p, c)| {
        build_node(input, rule, child, p, c, depth + 1)
    })
}

/// Makes `slot` a leaf over `prims`: writes their ids and the union of their boxes. O(len).
fn leaf(slot: Slot<'_>, prims: &[Prim]) -> usize {
    let mut b = Box3A::EMPTY;
    for (id, p) in slot.prims.iter_mut().zip(prims) {
        *id = p.id();
        b.grow_prim(p);
    }
    slot.leaf(&b.aabb())
}

/// Bounds of `point(x)` over `items`, in parallel chunks for large inputs when asked. O(len).
pub(crate) fn bounds_of<T: Sync>(
    parallel: bool,
    items: &[T],
    point: impl Fn(&T) -> Vec3A + Sync + Send,
) -> Aabb {
    let par = parallel && items.len() >= 1 << 16;
    parallel::map_reduce(
        par,
        items,
        1 << 14,
        Box3A::EMPTY,
        |xs| {
            xs.iter().fold(Box3A::EMPTY, |mut b, x| {
                b.grow(point(x));
                b
            })
        },
        |a, b| a.union(&b),
    )
    .aabb()
}

/// Bounds of the centroids of `prims`. O(len).
pub(crate) fn centroid_bounds(input: &BuildInput, prims: &[Prim]) -> Aabb {
    bounds_of(input.parallel, prims, Prim::centroid)
}

/// Cuts at the median primitive along the centroids' longest axis (ties broken by primitive id, so the result
/// is one well-defined order). Always cuts when `len >= 2`, and the halves differ by at most one.
/// Cost: O(len) for the centroid bounds when not given, and an O(len) selection.
pub(crate) struct ObjectMedian;

impl SplitRule for ObjectMedian {
    fn split(
        &self,
        input: &BuildInput,
        prims: &mut [Prim],
        centroids: Option<Aabb>,
    ) -> Option<Cut> {
        let axis = centroids
            .unwrap_or_else(|| centroid_bounds(input, prims))
            .largest_axis();
        let k = prims.len() / 2;
        prims.select_nth_unstable_by(k, |a, b| {
            let (ca, cb) = (a.centroid()[axis], b.centroid()[axis]);
            ca.total_cmp(&cb).then(a.id().cmp(&b.id()))
        });
        Some(Cut {
            left: k,
            centroids: [None, None],
        })
    }
}

/// Moves the items for which `goes_left` holds to the front (order within each side is not kept) and
/// returns how many there are. `goes_left` is called exactly once per item, in order.
///
/// Branch-free (Lomuto with an unconditional swap), since the side of each item is as unpredictable as a
/// coin toss for a good cut: O(len) with two loads and two stores per item and no mispredictions.
pub(crate) fn partition<T: Copy>(items: &mut [T], mut goes_left: impl FnMut(&T) -> bool) -> usize {
    let mut k = 0;
    for i in 0..items.len() {
        let x = items[i];
        let left = goes_left(&x);
        items[i] = items[k];
        items[k] = x;
        k += usize::from(left);
    }
    k
}
