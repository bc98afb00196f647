//! Closest-hit and any-hit queries of every builder against brute force over all triangles.

mod common;
use common::*;
use glam::Vec3;
use kinetrace::bvh::{BuildOptions, Builder, TraversalStats};
use kinetrace::{Mesh, MeshBvh, Ray};
use rand::Rng;

/// Rays of three kinds: aimed at points on random triangles (mostly hits), random origin and direction
/// (mostly misses), and from inside the cloud (many overlapping candidates).
fn rays(m: &Mesh, seed: u64, n: usize) -> Vec<Ray> {
    let mut r = rng(seed);
    (0..n)
        .map(|i| match i % 3 {
            0 => {
                let [a, b, c] = m.triangle(r.random_range(0..m.triangle_count()));
                let (u, v) = (r.random::<f32>(), r.random::<f32>());
                let (u, v) = if u + v > 1.0 {
                    (1.0 - u, 1.0 - v)
                } else {
                    (u, v)
                };
                let target = a + (b - a) * u + (c - a) * v;
                let o = rand_vec(&mut r, -1.0, 2.0);
                Ray::new(o, target - o)
            }
            1 => Ray::new(rand_vec(&mut r, -1.0, 2.0), rand_dir(&mut r)),
            _ => Ray::with_range(
                rand_vec(&mut r, 0.2, 0.8),
                rand_dir(&mut r),
                0.0,
                r.random_range(0.01..2.0),
            ),
        })
        .collect()
}

/// The oracle of every ray, computed once per scene (brute force over all triangles).
fn oracles(m: &Mesh, rays: &[Ray]) -> Vec<RayOracle> {
    rays.iter().map(|r| RayOracle::of_mesh(m, r)).collect()
}

fn check_against_brute(bvh: &MeshBvh, rays: &[Ray], oracles: &[RayOracle], what: &str) {
    let mut hits = vec![None; rays.len()];
    bvh.closest_hits(rays, &mut hits);
    let mut any = vec![false; rays.len()];
    bvh.any_hits(rays, &mut any);
    let mut n_hits = 0;
    for (i, (ray, oracle)) in rays.iter().zip(oracles).enumerate() {
        let what = format!("{what}: ray {i}");
        oracle.check_closest(hits[i].map(|h| (h.primitive, h.t)), &what);
        assert_eq!(
            bvh.closest_hit(ray),
            hits[i],
            "{what}: single and batch differ"
        );
        oracle.check_any(any[i], &format!("{what} any-hit"));
        assert_eq!(
            bvh.any_hit(ray),
            any[i],
            "{what}: single and batch any-hit differ"
        );
        n_hits += oracle.any() as usize;
    }
    // The ray sets must exercise both outcomes.
    assert!(
        n_hits > rays.len() / 5 && n_hits < rays.len(),
        "{what}: {n_hits} hits of {}",
        rays.len()
    );
}

#[test]
fn every_builder_matches_brute_force_on_random_soups() {
    for (seed, n) in [
        (1u64, 1usize),
        (2, 2),
        (3, 3),
        (4, 57),
        (5, 1000),
        (6, 3000),
    ] {
        let m = soup(seed, n);
        let rays = rays(&m, seed + 100, if n < 100 { 300 } else { 900 });
        let oracles = oracles(&m, &rays);
        for opt in all_build_options() {
            let bvh = MeshBvh::build(&m, &opt).unwrap();
            bvh.bvh().validate(Some(&m.triangle_bounds())).unwrap();
            if n >= 57 {
                check_against_brute(&bvh, &rays, &oracles, &format!("{opt:?} n={n}"));
            } else {
                for (ray, oracle) in rays.iter().zip(&oracles) {
                    let got = bvh.closest_hit(ray).map(|h| (h.primitive, h.t));
                    oracle.check_closest(got, &format!("{opt:?} n={n}"));
                }
            }
        }
    }
}

#[test]
fn every_builder_matches_brute_force_on_a_closed_surface() {
    let m = icosphere(3);
    let rays = rays(&m, 7, 900);
    let oracles = oracles(&m, &rays);
    for opt in all_build_options() {
        let bvh = MeshBvh::build(&m, &opt).unwrap();
        bvh.bvh().validate(Some(&m.triangle_bounds())).unwrap();
        check_against_brute(&bvh, &rays, &oracles, &format!("{opt:?} icosphere"));
    }
}

/// Distance, barycentrics and normal of every hit record against the exact oracle, within the bounds `f32`
/// arithmetic allows (derived in `tests/common/oracle.rs`; a few ulps for a well-conditioned hit).
#[test]
fn hit_records_match_the_exact_oracle_within_f32_bounds() {
    let m = soup(11, 2000);
    let bvh = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
    let mut checked = 0;
    for (i, ray) in rays(&m, 12, 3000).iter().enumerate() {
        let Some(h) = bvh.closest_hit(ray) else {
            continue;
        };
        let tri = m.triangle(h.primitive as usize);
        let v = ray_triangle(ray, tri);
        assert!(v.hit || !v.certain, "ray {i}: {h:?} is certainly a miss");
        checked += v.certain as usize;
        assert!(
            (h.t as f64 - v.t).abs() <= v.t_err,
            "ray {i}: t {} vs {v:?}",
            h.t
        );
        let got = [1.0 - h.u - h.v, h.u, h.v];
        // The record's first weight is 1 − u − v, rounded once more (|1 − u − v| ≤ 1: half an ulp of 1).
        let err = [
            v.bary_err[0] + v.bary_err[1] + v.bary_err[2] + f32::EPSILON as f64,
            v.bary_err[1],
            v.bary_err[2],
        ];
        for (k, ((g, e), b)) in got.iter().zip(err).zip(v.bary).enumerate() {
            assert!(
                (*g as f64 - b).abs() <= e,
                "ray {i}: barycentric {k}: {g} vs {b} (bound {e:e})"
            );
        }
        // The normal, normalize(e1 × e2) in f32: edges (one rounding), products (one), difference (one) put
        // each component within 4ε of its two products' magnitudes, so |Δn| ≤ 8ε|e1||e2|, the unit vector
        // moves by at most 2|Δn|/|n|, and normalising adds under 2ε (ε = f32::EPSILON / 2).
        let [a, b, c] = tri.map(dvec);
        let n = (b - a).cross(c - a);
        let cond = (b - a).length() * (c - a).length() / n.length();
        let bound = f32::EPSILON as f64 * (8.0 * cond + 1.0);
        assert!(
            (n.normalize() - h.normal.as_dvec3()).length() <= bound,
            "ray {i}: normal {} vs {} (bound {bound:e})",
            n.normalize(),
            h.normal
        );
    }
    assert!(checked > 500, "only {checked} certain hits checked");
}

#[test]
fn sah_builders_make_cheaper_trees_than_median_and_lbvh() {
    // Not a speed claim: an analytic property of the cost model the SAH builder minimises greedily.
    let m = soup(31, 20_000);
    let cost = |b| {
        MeshBvh::build(&m, &BuildOptions::new(b))
            .unwrap()
            .bvh()
            .sah_cost()
    };
    let (sah, lbvh, hybrid) = (
        cost(Builder::SAH),
        cost(Builder::LBVH),
        cost(Builder::HYBRID),
    );
    assert!(
        sah < lbvh && hybrid < lbvh,
        "sah {sah} hybrid {hybrid} lbvh {lbvh}"
    );
}

#[test]
fn traversal_stats_count_work() {
    let m = icosphere(3);
    let bvh = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
    let mut s = TraversalStats::default();
    let ray = Ray::new(Vec3::new(0.0, 0.0, -5.0), Vec3::Z);
    let h = bvh.closest_hit_counted(&ray, &mut s).unwrap();
    assert_brute_hit(&m, &ray, Some((h.primitive, h.t)), "counted");
    assert!(s.inner_visits >= 1 && s.prim_tests >= 1 && s.leaf_visits >= 1);
    // Every tested primitive sits in a visited leaf; the work is far below brute force.
    assert!(s.prim_tests < m.triangle_count() as u64 / 4, "{s:?}");
    let mut s2 = TraversalStats::default();
    assert!(bvh.any_hit_counted(&ray, &mut s2));
    assert!(s2.prim_tests <= s.prim_tests + 4);
}
