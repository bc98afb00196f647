//! Collision queries in the ECS: entities opt in with a [`Collider`]; each frame, in
//! [`TraceSystems::Queries`](super::TraceSystems::Queries), the pairs of colliders whose world boxes overlap in the
//! top-level tree are tested on this frame's refitted trees, the results published in [`Contacts`], and
//! [`CollisionStarted`] / [`CollisionEnded`] sent when a pair starts or stops touching.
//!
//! A world without colliders pays nothing: the system does not run.

use super::world::topology_id;
use super::{TraceMesh, TraceWorld, VertexPositions};
use crate::collide::bvtt::{Bvtt, Pair, Visit};
use crate::collide::{Contact, Impact, PairFront, PairQuery, PairStats, Placed, SweptMesh};
use crate::geometry::Aabb;
use bevy_ecs::prelude::*;
use glam::Vec3;
use std::collections::HashMap;
use std::ops::Range;
use std::time::{Duration, Instant};

/// Which collision layers an entity is on and which it collides with. Two colliders are tested when each
/// is on a layer the other collides with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CollisionLayers {
    /// Layers the entity is on (bit mask).
    pub memberships: u32,
    /// Layers it collides with.
    pub filters: u32,
}

impl CollisionLayers {
    /// On every layer, colliding with every layer.
    pub const ALL: CollisionLayers = CollisionLayers {
        memberships: u32::MAX,
        filters: u32::MAX,
    };

    /// On `memberships`, colliding with `filters`.
    pub const fn new(memberships: u32, filters: u32) -> Self {
        CollisionLayers {
            memberships,
            filters,
        }
    }

    /// True when the two may collide.
    pub fn interacts(&self, other: &CollisionLayers) -> bool {
        self.memberships & other.filters != 0 && other.memberships & self.filters != 0
    }
}

impl Default for CollisionLayers {
    fn default() -> Self {
        Self::ALL
    }
}

/// Opts a traceable entity (one with a [`TraceMesh`]) into collision queries.
///
/// ```
/// use kinetrace::ecs::{Collider, CollisionLayers};
/// // A cloth that also collides with itself, on layer 1, colliding with layers 0 and 1.
/// let cloth = Collider { self_collision: true, layers: CollisionLayers::new(0b10, 0b11), ..Default::default() };
/// # let _ = cloth;
/// ```
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Collider {
    /// Layer filter.
    pub layers: CollisionLayers,
    /// Also test the mesh against itself (non-adjacent triangles): cloth, flailing limbs.
    pub self_collision: bool,
    /// Test the motion over the frame (from last frame's world positions) instead of this frame's
    /// positions, for what moves fast enough to pass through another mesh between frames. Used for a pair
    /// when both colliders ask for it, and for self-collision. Costs a swept tree per entity and 15 cubic
    /// solves per candidate triangle pair. An entity's first frame has no motion yet: only features
    /// touching at that instant are reported. Its whole-frame box is tested against every other
    /// collider (the top-level tree holds this frame's boxes only).
    pub continuous: bool,
}

/// Settings of the collision pass, a resource that may be changed at run time.
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CollisionSettings {
    /// Keep each entity pair's BVTT front between frames and restart from it
    /// ([`PairFront`](crate::collide::PairFront)). Off by default: on our measurements (docs/BENCHMARKS.md,
    /// `bench collide`) it saved up to a third of the box tests on coherent motion but cost more time than
    /// it saved on the CPU.
    pub fronts: bool,
}

/// Two colliders that touch this frame (`a < b`; `a == b` for self-collision) and where their results are.
#[derive(Clone, Debug, PartialEq)]
pub struct ContactPair {
    /// The first entity (its triangles are `triangle_a`).
    pub a: Entity,
    /// The second entity.
    pub b: Entity,
    contacts: Range<usize>,
    impacts: Range<usize>,
}

/// This frame's collisions, published in [`TraceSystems::Queries`](super::TraceSystems::Queries).
///
/// Discrete pairs have [`Contact`]s (points and normals in world space); continuous pairs have
/// [`Impact`]s (first times of contact within the frame, points in world space).
#[derive(Resource, Default, Debug)]
pub struct Contacts {
    pairs: Vec<ContactPair>,
    contacts: Vec<Contact>,
    impacts: Vec<Impact>,
    /// Work done this frame.
    pub stats: PairStats,
    /// Entity pairs whose world boxes overlapped (what the top level let through).
    pub candidate_pairs: usize,
    /// Time the collision pass took.
    pub time: Duration,
    /// The frame ([`TraceStats::frame`](super::TraceStats)) these contacts are of: this one, or under
    /// [`Latency::NextFrame`](super::Latency) in the GPU-resident frame an earlier one.
    pub frame: u64,
}

impl Contacts {
    /// The touching pairs, sorted by entities.
    pub fn pairs(&self) -> &[ContactPair] {
        &self.pairs
    }

    /// True when nothing touches.
    pub fn is_empty(&self) -> bool {
        self.pairs.is_empty()
    }

    /// The triangle contacts of a pair.
    pub fn contacts(&self, pair: &ContactPair) -> &[Contact] {
        &self.contacts[pair.contacts.clone()]
    }

    /// The impacts of a continuous pair.
    pub fn impacts(&self, pair: &ContactPair) -> &[Impact] {
        &self.impacts[pair.impacts.clone()]
    }

    /// Empties the results for a new frame's.
    pub(crate) fn clear(&mut self, frame: u64) {
        self.pairs.clear();
        self.contacts.clear();
        self.impacts.clear();
        self.stats = PairStats::default();
        self.frame = frame;
    }

    /// Adds the results of one entity pair (`a <= b`, pushed in order) if it touches.
    pub(crate) fn push(
        &mut self,
        (a, b): (Entity, Entity),
        contacts: &[Contact],
        impacts: &[Impact],
    ) {
        if contacts.is_empty() && impacts.is_empty() {
            return;
        }
        let (first, count) = (self.contacts.len(), self.impacts.len());
        self.contacts.extend_from_slice(contacts);
        self.impacts.extend_from_slice(impacts);
        self.pairs.push(ContactPair {
            a,
            b,
            contacts: first..self.contacts.len(),
            impacts: count..self.impacts.len(),
        });
    }

    /// The pair of two entities, in either order, when they touch.
    pub fn between(&self, a: Entity, b: Entity) -> Option<&ContactPair> {
        let key = (a.min(b), a.max(b));
        self.pairs
            .binary_search_by_key(&key, |p| (p.a, p.b))
            .ok()
            .map(|i| &self.pairs[i])
    }
}

/// Sent when two colliders start touching (`a == b`: a mesh started touching itself).
#[derive(Message, Clone, Copy, Debug, PartialEq, Eq)]
pub struct CollisionStarted {
    /// The smaller entity.
    pub a: Entity,
    /// The other.
    pub b: Entity,
}

/// Sent when two colliders stop touching, or one of them stops being a collider.
#[derive(Message, Clone, Copy, Debug, PartialEq, Eq)]
pub struct CollisionEnded {
    /// The smaller entity.
    pub a: Entity,
    /// The other.
    pub b: Entity,
}

/// What the collision pass keeps between frames.
#[derive(Resource, Default)]
pub(crate) struct CollisionState {
    /// One job per candidate pair, kept with its scratch from frame to frame.
    jobs: Vec<Job>,
    /// Fronts per entity pair, with the frame they were last used (unused ones are dropped).
    fronts: HashMap<(Entity, Entity), (PairFront, u64)>,
    /// Swept trees and last world positions of continuous colliders.
    swept: HashMap<Entity, Swept>,
    /// Colliders in the world this frame: entity, settings, TLAS primitive id.
    colliders: Vec<(Entity, Collider)>,
    /// Candidate pairs from the top level.
    candidates: Vec<(Entity, Entity)>,
    stack: Vec<Pair>,
    /// Last frame's touching pairs.
    touching: Vec<(Entity, Entity)>,
    frame: u64,
}

/// The query of one candidate pair of entities (`a == b`: a mesh against itself) and what it found.
struct Job {
    pair: (Entity, Entity),
    /// Both colliders are continuous.
    continuous: bool,
    /// Single-threaded: jobs run in parallel with each other.
    query: PairQuery,
    front: PairFront,
    contacts: Vec<Contact>,
    impacts: Vec<Impact>,
    stats: PairStats,
}

impl Default for Job {
    fn default() -> Self {
        Job {
            pair: (Entity::PLACEHOLDER, Entity::PLACEHOLDER),
            continuous: false,
            query: PairQuery::new().parallel(false),
            front: PairFront::new(),
            contacts: Vec::new(),
            impacts: Vec::new(),
            stats: PairStats::default(),
        }
    }
}

impl Job {
    /// Runs the pair's query: continuous when both are and both have swept trees, else discrete (from
    /// the job's front when `fronts`).
    fn run(&mut self, world: &TraceWorld, swept: &HashMap<Entity, Swept>, fronts: bool) {
        self.contacts.clear();
        self.impacts.clear();
        let (a, b) = self.pair;
        let tree = |e| swept.get(&e).and_then(|s| s.mesh.as_ref()).map(|(m, _)| m);
        if self.continuous
            && let (Some(sa), Some(sb)) = (tree(a), tree(b))
        {
            self.stats = if a == b {
                self.query.swept_itself(sa, &mut self.impacts)
            } else {
                self.query.swept(sa, sb, &mut self.impacts)
            };
            return;
        }
        let (ia, ib) = (&world.instances[&a], &world.instances[&b]);
        let (pa, pb) = (
            Placed::new(&ia.bvh, ia.transform),
            Placed::new(&ib.bvh, ib.transform),
        );
        let (q, out, front) = (&mut self.query, &mut self.contacts, &mut self.front);
        let result = match (fronts, a == b) {
            (false, true) => q.itself(pa, out),
            (false, false) => q.meshes(pa, pb, out),
            (true, true) => q.itself_with_front(pa, front, out),
            (true, false) => q.meshes_with_front(pa, pb, front, out),
        };
        self.stats = result.unwrap_or_else(|err| {
            // Transforms in the world are checked finite and invertible when they are set.
            log::warn!("kinetrace: collision {a} / {b}: {err}");
            PairStats::default()
        });
    }
}

/// A continuous collider's motion.
struct Swept {
    /// The swept tree, and the topology it was built for.
    mesh: Option<(SweptMesh, u64)>,
    /// World positions at the end of the last frame, and this frame's.
    prev: Vec<Vec3>,
    curr: Vec<Vec3>,
    /// The frame `curr` was written.
    frame: u64,
}

/// The world box of a continuous collider over the whole frame.
fn swept_bounds(swept: &HashMap<Entity, Swept>, e: Entity) -> Option<Aabb> {
    swept.get(&e)?.mesh.as_ref().map(|(m, _)| m.bvh().bounds())
}

/// Run condition: some entity is a collider, or last frame's contacts must be ended — unless the
/// GPU-resident frame answers collisions ([`gpu_collide`](super::gpu_collide)).
pub(crate) fn collisions_needed(
    colliders: Query<(), With<Collider>>,
    contacts: Res<Contacts>,
    config: Res<super::TraceConfig>,
    gpu: Option<Res<super::GpuQueries>>,
) -> bool {
    let resident = config.resident && gpu.is_some();
    !resident && (!colliders.is_empty() || !contacts.is_empty())
}

/// Collects entity pairs of the top level's leaves whose boxes overlap.
struct TopPairs<'a> {
    world: &'a TraceWorld,
    out: &'a mut Vec<(Entity, Entity)>,
}

impl Visit for TopPairs<'_> {
    fn leaves(
        &mut self,
        a: &crate::bvh::Node,
        b: &crate::bvh::Node,
        same: bool,
        _: &mut PairStats,
    ) {
        let prims = self.world.tlas().prim_indices();
        for sa in a.slots() {
            for sb in b.slots() {
                if same && sb <= sa {
                    continue;
                }
                let (ea, eb) = (
                    self.world.tlas_entity(prims[sa]),
                    self.world.tlas_entity(prims[sb]),
                );
                self.out.push((ea.min(eb), ea.max(eb)));
            }
        }
    }
}

/// [`TraceSystems::Queries`](super::TraceSystems::Queries): the collision pass (see the module docs).
#[allow(clippy::too_many_arguments)] // a system: each parameter is one thing it reads
pub(crate) fn collide_system(
    colliders: Query<(Entity, &Collider, &TraceMesh, Option<&VertexPositions>)>,
    world: Res<TraceWorld>,
    settings: Res<CollisionSettings>,
    mut state: ResMut<CollisionState>,
    mut contacts: ResMut<Contacts>,
    mut started: MessageWriter<CollisionStarted>,
    mut ended: MessageWriter<CollisionEnded>,
    stats: Res<super::TraceStats>,
) {
    let t = Instant::now();
    let state = &mut *state;
    state.frame += 1;
    let frame = state.frame;
    let c = &mut *contacts;
    c.clear(stats.frame);

    state.colliders.clear();
    state.colliders.extend(
        colliders
            .iter()
            .filter(|(e, ..)| world.contains(*e))
            .map(|(e, col, ..)| (e, *col)),
    );
    state.colliders.sort_unstable_by_key(|(e, _)| *e);

    // Continuous colliders: this frame's world positions, last frame's kept.
    for (e, col, mesh, positions) in &colliders {
        let Some(inst) = world.instances.get(&e).filter(|_| col.continuous) else {
            continue;
        };
        let object = positions.map_or(mesh.0.positions(), |p| &p.0[..]);
        let to_world = inst.transform;
        let s = state.swept.entry(e).or_insert_with(|| Swept {
            mesh: None,
            prev: Vec::new(),
            curr: Vec::new(),
            frame: 0,
        });
        std::mem::swap(&mut s.prev, &mut s.curr);
        s.curr.clear();
        s.curr
            .extend(object.iter().map(|p| to_world.transform_point3(*p)));
        if s.frame + 1 != frame || s.prev.len() != s.curr.len() {
            // No motion known yet: this frame is swept from where the mesh is now.
            s.prev.clone_from(&s.curr);
        }
        s.frame = frame;
        let topology = topology_id(&mesh.0);
        let refitted = match &mut s.mesh {
            Some((m, t)) if *t == topology => m.update(&s.prev, &s.curr).is_ok(),
            _ => false,
        };
        if !refitted {
            s.mesh = match SweptMesh::build(&mesh.0, &s.prev, &s.curr, &Default::default()) {
                Ok(m) => Some((m, topology)),
                Err(err) => {
                    log::warn!("kinetrace: {e}: no continuous collision this frame: {err}");
                    None
                }
            };
        }
    }
    state.swept.retain(|_, s| s.frame == frame);

    // Top level: entity pairs whose world boxes overlap.
    state.candidates.clear();
    if state.colliders.len() > 1 && !world.tlas().is_empty() {
        let bvtt = Bvtt::itself(world.tlas().nodes());
        let mut visit = TopPairs {
            world: &world,
            out: &mut state.candidates,
        };
        bvtt.walk(
            Pair::ROOTS,
            &mut state.stack,
            &mut visit,
            &mut PairStats::default(),
        );
    }
    // Continuous colliders sweep: their boxes over the whole frame against every other collider's.
    for (e, _) in state.colliders.iter().filter(|(_, c)| c.continuous) {
        let Some(mine) = swept_bounds(&state.swept, *e) else {
            continue;
        };
        for (o, _) in &state.colliders {
            let theirs = swept_bounds(&state.swept, *o).unwrap_or(world.instances[o].world_bounds);
            if o != e && mine.overlaps(&theirs) {
                state.candidates.push((*e.min(o), *e.max(o)));
            }
        }
    }
    state.candidates.sort_unstable();
    state.candidates.dedup();
    let lookup = |cols: &[(Entity, Collider)], e: Entity| {
        cols.binary_search_by_key(&e, |(x, _)| *x)
            .ok()
            .map(|i| cols[i].1)
    };
    let cols = std::mem::take(&mut state.colliders);
    state.candidates.retain(|&(a, b)| {
        matches!((lookup(&cols, a), lookup(&cols, b)), (Some(x), Some(y)) if x.layers.interacts(&y.layers))
    });
    c.candidate_pairs = state.candidates.len();
    for (e, _) in cols.iter().filter(|(_, col)| col.self_collision) {
        state.candidates.push((*e, *e));
    }
    state.candidates.sort_unstable();

    // One job per candidate pair, run in parallel: many pairs of modest size spread over threads better
    // than one pair's sub-walks do.
    let candidates = std::mem::take(&mut state.candidates);
    let n = candidates.len();
    if state.jobs.len() < n {
        state.jobs.resize_with(n, Job::default);
    }
    let mut jobs = std::mem::take(&mut state.jobs);
    for (job, &(a, b)) in jobs.iter_mut().zip(&candidates) {
        job.pair = (a, b);
        job.continuous = lookup(&cols, a).is_some_and(|x| x.continuous)
            && lookup(&cols, b).is_some_and(|x| x.continuous);
        if settings.fronts {
            job.front = state
                .fronts
                .remove(&(a, b))
                .map(|(f, _)| f)
                .unwrap_or_default();
        }
    }
    let (swept, fronts) = (&state.swept, settings.fronts);
    crate::parallel::for_each_mut(true, &mut jobs[..n], |_, job| {
        job.run(&world, swept, fronts)
    });
    for job in &mut jobs[..n] {
        let (a, b) = job.pair;
        if fronts {
            state
                .fronts
                .insert((a, b), (std::mem::take(&mut job.front), frame));
        }
        c.stats.add(&job.stats);
        c.push((a, b), &job.contacts, &job.impacts);
    }
    state.jobs = jobs;
    state.candidates = candidates;
    state.colliders = cols;
    state.fronts.retain(|_, (_, used)| *used == frame);

    state.send_changes(c, &mut started, &mut ended);
    c.time = t.elapsed();
}

impl CollisionState {
    /// Sends [`CollisionStarted`] and [`CollisionEnded`] for the pairs of `c` that began or ended touching
    /// since the last contacts sent through here, and remembers `c`'s.
    pub(crate) fn send_changes(
        &mut self,
        c: &Contacts,
        started: &mut MessageWriter<CollisionStarted>,
        ended: &mut MessageWriter<CollisionEnded>,
    ) {
        // Both lists are sorted.
        let (now, before) = (&c.pairs, &self.touching);
        let (mut i, mut j) = (0, 0);
        loop {
            let x = now.get(i).map(|p| (p.a, p.b));
            match (x, before.get(j).copied()) {
                (None, None) => break,
                (Some(x), Some(y)) if x == y => (i, j) = (i + 1, j + 1),
                (Some(x), y) if y.is_none_or(|y| x < y) => {
                    started.write(CollisionStarted { a: x.0, b: x.1 });
                    i += 1;
                }
                (_, y) => {
                    let (a, b) = y.expect("x is none or greater");
                    ended.write(CollisionEnded { a, b });
                    j += 1;
                }
            }
        }
        self.touching.clear();
        self.touching.extend(c.pairs.iter().map(|p| (p.a, p.b)));
    }
}
