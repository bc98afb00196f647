//! Tracing one frustum through the tree (thesis §6.1.3): frustum–box culling, culling beyond the farthest
//! nearest hit, Plücker tests of the corner rays against each triangle's edges, centre sample rays built
//! only when no single triangle covers the whole frustum, and the reflected frusta from an implicit
//! quadtree merge of the sub-frusta.
//!
//! All rays of a frustum share its apex `o`, so the Plücker product of a ray `o + t·d` with the edge line
//! `(p, q)` reduces to `d · ((p − o) × (q − o))`: linear in `d`. A sample ray's direction is the bilinear
//! blend of the corner directions, so its three edge values are the same blend of the corner rays' values,
//! and so is its inverse hit depth `1/t = d · n / ((a − o) · n)`. A sample ray is thus tested with four
//! bilinear blends and no ray–triangle test; triangles sharing an edge get exactly negated edge values, so
//! no sample slips between them.

use super::frustum::{Frustum, bilerp};
use super::scene::{Facet, NO_SURFACE, SoundScene};
use glam::{Vec3, Vec4};

/// What the frustum's samples hit so far.
enum Coverage {
    /// Nothing yet.
    Empty,
    /// Case 2 of the thesis: every sample hits one triangle; `inv` gives the inverse depth `d · inv` along
    /// direction `d`, `far` bounds the distance of its points from the apex.
    Whole { surface: u32, inv: Vec3, far: f32 },
    /// Per-sample hits, row-major `n × n`.
    Samples(Samples),
}

struct Samples {
    /// Surface hit per sample ([`NO_SURFACE`]: none).
    surface: Vec<u32>,
    /// Inverse hit depth per sample, in units of the sample's direction (0: no hit; larger is nearer).
    inv: Vec<f32>,
    /// Length of each sample's direction, to turn depths into distances.
    len: Vec<f32>,
    /// Distance of each sample's hit from the apex, `len / inv` (infinite: no hit).
    dist: Vec<f32>,
}

/// The surfaces a frustum's `n × n` sub-frusta hit, after tracing.
pub(crate) enum Traced {
    Empty,
    Whole(u32),
    Samples(Vec<u32>),
}

/// The most sub-frusta per side ([`SoundConfig::sampling`](super::SoundConfig) is at most this).
const MAX_SAMPLING: usize = 256;

/// What every triangle test of one frustum shares, made once per frustum.
struct Tracer<'f> {
    f: &'f Frustum,
    n: usize,
    /// The sample centres' parameter along a side: `centre[i] = (i + ½) / n`.
    centre: [f32; MAX_SAMPLING],
    /// Inward normals of the frustum's side planes.
    sides: [Vec3; 4],
    /// The reflector's inverse depth, as a triangle's `inv` (none for a primary frustum).
    near_inv: Option<Vec3>,
}

/// Traces `f` with `n × n` sub-frusta; returns the surface each sub-frustum's centre ray hits first.
pub(crate) fn trace(scene: &SoundScene, f: &Frustum, n: usize) -> Traced {
    // The reflector a reflected frustum starts on: hits must lie beyond it, and it cannot be hit again.
    let reflector = f.chain.last().copied().unwrap_or(NO_SURFACE);
    let cull = f.cull(n);
    let mut centre = [0.0; MAX_SAMPLING];
    for (i, c) in centre.iter_mut().take(n).enumerate() {
        *c = (i as f32 + 0.5) / n as f32;
    }
    let tracer = Tracer {
        f,
        n,
        centre,
        sides: cull.sides,
        near_inv: f.near.map(|pl| pl.n / (pl.c - pl.n.dot(f.apex))),
    };
    let mut cov = Coverage::Empty;
    scene.frustum_leaves(
        &cull,
        &mut cov,
        |cov, facet| {
            if facet.surface != reflector {
                tracer.triangle(cov, facet);
            }
        },
        far_bound,
    );
    match cov {
        Coverage::Empty => Traced::Empty,
        Coverage::Whole { surface, .. } => Traced::Whole(surface),
        Coverage::Samples(s) => Traced::Samples(s.surface),
    }
}

/// Farthest distance any sample can still see: infinite while a sample has no hit.
fn far_bound(cov: &Coverage) -> f32 {
    match cov {
        Coverage::Empty => f32::INFINITY,
        Coverage::Whole { far, .. } => *far,
        Coverage::Samples(s) => s.dist.iter().fold(0.0f32, |m, &d| m.max(d)),
    }
}

/// True when one lane of `x`'s first three is negative.
#[inline]
fn any_edge_negative(x: Vec4) -> bool {
    x.cmplt(Vec4::ZERO).bitmask() & 0b111 != 0
}

impl Tracer<'_> {
    /// Adds one triangle to the coverage (the five cases of the thesis).
    fn triangle(&self, cov: &mut Coverage, facet: &Facet) {
        let (f, n) = (self.f, self.n);
        let o = f.apex;
        let [a, b, c] = facet.corners;
        let rel = [a - o, b - o, c - o];
        // Wholly outside one side plane: no ray of the frustum meets it.
        if self
            .sides
            .iter()
            .any(|s| rel.iter().all(|r| s.dot(*r) < 0.0))
        {
            return;
        }
        let normal = facet.normal;
        let h = rel[0].dot(normal);
        if h == 0.0 {
            return; // apex in the triangle's plane: every ray grazes it
        }
        let sigma = h.signum();
        let edges = [(0, 1), (1, 2), (2, 0)].map(|(p, q)| sigma * rel[p].cross(rel[q]));
        let plucker: [[f32; 4]; 3] = edges.map(|e| f.dirs.map(|d| d.dot(e)));
        // Case 1: all four corner rays outside one edge.
        if plucker.iter().any(|p| p.iter().all(|&x| x < 0.0)) {
            return;
        }
        let inv = normal / h;
        let inv_c = f.dirs.map(|d| d.dot(inv));
        // How much nearer the reflector is than the triangle, per corner; the triangle must lie beyond it.
        let beyond_c: Option<[f32; 4]> = self.near_inv.map(|k| {
            let w = f.dirs.map(|d| d.dot(k));
            std::array::from_fn(|i| w[i] - inv_c[i])
        });
        if let Some(q) = beyond_c
            && q.iter().all(|&x| x <= 0.0)
        {
            return;
        }
        let inside = plucker.iter().all(|p| p.iter().all(|&x| x >= 0.0));
        let beyond = beyond_c.is_none_or(|q| q.iter().all(|&x| x > 0.0));
        if inside && beyond {
            // Case 2: the whole frustum hits the triangle. Keep it whole while it is nearer everywhere.
            match cov {
                Coverage::Empty => {
                    *cov = whole(o, facet, inv);
                    return;
                }
                Coverage::Whole { inv: old, .. } => {
                    let nearer = f.dirs.map(|d| d.dot(inv) - d.dot(*old));
                    if nearer.iter().all(|&x| x > 0.0) {
                        *cov = whole(o, facet, inv);
                        return;
                    }
                    if nearer.iter().all(|&x| x <= 0.0) {
                        return;
                    }
                }
                Coverage::Samples(_) => {}
            }
        }
        // Cases 3–5: per-sample tests, the samples built now if they were not yet. Each corner's three
        // edge values and inverse depth blend as one vector (lane by lane the scalar arithmetic).
        let corner: [Vec4; 4] = std::array::from_fn(|k| {
            Vec4::new(plucker[0][k], plucker[1][k], plucker[2][k], inv_c[k])
        });
        let centre = &self.centre[..n];
        let s = self.samples(cov);
        for (j, &v) in centre.iter().enumerate() {
            // Whole row outside one edge: the edge value is linear in u along a row.
            let first = bilerp(corner, centre[0], v);
            let last = bilerp(corner, centre[n - 1], v);
            if (first.cmplt(Vec4::ZERO) & last.cmplt(Vec4::ZERO)).bitmask() & 0b111 != 0 {
                continue;
            }
            for (i, &u) in centre.iter().enumerate() {
                let e = bilerp(corner, u, v);
                if any_edge_negative(e) || e.x + e.y + e.z <= 0.0 {
                    continue;
                }
                let w = e.w;
                let k = j * n + i;
                if w > s.inv[k] && beyond_c.is_none_or(|q| bilerp(q, u, v) > 0.0) {
                    s.inv[k] = w;
                    s.dist[k] = s.len[k] / w;
                    s.surface[k] = facet.surface;
                }
            }
        }
    }

    /// The per-sample arrays, filled from the whole-frustum hit if there was one.
    fn samples<'c>(&self, cov: &'c mut Coverage) -> &'c mut Samples {
        let (f, n) = (self.f, self.n);
        let centre = &self.centre[..n];
        if !matches!(cov, Coverage::Samples(_)) {
            let mut s = Samples {
                surface: vec![NO_SURFACE; n * n],
                inv: vec![0.0; n * n],
                len: Vec::with_capacity(n * n),
                dist: vec![f32::INFINITY; n * n],
            };
            for &v in centre {
                for &u in centre {
                    s.len.push(f.dir_at(u, v).length());
                }
            }
            if let Coverage::Whole { surface, inv, .. } = cov {
                let inv_c = f.dirs.map(|d| d.dot(*inv));
                for (j, &v) in centre.iter().enumerate() {
                    for (i, &u) in centre.iter().enumerate() {
                        let k = j * n + i;
                        let w = bilerp(inv_c, u, v);
                        s.inv[k] = w;
                        if w > 0.0 {
                            s.dist[k] = s.len[k] / w;
                        }
                        s.surface[k] = *surface;
                    }
                }
            }
            *cov = Coverage::Samples(s);
        }
        match cov {
            Coverage::Samples(s) => s,
            _ => unreachable!("just made"),
        }
    }
}

fn whole(o: Vec3, facet: &Facet, inv: Vec3) -> Coverage {
    let far = facet
        .corners
        .iter()
        .map(|p| p.distance(o))
        .fold(0.0, f32::max);
    Coverage::Whole {
        surface: facet.surface,
        inv,
        far,
    }
}

/// Maximal square blocks of sub-frusta hitting one surface (an implicit quadtree over the `n × n` grid,
/// `n` a power of two), as `(i, j, size, surface)`.
pub(crate) fn merge(hits: &[u32], n: usize, out: &mut Vec<(usize, usize, usize, u32)>) {
    fn block(
        hits: &[u32],
        n: usize,
        i: usize,
        j: usize,
        size: usize,
        out: &mut Vec<(usize, usize, usize, u32)>,
    ) {
        let first = hits[j * n + i];
        let uniform = (j..j + size).all(|y| {
            hits[y * n + i..y * n + i + size]
                .iter()
                .all(|&s| s == first)
        });
        if uniform {
            if first != NO_SURFACE {
                out.push((i, j, size, first));
            }
            return;
        }
        let h = size / 2;
        for (di, dj) in [(0, 0), (h, 0), (0, h), (h, h)] {
            block(hits, n, i + di, j + dj, h, out);
        }
    }
    block(hits, n, 0, 0, n, out);
}
