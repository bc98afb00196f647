//! Divide-and-conquer ray tracing (DACRT, seed 004 §5) on the task pool (shaders/taskpool_dacrt.wgsl):
//! closest hits of a batch of rays against a mesh without building any tree. Tasks pair a list of rays
//! with a list of triangles and a box; a task splits its box at the middle of its longest axis and sorts
//! both lists into the halves (2 rounds), each half's box then shrinking to its triangles' bounds, until the seed's cost rule (`tris · rays < 80 · (tris + rays)`)
//! says testing every pair is cheaper; the pair tests keep each ray's nearest distance with an atomic
//! minimum, and a final parked round names the lowest triangle at that distance, the same answer as
//! [`GpuRays`](crate::gpu::GpuRays) with [`Query::Closest`](crate::gpu::Query::Closest).
//!
//! When to use it: the seed found DACRT far slower than building a BVH and tracing it, even counting the
//! build; it pays only for a single batch against geometry that will not be traced again. Cost: about
//! 2·depth + 2 rounds of the pool (each a fixed sequence of dispatches, one submission per 8 rounds and a
//! blocking read of 64 bytes), every pair in the leaves tested twice, and index slots for every ray and
//! triangle copied into each half they reach: [`DacrtOptions::slot_factor`] bounds those copies.
//! Children get fresh index ranges instead of being swapped in place (the seed's scheme), so no two tasks
//! share data and none waits on another: simpler, at the price of that memory.

use super::{PoolCounts, TaskKind, TaskPool};
use crate::gpu::GpuContext;
use crate::gpu::buffers::{GpuBuffer, Readback};
use crate::gpu::trace::GpuRay;
use crate::{Aabb, Error, Mesh, Ray, Result};

/// Words per DACRT task record (see the shader).
const WORDS: u32 = 32;

/// Bounds of one DACRT run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DacrtOptions {
    /// The most tasks the run may create.
    pub task_capacity: u32,
    /// Index slots per ray and per triangle: the ray and triangle lists of all tasks together may hold
    /// this many times the batch's rays and the mesh's triangles.
    pub slot_factor: u32,
}

impl Default for DacrtOptions {
    /// 2^18 tasks (32 MiB of records) and 64 slots per ray and triangle (4 bytes each).
    fn default() -> Self {
        Self {
            task_capacity: 1 << 18,
            slot_factor: 64,
        }
    }
}

/// One ray's closest hit from [`dacrt`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DacrtHit {
    /// Distance of the closest hit; the ray's `tmax` for a miss.
    pub t: f32,
    /// The triangle hit (the lowest index among those at distance `t`), `None` for a miss.
    pub prim: Option<u32>,
}

/// Closest hits of `rays` against `mesh` by DACRT on the GPU task pool. Blocking.
///
/// Errors: [`Error::TaskPoolFull`] when the run needs more tasks or index slots than `options` allow
/// (`capacity` and `asked` then count tasks, or slots), [`Error::InvalidOption`] for a zero capacity or
/// factor, or a GPU error.
pub fn dacrt(
    ctx: &GpuContext,
    mesh: &Mesh,
    rays: &[Ray],
    options: &DacrtOptions,
) -> Result<(Vec<DacrtHit>, PoolCounts)> {
    if options.slot_factor == 0 {
        return Err(Error::InvalidOption("DACRT slot factor 0".into()));
    }
    let (nt, nr) = (mesh.triangle_count() as u32, rays.len() as u32);
    let misses = rays
        .iter()
        .map(|r| DacrtHit {
            t: r.tmax,
            prim: None,
        })
        .collect();
    if nt == 0 || nr == 0 {
        return Ok((misses, PoolCounts::default()));
    }
    let verts: Vec<[f32; 4]> = (0..nt as usize)
        .flat_map(|i| mesh.triangle(i).map(|v| v.extend(0.0).to_array()))
        .collect();
    let gpu_rays: Vec<GpuRay> = rays.iter().map(GpuRay::new).collect();
    let hits: Vec<u32> = gpu_rays
        .iter()
        .flat_map(|r| [r.tmax().to_bits(), u32::MAX])
        .collect();
    let slots = |n: u32| n.saturating_mul(options.slot_factor).max(n);
    let (tri_slots, ray_slots) = (slots(nt), slots(nr));
    let vb = GpuBuffer::storage(ctx, "dacrt triangles", verts.len() as u64 * 16);
    vb.write(ctx, &verts);
    let rb = GpuBuffer::storage(ctx, "dacrt rays", gpu_rays.len() as u64 * 80);
    rb.write(ctx, &gpu_rays);
    let hb = GpuBuffer::storage(ctx, "dacrt hits", hits.len() as u64 * 4);
    hb.write(ctx, &hits);
    let ti = GpuBuffer::storage(ctx, "dacrt triangle lists", tri_slots as u64 * 4);
    ti.write(ctx, &(0..nt).collect::<Vec<u32>>());
    let ri = GpuBuffer::storage(ctx, "dacrt ray lists", ray_slots as u64 * 4);
    ri.write(ctx, &(0..nr).collect::<Vec<u32>>());
    let kind = TaskKind {
        module: |k| &k.dacrt,
        words: WORDS,
    };
    let pool = TaskPool::new(
        ctx,
        kind,
        &[&vb, &rb, &hb, &ti, &ri],
        options.task_capacity,
        [tri_slots, ray_slots],
    )?;
    let (counts, state) = pool.run(ctx, &root(mesh, nt, nr), &[nt, nr])?;
    for (w, cap) in [(12, tri_slots), (13, ray_slots)] {
        if state[w] > 0 {
            return Err(Error::TaskPoolFull {
                capacity: cap as usize,
                asked: state[w] as usize,
            });
        }
    }
    let mut enc = ctx.encoder();
    let back = Readback::<[u32; 2]>::record(ctx, &mut enc, hb.buffer(), nr as usize);
    ctx.submit(enc);
    let found = back.wait(ctx)?;
    let hits = misses
        .into_iter()
        .zip(found)
        .map(|(miss, [t, prim])| match prim {
            u32::MAX => miss,
            p => DacrtHit {
                t: f32::from_bits(t),
                prim: Some(p),
            },
        })
        .collect();
    Ok((hits, counts))
}

/// The root task: every ray and triangle, the mesh's bounds split at the middle of the longest axis.
fn root(mesh: &Mesh, nt: u32, nr: u32) -> Vec<u32> {
    let b = mesh
        .triangle_bounds()
        .iter()
        .fold(Aabb::EMPTY, |a, t| a.union(t));
    let e = b.max - b.min;
    let axis = if e.x >= e.y && e.x >= e.z {
        0
    } else if e.y >= e.z {
        1
    } else {
        2
    };
    let mid = b.min[axis] * 0.5 + b.max[axis] * 0.5;
    let mut r = vec![0u32; WORDS as usize];
    r[..8].copy_from_slice(&[0, nr, 0, nt.div_ceil(64) + nr.div_ceil(64), 0, nt, 0, 0]);
    for k in 0..3 {
        r[8 + k] = b.min[k].to_bits();
        r[12 + k] = b.max[k].to_bits();
    }
    r[11] = axis as u32;
    r[15] = mid.to_bits();
    r
}
