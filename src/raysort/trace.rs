//! The strategies that answer a batch of secondary rays against one mesh, answers in request order.
//!
//! - [`Strategy::Bvh`]: each ray through the mesh's BVH, in request order.
//! - [`Strategy::SortedBvh`]: the same traversal in key order ([`sort_rays`]); pays where request order is
//!   incoherent, costs the sort (24–33 ns a ray on the crowd at 512², loaded 2-core VM).
//! - [`Strategy::SortedPackets`]: the rays in key order, each kind apart, as packets of consecutive rays
//!   ([`MeshBvh::closest_hits_packet`], [`MeshBvh::any_hits_packet`]): neighbours in key order start near
//!   each other and point the same way, so a packet shares its node visits where the rays allow: on the
//!   crowd (`bench raysort`, idle 2-core AMD EPYC VM, packets of 64), 1.70× / 1.92× the BVH's speed on
//!   shadow rays toward one light at 512² / 1024², 1.10× / 1.46× on reflection rays. Costs the sort and the
//!   packets' range scans; node tests count once per packet.
//! - [`Strategy::SortedRuns`]: the same packets, cut where the key changes above its low bits, so that a
//!   packet never mixes origin cells or direction blocks; sorted on those high bits only
//!   ([`SortedRays::sort_above`]: cheaper than the full sort, ties left in pixel order, which traverses 4–6%
//!   faster than full key order). Reflection rays on the crowd (`bench raysort`'s, 23,040 triangles; one
//!   thread, thread CPU time, idle 2-core AMD EPYC VM), sort counted: **1.49× the BVH in pixel order at
//!   512², 1.88× at 1024²** (single rays through the 4-wide tree; the packets walk the same tree, leaves
//!   tested four rays at a time against each triangle); shadow rays toward one light 1.88× / 2.27×, toward
//!   four 1.34× / 1.64×. Short runs (about 16 rays a packet at 512²) pay a packet's set-up per ray: the
//!   packets' per-ray state is kept per thread and set only for the packet's own rays. On a crowd of
//!   192,000 triangles (an earlier tree), 0.99× before the sort: pixel order is already coherent.
//! - [`Strategy::Crsh`]: the coherent ray-space hierarchy over the sorted rays. Each top node is tested
//!   against the mesh's bounding sphere, then against every triangle's sphere; survivors go down to the
//!   children, and each level-1 node's survivors to the exact watertight test of its rays. Cost per top node:
//!   one sphere test per triangle, so O(rays / s^D · triangles) — far above a BVH on big meshes.
//! - [`Strategy::Rah`]: the baseline, the same hierarchy over the rays in request order, no mesh sphere.
//!
//! Shadow rays ask for any hit, reflection rays for the closest (smallest `t`, then lowest triangle).

use super::cone::bounding_sphere;
use super::hierarchy::RayHierarchy;
use super::{KeyLayout, RayKind, SecondaryRay, SortScratch, SortedRays, sort_rays};
use crate::bvh::{BuildOptions, Hit, MAX_PACKET, MeshBvh, TraversalStats, query_corners};
use crate::geometry::TriangleRay;
use crate::{Mesh, Result, parallel};
use glam::Vec3;
use std::ops::Range;
use std::sync::atomic::{AtomicU64, Ordering};

/// Low key bits a sorted run may differ in (`Strategy::SortedRuns`'s `drop_bits`, the ECS's sorted runs):
/// with the default [`KeyLayout`], the low 5 bits of each direction angle, so that a run keeps one origin
/// cell and one block of 32 × 32 direction steps. Of 6, 10 and 14 on the crowd's reflection rays at 1024²,
/// 10 and 14 were fastest (1.30–1.32× the BVH before the sort, `bench raysort`, loaded 2-core dev VM).
pub const RUN_LOW_BITS: u32 = 10;

/// How a batch is traced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Strategy {
    /// The BVH, rays in request order.
    Bvh,
    /// The BVH, rays in key order.
    SortedBvh,
    /// The BVH, rays in key order traced as packets of `size` consecutive rays of one kind.
    SortedPackets {
        /// Rays per packet (clamped to `1..=MAX_PACKET`).
        size: usize,
    },
    /// The BVH, rays in key order traced as runs: packets of at most `size` consecutive rays of one kind
    /// whose keys agree above their low `drop_bits` bits; a run of one ray is traced alone. Unlike
    /// [`SortedPackets`](Self::SortedPackets), a packet never spans two origin cells or direction
    /// blocks, so its rays stay close.
    SortedRuns {
        /// Rays per packet at most (clamped to `1..=MAX_PACKET`).
        size: usize,
        /// Low key bits a run may differ in (10 with the default layout: the low 5 bits of each angle).
        drop_bits: u32,
    },
    /// The coherent ray-space hierarchy: sorted rays, branching `s`, depth `D`, mesh-sphere cull.
    Crsh {
        /// Children per node `s` (the seed: 8 or 16).
        branching: usize,
        /// Node levels `D` (the seed: 2 to 4).
        depth: usize,
    },
    /// RAH: the hierarchy over rays in request order, no mesh-sphere cull.
    Rah {
        /// Children per node.
        branching: usize,
        /// Node levels.
        depth: usize,
    },
}

/// The answer to one secondary ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Answer {
    /// Nothing in the ray's range (also the answer to an invalid ray).
    Miss,
    /// A shadow ray found something in its range.
    Occluded,
    /// A reflection ray's closest hit.
    Hit(Hit),
}

/// Intersection tests a batch took, the seed's metric.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RayTestStats {
    /// Coarse tests: ray-node against triangle or mesh sphere (hierarchies), ray against box (BVH: two per
    /// inner node visited).
    pub node_tests: u64,
    /// Exact ray–triangle tests.
    pub triangle_tests: u64,
}

impl RayTestStats {
    /// All tests.
    pub fn total(&self) -> u64 {
        self.node_tests + self.triangle_tests
    }
}

/// Answers in request order and the tests they took.
#[derive(Clone, Debug, PartialEq)]
pub struct Traced {
    /// One per ray, in request order.
    pub answers: Vec<Answer>,
    /// Work done.
    pub stats: RayTestStats,
}

impl Traced {
    /// Puts `done[k]`, the answer to ray `order[k]` and its BVH traversal counts, in place: two box tests
    /// per inner node visited, one exact test per primitive tested.
    fn record(
        &mut self,
        order: impl IntoIterator<Item = u32>,
        done: impl IntoIterator<Item = (Answer, TraversalStats)>,
    ) {
        for (i, (a, st)) in order.into_iter().zip(done) {
            self.answers[i as usize] = a;
            self.stats.node_tests += 2 * st.inner_visits;
            self.stats.triangle_tests += st.prim_tests;
        }
    }
}

/// One mesh prepared for every strategy: its BVH, its bounding sphere and one sphere per triangle.
/// Memory: the BVH plus 56 bytes per triangle.
#[derive(Clone, Debug)]
pub struct RayScene {
    bvh: MeshBvh,
    /// The mesh's bounding sphere.
    pub(super) sphere: (Vec3, f32),
    /// Triangles of non-zero area: mesh index, corners and bounding sphere.
    pub(super) tris: Vec<(u32, [Vec3; 3], Vec3, f32)>,
}

impl RayScene {
    /// Builds the BVH with `options` and the spheres. Errors as [`MeshBvh::build`].
    pub fn build(mesh: &Mesh, options: &BuildOptions) -> Result<Self> {
        let bvh = MeshBvh::build(mesh, options)?;
        let tris: Vec<_> = (0..mesh.triangle_count())
            .filter_map(|i| {
                let t = mesh.triangle(i);
                if query_corners(t) != t {
                    return None; // zero area: never hit
                }
                let (c, r) = bounding_sphere(&t);
                Some((i as u32, t, c, r))
            })
            .collect();
        let sphere = if mesh.positions().is_empty() {
            (Vec3::ZERO, 0.0)
        } else {
            bounding_sphere(mesh.positions())
        };
        Ok(Self { bvh, sphere, tris })
    }

    /// The mesh's BVH.
    pub fn bvh(&self) -> &MeshBvh {
        &self.bvh
    }

    /// Answers `rays` with `strategy`; `layout` keys the sorting strategies. `Error::InvalidOption` for a
    /// layout over 32 bits or a hierarchy shape out of range.
    pub fn trace(
        &self,
        rays: &[SecondaryRay],
        strategy: Strategy,
        layout: &KeyLayout,
        parallel: bool,
    ) -> Result<Traced> {
        match strategy {
            Strategy::Bvh => Ok(self.trace_bvh(rays, (0..rays.len() as u32).collect(), parallel)),
            Strategy::SortedBvh => {
                let order = sort_rays(rays, layout, parallel)?.order;
                Ok(self.trace_bvh(rays, order, parallel))
            }
            Strategy::SortedPackets { size } => {
                let sorted = sort_rays(rays, layout, parallel)?;
                Ok(self.trace_packets(rays, &sorted, size, 32, parallel))
            }
            Strategy::SortedRuns { size, drop_bits } => {
                // The runs read no key bit below `drop_bits`: sort on the bits above only.
                let (mut sorted, drop_bits) = (SortedRays::default(), drop_bits.min(32));
                let scratch = &mut SortScratch::default();
                sorted.sort_above(rays, layout, drop_bits, parallel, scratch)?;
                Ok(self.trace_packets(rays, &sorted, size, drop_bits, parallel))
            }
            Strategy::Crsh { branching, depth } => {
                let sorted = sort_rays(rays, layout, parallel)?;
                let mut order = sorted.order;
                order.truncate(sorted.keys.len()); // the valid rays
                self.trace_hierarchy(rays, order, branching, depth, true, parallel)
            }
            Strategy::Rah { branching, depth } => {
                let order = (0..rays.len() as u32)
                    .filter(|&i| rays[i as usize].ray.is_valid())
                    .collect();
                self.trace_hierarchy(rays, order, branching, depth, false, parallel)
            }
        }
    }

    /// Every ray through the BVH in `order` (a permutation of the batch).
    fn trace_bvh(&self, rays: &[SecondaryRay], order: Vec<u32>, parallel: bool) -> Traced {
        let one = |j: usize| self.bvh_answer(&rays[order[j] as usize]);
        let mut traced = Traced {
            answers: vec![Answer::Miss; rays.len()],
            stats: RayTestStats::default(),
        };
        let requests = order.iter().copied();
        if parallel {
            let mut done = vec![(Answer::Miss, TraversalStats::default()); rays.len()];
            parallel::fill(true, &mut done, 256, one);
            traced.record(requests, done);
        } else {
            // On one thread each answer goes straight to its place.
            traced.record(requests, (0..order.len()).map(one));
        }
        traced
    }

    /// One ray's answer through the BVH alone, and the traversal's counts.
    pub(super) fn bvh_answer(&self, r: &SecondaryRay) -> (Answer, TraversalStats) {
        let mut st = TraversalStats::default();
        let a = match r.kind {
            RayKind::Shadow { .. } if self.bvh.any_hit_counted(&r.ray, &mut st) => Answer::Occluded,
            RayKind::Shadow { .. } => Answer::Miss,
            RayKind::Reflection => {
                (self.bvh.closest_hit_counted(&r.ray, &mut st)).map_or(Answer::Miss, Answer::Hit)
            }
        };
        (a, st)
    }

    /// The valid sorted rays as packets of at most `size` consecutive rays of one kind whose keys agree
    /// above their low `drop_bits` bits (32: any keys, packets of `size`). Each packet gathers its rays on
    /// the stack; beyond the answers, one 8-byte word per ray, and in parallel the answers in trace order
    /// (on one thread they go straight to their place). A batch of mixed kinds is cut where the kind
    /// changes (read beside the ray the packet gathers), not split by a pass over the batch.
    fn trace_packets(
        &self,
        rays: &[SecondaryRay],
        sorted: &SortedRays,
        size: usize,
        drop_bits: u32,
        parallel: bool,
    ) -> Traced {
        let size = size.clamp(1, MAX_PACKET);
        let shadow = |i: u32| matches!(rays[i as usize].kind, RayKind::Shadow { .. });
        // (request index, key) of each valid ray, in key order.
        let run: Vec<(u32, u32)> = (sorted.order.iter().copied())
            .zip(sorted.keys.iter().copied())
            .collect();
        let packets = packet_ranges(&run, size, drop_bits, shadow);
        // A packet's rays gathered into `batch` (kept from packet to packet on one thread: filling 64 rays
        // anew per packet cost more than a short packet's traversal).
        let empty = || [crate::Ray::new(Vec3::ZERO, Vec3::X); MAX_PACKET];
        let trace = |r: Range<usize>, batch: &mut [crate::Ray], out: &mut [_]| {
            for (b, &(i, _)) in batch.iter_mut().zip(&run[r.clone()]) {
                *b = rays[i as usize].ray;
            }
            self.trace_packet(&batch[..r.len()], shadow(run[r.start].0), out);
        };
        let mut traced = Traced {
            answers: vec![Answer::Miss; rays.len()],
            stats: RayTestStats::default(),
        };
        let ids = |r: Range<usize>| run[r].iter().map(|&(i, _)| i);
        if parallel {
            let mut done = vec![(Answer::Miss, TraversalStats::default()); run.len()];
            let mut rest = &mut done[..];
            let mut work = Vec::new();
            for r in packets {
                let (out, tail) = rest.split_at_mut(r.len());
                work.push((r, out));
                rest = tail;
            }
            parallel::for_each_mut(true, &mut work, |_, (r, out)| {
                trace(r.clone(), &mut empty(), out)
            });
            traced.record(ids(0..run.len()), done);
        } else {
            let mut out = [(Answer::Miss, TraversalStats::default()); MAX_PACKET];
            let mut batch = empty();
            for r in packets {
                let out = &mut out[..r.len()];
                trace(r.clone(), &mut batch, out);
                traced.record(ids(r), out.iter().copied());
            }
        }
        traced
    }

    /// One packet of rays of one kind (`any`: shadow rays); a packet of one ray is traced alone. The
    /// node and triangle tests of the packet go to its first ray.
    fn trace_packet(&self, rays: &[crate::Ray], any: bool, out: &mut [(Answer, TraversalStats)]) {
        let bvh = &self.bvh;
        if any {
            packet_answers(
                rays,
                out,
                false,
                |r, st| bvh.any_hit_counted(r, st),
                |r, hit, st| bvh.any_hits_packet(r, hit, st),
                |h| if h { Answer::Occluded } else { Answer::Miss },
            );
        } else {
            packet_answers(
                rays,
                out,
                None,
                |r, st| bvh.closest_hit_counted(r, st),
                |r, hit, st| bvh.closest_hits_packet(r, hit, st),
                |h| h.map_or(Answer::Miss, Answer::Hit),
            );
        }
    }

    /// The valid rays of `order` through a hierarchy built over them in that order. The hierarchy's cones
    /// hold the rays' directions from their origins forward, so a ray whose range reaches behind its origin
    /// (`tmin < 0`) is answered by the BVH instead, its tests counted as the BVH's.
    fn trace_hierarchy(
        &self,
        rays: &[SecondaryRay],
        order: Vec<u32>,
        branching: usize,
        depth: usize,
        cull_mesh: bool,
        parallel: bool,
    ) -> Result<Traced> {
        let (behind, order) = split_reaching_back(order, rays);
        let ordered: Vec<_> = order.iter().map(|&i| rays[i as usize].ray).collect();
        let h = RayHierarchy::build(&ordered, branching, depth, parallel)?;
        let counts = [AtomicU64::new(0), AtomicU64::new(0)];
        let everything: Vec<u32> = (0..self.tris.len() as u32).collect();
        let per_top = branching.pow(depth as u32);
        let mut done = vec![Answer::Miss; ordered.len()];
        parallel::fill_chunks(parallel, &mut done, per_top, |top, out| {
            let mut walk = Walk {
                scene: self,
                h: &h,
                rays: &ordered,
                kinds: rays,
                order: &order,
                out,
                base: top * per_top,
                stats: RayTestStats::default(),
            };
            let node = &h.level(depth)[top];
            let (c, r) = self.sphere;
            if cull_mesh {
                walk.stats.node_tests += 1;
            }
            if !cull_mesh || node.hits_sphere(c, r) {
                walk.descend(depth, top, &everything);
            }
            counts[0].fetch_add(walk.stats.node_tests, Ordering::Relaxed);
            counts[1].fetch_add(walk.stats.triangle_tests, Ordering::Relaxed);
        });
        let mut traced = Traced {
            answers: vec![Answer::Miss; rays.len()],
            stats: RayTestStats {
                node_tests: counts[0].load(Ordering::Relaxed),
                triangle_tests: counts[1].load(Ordering::Relaxed),
            },
        };
        for (&i, a) in order.iter().zip(done) {
            traced.answers[i as usize] = a;
        }
        let reaching_back = behind.iter().map(|&i| self.bvh_answer(&rays[i as usize]));
        traced.record(behind.iter().copied(), reaching_back);
        Ok(traced)
    }
}

/// The request indices `order` split into the rays whose range reaches behind their origin (`tmin < 0`),
/// which the hierarchies' cones (directions from the origins forward) do not hold and the BVH answers, and
/// the others, for the hierarchy; each part keeps `order`'s order.
pub(super) fn split_reaching_back(
    order: impl IntoIterator<Item = u32>,
    rays: &[SecondaryRay],
) -> (Vec<u32>, Vec<u32>) {
    (order.into_iter()).partition(|&i| rays[i as usize].ray.tmin < 0.0)
}

/// The traversal of one top node's subtree.
struct Walk<'a> {
    scene: &'a RayScene,
    h: &'a RayHierarchy,
    /// The hierarchy's rays and, through `order`, their kinds.
    rays: &'a [crate::Ray],
    kinds: &'a [SecondaryRay],
    order: &'a [u32],
    /// Answers of the top node's rays, from hierarchy position `base` on.
    out: &'a mut [Answer],
    base: usize,
    stats: RayTestStats,
}

impl Walk<'_> {
    /// Tests node `j` of level `k` against the triangles `candidates` and takes the survivors down.
    fn descend(&mut self, k: usize, j: usize, candidates: &[u32]) {
        let tris = &self.scene.tris;
        self.stats.node_tests += candidates.len() as u64;
        let survivors = (self.h).survivors(k, j, candidates, |t| {
            let (_, _, c, r) = tris[t as usize];
            (c, r)
        });
        if survivors.is_empty() {
            return;
        }
        for child in self.h.children(k, j, self.rays.len()) {
            if k == 1 {
                self.out[child - self.base] = self.exact(child, &survivors);
            } else {
                self.descend(k - 1, child, &survivors);
            }
        }
    }

    /// The exact watertight tests of hierarchy ray `i` against `candidates`.
    fn exact(&mut self, i: usize, candidates: &[u32]) -> Answer {
        let ray = &self.rays[i];
        let shadow = matches!(
            self.kinds[self.order[i] as usize].kind,
            RayKind::Shadow { .. }
        );
        let tests = &mut self.stats.triangle_tests;
        let tris = &self.scene.tris;
        let found = exact_hit(ray, ray.tmax, candidates, shadow, tests, |t| {
            let (p, corners, ..) = tris[t as usize];
            (p, corners)
        });
        match found {
            None => Answer::Miss,
            Some(_) if shadow => Answer::Occluded,
            Some(h) => Answer::Hit(h),
        }
    }
}

/// The packets of `run` (sorted rays) as ranges: at most `size` consecutive rays of one kind (`shadow`
/// of a request index says which) whose keys agree above their low `drop_bits` bits.
fn packet_ranges<'a>(
    run: &'a [(u32, u32)],
    size: usize,
    drop_bits: u32,
    shadow: impl Fn(u32) -> bool + 'a,
) -> impl Iterator<Item = Range<usize>> + 'a {
    let mut start = 0;
    std::iter::from_fn(move || {
        if start >= run.len() {
            return None;
        }
        let limit = (start + size).min(run.len());
        let (block, kind) = ((run[start].1 as u64) >> drop_bits, shadow(run[start].0));
        let end = (start + 1..limit)
            .find(|&k| (run[k].1 as u64) >> drop_bits != block || shadow(run[k].0) != kind)
            .unwrap_or(limit);
        let r = start..end;
        start = end;
        Some(r)
    })
}

/// A packet's answers into `out`: `one` traces a lone ray, `many` the packet (its results start as
/// `none`), `answer` reads a result; the packet's tests go to its first ray.
fn packet_answers<T: Copy>(
    rays: &[crate::Ray],
    out: &mut [(Answer, TraversalStats)],
    none: T,
    one: impl Fn(&crate::Ray, &mut TraversalStats) -> T,
    many: impl Fn(&[crate::Ray], &mut [T], &mut TraversalStats),
    answer: impl Fn(T) -> Answer,
) {
    let mut st = TraversalStats::default();
    let mut hit = [none; MAX_PACKET];
    if let [ray] = rays {
        hit[0] = one(ray, &mut st);
    } else {
        many(rays, &mut hit[..rays.len()], &mut st);
    }
    for (o, h) in out.iter_mut().zip(hit) {
        o.0 = answer(h);
    }
    out[0].1 = st;
}

/// The exact watertight tests of `ray` within `[ray.tmin, tmax]` against `candidates`, whose mesh index
/// and corners `tri(t)` gives: the first hit for `any`, else the closest (smallest `t`, then lowest mesh
/// index). Counts the tests into `tests`. The hierarchies' last step, on one mesh or per world entity.
pub(crate) fn exact_hit(
    ray: &crate::Ray,
    mut tmax: f32,
    candidates: &[u32],
    any: bool,
    tests: &mut u64,
    tri: impl Fn(u32) -> (u32, [Vec3; 3]),
) -> Option<Hit> {
    let tr = TriangleRay::new(ray);
    let mut best: Option<Hit> = None;
    for &t in candidates {
        let (p, [a, b, c]) = tri(t);
        *tests += 1;
        let Some(h) = tr.intersect(a, b, c, ray.tmin, tmax) else {
            continue;
        };
        if best.is_none_or(|o| h.t < o.t || (h.t == o.t && p < o.primitive)) {
            tmax = h.t;
            best = Some(Hit {
                t: h.t,
                primitive: p,
                u: h.u,
                v: h.v,
                normal: (b - a).cross(c - a).normalize_or_zero(),
            });
            if any {
                break;
            }
        }
    }
    best
}
