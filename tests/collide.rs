//! Discrete collision queries against brute force over all triangle pairs: the traversal (and the front,
//! and the thread split) must find exactly the pairs that the exact triangle test accepts when it is run on
//! every pair.

mod common;

use common::{icosphere, map_mesh, rng, soup};
use glam::{Affine3A, Quat, Vec3};
use kinetrace::bvh::{BuildOptions, Builder};
use kinetrace::collide::ccd::triangle_pair_toi;
use kinetrace::collide::tri_tri::triangle_contact;
use kinetrace::collide::{Contact, Impact, PairFront, PairQuery, Placed, SweptMesh};
use kinetrace::{Error, Mesh, MeshBvh};
use rand::Rng;

/// A sheet of `n × n` quads folded in two along `x = 0.5`, the folded half waving through the other
/// (crossing it along several lines), with random bumps of `amplitude`.
fn crumpled_sheet(n: u32, amplitude: f32, seed: u64) -> Mesh {
    let mut r = rng(seed);
    let mut pos = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (u, v) = (i as f32 / n as f32, j as f32 / n as f32);
            let bump = r.random_range(-amplitude..amplitude);
            pos.push(if u <= 0.5 {
                Vec3::new(u, v, bump)
            } else {
                let fold = 0.08 * (12.0 * (u - 0.5)).sin() * (1.0 + (9.0 * v).cos());
                Vec3::new(1.0 - u, v, fold + bump)
            });
        }
    }
    let mut idx = Vec::new();
    let at = |i: u32, j: u32| j * (n + 1) + i;
    for j in 0..n {
        for i in 0..n {
            idx.extend([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            idx.extend([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    Mesh::new(pos, idx).unwrap()
}

/// Every pair of triangles, `b` moved by `b_to_world` (and `a` by the identity), through the exact test.
fn brute_pairs(a: &Mesh, b: &Mesh, b_to_world: &Affine3A) -> Vec<Contact> {
    let mut out = Vec::new();
    for i in 0..a.triangle_count() {
        let ta = a.triangle(i);
        for j in 0..b.triangle_count() {
            let tb = b.triangle(j).map(|p| b_to_world.transform_point3(p));
            if let Some(c) = triangle_contact(&ta, &tb) {
                out.push(contact(i, j, c));
            }
        }
    }
    out
}

/// Every pair of triangles of one mesh that share no vertex, lower index first.
fn brute_self(m: &Mesh) -> Vec<Contact> {
    let idx = m.indices();
    let mut out = Vec::new();
    for i in 0..m.triangle_count() {
        let vi = &idx[3 * i..3 * i + 3];
        for j in i + 1..m.triangle_count() {
            if idx[3 * j..3 * j + 3].iter().any(|v| vi.contains(v)) {
                continue;
            }
            if let Some(c) = triangle_contact(&m.triangle(i), &m.triangle(j)) {
                out.push(contact(i, j, c));
            }
        }
    }
    out
}

fn contact(i: usize, j: usize, c: kinetrace::collide::tri_tri::TriContact) -> Contact {
    Contact {
        triangle_a: i as u32,
        triangle_b: j as u32,
        point: c.point,
        normal: c.normal,
        depth: c.depth,
    }
}

fn build(m: &Mesh, builder: Builder, leaf: u32) -> MeshBvh {
    MeshBvh::build(m, &BuildOptions::new(builder).max_leaf_size(leaf)).unwrap()
}

const BUILDS: [(Builder, u32); 3] = [(Builder::LBVH, 1), (Builder::SAH, 1), (Builder::SAH, 4)];

#[test]
fn two_spheres_match_brute_force() {
    let a = icosphere(3);
    let b = map_mesh(&icosphere(2), |p| p * 0.7);
    let placements = [
        Affine3A::from_translation(Vec3::new(1.2, 0.3, 0.1)),
        Affine3A::from_scale_rotation_translation(
            Vec3::new(1.3, 0.6, 0.9),
            Quat::from_euler(glam::EulerRot::XYZ, 0.3, -1.1, 2.0),
            Vec3::new(-0.9, 0.5, 0.4),
        ),
        // Far from the origin, where a box's rounding is large.
        Affine3A::from_translation(Vec3::new(0.5, 0.0, 0.0)),
    ];
    let mut q = PairQuery::new();
    let mut got = Vec::new();
    for (k, b_to_world) in placements.iter().enumerate() {
        let want = brute_pairs(&a, &b, b_to_world);
        assert!(!want.is_empty(), "placement {k} must make contacts");
        for (builder, leaf) in BUILDS {
            let (ta, tb) = (build(&a, builder, leaf), build(&b, builder, leaf));
            q.meshes(
                Placed::new(&ta, Affine3A::IDENTITY),
                Placed::new(&tb, *b_to_world),
                &mut got,
            )
            .unwrap();
            assert_eq!(got, want, "placement {k}, {} leaf {leaf}", builder.name());
        }
    }
}

#[test]
fn far_from_the_origin_the_world_frame_is_a_translation_away() {
    // Both meshes 1e5 units out: contacts are those of the same meshes at the origin, moved.
    let a = icosphere(2);
    let b = map_mesh(&icosphere(2), |p| p * 0.8 + Vec3::new(1.1, 0.2, 0.0));
    let far = Affine3A::from_translation(Vec3::new(1e5, -2e5, 3e5));
    let (ta, tb) = (build(&a, Builder::SAH, 1), build(&b, Builder::SAH, 1));
    let mut q = PairQuery::new();
    let (mut near, mut moved) = (Vec::new(), Vec::new());
    q.meshes(
        Placed::new(&ta, Affine3A::IDENTITY),
        Placed::new(&tb, Affine3A::IDENTITY),
        &mut near,
    )
    .unwrap();
    q.meshes(Placed::new(&ta, far), Placed::new(&tb, far), &mut moved)
        .unwrap();
    assert!(!near.is_empty());
    let pairs = |c: &[Contact]| {
        c.iter()
            .map(|c| (c.triangle_a, c.triangle_b))
            .collect::<Vec<_>>()
    };
    assert_eq!(pairs(&near), pairs(&moved));
    for (n, m) in near.iter().zip(&moved) {
        assert!((far.transform_point3(n.point) - m.point).length() < 0.05);
        assert!((n.normal - m.normal).length() < 1e-5);
    }
}

#[test]
fn soups_match_brute_force() {
    let a = soup(11, 1500);
    let b = soup(12, 1500);
    let b_to_world = Affine3A::from_rotation_z(0.4);
    let want = brute_pairs(&a, &b, &b_to_world);
    assert!(want.len() > 10, "{} contacts", want.len());
    let mut got = Vec::new();
    for (builder, leaf) in BUILDS {
        let (ta, tb) = (build(&a, builder, leaf), build(&b, builder, leaf));
        for parallel in [false, true] {
            PairQuery::new()
                .parallel(parallel)
                .meshes(
                    Placed::new(&ta, Affine3A::IDENTITY),
                    Placed::new(&tb, b_to_world),
                    &mut got,
                )
                .unwrap();
            assert_eq!(
                got,
                want,
                "{} leaf {leaf} parallel {parallel}",
                builder.name()
            );
        }
    }
}

#[test]
fn self_collision_matches_brute_force_and_skips_neighbours() {
    for (mesh, what) in [
        (crumpled_sheet(24, 0.06, 5), "crumpled sheet"),
        (soup(21, 1200), "soup"),
    ] {
        let want = brute_self(&mesh);
        assert!(want.len() > 10, "{what}: {} contacts", want.len());
        let mut got = Vec::new();
        for (builder, leaf) in BUILDS {
            let t = build(&mesh, builder, leaf);
            for parallel in [false, true] {
                PairQuery::new()
                    .parallel(parallel)
                    .itself(Placed::new(&t, Affine3A::IDENTITY), &mut got)
                    .unwrap();
                assert_eq!(got, want, "{what}, {} leaf {leaf}", builder.name());
            }
        }
    }
    // A closed sphere touches itself only at shared vertices and edges: no contacts at all.
    let sphere = build(&icosphere(3), Builder::LBVH, 1);
    let mut got = Vec::new();
    PairQuery::new()
        .itself(Placed::new(&sphere, Affine3A::IDENTITY), &mut got)
        .unwrap();
    assert!(got.is_empty(), "{got:?}");
}

/// The sheet at frame `f` of a coherent wave animation.
fn wave(base: &Mesh, f: u32) -> Vec<Vec3> {
    let t = f as f32 * 0.05;
    base.positions()
        .iter()
        .map(|p| {
            p + Vec3::new(
                0.0,
                0.0,
                0.05 * (6.0 * p.x + t).sin() * (4.0 * p.y - t).cos(),
            )
        })
        .collect()
}

#[test]
fn front_gives_the_same_contacts_frame_after_frame() {
    let sheet = crumpled_sheet(20, 0.05, 9);
    let other = map_mesh(&icosphere(2), |p| p * 0.3 + Vec3::new(0.5, 0.5, 0.0));
    for parallel in [false, true] {
        let mut q = PairQuery::new().parallel(parallel);
        let mut t = build(&sheet, Builder::LBVH, 1);
        let ball = build(&other, Builder::SAH, 1);
        let (mut pair_front, mut self_front) = (PairFront::new(), PairFront::new());
        let (mut with, mut without) = (Vec::new(), Vec::new());
        let (mut tests_with, mut tests_without) = (0, 0);
        for f in 0..40 {
            let pos = wave(&sheet, f);
            if f == 25 {
                // A rebuild changes the topology: the fronts must notice and start over.
                t = build(&sheet.with_positions(pos.clone()).unwrap(), Builder::SAH, 1);
            } else {
                t.refit(&pos).unwrap();
            }
            let placed = Placed::new(&t, Affine3A::IDENTITY);
            let ball_at = Placed::new(
                &ball,
                Affine3A::from_translation(Vec3::Z * (f as f32 * 0.004)),
            );
            tests_with += q
                .meshes_with_front(placed, ball_at, &mut pair_front, &mut with)
                .unwrap()
                .box_tests;
            tests_without += q.meshes(placed, ball_at, &mut without).unwrap().box_tests;
            assert_eq!(with, without, "pair, frame {f}");
            let current = sheet.with_positions(pos).unwrap();
            assert_eq!(
                without,
                brute_pairs(
                    &current,
                    &other,
                    &Affine3A::from_translation(Vec3::Z * (f as f32 * 0.004))
                ),
                "frame {f}"
            );
            tests_with += q
                .itself_with_front(placed, &mut self_front, &mut with)
                .unwrap()
                .box_tests;
            tests_without += q.itself(placed, &mut without).unwrap().box_tests;
            assert_eq!(with, without, "self, frame {f}");
            assert!(!self_front.is_empty());
        }
        // Not a timing: a count of work, which the front exists to lower.
        assert!(
            tests_with < tests_without,
            "{tests_with} vs {tests_without}"
        );
    }
}

#[test]
fn empty_and_tiny_meshes() {
    let empty = MeshBvh::default();
    let one = build(
        &Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![0, 1, 2]).unwrap(),
        Builder::LBVH,
        1,
    );
    let mut q = PairQuery::new();
    let mut out = vec![];
    let id = Affine3A::IDENTITY;
    assert_eq!(
        q.meshes(Placed::new(&empty, id), Placed::new(&one, id), &mut out)
            .unwrap()
            .box_tests,
        0
    );
    assert!(out.is_empty());
    q.itself(Placed::new(&one, id), &mut out).unwrap();
    assert!(out.is_empty());
    // A triangle against itself (two meshes): coplanar, overlapping.
    q.meshes(Placed::new(&one, id), Placed::new(&one, id), &mut out)
        .unwrap();
    assert_eq!(out.len(), 1);
    assert_eq!(out[0].depth, 0.0);
}

#[test]
fn bad_transforms_are_errors() {
    let one = build(&icosphere(0), Builder::LBVH, 1);
    let mut q = PairQuery::new();
    let mut out = vec![];
    let id = Affine3A::IDENTITY;
    let nan = Affine3A::from_translation(Vec3::new(f32::NAN, 0.0, 0.0));
    let flat = Affine3A::from_scale(Vec3::new(1.0, 0.0, 1.0));
    for (a, b) in [(nan, id), (id, nan), (flat, id)] {
        let r = q.meshes(Placed::new(&one, a), Placed::new(&one, b), &mut out);
        assert!(matches!(r, Err(Error::InvalidTransform(_))), "{r:?}");
    }
    assert!(q.itself(Placed::new(&one, flat), &mut out).is_err());
    // A flattened `b` is legal: it is only ever mapped forwards.
    q.meshes(Placed::new(&one, id), Placed::new(&one, flat), &mut out)
        .unwrap();
}

/// Every pair of moving triangles through the continuous test (`itself`: lower index first, neighbours
/// skipped).
fn brute_swept(
    a: &Mesh,
    a0: &[Vec3],
    a1: &[Vec3],
    b: &Mesh,
    b0: &[Vec3],
    b1: &[Vec3],
    itself: bool,
) -> Vec<Impact> {
    let corners = |m: &Mesh, p: &[Vec3], i: usize| {
        let t = &m.indices()[3 * i..3 * i + 3];
        [t[0], t[1], t[2]].map(|v| p[v as usize])
    };
    let mut out = Vec::new();
    for i in 0..a.triangle_count() {
        for j in 0..b.triangle_count() {
            if itself {
                let (ti, tj) = (
                    &a.indices()[3 * i..3 * i + 3],
                    &a.indices()[3 * j..3 * j + 3],
                );
                if j <= i || ti.iter().any(|v| tj.contains(v)) {
                    continue;
                }
            }
            let ca = [corners(a, a0, i), corners(a, a1, i)];
            let cb = [corners(b, b0, j), corners(b, b1, j)];
            if let Some(h) = triangle_pair_toi(&ca, &cb) {
                out.push(Impact {
                    triangle_a: i as u32,
                    triangle_b: j as u32,
                    t: h.t,
                    feature: h.feature,
                    point: h.point,
                });
            }
        }
    }
    out
}

#[test]
fn swept_meshes_match_brute_force() {
    // A sphere flying through a waving sheet within one frame, and the sheet against itself.
    let sheet = crumpled_sheet(12, 0.02, 3);
    let ball = map_mesh(&icosphere(1), |p| p * 0.2);
    let (s0, s1) = (wave(&sheet, 0), wave(&sheet, 3));
    let fly = |z: f32| {
        ball.positions()
            .iter()
            .map(|p| *p + Vec3::new(0.3, 0.4, z))
            .collect::<Vec<_>>()
    };
    let (b0, b1) = (fly(0.6), fly(-0.6));
    let opts = BuildOptions::new(Builder::SAH);
    let mut ts = SweptMesh::build(&sheet, &s0, &s0, &opts).unwrap();
    ts.update(&s0, &s1).unwrap();
    let tb = SweptMesh::build(&ball, &b0, &b1, &opts).unwrap();
    let mut got = Vec::new();
    for parallel in [false, true] {
        let mut q = PairQuery::new().parallel(parallel);
        q.swept(&ts, &tb, &mut got);
        let want = brute_swept(&sheet, &s0, &s1, &ball, &b0, &b1, false);
        assert!(want.len() > 5, "{} impacts", want.len());
        assert_eq!(got, want);
        q.swept_itself(&ts, &mut got);
        assert_eq!(got, brute_swept(&sheet, &s0, &s1, &sheet, &s0, &s1, true));
    }
    // Positions of the wrong length are errors, not panics.
    assert!(matches!(
        ts.update(&s0, &s1[1..]),
        Err(Error::VertexCountMismatch { .. })
    ));
    // So are non-finite ones, in an update and in a build.
    let mut bad = s1.clone();
    bad[7].y = f32::NAN;
    assert!(matches!(
        ts.update(&s0, &bad),
        Err(Error::NonFiniteVertex { .. })
    ));
    assert!(matches!(
        SweptMesh::build(&sheet, &bad, &s1, &opts),
        Err(Error::NonFiniteVertex { .. })
    ));
}
