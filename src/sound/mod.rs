//! Frustum-traced sound propagation (Lauterbach's thesis §6.1): specular paths from a point source to a
//! listener, with per-band absorption, through the same trees the ray queries use — one
//! [`MeshBvh`](crate::MeshBvh) ([`SoundScene::new`]) or a two-level scene of instances with transforms
//! ([`SoundScene::instanced`], what the ECS uses) — so moving and deforming meshes occlude and reflect once
//! their tree is refitted or their transform set.
//!
//! How it works: frusta with four corner rays cover every direction around the source (each cube face split
//! into [`SoundConfig::primary`]² frusta). Each frustum is traced through the tree (`trace.rs`) with
//! frustum–box culling (boxes between two columns or rows of centre sample rays included) and culling
//! beyond the farthest nearest hit; Plücker tests of its corner rays decide
//! per triangle whether it misses, covers the whole frustum, or needs the `n × n` centre sample rays
//! ([`SoundConfig::sampling`]), which are built only then. The sub-frusta hitting one surface are merged
//! along an implicit quadtree and reflected into the next order's frusta, up to
//! [`SoundConfig::max_order`]. Every frustum that contains the listener gives a candidate path, validated
//! with one exact ray per leg (`paths.rs`).
//!
//! When to use it: interactive acoustics of a scene with up to a few hundred thousand triangles. Cost: the
//! number of frusta grows with the reflection order and with the sampling rate. A frustum that straddles
//! surfaces splits into merged blocks of sub-frusta along their borders, about as many as its side has
//! samples, and its children split again. Each doubling of [`SoundConfig::sampling`] multiplied the
//! frusta by 4.6–4.9 in an empty shoebox and by 9.3–10.4 among curved characters, order 3. The thesis
//! found the cost growing about logarithmically with the sampling rate in its scenes; these do not. Each
//! frustum is one tree traversal plus `n²` samples for the triangles it only partly covers. Levels of
//! the frustum tree run on all threads; results do not depend on the thread count.
//!
//! Measured (`bench sound`, release, a 2-core AMD EPYC VM, three runs, best of five updates each):
//! - **A 10 × 8 × 3.5 m room with 16 walking characters** (23,244 triangles), order 3, one ECS update
//!   (surfaces and propagation): 10,399 frusta at the default 4² samples in 17.9–20.8 ms, 108,635 at
//!   8² in 67–102 ms, 1.01M at 16² in 547–654 ms. Two threads against one: 1.2–1.9×.
//! - **The same room empty:** 59 of the 63 image-source paths found at 4² (5,920 frusta, 1.7–2.7 ms),
//!   61 at 8² (28,935 frusta, 8.9–11.9 ms), 62 at 16² (132,653 frusta, 42–61 ms). One thread traces
//!   1.3–2.3M frusta per second there.
//! - **`tests/sound.rs`, three source–listener pairs in a 5 × 3.7 × 2.9 m shoebox:** 14 of 189 image
//!   sources missed at 4² and 6 at 8². Every missed one has a reflection point within the footprint
//!   below of its wall's border.
//!
//! Limits (thesis §6.1.7): discrete sampling misses a path when one of its reflection points lies closer
//! to its surface's border than a sub-frustum's footprint there — at most `r · sin ρ / cos(θ + ρ)` for a
//! reflection at path length `r` and incidence angle `θ`, with `ρ = √2 / (primary · sampling)` radians;
//! grazing reflections (θ near 90°) are missed first. Found paths are exact. Specular reflection only: no
//! diffraction, no diffuse scattering, point sources.
//!
//! ```
//! use kinetrace::prelude::*;
//! use kinetrace::sound::{AcousticMaterial, SoundConfig, SoundScene, propagate};
//! use kinetrace::scenes;
//! use glam::Vec3;
//! // A closed 4 × 3 × 2.5 room, every wall absorbing 20 %.
//! let room = scenes::shoebox(Vec3::ZERO, Vec3::new(4.0, 3.0, 2.5));
//! let bvh = MeshBvh::build(&room, &BuildOptions::default())?;
//! let materials = vec![0; room.triangle_count()];
//! let scene = SoundScene::new(&bvh, &materials, vec![AcousticMaterial::uniform(0.2)?])?;
//! let (source, listener) = (Vec3::new(1.0, 1.0, 1.2), Vec3::new(3.0, 2.0, 1.5));
//! let found = propagate(&scene, source, listener, &SoundConfig::default())?;
//! let direct = found.paths.iter().find(|p| p.order == 0).expect("line of sight");
//! assert_eq!(direct.length, source.distance(listener));
//! assert_eq!(found.paths.iter().filter(|p| p.order == 1).count(), 6); // one per wall
//! # Ok::<(), kinetrace::Error>(())
//! ```

mod frustum;
mod material;
mod paths;
mod scene;
mod trace;

pub use material::{AcousticMaterial, BAND_HZ, BANDS};
pub use paths::SoundPath;
pub use scene::{SoundInstance, SoundScene};

use crate::{Error, Result, parallel};
use frustum::Frustum;
use glam::Vec3;
use trace::{Traced, merge};

/// Settings of [`propagate`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SoundConfig {
    /// Frusta per cube-face side around the source (`6 · primary²` primary frusta), 1 to [`MAX_PRIMARY`].
    /// Default 4.
    pub primary: usize,
    /// Sub-frusta per frustum side, a power of two (the thesis tested 4 to 32). Default 4: a path is
    /// missed only where one of its reflection points lies within a sub-frustum's footprint of its
    /// surface's border (see the module docs), and each doubling multiplies the frusta several times
    /// (measured in the module docs: raise it where paths near edges matter more than the update's time).
    pub sampling: usize,
    /// Highest reflection order traced. Default 3.
    pub max_order: u32,
    /// Speed of sound in scene units per second. Default 343 (metres).
    pub speed_of_sound: f32,
    /// Trace each level of the frustum tree on all threads (with the `parallel` feature). Default true.
    pub parallel: bool,
}

impl Default for SoundConfig {
    fn default() -> Self {
        Self {
            primary: 4,
            sampling: 4,
            max_order: 3,
            speed_of_sound: 343.0,
            parallel: true,
        }
    }
}

/// What [`propagate`] found.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Propagation {
    /// Valid paths, by order, then delay.
    pub paths: Vec<SoundPath>,
    /// Frusta traced, all orders.
    pub frusta: u64,
}

/// The most frusta per cube-face side [`SoundConfig::primary`] may ask for (6 · 256² = 393k primary
/// frusta, far past real-time budgets).
pub const MAX_PRIMARY: usize = 256;

/// Specular paths from `source` to `listener` up to `config.max_order` reflections.
///
/// Errors: [`Error::InvalidOption`] for a non-finite source or listener, `primary == 0`, a `sampling` that
/// is not a power of two up to 256, or a speed of sound that is not finite and positive.
pub fn propagate(
    scene: &SoundScene,
    source: Vec3,
    listener: Vec3,
    config: &SoundConfig,
) -> Result<Propagation> {
    if !source.is_finite() || !listener.is_finite() {
        return Err(Error::InvalidOption(format!(
            "source {source} and listener {listener} must be finite"
        )));
    }
    if !(1..=MAX_PRIMARY).contains(&config.primary)
        || !config.sampling.is_power_of_two()
        || config.sampling > 256
    {
        return Err(Error::InvalidOption(format!(
            "sound needs primary in 1..={MAX_PRIMARY} and sampling a power of two up to 256, got {} and {}",
            config.primary, config.sampling
        )));
    }
    if !(config.speed_of_sound.is_finite() && config.speed_of_sound > 0.0) {
        return Err(Error::InvalidOption(format!(
            "speed of sound {} is not finite and positive",
            config.speed_of_sound
        )));
    }
    let n = config.sampling;
    let mut level = Frustum::around(source, config.primary);
    let mut out = Propagation::default();
    for order in 0..=config.max_order {
        out.frusta += level.len() as u64;
        let reflect = order < config.max_order;
        let (paths, next) = parallel::map_reduce(
            config.parallel,
            &level,
            16,
            (Vec::new(), Vec::new()),
            |chunk| {
                let mut paths = Vec::new();
                let mut next = Vec::new();
                for f in chunk {
                    paths.extend(paths::path_to(
                        scene,
                        f,
                        source,
                        listener,
                        config.speed_of_sound,
                    ));
                    if reflect {
                        children(scene, f, n, &mut next);
                    }
                }
                (paths, vec![next])
            },
            // The next level stays one list per chunk until here, so merging moves lists, not frusta.
            |(mut pa, mut na), (pb, nb)| {
                pa.extend(pb);
                na.extend(nb);
                (pa, na)
            },
        );
        out.paths.extend(paths);
        level = next.into_iter().flatten().collect();
    }
    // One image source is one path, even when two frusta meet exactly at the listener.
    out.paths.sort_by(|a, b| {
        (a.order, &a.surfaces)
            .cmp(&(b.order, &b.surfaces))
            .then(a.delay.total_cmp(&b.delay))
    });
    out.paths.dedup_by(|a, b| a.surfaces == b.surfaces);
    out.paths
        .sort_by(|a, b| a.order.cmp(&b.order).then(a.delay.total_cmp(&b.delay)));
    Ok(out)
}

/// The reflected frusta of `f`: one per maximal block of sub-frusta hitting one surface.
fn children(scene: &SoundScene, f: &Frustum, n: usize, out: &mut Vec<Frustum>) {
    let mut blocks = Vec::new();
    match trace::trace(scene, f, n) {
        Traced::Empty => {}
        Traced::Whole(s) => blocks.push((0, 0, n, s)),
        Traced::Samples(hits) => merge(&hits, n, &mut blocks),
    }
    for (i, j, size, s) in blocks {
        let surface = scene.surfaces[s as usize];
        let plane = frustum::Plane {
            n: surface.normal,
            c: surface.offset,
        };
        let reflectance = scene.materials[surface.material as usize].reflectance();
        let (nf, sf) = (n as f32, size as f32);
        let rect = (
            i as f32 / nf,
            j as f32 / nf,
            (i as f32 + sf) / nf,
            (j as f32 + sf) / nf,
        );
        out.push(f.reflected(rect, plane, s, &reflectance));
    }
}

#[cfg(test)]
mod tests {
    use super::frustum::Frustum;
    use super::scene::NO_SURFACE;
    use super::trace::{Traced, merge, trace};
    use super::*;
    use crate::bvh::BuildOptions;
    use crate::{Mesh, MeshBvh, scenes};
    use rand::{Rng, SeedableRng, rngs::SmallRng};

    /// The surface the ray `apex + t·d` (`t > 0`) of frustum `f` meets first, by an f64 ray–triangle
    /// test of every triangle of `scene` in turn: only hits beyond its near plane and off its reflector
    /// count, as for the tracer. `None` where rounding could decide it: the first hit within 1e-5
    /// (barycentric) of its triangle's edges or 1e-4 of the near plane, or another surface's hit within
    /// 1e-5 of its distance. [`NO_SURFACE`] where nothing is hit.
    fn brute_force(scene: &SoundScene, f: &Frustum, d: Vec3) -> Option<u32> {
        let (o, d) = (f.apex.as_dvec3(), d.as_dvec3());
        let reflector = f.chain.last().copied().unwrap_or(NO_SURFACE);
        // (distance, surface, whether rounding could decide it)
        let mut hits = Vec::new();
        for facet in scene.facets() {
            if facet.surface == NO_SURFACE || facet.surface == reflector {
                continue;
            }
            let [a, b, c] = facet.corners.map(|p| p.as_dvec3());
            let (e1, e2) = (b - a, c - a);
            let p = d.cross(e2);
            let det = e1.dot(p);
            if det == 0.0 {
                continue;
            }
            let s = o - a;
            let q = s.cross(e1);
            let (u, v, t) = (s.dot(p) / det, d.dot(q) / det, e2.dot(q) / det);
            let inside = u.min(v).min(1.0 - u - v);
            if inside < -1e-5 || t <= 0.0 {
                continue;
            }
            let x = o + d * t;
            let side = f
                .near
                .map_or(1.0, |pl| pl.n.as_dvec3().dot(x) - pl.c as f64);
            if side < -1e-4 {
                continue;
            }
            hits.push((t, facet.surface, inside < 1e-5 || side < 1e-4));
        }
        hits.sort_by(|a, b| a.0.total_cmp(&b.0));
        match hits[..] {
            [] => Some(NO_SURFACE),
            [(_, _, true), ..] => None,
            [(t, s, _), (t2, s2, _), ..] if s2 != s && t2 - t <= 1e-5 * t => None,
            [(_, s, _), ..] => Some(s),
        }
    }

    /// A frustum's traced samples (Plücker tests of its corner rays, samples blended from them, culling
    /// beyond the farthest nearest hit, the quadtree's whole-frustum case) hit the surfaces that one f64
    /// ray per sample finds by testing every triangle: primary frusta and the reflected frusta of their
    /// merged sub-frusta, at 4² and 8² samples, in a room cluttered with random triangles of every size
    /// and a bumpy torus (curved, many small triangles). Samples that rounding could decide either way
    /// are skipped, and fewer than 2% are (1.1% here).
    #[test]
    fn traced_samples_hit_the_surfaces_one_ray_per_sample_finds() {
        let mut r = SmallRng::seed_from_u64(3);
        let room = scenes::shoebox(Vec3::ZERO, Vec3::new(6.0, 5.0, 3.0));
        let torus = scenes::bumpy_torus(600);
        let torus_at: Vec<Vec3> = (torus.positions().iter())
            .map(|p| *p * 0.6 + Vec3::new(4.0, 3.0, 1.5))
            .collect();
        let mut pos: Vec<Vec3> = room.positions().to_vec();
        let mut idx: Vec<u32> = room.indices().to_vec();
        let torus = torus.with_positions(torus_at).unwrap();
        let base = pos.len() as u32;
        pos.extend(torus.positions());
        idx.extend(torus.indices().iter().map(|i| i + base));
        for k in 0..300 {
            let size = [0.05, 0.4, 2.0][k % 3];
            let o = Vec3::new(
                r.random_range(0.5..5.5),
                r.random_range(0.5..4.5),
                r.random_range(0.3..2.7),
            );
            let base = pos.len() as u32;
            for _ in 0..3 {
                let d = Vec3::new(r.random(), r.random(), r.random()) - 0.5;
                pos.push(o + d * size);
            }
            idx.extend([base, base + 1, base + 2]);
        }
        let mesh = Mesh::new(pos, idx).unwrap();
        let bvh = MeshBvh::build(&mesh, &BuildOptions::default()).unwrap();
        let materials: Vec<u32> = (0..mesh.triangle_count()).map(|i| (i % 2) as u32).collect();
        let walls = vec![AcousticMaterial::uniform(0.1).unwrap(); 2];
        let scene = SoundScene::new(&bvh, &materials, walls).unwrap();
        let source = Vec3::new(1.1, 1.3, 1.4);
        let (mut checked, mut skipped, mut partial) = (0, 0, 0);
        for n in [4, 8] {
            let primary = Frustum::around(source, 2);
            let mut reflected = Vec::new();
            for f in &primary {
                children(&scene, f, n, &mut reflected);
            }
            assert!(
                reflected.len() > primary.len(),
                "{} reflected",
                reflected.len()
            );
            for f in primary.iter().chain(reflected.iter().step_by(7)) {
                let traced = trace(&scene, f, n);
                partial += matches!(traced, Traced::Samples(_)) as usize;
                for j in 0..n {
                    for i in 0..n {
                        let (u, v) = ((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
                        let Some(want) = brute_force(&scene, f, f.dir_at(u, v)) else {
                            skipped += 1;
                            continue;
                        };
                        let got = match &traced {
                            Traced::Empty => NO_SURFACE,
                            Traced::Whole(s) => *s,
                            Traced::Samples(hits) => hits[j * n + i],
                        };
                        assert_eq!(got, want, "{n}² samples, sample ({i}, {j}) of {f:?}");
                        checked += 1;
                    }
                }
            }
        }
        assert!(partial > 50, "{partial} frusta only partly covered");
        assert!(
            skipped * 50 < checked,
            "{skipped} skipped, {checked} checked"
        );
    }

    /// The quadtree merge of a frustum's samples: the blocks cover every sample that hit a surface once
    /// and no other, each block's samples all hit its surface, and no four sibling blocks could have been
    /// one (each block is as large as the quadtree allows). Random hit grids of few surfaces, with runs
    /// and uniform quarters, at 1² to 16².
    #[test]
    fn merged_blocks_cover_each_hit_sample_once_and_are_maximal() {
        let mut r = SmallRng::seed_from_u64(8);
        for case in 0..400 {
            let n = 1 << (case % 5);
            // Few surfaces, in patches: each sample copies a neighbour's surface most of the time.
            let mut hits = vec![NO_SURFACE; n * n];
            for k in 0..n * n {
                hits[k] = match (k % n > 0, r.random_range(0..4)) {
                    (true, 0..=2) => hits[k - 1],
                    _ if k >= n && r.random_bool(0.5) => hits[k - n],
                    _ => [NO_SURFACE, 0, 1, 2][r.random_range(0..4)],
                };
            }
            let mut blocks = Vec::new();
            merge(&hits, n, &mut blocks);
            let mut covered = vec![0; n * n];
            for &(i, j, size, surface) in &blocks {
                assert!(
                    size.is_power_of_two() && i % size == 0 && j % size == 0,
                    "{blocks:?}"
                );
                for y in j..j + size {
                    for x in i..i + size {
                        assert_eq!(hits[y * n + x], surface, "{n}²: block {:?}", (i, j, size));
                        covered[y * n + x] += 1;
                    }
                }
                // Its parent square held more than one surface (or samples that hit none).
                if size < n {
                    let (pi, pj, ps) = (
                        i / (2 * size) * 2 * size,
                        j / (2 * size) * 2 * size,
                        2 * size,
                    );
                    let uniform =
                        (pj..pj + ps).all(|y| (pi..pi + ps).all(|x| hits[y * n + x] == surface));
                    assert!(
                        !uniform,
                        "{n}²: block {:?} could be its parent",
                        (i, j, size)
                    );
                }
            }
            for (k, &c) in covered.iter().enumerate() {
                assert_eq!(c, (hits[k] != NO_SURFACE) as u32, "{n}²: sample {k}");
            }
        }
    }
}
