//! Collision queries between meshes that deform: which triangles of two meshes (or of one mesh) touch this
//! frame, on the refitted trees the ray queries use.
//!
//! - **Discrete** ([`PairQuery::meshes`], [`PairQuery::itself`]): a simultaneous traversal of the two trees
//!   (thesis §6.2.3) finds overlapping leaves; an exact triangle–triangle test ([`tri_tri`], exact
//!   orientation predicates, so coplanar and touching triangles are decided right) turns them into
//!   [`Contact`]s with a point, a normal and a penetration estimate.
//! - **Self-collision** of one mesh (cloth, flailing limbs) skips triangles that share a vertex.
//! - **Front caching** ([`PairFront`]): while the trees are refitted rather than rebuilt, a query restarts
//!   from where the last one stopped (thesis §6.2.3).
//! - **Continuous** ([`ccd`], [`SweptMesh`]): first time of contact between last frame's and this frame's
//!   vertex positions, for fast motion that a discrete test would tunnel through.
//! - On the GPU, `gpu::GpuPairs` (feature `gpu`) runs the traversal; the exact tests stay on the CPU, so the
//!   contacts are the same.
//!
//! ```
//! use kinetrace::collide::{PairQuery, Placed};
//! use kinetrace::{Mesh, MeshBvh, bvh::BuildOptions};
//! use glam::{Affine3A, Vec3};
//! // Two unit triangles, the second standing upright through the first.
//! let flat = Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![0, 1, 2])?;
//! let upright = Mesh::new(vec![Vec3::new(0.2, 0.2, -0.5), Vec3::new(0.2, 0.2, 0.5), Vec3::new(0.6, 0.2, 0.0)], vec![0, 1, 2])?;
//! let (a, b) = (MeshBvh::build(&flat, &BuildOptions::default())?, MeshBvh::build(&upright, &BuildOptions::default())?);
//! let mut query = PairQuery::new();
//! let mut contacts = Vec::new();
//! query.meshes(Placed::new(&a, Affine3A::IDENTITY), Placed::new(&b, Affine3A::IDENTITY), &mut contacts)?;
//! assert_eq!(contacts.len(), 1);
//! // Moved 10 units up, they no longer touch.
//! query.meshes(Placed::new(&a, Affine3A::IDENTITY), Placed::new(&b, Affine3A::from_translation(Vec3::Z * 10.0)), &mut contacts)?;
//! assert!(contacts.is_empty());
//! # Ok::<(), kinetrace::Error>(())
//! ```

pub(crate) mod bvtt;
pub mod ccd;
mod front;
mod narrow;
mod swept;
pub mod tri_tri;

pub use bvtt::PairStats;
pub use front::PairFront;

#[cfg(feature = "gpu")]
use crate::Error;
use crate::geometry::{check_finite, checked_inverse};
use crate::{MeshBvh, Result, parallel};
use bvtt::{Bvtt, Pair};
use glam::{Affine3A, Mat3A, Vec3};
use narrow::{Collect, Discrete, NarrowPhase, Side};
pub use swept::{Impact, SweptMesh};

/// Two triangles that touch.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Contact {
    /// Triangle of the first mesh (index into its index buffer / 3). For a mesh against itself, the
    /// smaller of the two.
    pub triangle_a: u32,
    /// Triangle of the second mesh.
    pub triangle_b: u32,
    /// A point of the intersection, in world space (see [`tri_tri::TriContact::point`]).
    pub point: Vec3,
    /// Unit normal of `triangle_b` in world space: the direction to push `triangle_a` out.
    pub normal: Vec3,
    /// How far `triangle_a` reaches behind `triangle_b`'s plane, in world units (≥ 0).
    pub depth: f32,
}

/// A mesh's tree and where it stands in the world.
#[derive(Clone, Copy, Debug)]
pub struct Placed<'a> {
    /// The tree, over the mesh's current (object-space) vertex positions.
    pub mesh: &'a MeshBvh,
    /// Object to world.
    pub to_world: Affine3A,
}

impl<'a> Placed<'a> {
    /// `mesh` placed by `to_world`.
    pub fn new(mesh: &'a MeshBvh, to_world: Affine3A) -> Self {
        Placed { mesh, to_world }
    }
}

/// One worker's scratch: its stack and what its walks found.
#[derive(Clone, Debug)]
struct Chunk<T> {
    stack: Vec<Pair>,
    found: Vec<T>,
    stopped: Vec<Pair>,
    stats: PairStats,
}

impl<T> Default for Chunk<T> {
    fn default() -> Self {
        Chunk {
            stack: Vec::new(),
            found: Vec::new(),
            stopped: Vec::new(),
            stats: PairStats::default(),
        }
    }
}

/// The start pairs of a query's workers.
#[derive(Clone, Debug, Default)]
struct Starts {
    pairs: Vec<Pair>,
    next: Vec<Pair>,
}

/// Runs collision queries, keeping its scratch memory from one to the next: keep one per system (or
/// thread) and reuse it, and a query allocates nothing once the buffers have grown to the scene.
///
/// Cost: proportional to the pairs of overlapping boxes the traversal meets, plus one exact test per
/// pair of triangles in overlapping leaves. Contacts come out sorted by `(triangle_a, triangle_b)`,
/// whatever the thread count and whether or not a front is used.
#[derive(Clone, Debug)]
pub struct PairQuery {
    parallel: bool,
    starts: Starts,
    contacts: Vec<Chunk<Contact>>,
    impacts: Vec<Chunk<Impact>>,
}

impl Default for PairQuery {
    fn default() -> Self {
        Self::new()
    }
}

/// Pairs handed to each worker when a query runs in parallel (more than one per worker, to balance).
const PAIRS_PER_WORKER: usize = 64;

/// Chunks of work per worker: many, so that rayon's stealing evens out sub-walks of very different sizes.
const CHUNKS_PER_WORKER: usize = 16;

impl PairQuery {
    /// A query that uses all threads (with the `parallel` feature).
    pub fn new() -> Self {
        PairQuery {
            parallel: true,
            starts: Starts::default(),
            contacts: Vec::new(),
            impacts: Vec::new(),
        }
    }

    /// Runs on one thread when `on` is false.
    pub fn parallel(mut self, on: bool) -> Self {
        self.parallel = on;
        self
    }

    /// Contacts between the triangles of `a` and `b`, written to `out` (cleared first).
    ///
    /// Errors: [`Error::InvalidTransform`] when a transform is not finite or `a`'s cannot be inverted.
    pub fn meshes(
        &mut self,
        a: Placed<'_>,
        b: Placed<'_>,
        out: &mut Vec<Contact>,
    ) -> Result<PairStats> {
        let trees = (a.mesh.topology_id(), b.mesh.topology_id());
        Ok(self.contacts_of(discrete(&a, &b)?, trees, None, out))
    }

    /// Like [`meshes`](Self::meshes), restarting from `front` when both trees kept their topology since
    /// the last query with it (and recording the new front).
    pub fn meshes_with_front(
        &mut self,
        a: Placed<'_>,
        b: Placed<'_>,
        front: &mut PairFront,
        out: &mut Vec<Contact>,
    ) -> Result<PairStats> {
        let trees = (a.mesh.topology_id(), b.mesh.topology_id());
        Ok(self.contacts_of(discrete(&a, &b)?, trees, Some(front), out))
    }

    /// Contacts between non-adjacent triangles of one mesh (triangles sharing a vertex are skipped), with
    /// `triangle_a < triangle_b`.
    ///
    /// Errors: [`Error::InvalidTransform`] when the transform is not finite or cannot be inverted.
    pub fn itself(&mut self, m: Placed<'_>, out: &mut Vec<Contact>) -> Result<PairStats> {
        let id = m.mesh.topology_id();
        Ok(self.contacts_of(discrete_self(&m)?, (id, id), None, out))
    }

    /// Like [`itself`](Self::itself), with a front.
    pub fn itself_with_front(
        &mut self,
        m: Placed<'_>,
        front: &mut PairFront,
        out: &mut Vec<Contact>,
    ) -> Result<PairStats> {
        let id = m.mesh.topology_id();
        Ok(self.contacts_of(discrete_self(&m)?, (id, id), Some(front), out))
    }

    /// Contacts of `a` and `b` from their overlapping leaf pairs as [`GpuPairs`](crate::gpu::GpuPairs)
    /// found them (the GPU traversal of the same trees, with `b` placed in `a`'s frame by
    /// `a.to_world⁻¹ · b.to_world`): the exact tests of the CPU query on the GPU's candidates, so the
    /// contacts equal [`meshes`](Self::meshes)'s. Box tests are the GPU's and not counted here.
    ///
    /// Errors: as [`meshes`](Self::meshes), and [`Error::Gpu`] for a pair that does not name two leaves.
    #[cfg(feature = "gpu")]
    pub fn meshes_from_leaf_pairs(
        &mut self,
        a: Placed<'_>,
        b: Placed<'_>,
        leaf_pairs: &[[u32; 2]],
        out: &mut Vec<Contact>,
    ) -> Result<PairStats> {
        self.narrow_leaf_pairs(discrete(&a, &b)?, leaf_pairs, out)
    }

    /// Self-collision contacts from the leaf pairs [`GpuPairs`](crate::gpu::GpuPairs) found in one tree
    /// (in either order within a pair): equal to [`itself`](Self::itself)'s.
    #[cfg(feature = "gpu")]
    pub fn itself_from_leaf_pairs(
        &mut self,
        m: Placed<'_>,
        leaf_pairs: &[[u32; 2]],
        out: &mut Vec<Contact>,
    ) -> Result<PairStats> {
        self.narrow_leaf_pairs(discrete_self(&m)?, leaf_pairs, out)
    }

    #[cfg(feature = "gpu")]
    fn narrow_leaf_pairs(
        &mut self,
        (to_world, bvtt, narrow): (ToWorld, Bvtt<'_>, Discrete<'_>),
        leaf_pairs: &[[u32; 2]],
        out: &mut Vec<Contact>,
    ) -> Result<PairStats> {
        let (parallel, chunks) = (self.parallel, &mut self.contacts);
        let stats = run_leaf_pairs(parallel, chunks, &bvtt, &narrow, leaf_pairs, out)?;
        to_world.apply(out);
        Ok(stats)
    }

    /// A discrete query prepared by [`discrete`] or [`discrete_self`], over trees with these topology ids.
    fn contacts_of(
        &mut self,
        (to_world, bvtt, narrow): (ToWorld, Bvtt<'_>, Discrete<'_>),
        trees: (u64, u64),
        front: Option<&mut PairFront>,
        out: &mut Vec<Contact>,
    ) -> PairStats {
        let (parallel, starts, chunks) = (self.parallel, &mut self.starts, &mut self.contacts);
        let stats = run(parallel, starts, chunks, &bvtt, &narrow, trees, front, out);
        to_world.apply(out);
        stats
    }
}

/// The traversal and narrow phase of a discrete query between two placed meshes, in `a`'s frame.
fn discrete<'a>(a: &Placed<'a>, b: &Placed<'a>) -> Result<(ToWorld, Bvtt<'a>, Discrete<'a>)> {
    let to_world = ToWorld::new(&a.to_world)?;
    let b_to_a = to_world.inverse * check_finite(&b.to_world)?;
    let bvtt = Bvtt::pair(a.mesh.bvh().nodes(), b.mesh.bvh().nodes(), &b_to_a);
    let narrow = Discrete {
        a: Side::of(a.mesh),
        b: Side::of(b.mesh),
        b_to_a: (b_to_a != Affine3A::IDENTITY).then_some(b_to_a),
        itself: false,
    };
    Ok((to_world, bvtt, narrow))
}

/// The traversal and narrow phase of a discrete query of a mesh against itself.
fn discrete_self<'a>(m: &Placed<'a>) -> Result<(ToWorld, Bvtt<'a>, Discrete<'a>)> {
    let to_world = ToWorld::new(&m.to_world)?;
    let side = Side::of(m.mesh);
    let narrow = Discrete {
        a: side,
        b: side,
        b_to_a: None,
        itself: true,
    };
    Ok((to_world, Bvtt::itself(m.mesh.bvh().nodes()), narrow))
}

/// The narrow phase over leaf pairs found elsewhere (by [`crate::gpu::GpuPairs`]): every pair of overlapping
/// leaves given, split over workers; results sorted by triangle pair.
#[cfg(feature = "gpu")]
fn run_leaf_pairs<N: NarrowPhase>(
    parallel: bool,
    chunks: &mut Vec<Chunk<N::Out>>,
    bvtt: &Bvtt<'_>,
    narrow: &N,
    leaf_pairs: &[[u32; 2]],
    out: &mut Vec<N::Out>,
) -> Result<PairStats> {
    out.clear();
    let leaf =
        |nodes: &[crate::bvh::Node], i: u32| nodes.get(i as usize).is_some_and(|n| n.is_leaf());
    if let Some(bad) = leaf_pairs
        .iter()
        .find(|[a, b]| !leaf(bvtt.a, *a) || !leaf(bvtt.b, *b))
    {
        return Err(Error::Gpu(format!(
            "leaf pair {bad:?} does not name two leaves of the trees"
        )));
    }
    let parallel = parallel && parallel::threads() > 1;
    let n = if parallel {
        parallel::threads() * CHUNKS_PER_WORKER
    } else {
        1
    };
    if chunks.len() < n {
        chunks.resize_with(n, Chunk::default);
    }
    parallel::for_each_mut(parallel, &mut chunks[..n], |i, c| {
        c.found.clear();
        c.stats = PairStats::default();
        let range = i * leaf_pairs.len() / n..(i + 1) * leaf_pairs.len() / n;
        for &[a, b] in &leaf_pairs[range] {
            let (na, nb) = (&bvtt.a[a as usize], &bvtt.b[b as usize]);
            narrow.leaves(na, nb, bvtt.itself && a == b, &mut c.stats, &mut c.found);
        }
    });
    let mut stats = PairStats::default();
    for c in &chunks[..n] {
        out.extend_from_slice(&c.found);
        stats.add(&c.stats);
    }
    out.sort_unstable_by_key(N::key);
    Ok(stats)
}

/// A query in `a`'s frame: from the front when it can resume, else from the roots, split over workers;
/// then the next front. Results are sorted by triangle pair.
#[allow(clippy::too_many_arguments)]
fn run<N: NarrowPhase>(
    parallel: bool,
    starts: &mut Starts,
    chunks: &mut Vec<Chunk<N::Out>>,
    bvtt: &Bvtt<'_>,
    narrow: &N,
    trees: (u64, u64),
    mut front: Option<&mut PairFront>,
    out: &mut Vec<N::Out>,
) -> PairStats {
    out.clear();
    let mut stats = PairStats::default();
    if bvtt.is_empty() {
        if let Some(f) = front {
            f.clear();
        }
        return stats;
    }
    let parallel = parallel && parallel::threads() > 1;
    let workers = if parallel { parallel::threads() } else { 1 };
    let resume = front.as_deref_mut().is_some_and(|f| f.resume(trees));
    if let Some(f) = front.as_deref_mut().filter(|_| resume) {
        // Copied, not swapped: one query serves many fronts of different sizes, and swapping would pass
        // buffers between them, growing one of them nearly every frame.
        starts.pairs.clear();
        starts.pairs.extend_from_slice(&f.pairs);
    } else {
        let mut visit = Collect {
            narrow,
            found: out,
            stopped: front.as_deref_mut().map(|f| &mut f.stopped),
        };
        let want = if parallel {
            workers * PAIRS_PER_WORKER
        } else {
            1
        };
        bvtt.split(
            want,
            &mut starts.pairs,
            &mut starts.next,
            &mut visit,
            &mut stats,
        );
    }
    let n = if parallel {
        (workers * CHUNKS_PER_WORKER).min(starts.pairs.len()).max(1)
    } else {
        1
    };
    if chunks.len() < n {
        chunks.resize_with(n, Chunk::default);
    }
    let (pairs, record) = (&starts.pairs, front.is_some());
    parallel::for_each_mut(parallel, &mut chunks[..n], |i, c| {
        c.found.clear();
        c.stopped.clear();
        c.stats = PairStats::default();
        let range = i * pairs.len() / n..(i + 1) * pairs.len() / n;
        let mut visit = Collect {
            narrow,
            found: &mut c.found,
            stopped: record.then_some(&mut c.stopped),
        };
        for p in &pairs[range] {
            bvtt.walk(*p, &mut c.stack, &mut visit, &mut c.stats);
        }
    });
    for c in &chunks[..n] {
        out.extend_from_slice(&c.found);
        stats.add(&c.stats);
        if let Some(f) = front.as_deref_mut() {
            f.stopped.extend_from_slice(&c.stopped);
        }
    }
    if let Some(f) = front {
        f.finish(stats.box_tests);
    }
    out.sort_unstable_by_key(N::key);
    stats
}

/// Maps contacts from a mesh's frame to the world.
struct ToWorld {
    to_world: Affine3A,
    inverse: Affine3A,
    /// Inverse transpose of the linear part: normals transform by it.
    normals: Mat3A,
}

impl ToWorld {
    fn new(to_world: &Affine3A) -> Result<Self> {
        let inverse = checked_inverse(to_world)?;
        Ok(ToWorld {
            to_world: *to_world,
            inverse,
            normals: inverse.matrix3.transpose(),
        })
    }

    fn apply(&self, contacts: &mut [Contact]) {
        if self.to_world == Affine3A::IDENTITY {
            return;
        }
        for c in contacts {
            c.point = self.to_world.transform_point3(c.point);
            let n = self.normals * c.normal;
            let len = n.length();
            // A plane's normal n maps to M⁻ᵀn, and distances to it shrink by |M⁻ᵀn|.
            c.normal = n / len;
            c.depth /= len;
        }
    }
}
