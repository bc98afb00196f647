//! Suite `cpu`: builders, refit and queries on one thread and on all threads, and the Rust peers obvhs and
//! the bvh crate on the same triangles and rays.

use crate::peers::{self, BenchRay, PeerResult};
use crate::record::{Records, best_of};
use glam::Vec3;
use kinetrace::bvh::wide::WideBvh;
use kinetrace::bvh::wide::simd::{self, RayLanes};
use kinetrace::bvh::{BuildOptions, Builder, PartialOptions};
use kinetrace::geometry::TriangleRay;
use kinetrace::scenes::{bumpy_torus, soup};
use kinetrace::{Aabb, Hit, Mesh, MeshBvh, Ray};

const SUITE: &str = "cpu";
/// The bvh crate's traversal has no ray interval to shrink: it gets a subset of the rays.
const BVH_CRATE_RAYS: usize = 8192;

pub fn run(rec: &mut Records) {
    println!(
        "suite cpu on {} (kinetrace/peer ratios above 1 mean kinetrace is faster)",
        crate::record::machine()
    );
    let sizes: &[usize] = if rec.quick {
        &[100_000]
    } else {
        &[100_000, 1_000_000]
    };
    for &n in sizes {
        for (kind, mesh) in [("surface", bumpy_torus(n)), ("scattered", soup(7, n))] {
            scene(
                rec,
                &format!("{kind} {}k", mesh.triangle_count() / 1000),
                &mesh,
            );
        }
    }
}

/// Runs `f` on a one-thread rayon pool: the single-thread figures.
pub fn one_thread<T: Send>(f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("a thread pool")
        .install(f)
}

/// The suite's ray sets in the peers' form.
fn ray_sets(mesh: &Mesh, n: usize) -> [(&'static str, Vec<BenchRay>); 2] {
    crate::rays::camera_and_random(mesh, n).map(|(kind, rays)| {
        let rays = rays
            .iter()
            .map(|r| BenchRay {
                origin: r.origin,
                dir: r.dir(),
                tmax: r.tmax,
            })
            .collect();
        (kind, rays)
    })
}

fn to_rays(rays: &[BenchRay]) -> Vec<Ray> {
    rays.iter()
        .map(|r| Ray::with_range(r.origin, r.dir, 0.0, r.tmax))
        .collect()
}

fn scene(rec: &mut Records, name: &str, mesh: &Mesh) {
    let n = mesh.triangle_count() as f64;
    let reps = rec.reps();
    println!("\n{name}: {} triangles", mesh.triangle_count());

    // Builders: one thread and all threads, and the SAH cost of each tree.
    let mut lbvh_1t = 0.0;
    let mut sah_1t = 0.0;
    let mut sah_cost = 0.0;
    for b in Builder::ALL.into_iter().chain([Builder::PLOC]) {
        // The binary tree alone: the wide query tree's collapse is timed on its own below.
        let opt = BuildOptions::new(b).wide(false);
        let (t1, bvh) =
            one_thread(|| best_of(reps, || MeshBvh::build(mesh, &opt.parallel(false)).unwrap()));
        let (tn, _) = best_of(reps, || MeshBvh::build(mesh, &opt).unwrap());
        rec.add(
            SUITE,
            name,
            &format!("kinetrace {}", b.name()),
            "build 1 thread",
            n / t1 / 1e6,
            "Mtris/s",
        );
        rec.add(
            SUITE,
            name,
            &format!("kinetrace {}", b.name()),
            "build all threads",
            n / tn / 1e6,
            "Mtris/s",
        );
        let cost = bvh.bvh().sah_cost();
        rec.add(
            SUITE,
            name,
            &format!("kinetrace {}", b.name()),
            "SAH cost",
            cost,
            "",
        );
        if matches!(b, Builder::Lbvh { .. } | Builder::Sah { .. }) {
            wide_rows(rec, name, b.name(), &bvh);
        }
        match b {
            Builder::Lbvh { .. } => lbvh_1t = t1,
            Builder::Sah { .. } => (sah_1t, sah_cost) = (t1, cost),
            _ => {}
        }
    }

    // Refit, one thread, alternating between two poses so every call really moves the boxes: the binary
    // tree alone, and with the wide tree's lanes copied after it.
    let poses: [Vec<Vec3>; 2] = [
        mesh.positions().to_vec(),
        mesh.positions()
            .iter()
            .map(|p| *p + Vec3::new((p.y * 9.0).sin(), 0.0, (p.x * 7.0).cos()) * 0.01)
            .collect(),
    ];
    for (subject, wide) in [
        ("kinetrace refit", false),
        ("kinetrace refit + wide4", true),
    ] {
        let mut bvh = MeshBvh::build(mesh, &BuildOptions::default().wide(wide)).unwrap();
        let mut k = 0;
        let (t_refit, _) = best_of(reps * 4, || {
            k += 1;
            bvh.refit(&poses[k % 2]).unwrap()
        });
        rec.add(
            SUITE,
            name,
            subject,
            "refit 1 thread",
            n / t_refit / 1e6,
            "Mtris/s",
        );
    }
    partial_rows(rec, name, mesh);
    let wide = MeshBvh::build(mesh, &BuildOptions::default()).unwrap();
    let binary = MeshBvh::build(mesh, &BuildOptions::default().wide(false)).unwrap();
    kernel_rows(rec, name, &wide);
    let mut compact = wide.clone();
    compact.set_compact(true);
    compact_rows(rec, name, &wide, &compact);

    // Peers on the same triangles.
    let ray_count = if rec.quick { 1 << 16 } else { 1 << 18 };
    let sets = ray_sets(mesh, ray_count);
    let mut obvhs: Vec<Vec<PeerResult>> = Vec::new();
    let mut bvh_crate: Vec<Vec<PeerResult>> = Vec::new();
    for (_, rays) in &sets {
        obvhs.push(peers::measure_obvhs(
            mesh.positions(),
            mesh.indices(),
            rays,
            reps,
            false,
        ));
        bvh_crate.push(peers::measure_bvh_crate(
            mesh.positions(),
            mesh.indices(),
            &rays[..BVH_CRATE_RAYS],
            reps,
        ));
    }
    for p in obvhs[0].iter().chain(&bvh_crate[0]) {
        rec.add(
            SUITE,
            name,
            p.name,
            "build 1 thread",
            n / p.build_s / 1e6,
            "Mtris/s",
        );
        if let Some(c) = p.sah_cost {
            rec.add(SUITE, name, p.name, "SAH cost", c, "");
        }
    }
    let fastest = peer(&obvhs[0], "obvhs ploc-fastest bvh2");
    let medium = peer(&obvhs[0], "obvhs ploc-medium bvh2");
    rec.add(
        SUITE,
        name,
        "ratio",
        "lbvh/obvhs-fastest build",
        fastest.build_s / lbvh_1t,
        "x (target >= 2)",
    );
    rec.add(
        SUITE,
        name,
        "ratio",
        "sah/obvhs-medium build",
        medium.build_s / sah_1t,
        "x (target >= 1)",
    );
    if let Some(c) = medium.sah_cost {
        rec.add(
            SUITE,
            name,
            "ratio",
            "sah/obvhs-medium cost",
            sah_cost / c,
            "x (target <= 1)",
        );
    }

    // Queries on the SAH tree, binary and 4-wide: one thread per ray loop, and batched on all threads.
    for (set, (kind, brays)) in sets.iter().enumerate() {
        let rays = to_rays(brays);
        let m = rays.len() as f64;
        for (tree, bvh) in [
            ("sah", &binary),
            ("sah wide4", &wide),
            ("sah compact4", &compact),
        ] {
            let (tc, hits) = one_thread(|| {
                best_of(reps, || {
                    rays.iter().map(|r| bvh.closest_hit(r)).collect::<Vec<_>>()
                })
            });
            let (ta, _) =
                one_thread(|| best_of(reps, || rays.iter().filter(|r| bvh.any_hit(r)).count()));
            let mut any = vec![false; rays.len()];
            let (tai, _) =
                one_thread(|| best_of(reps, || bvh.any_hits_interleaved(&rays, &mut any)));
            let mut out = vec![None; rays.len()];
            let (tci, _) =
                one_thread(|| best_of(reps, || bvh.closest_hits_interleaved(&rays, &mut out)));
            assert!(
                out == hits,
                "interleaved closest hits differ from closest_hit's"
            );
            let (tcn, _) = best_of(reps, || bvh.closest_hits(&rays, &mut out));
            let (tan, _) = best_of(reps, || bvh.any_hits(&rays, &mut any));
            let subject = format!("kinetrace {tree} {kind}");
            for (metric, t) in [
                ("closest 1 thread", tc),
                ("closest interleaved 1 thread", tci),
                ("any-hit 1 thread", ta),
                ("any-hit interleaved 1 thread", tai),
                ("closest all threads", tcn),
                ("any-hit all threads", tan),
            ] {
                rec.add(SUITE, name, &subject, metric, m / t / 1e6, "Mrays/s");
            }
            for p in &obvhs[set] {
                let s = format!("{} {kind}", p.name);
                if let Some(t) = p.closest_s {
                    let r = leak(format!("closest {tree}/{} {kind}", p.name));
                    rec.add(SUITE, name, "ratio", r, t / tc, "x");
                }
                if let Some(t) = p.any_s {
                    let r = leak(format!("any-hit {tree}/{} {kind}", p.name));
                    rec.add(SUITE, name, "ratio", r, t / ta, "x");
                }
                if let Some(h) = &p.closest_hits {
                    let what = leak(format!("hits differing from kinetrace {tree}"));
                    rec.add(SUITE, name, &s, what, differing(&hits, h) as f64, "rays");
                }
            }
        }
        for p in &obvhs[set] {
            let s = format!("{} {kind}", p.name);
            if let Some(t) = p.closest_s {
                rec.add(SUITE, name, &s, "closest 1 thread", m / t / 1e6, "Mrays/s");
            }
            if let Some(t) = p.any_s {
                rec.add(SUITE, name, &s, "any-hit 1 thread", m / t / 1e6, "Mrays/s");
            }
        }
        // The bvh crate traced a prefix of the rays; time ours (binary) on the same prefix.
        let sub = &rays[..BVH_CRATE_RAYS];
        let (tcs, _) = one_thread(|| {
            best_of(reps, || {
                sub.iter()
                    .map(|r| binary.closest_hit(r))
                    .collect::<Vec<_>>()
            })
        });
        for p in &bvh_crate[set] {
            if let Some(t) = p.closest_s {
                let s = format!("{} {kind}", p.name);
                rec.add(
                    SUITE,
                    name,
                    &s,
                    "closest 1 thread",
                    BVH_CRATE_RAYS as f64 / t / 1e6,
                    "Mrays/s",
                );
                rec.add(
                    SUITE,
                    name,
                    "ratio",
                    leak(format!("closest/{} {kind}", p.name)),
                    t / tcs,
                    "x",
                );
            }
        }
    }
}

/// Partial rebuilds, one thread, on a pose where the triangles within a sixteenth of the box's diagonal
/// of one triangle's centroid fly apart (up to a tenth of the diagonal) and the rest stays: the time of
/// [`MeshBvh::refit_partial`] against a refit alone and a full binned-SAH rebuild of the same pose, the
/// triangles it rebuilt, and the SAH cost it reaches against both; the dry run that counts the degraded
/// triangles ([`kinetrace::bvh::Bvh::degraded_primitives`]) against the refit, and the share of the
/// partial call spent re-collapsing the wide tree. Only the calls are timed (each starts from its own
/// clone of the built tree).
fn partial_rows(rec: &mut Records, name: &str, mesh: &Mesh) {
    let reps = rec.reps();
    let n = mesh.triangle_count() as f64;
    let centroid = |t: usize| mesh.triangle(t).into_iter().sum::<Vec3>() / 3.0;
    let diagonal = mesh
        .triangle_bounds()
        .iter()
        .fold(Aabb::EMPTY, |a, t| a.union(t))
        .extent()
        .length();
    let (centre, radius, reach) = (
        centroid(mesh.triangle_count() / 3),
        diagonal / 16.0,
        diagonal / 10.0,
    );
    let mut pos = mesh.positions().to_vec();
    for (t, tri) in mesh.indices().chunks_exact(3).enumerate() {
        if centroid(t).distance(centre) < radius {
            // A fixed pseudo-random direction per triangle (no RNG needed for a benchmark pose).
            let h = (t as f32 * 12.9898).sin() * 43758.547;
            let d = Vec3::new(h.fract(), (h * 1.7).fract(), (h * 2.3).fract()) * 2.0 - Vec3::ONE;
            for &i in tri {
                pos[i as usize] += d * reach;
            }
        }
    }
    let built = MeshBvh::build(mesh, &BuildOptions::default()).unwrap();
    let options = PartialOptions::default();
    // Best of `reps` over `f` applied to a fresh clone of the built tree, the clone not timed: seconds,
    // the tree and what `f` returned.
    let timed = |f: &(dyn Fn(&mut MeshBvh) -> usize + Sync)| {
        one_thread(|| {
            let mut best = (f64::INFINITY, built.clone(), 0);
            for _ in 0..reps.max(1) {
                let mut t = built.clone();
                let start = std::time::Instant::now();
                let r = f(&mut t);
                let s = start.elapsed().as_secs_f64();
                if s < best.0 {
                    best = (s, t, r);
                }
            }
            best
        })
    };
    let (t_partial, part, rebuilt) =
        timed(&|t| t.refit_partial(&pos, &options).unwrap().1.primitives);
    let (t_refit, refit, _) = timed(&|t| {
        t.refit(&pos).unwrap();
        0
    });
    // What the adaptive policy pays to weigh a partial rebuild (the selection's dry run, on the refitted
    // tree) and the share of the partial call that re-collapses the whole wide tree.
    let (t_check, _) = one_thread(|| {
        best_of(reps * 4, || {
            refit.bvh().degraded_primitives(&options).unwrap()
        })
    });
    let (t_collapse, _) = one_thread(|| best_of(reps, || WideBvh::collapse(part.bvh().nodes())));
    let moved = mesh.with_positions(pos.clone()).unwrap();
    let (t_full, fresh) = one_thread(|| {
        best_of(reps, || {
            MeshBvh::build(&moved, &BuildOptions::default()).unwrap()
        })
    });
    let subject = "kinetrace partial rebuild (local explosion)";
    rec.add(
        SUITE,
        name,
        subject,
        "refit + partial 1 thread",
        n / t_partial / 1e6,
        "Mtris/s",
    );
    rec.add(
        SUITE,
        name,
        subject,
        "refit alone 1 thread",
        n / t_refit / 1e6,
        "Mtris/s",
    );
    rec.add(
        SUITE,
        name,
        subject,
        "full sah rebuild 1 thread",
        n / t_full / 1e6,
        "Mtris/s",
    );
    rec.add(
        SUITE,
        name,
        subject,
        "triangles rebuilt",
        rebuilt as f64,
        "tris",
    );
    rec.add(
        SUITE,
        name,
        subject,
        "partial check 1 thread",
        n / t_check / 1e6,
        "Mtris/s",
    );
    rec.add(
        SUITE,
        name,
        "ratio",
        "partial check/refit time",
        t_check / t_refit,
        "x",
    );
    rec.add(
        SUITE,
        name,
        "ratio",
        "wide re-collapse/partial time",
        t_collapse / t_partial,
        "x",
    );
    let sah = part.bvh().sah_cost();
    rec.add(
        SUITE,
        name,
        "ratio",
        "partial/full-sah time",
        t_partial / t_full,
        "x (lower is better)",
    );
    rec.add(
        SUITE,
        name,
        "ratio",
        "partial/refit sah cost",
        sah / refit.bvh().sah_cost(),
        "x",
    );
    rec.add(
        SUITE,
        name,
        "ratio",
        "partial/full-sah sah cost",
        sah / fresh.bvh().sah_cost(),
        "x",
    );
}

/// The compact (quantised) wide tree against the float one: bytes per triangle and their ratio; its
/// query speed is in the query rows (`sah compact4`).
fn compact_rows(rec: &mut Records, name: &str, wide: &MeshBvh, compact: &MeshBvh) {
    let n = wide.bvh().primitive_count() as f64;
    let wb = wide
        .wide()
        .expect("built with the wide tree")
        .memory_bytes() as f64;
    let cb = compact.compact().expect("made compact").memory_bytes() as f64;
    rec.add(
        SUITE,
        name,
        "kinetrace sah compact4",
        "bytes per triangle",
        cb / n,
        "B",
    );
    rec.add(
        SUITE,
        name,
        "ratio",
        "wide4/compact4 bytes",
        wb / cb,
        "x (ReduceM: 3-5)",
    );
}

/// The wide query tree derived from `bvh` (built with `builder`): collapse time on one thread, its bytes
/// per triangle.
fn wide_rows(rec: &mut Records, name: &str, builder: &str, bvh: &MeshBvh) {
    let n = bvh.bvh().primitive_count() as f64;
    let nodes = bvh.bvh().nodes();
    let (t, wide) = one_thread(|| best_of(rec.reps(), || WideBvh::collapse(nodes)));
    let subject = format!("kinetrace {builder} wide4");
    rec.add(
        SUITE,
        name,
        &subject,
        "collapse 1 thread",
        n / t / 1e6,
        "Mtris/s",
    );
    let bytes = wide.memory_bytes() as f64 / n;
    rec.add(SUITE, name, &subject, "bytes per triangle", bytes, "B");
}

/// The collapse's cost ratio, measured: one four-box test against one watertight triangle test, each run
/// over every node (triangle) of `bvh` for a few rays through the mesh's box, one thread.
fn kernel_rows(rec: &mut Records, name: &str, bvh: &MeshBvh) {
    let wide = bvh.wide().expect("built with the wide tree");
    let b = bvh.bvh().bounds();
    let rays: Vec<Ray> = (0..16)
        .map(|i| {
            let f = i as f32 / 16.0;
            Ray::new(
                b.min - b.extent() * 0.1,
                b.extent() * Vec3::new(1.0, f, 1.0 - f),
            )
        })
        .collect();
    let (tb, _) = one_thread(|| {
        best_of(rec.reps(), || {
            let mut k = 0u32;
            for r in &rays {
                let lanes = RayLanes::new(r);
                for node in wide.nodes() {
                    k += simd::hit4(std::hint::black_box(node), &lanes, r.tmax).0;
                }
            }
            k
        })
    });
    let (tt, _) = one_thread(|| {
        best_of(rec.reps(), || {
            let mut k = 0usize;
            for r in &rays {
                let tr = TriangleRay::new(r);
                for &[a, b, c] in bvh.slot_triangles() {
                    k += tr.intersect(a, b, c, r.tmin, r.tmax).is_some() as usize;
                }
            }
            k
        })
    });
    let per_box = tb / (rays.len() * wide.nodes().len()) as f64;
    let per_tri = tt / (rays.len() * bvh.slot_triangles().len()) as f64;
    let subject = "kinetrace kernels";
    rec.add(SUITE, name, subject, "four-box test", per_box * 1e9, "ns");
    rec.add(SUITE, name, subject, "triangle test", per_tri * 1e9, "ns");
    rec.add(
        SUITE,
        name,
        subject,
        "four-box/triangle",
        per_box / per_tri,
        "x",
    );
}

fn peer<'a>(v: &'a [PeerResult], name: &str) -> &'a PeerResult {
    v.iter().find(|p| p.name == name).expect("peer measured")
}

/// Rays whose closest hit differs between two answers by more than a different triangle at an (almost) equal
/// distance: a sanity check of the comparison, since peers use other triangle tests.
fn differing(ours: &[Option<Hit>], theirs: &[Option<(u32, f32)>]) -> usize {
    ours.iter()
        .zip(theirs)
        .filter(|(a, b)| match (a, b) {
            (Some(a), Some((p, t))) => {
                a.primitive != *p && (a.t - t).abs() > 1e-4 * t.abs().max(1.0)
            }
            (None, None) => false,
            _ => true,
        })
        .count()
}

/// Metric names are `&'static str` in the records; the few built at run time live for the whole run anyway.
fn leak(s: String) -> &'static str {
    Box::leak(s.into_boxed_str())
}
