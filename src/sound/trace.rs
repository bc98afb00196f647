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
use super::scene::{NO_SURFACE, SoundScene};
use glam::Vec3;

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
}

/// The surfaces a frustum's `n × n` sub-frusta hit, after tracing.
pub(crate) enum Traced {
    Empty,
    Whole(u32),
    Samples(Vec<u32>),
}

/// Parameter of sample `i` of `n` along one side of the square: the sub-frustum's centre.
#[inline]
fn centre(i: usize, n: usize) -> f32 {
    (i as f32 + 0.5) / n as f32
}

/// Traces `f` with `n × n` sub-frusta; returns the surface each sub-frustum's centre ray hits first.
pub(crate) fn trace(scene: &SoundScene, f: &Frustum, n: usize) -> Traced {
    // The reflector a reflected frustum starts on: hits must lie beyond it, and it cannot be hit again.
    let near_inv = f.near.map(|pl| pl.n / (pl.c - pl.n.dot(f.apex)));
    let reflector = f.chain.last().copied().unwrap_or(NO_SURFACE);
    let mut cov = Coverage::Empty;
    scene.frustum_leaves(
        &f.cull(),
        &mut cov,
        |cov, tri, surface| {
            if surface != reflector {
                triangle(f, n, cov, tri, surface, near_inv);
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
        Coverage::Samples(s) => s.inv.iter().zip(&s.len).fold(0.0f32, |m, (&w, &l)| {
            if w > 0.0 { m.max(l / w) } else { f32::INFINITY }
        }),
    }
}

/// Adds one triangle to the coverage (the five cases of the thesis).
fn triangle(
    f: &Frustum,
    n: usize,
    cov: &mut Coverage,
    [a, b, c]: [Vec3; 3],
    surface: u32,
    near_inv: Option<Vec3>,
) {
    let o = f.apex;
    let normal = (b - a).cross(c - a);
    let h = (a - o).dot(normal);
    if h == 0.0 {
        return; // apex in the triangle's plane: every ray grazes it
    }
    let sigma = h.signum();
    let edges = [(a, b), (b, c), (c, a)].map(|(p, q)| sigma * (p - o).cross(q - o));
    let plucker: [[f32; 4]; 3] = edges.map(|e| f.dirs.map(|d| d.dot(e)));
    // Case 1: all four corner rays outside one edge.
    if plucker.iter().any(|p| p.iter().all(|&x| x < 0.0)) {
        return;
    }
    let inv = normal / h;
    let inv_c = f.dirs.map(|d| d.dot(inv));
    // How much nearer the reflector is than the triangle, per corner; the triangle must lie beyond it.
    let beyond_c: Option<[f32; 4]> = near_inv.map(|k| {
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
                *cov = whole(o, [a, b, c], surface, inv);
                return;
            }
            Coverage::Whole { inv: old, .. } => {
                let nearer = f.dirs.map(|d| d.dot(inv) - d.dot(*old));
                if nearer.iter().all(|&x| x > 0.0) {
                    *cov = whole(o, [a, b, c], surface, inv);
                    return;
                }
                if nearer.iter().all(|&x| x <= 0.0) {
                    return;
                }
            }
            Coverage::Samples(_) => {}
        }
    }
    // Cases 3–5: per-sample tests, the samples built now if they were not yet.
    let s = samples(f, n, cov);
    for j in 0..n {
        let v = centre(j, n);
        // Whole row outside one edge: the edge value is linear in u along a row.
        let row = |p: &[f32; 4], u: f32| bilerp(*p, u, v);
        if plucker
            .iter()
            .any(|p| row(p, centre(0, n)) < 0.0 && row(p, centre(n - 1, n)) < 0.0)
        {
            continue;
        }
        for i in 0..n {
            let u = centre(i, n);
            let e = plucker.map(|p| bilerp(p, u, v));
            if e.iter().any(|&x| x < 0.0) || e[0] + e[1] + e[2] <= 0.0 {
                continue;
            }
            let w = bilerp(inv_c, u, v);
            let k = j * n + i;
            if w > s.inv[k] && beyond_c.is_none_or(|q| bilerp(q, u, v) > 0.0) {
                s.inv[k] = w;
                s.surface[k] = surface;
            }
        }
    }
}

fn whole(o: Vec3, tri: [Vec3; 3], surface: u32, inv: Vec3) -> Coverage {
    let far = tri.iter().map(|p| p.distance(o)).fold(0.0, f32::max);
    Coverage::Whole { surface, inv, far }
}

/// The per-sample arrays, filled from the whole-frustum hit if there was one.
fn samples<'c>(f: &Frustum, n: usize, cov: &'c mut Coverage) -> &'c mut Samples {
    if !matches!(cov, Coverage::Samples(_)) {
        let mut s = Samples {
            surface: vec![NO_SURFACE; n * n],
            inv: vec![0.0; n * n],
            len: Vec::with_capacity(n * n),
        };
        for j in 0..n {
            for i in 0..n {
                s.len.push(f.dir_at(centre(i, n), centre(j, n)).length());
            }
        }
        if let Coverage::Whole { surface, inv, .. } = cov {
            let inv_c = f.dirs.map(|d| d.dot(*inv));
            for j in 0..n {
                for i in 0..n {
                    s.inv[j * n + i] = bilerp(inv_c, centre(i, n), centre(j, n));
                    s.surface[j * n + i] = *surface;
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
