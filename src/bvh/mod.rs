//! Binary bounding volume hierarchies: one [`Node`] layout, four builders, refit with a degradation metric,
//! closest-hit and any-hit traversal, and quality metrics.
//!
//! [`Bvh`] is the tree over any primitives given by their boxes; [`MeshBvh`] pairs it with a triangle mesh
//! and answers ray queries. Every builder returns the same `Bvh`, so the choice is a matter of speed against
//! quality:
//!
//! | builder | build cost | tree quality | use when |
//! |---|---|---|---|
//! | [`Builder::Median`] | lowest top-down | 50–90% of SAH | a simple cheap rebuild |
//! | [`Builder::Lbvh`] | lowest overall, parallel | lowest, poor on teapot-in-stadium | rebuilding every frame |
//! | [`Builder::Hybrid`] | LBVH + SAH below `k` levels | close to SAH | frequent rebuilds of uneven meshes |
//! | [`Builder::Sah`] | highest | best | static meshes, rare rebuilds |
//! | [`Builder::Ploc`] | Morton sort + ~log n clustering rounds, parallel | close to SAH | frequent rebuilds that want SAH-like trees |
//!
//! Between a refit and a rebuild, [`Bvh::rebuild_degraded`] (and [`MeshBvh::refit_partial`]) rebuilds only
//! the subtrees whose degradation crossed a threshold, in place (see [`PartialOptions`]).
//!
//! Primitives are *indexed*, not moved: leaves refer to a range of slots in [`Bvh::prim_indices`], which maps
//! slots to the caller's primitive ids. Output is deterministic: the same input and options give the same
//! bytes, whatever the number of threads.

mod build_hybrid;
mod build_lbvh;
mod build_median;
pub(crate) mod build_ploc;
mod build_sah;
mod layout;
mod mesh_bvh;
mod node;
mod packet;
pub mod partial;
mod prefetch;
pub mod quality;
pub(crate) mod radix_sort;
mod refit;
mod stack;
mod topdown;
mod traverse;
mod validate;
pub mod wide;

pub use build_ploc::{DEFAULT_PLOC_RADIUS, MAX_PLOC_RADIUS};
pub use build_sah::MAX_BINS;
pub use mesh_bvh::{GATHER_BELOW_BYTES, Hit, MeshBvh};
pub(crate) use mesh_bvh::{LeafRay, is_collapsed, query_corners};
pub(crate) use mesh_bvh::{next_topology_id, slot_indices};
pub use node::{LEAF_BIT, MAX_DEPTH, MAX_LEAF_SIZE, MAX_PRIMITIVES, Node};
pub use packet::MAX_PACKET;
pub(crate) use packet::for_each_packet;
pub use partial::{PartialOptions, PartialRebuild};
pub(crate) use prefetch::prefetch;
pub(crate) use refit::refit_nodes;
pub use traverse::TraversalStats;
pub(crate) use traverse::{traverse, traverse_by};
pub(crate) use wide::interleaved;

use crate::geometry::Aabb;
use crate::{Error, Result};
use glam::Vec3;
use std::sync::Arc;

/// Bits of the Morton codes that the LBVH and hybrid builders sort by.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum MortonBits {
    /// 10 bits per axis: three radix passes, the GPU builder's codes. Enough for most meshes.
    #[default]
    Bits30,
    /// 21 bits per axis: twice the sort passes, for scenes with small detail in a large box.
    Bits63,
}

impl MortonBits {
    /// Number of code bits.
    pub fn bits(self) -> u32 {
        match self {
            MortonBits::Bits30 => 30,
            MortonBits::Bits63 => 63,
        }
    }
}

/// Which construction algorithm to run. See the [module docs](self) for the trade-offs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Builder {
    /// Spatial median of the longest axis (thesis §4.1.2).
    Median,
    /// Binned SAH with `bins` bins per axis (2..=[`MAX_BINS`]).
    Sah {
        /// Bins per axis; 16 by default.
        bins: u32,
    },
    /// Karras 2012 radix tree over sorted Morton codes.
    Lbvh {
        /// Morton code length.
        morton: MortonBits,
    },
    /// LBVH for the top `lbvh_levels` levels, binned SAH below (thesis §5.3).
    Hybrid {
        /// LBVH levels; 6 by default, as in the thesis.
        lbvh_levels: u32,
        /// SAH bins per axis below.
        bins: u32,
        /// Morton code length of the LBVH part.
        morton: MortonBits,
    },
    /// Parallel locally-ordered clustering (Meister and Bittner 2018): bottom-up merging of mutual nearest
    /// neighbours along the Morton curve. One primitive per leaf before [`BuildOptions::max_leaf_size`]
    /// collapses small subtrees.
    Ploc {
        /// Neighbours searched on each side, 1..=[`MAX_PLOC_RADIUS`]; 16 by default, as in the paper.
        radius: u32,
    },
}

impl Builder {
    /// Binned SAH with 16 bins.
    pub const SAH: Builder = Builder::Sah { bins: 16 };
    /// LBVH over 30-bit codes.
    pub const LBVH: Builder = Builder::Lbvh {
        morton: MortonBits::Bits30,
    };
    /// Six LBVH levels over 30-bit codes, then 16-bin SAH.
    pub const HYBRID: Builder = Builder::hybrid(6);
    /// PLOC with the paper's search radius of 16.
    pub const PLOC: Builder = Builder::Ploc {
        radius: DEFAULT_PLOC_RADIUS,
    };

    /// [`HYBRID`](Self::HYBRID) with `lbvh_levels` LBVH levels instead of six: more levels build faster
    /// and give a worse tree. Other bins or code lengths need the variant with all three fields, as in
    /// `Builder::Hybrid { lbvh_levels: 4, bins: 8, morton: MortonBits::Bits63 }`.
    ///
    /// ```
    /// use kinetrace::bvh::{Builder, MortonBits};
    /// let b = Builder::hybrid(4);
    /// assert_eq!(b, Builder::Hybrid { lbvh_levels: 4, bins: 16, morton: MortonBits::Bits30 });
    /// ```
    pub const fn hybrid(lbvh_levels: u32) -> Builder {
        Builder::Hybrid {
            lbvh_levels,
            bins: 16,
            morton: MortonBits::Bits30,
        }
    }

    /// All four builders with their defaults.
    pub const ALL: [Builder; 4] = [
        Builder::Median,
        Builder::SAH,
        Builder::LBVH,
        Builder::HYBRID,
    ];

    /// A short name for tables and logs.
    pub fn name(&self) -> &'static str {
        match self {
            Builder::Median => "median",
            Builder::Sah { .. } => "sah",
            Builder::Lbvh { .. } => "lbvh",
            Builder::Hybrid { .. } => "hybrid",
            Builder::Ploc { .. } => "ploc",
        }
    }
}

/// How to build a tree.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct BuildOptions {
    /// The algorithm.
    pub builder: Builder,
    /// Most primitives per leaf, 1..=[`MAX_LEAF_SIZE`]; 1 by default, as in the thesis. Builders make
    /// smaller leaves where that is cheaper (SAH) or where a split cannot separate primitives.
    pub max_leaf_size: u32,
    /// Use all threads (with the `parallel` feature). The result is identical either way.
    pub parallel: bool,
    /// [`MeshBvh`] only: also derive the 4-wide query tree ([`wide`]) that its ray queries then walk; on by
    /// default. Costs a collapse pass per build (measured in `bench cpu`: somewhat less than an LBVH build
    /// of the same mesh) and about 50 bytes per triangle; turn it off for meshes rebuilt every frame that
    /// answer few rays. [`Bvh::build`] ignores it.
    pub wide: bool,
}

impl Default for BuildOptions {
    fn default() -> Self {
        Self {
            builder: Builder::SAH,
            max_leaf_size: 1,
            parallel: true,
            wide: true,
        }
    }
}

impl BuildOptions {
    /// Default options with the given builder.
    pub fn new(builder: Builder) -> Self {
        Self {
            builder,
            ..Self::default()
        }
    }

    /// Sets [`max_leaf_size`](Self::max_leaf_size).
    pub fn max_leaf_size(mut self, n: u32) -> Self {
        self.max_leaf_size = n;
        self
    }

    /// Sets [`parallel`](Self::parallel).
    pub fn parallel(mut self, on: bool) -> Self {
        self.parallel = on;
        self
    }

    /// Sets [`wide`](Self::wide).
    pub fn wide(mut self, on: bool) -> Self {
        self.wide = on;
        self
    }

    fn check(&self) -> Result<()> {
        if !(1..=MAX_LEAF_SIZE).contains(&self.max_leaf_size) {
            return Err(Error::InvalidOption(format!(
                "max_leaf_size {} is outside 1..={MAX_LEAF_SIZE}",
                self.max_leaf_size
            )));
        }
        if let Builder::Ploc { radius } = self.builder
            && !(1..=MAX_PLOC_RADIUS).contains(&radius)
        {
            return Err(Error::InvalidOption(format!(
                "PLOC radius {radius} is outside 1..={MAX_PLOC_RADIUS}"
            )));
        }
        let bins = match self.builder {
            Builder::Sah { bins } | Builder::Hybrid { bins, .. } => bins,
            _ => 2,
        };
        if !(2..=MAX_BINS).contains(&bins) {
            return Err(Error::InvalidOption(format!(
                "{bins} SAH bins is outside 2..={MAX_BINS}"
            )));
        }
        Ok(())
    }
}

/// What builders read: the primitives' boxes and centroids.
pub(crate) struct BuildInput<'a> {
    pub bounds: &'a [Aabb],
    pub centroids: &'a [Vec3],
    pub max_leaf: usize,
    pub parallel: bool,
}

/// A binary BVH over primitives given by their boxes.
///
/// `nodes[0]` is the root (no nodes for an empty tree). Leaves hold slots into [`prim_indices`], which
/// maps each slot to the primitive id the builder was given (its position in the input slice).
///
/// [`prim_indices`]: Bvh::prim_indices
///
/// A clone shares the slot order with the original until either changes it (it is topology: refits keep
/// it), so copies of one tree for many deforming instances pay for their boxes only.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Bvh {
    nodes: Vec<Node>,
    prims: Arc<[u32]>,
}

impl Bvh {
    /// Builds a tree over primitives with the given boxes.
    ///
    /// Errors: [`Error::InvalidOption`] for options out of range, [`Error::NonFiniteBounds`] for a box that is
    /// empty or not finite, [`Error::TooManyPrimitives`] past [`MAX_PRIMITIVES`].
    ///
    /// ```
    /// use kinetrace::bvh::{Bvh, BuildOptions, Builder};
    /// use kinetrace::geometry::Aabb;
    /// use glam::Vec3;
    /// let boxes: Vec<Aabb> = (0..100)
    ///     .map(|i| Aabb::from_point(Vec3::new(i as f32, 0.0, 0.0)))
    ///     .collect();
    /// let bvh = Bvh::build(&boxes, &BuildOptions::new(Builder::LBVH))?;
    /// assert_eq!(bvh.nodes().len(), 199);
    /// bvh.validate(Some(&boxes))?;
    /// # Ok::<(), kinetrace::Error>(())
    /// ```
    pub fn build(bounds: &[Aabb], options: &BuildOptions) -> Result<Bvh> {
        options.check()?;
        let n = bounds.len();
        if n > MAX_PRIMITIVES {
            return Err(Error::TooManyPrimitives {
                count: n,
                max: MAX_PRIMITIVES,
            });
        }
        if let Some(primitive) = bounds
            .iter()
            .position(|b| b.is_empty() || !b.min.is_finite() || !b.max.is_finite())
        {
            return Err(Error::NonFiniteBounds { primitive });
        }
        if n == 0 {
            return Ok(Bvh::default());
        }
        let centroids: Vec<Vec3> = bounds.iter().map(Aabb::center).collect();
        let input = BuildInput {
            bounds,
            centroids: &centroids,
            max_leaf: options.max_leaf_size as usize,
            parallel: options.parallel && cfg!(feature = "parallel"),
        };
        let mut prims: Vec<u32> = (0..n as u32).collect();
        let mut nodes = vec![Node::default(); 2 * n - 1];
        let slot = layout::root_slot(&mut nodes, &mut prims);
        let used = match options.builder {
            Builder::Median => topdown::build(&input, &build_median::SpatialMedian, slot, 0),
            Builder::Sah { bins } => {
                topdown::build(&input, &build_sah::BinnedSah { bins }, slot, 0)
            }
            Builder::Lbvh { morton } => build_lbvh::build(&input, slot, morton, None),
            Builder::Hybrid {
                lbvh_levels,
                bins,
                morton,
            } => build_hybrid::build(&input, slot, morton, lbvh_levels as usize, bins),
            Builder::Ploc { radius } => build_ploc::build(&input, slot, radius),
        };
        layout::compact(&mut nodes, used);
        Ok(Bvh {
            nodes,
            prims: prims.into(),
        })
    }

    /// A tree from its parts, as read back from the GPU builder.
    #[cfg(feature = "gpu")]
    pub(crate) fn from_parts(nodes: Vec<Node>, prims: Vec<u32>) -> Bvh {
        Bvh {
            nodes,
            prims: prims.into(),
        }
    }

    /// The nodes, root first. These are the bytes uploaded to the GPU.
    pub fn nodes(&self) -> &[Node] {
        &self.nodes
    }

    /// The nodes, for refits that compute leaf boxes their own way.
    pub(crate) fn nodes_mut(&mut self) -> &mut [Node] {
        &mut self.nodes
    }

    /// Slot → primitive id. Leaf `l` holds primitives `prim_indices()[l.slots()]`.
    pub fn prim_indices(&self) -> &[u32] {
        &self.prims
    }

    /// Number of primitives.
    pub fn primitive_count(&self) -> usize {
        self.prims.len()
    }

    /// True for the tree of no primitives.
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// The root's box ([`Aabb::EMPTY`] for an empty tree).
    pub fn bounds(&self) -> Aabb {
        self.nodes.first().map_or(Aabb::EMPTY, Node::aabb)
    }

    /// Number of inner nodes.
    pub fn inner_count(&self) -> usize {
        self.nodes.len() - self.leaf_count()
    }

    /// Number of leaves (`(nodes + 1) / 2` in a binary tree).
    pub fn leaf_count(&self) -> usize {
        self.nodes.len().div_ceil(2)
    }
}
