//! Tests of continuous collision detection: analytic trajectories with known
//! contact times, degenerate configurations and a randomized never-miss
//! property check against an independent `f64` reference.

mod common;

use common::closest_on_triangle;
use glam::{DVec3, Vec3};
use kinetrace::collide::ccd::*;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

fn v(x: f32, y: f32, z: f32) -> Vec3 {
    Vec3::new(x, y, z)
}

/// The unit right triangle in the plane z = 0.
const FLOOR: [Vec3; 3] = [Vec3::ZERO, Vec3::X, Vec3::Y];

fn still<T: Copy>(x: T) -> [T; 2] {
    [x, x]
}

#[track_caller]
fn assert_time(got: Option<f32>, want: f64) {
    let t = got.unwrap_or_else(|| panic!("missed contact at t = {want}"));
    assert!((t as f64 - want).abs() <= 1e-6, "t = {t}, want {want}");
}

// ---------------------------------------------------------------- vertex–face

#[test]
fn vertex_falls_onto_face_interior() {
    let p = [v(0.25, 0.25, 1.0), v(0.25, 0.25, -3.0)];
    assert_time(vertex_face_toi(p, still(FLOOR)), 0.25);
}

#[test]
fn vertex_starts_on_face() {
    let p = [v(0.25, 0.25, 0.0), v(0.25, 0.25, -1.0)];
    assert_time(vertex_face_toi(p, still(FLOOR)), 0.0);
    // Leaving the face still touches at t = 0.
    let p = [v(0.25, 0.25, 0.0), v(0.5, 0.25, 1.0)];
    assert_time(vertex_face_toi(p, still(FLOOR)), 0.0);
}

#[test]
fn vertex_ends_on_face() {
    let p = [v(0.25, 0.25, 1.0), v(0.25, 0.25, 0.0)];
    assert_time(vertex_face_toi(p, still(FLOOR)), 1.0);
}

#[test]
fn vertex_passing_beside_face() {
    let p = [v(2.0, 2.0, 1.0), v(2.0, 2.0, -1.0)];
    assert_eq!(vertex_face_toi(p, still(FLOOR)), None);
    // Just outside the hypotenuse x + y = 1 (by about 7e-6).
    let p = [v(0.5, 0.50001, 1.0), v(0.5, 0.50001, -1.0)];
    assert_eq!(vertex_face_toi(p, still(FLOOR)), None);
    // Through a corner is a contact.
    let p = [v(1.0, 0.0, 1.0), v(1.0, 0.0, -1.0)];
    assert_time(vertex_face_toi(p, still(FLOOR)), 0.5);
    // Stopping short of the face is not.
    let p = [v(0.25, 0.25, 1.0), v(0.25, 0.25, 1e-3)];
    assert_eq!(vertex_face_toi(p, still(FLOOR)), None);
}

#[test]
fn vertex_crossing_at_huge_speed() {
    let p = [v(0.25, 0.25, 5000.0), v(0.25, 0.25, -5000.0)];
    assert_time(vertex_face_toi(p, still(FLOOR)), 0.5);
    // Same speed, but passing 1e-3 beside the face.
    let p = [v(-1e-3, 0.25, 5000.0), v(-1e-3, 0.25, -5000.0)];
    assert_eq!(vertex_face_toi(p, still(FLOOR)), None);
    // Diagonal: 1e4 per frame sideways as well.
    let p = [v(-4999.75, 0.25, 5000.0), v(5000.25, 0.25, -5000.0)];
    assert_time(vertex_face_toi(p, still(FLOOR)), 0.5);
}

#[test]
fn vertex_tiny_motion() {
    let p = [v(0.25, 0.25, 0.5e-7), v(0.25, 0.25, -0.5e-7)];
    assert_time(vertex_face_toi(p, still(FLOOR)), 0.5);
    let p = [v(0.25, 0.25, 1e-7), v(0.25, 0.25, 0.5e-7)];
    assert_eq!(vertex_face_toi(p, still(FLOOR)), None);
}

#[test]
fn rotating_face_static_vertex() {
    // Corners a, b on the x axis; c turns about it by 60 degrees, moving on a
    // straight chord. The face plane contains the x axis and c(t), so the
    // static vertex p = (0, py, pz) is on it when c_y(t)·pz = c_z(t)·py.
    let angle = 60f32.to_radians();
    let c0 = v(0.0, 1.0, 0.0);
    let c1 = v(0.0, angle.cos(), angle.sin());
    let tri = [
        [v(-1.0, 0.0, 0.0), v(1.0, 0.0, 0.0), c0],
        [v(-1.0, 0.0, 0.0), v(1.0, 0.0, 0.0), c1],
    ];
    let p = v(0.1, 0.25, 0.2);
    let (py, pz) = (p.y as f64, p.z as f64);
    let (y0, z0) = (c0.y as f64, c0.z as f64);
    let (dy, dz) = (c1.y as f64 - y0, c1.z as f64 - z0);
    let want = (y0 * pz - z0 * py) / (dz * py - dy * pz);
    assert!(want > 0.0 && want < 1.0);
    assert_time(vertex_face_toi(still(p), tri), want);
    // A vertex beyond the reach of the turning face is never hit.
    let far = v(0.1, 2.0, 1.5);
    assert_eq!(vertex_face_toi(still(far), tri), None);
}

#[test]
fn moving_face_and_vertex() {
    // Face rises from z = 0 to z = 1 while sliding in x; the vertex falls
    // from z = 3 to z = -5: 3 - 8t = t at t = 1/3.
    let shift = v(0.1, 0.0, 1.0);
    let tri = [FLOOR, FLOOR.map(|c| c + shift)];
    let p = [v(0.3, 0.3, 3.0), v(0.2, 0.3, -5.0)];
    assert_time(vertex_face_toi(p, tri), 1.0 / 3.0);
}

#[test]
fn vertex_grazing_face_double_root() {
    // The face tilts about the x axis while the vertex moves: f(t) is
    // proportional to -(t - 1/2)^2, the vertex touches the face at t = 1/2
    // without crossing its plane.
    let tri = [
        [v(-1.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(0.0, 1.0, -1.0)],
        [v(-1.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(0.0, 1.0, 1.0)],
    ];
    let p = [v(0.0, 0.25, -0.375), v(0.0, 0.5, 0.375)];
    assert_time(vertex_face_toi(p, tri), 0.5);
    // Shifted by 1e-4 along -z, the path misses the face plane entirely.
    let p = [v(0.0, 0.25, -0.3751), v(0.0, 0.5, 0.3749)];
    assert_eq!(vertex_face_toi(p, tri), None);
    // Shifted along +z, it crosses the plane twice, close together: with
    // z(t) = z0 + t (z1 - z0) and y(t) = (1 + t) / 4, the plane is reached
    // where z(t) = (2t - 1) y(t), i.e. -t²/2 + (z1 - z0 - 1/4) t + z0 + 1/4 = 0.
    let p = [v(0.0, 0.25, -0.3749), v(0.0, 0.5, 0.3751)];
    let (z0, z1) = (p[0].z as f64, p[1].z as f64);
    let (b, c) = (z1 - z0 - 0.25, z0 + 0.25);
    let first = b - (b * b + 2.0 * c).sqrt(); // smaller root of -t²/2 + b t + c
    assert!((first - (0.5 - 2e-4f64.sqrt())).abs() < 1e-4);
    assert_time(vertex_face_toi(p, tri), first);
}

#[test]
fn vertex_sliding_in_face_plane() {
    // Always coplanar: the vertex slides in z = 0 and enters the face
    // through the edge x = 0 at t = 0.5.
    let p = [v(-1.0, 0.25, 0.0), v(1.0, 0.25, 0.0)];
    assert_time(vertex_face_toi(p, still(FLOOR)), 0.5);
    // In the plane but passing beside the face.
    let p = [v(-1.0, 2.0, 0.0), v(1.0, 2.0, 0.0)];
    assert_eq!(vertex_face_toi(p, still(FLOOR)), None);
}

#[test]
fn sliding_in_tilted_plane() {
    // Everything in the plane x + y + z = 0 (exactly representable). The
    // vertex moves through the centroid of an equilateral face along
    // s·(2, -1, -1) with s = 1 - 2t; it is inside for |s| <= 1/3.
    let tri = still([v(1.0, -1.0, 0.0), v(0.0, 1.0, -1.0), v(-1.0, 0.0, 1.0)]);
    let p = [v(2.0, -1.0, -1.0), v(-2.0, 1.0, 1.0)];
    assert_time(vertex_face_toi(p, tri), 1.0 / 3.0);
    // Edges in the same plane: e0 = B C of that face, e1 = P Q sliding by
    // (-2, 1, 1). B lies on e1 when B - P(t) = (-2 + 2t, 2 - t, -t) is
    // k (Q - P) = k (-1, 2, -1) with k in [0, 1]: at t = k = 2/3.
    let e0 = still([v(0.0, 1.0, -1.0), v(-1.0, 0.0, 1.0)]);
    let e1 = shifted(
        seg(v(2.0, -1.0, -1.0), v(1.0, 1.0, -2.0)),
        v(-2.0, 1.0, 1.0),
    );
    let hit = edge_edge_toi(e0, e1).expect("coplanar edges meet");
    assert!((hit as f64 - 2.0 / 3.0).abs() <= 1e-6, "t = {hit}");
}

// ------------------------------------------------------------------ edge–edge

fn seg(a: Vec3, b: Vec3) -> [Vec3; 2] {
    [a, b]
}

fn shifted(e: [Vec3; 2], d: Vec3) -> [[Vec3; 2]; 2] {
    [e, [e[0] + d, e[1] + d]]
}

const X_AXIS: [Vec3; 2] = [v_const(-1.0, 0.0, 0.0), v_const(1.0, 0.0, 0.0)];

const fn v_const(x: f32, y: f32, z: f32) -> Vec3 {
    Vec3::new(x, y, z)
}

#[test]
fn edges_crossing_perpendicular() {
    let e1 = shifted(
        seg(v(0.25, -1.0, 1.0), v(0.25, 1.0, 1.0)),
        v(0.0, 0.0, -4.0),
    );
    assert_time(edge_edge_toi(still(X_AXIS), e1), 0.25);
    // Both moving: e0 rises 1, e1 falls 2 and slides.
    let e0 = shifted(X_AXIS, v(0.0, 0.0, 1.0));
    let e1 = [
        seg(v(0.5, -1.0, 2.0), v(0.5, 1.0, 2.0)),
        seg(v(0.2, -1.0, 0.0), v(0.2, 1.0, 0.0)),
    ];
    assert_time(edge_edge_toi(e0, e1), 2.0 / 3.0);
}

#[test]
fn edges_near_parallel() {
    let e0 = still(seg(Vec3::ZERO, Vec3::X));
    // Parallel within 6e-10 and overlapping in the plane at t = 0.5.
    let e1 = shifted(seg(v(0.2, 0.0, 1.0), v(0.8, 6e-10, 1.0)), v(0.0, 0.0, -2.0));
    assert_time(edge_edge_toi(e0, e1), 0.5);
    // Crossing at an angle of 1e-9 in the middle of both.
    let e1 = shifted(
        seg(v(0.0, -5e-10, 1.0), v(1.0, 5e-10, 1.0)),
        v(0.0, 0.0, -4.0),
    );
    assert_time(edge_edge_toi(e0, e1), 0.25);
    // The same, 1e-3 to the side: no contact.
    let e1 = shifted(
        seg(v(0.2, 1e-3, 1.0), v(0.8, 1e-3 + 6e-10, 1.0)),
        v(0.0, 0.0, -2.0),
    );
    assert_eq!(edge_edge_toi(e0, e1), None);
    // Exactly parallel, 1e-3 apart, crossing the plane z = 0 together.
    let e1 = shifted(seg(v(0.2, 1e-3, 1.0), v(0.8, 1e-3, 1.0)), v(0.0, 0.0, -2.0));
    assert_eq!(edge_edge_toi(e0, e1), None);
    // Exactly parallel and landing on each other.
    let e1 = shifted(seg(v(0.2, 0.0, 1.0), v(0.8, 0.0, 1.0)), v(0.0, 0.0, -2.0));
    assert_time(edge_edge_toi(e0, e1), 0.5);
}

#[test]
fn edges_collinear() {
    let e0 = still(seg(Vec3::ZERO, Vec3::X));
    // Overlapping from the start, sliding along each other.
    let e1 = shifted(seg(v(0.5, 0.0, 0.0), v(1.5, 0.0, 0.0)), v(-1.0, 0.0, 0.0));
    assert_time(edge_edge_toi(e0, e1), 0.0);
    // Approaching along the common line: endpoints meet when 2 - 2t = 1.
    let e1 = shifted(seg(v(2.0, 0.0, 0.0), v(3.0, 0.0, 0.0)), v(-2.0, 0.0, 0.0));
    assert_time(edge_edge_toi(e0, e1), 0.5);
    // On the common line but stopping short.
    let e1 = shifted(seg(v(3.0, 0.0, 0.0), v(4.0, 0.0, 0.0)), v(-1.5, 0.0, 0.0));
    assert_eq!(edge_edge_toi(e0, e1), None);
    // Coplanar and parallel, the lines merging at t = 0.25.
    let e1 = shifted(seg(v(0.5, 1.0, 0.0), v(1.5, 1.0, 0.0)), v(0.0, -4.0, 0.0));
    assert_time(edge_edge_toi(e0, e1), 0.25);
}

#[test]
fn edge_endpoint_touching_edge() {
    // A vertical edge whose lower endpoint lands on the x axis at t = 0.5.
    let e1 = shifted(seg(v(0.3, 0.0, 1.0), v(0.3, 0.0, 2.0)), v(0.0, 0.0, -2.0));
    assert_time(edge_edge_toi(still(X_AXIS), e1), 0.5);
    // Endpoint to endpoint.
    let e1 = shifted(seg(v(1.0, 0.0, 1.0), v(1.0, 1.0, 1.0)), v(0.0, 0.0, -2.0));
    assert_time(edge_edge_toi(still(X_AXIS), e1), 0.5);
}

#[test]
fn edges_passing_at_1e7() {
    // The near endpoint of e1 passes 1e-7 beside the x axis.
    let e1 = shifted(
        seg(v(0.25, 1e-7, 1.0), v(0.25, 1.0, 1.0)),
        v(0.0, 0.0, -2.0),
    );
    assert_eq!(edge_edge_toi(still(X_AXIS), e1), None);
    // Parallel edges passing 1e-7 apart.
    let e1 = shifted(
        seg(v(-0.5, 1e-7, 1.0), v(0.5, 1e-7, 1.0)),
        v(0.0, 0.0, -2.0),
    );
    assert_eq!(edge_edge_toi(still(X_AXIS), e1), None);
}

// ------------------------------------------------------------- triangle pairs

fn moved(tri: [Vec3; 3], d: Vec3) -> [[Vec3; 3]; 2] {
    [tri, tri.map(|c| c + d)]
}

fn swapped(f: Feature) -> Feature {
    match f {
        Feature::VertexFace { vertex } => Feature::FaceVertex { vertex },
        Feature::FaceVertex { vertex } => Feature::VertexFace { vertex },
        Feature::EdgeEdge { edge_a, edge_b } => Feature::EdgeEdge {
            edge_a: edge_b,
            edge_b: edge_a,
        },
    }
}

/// Checks `triangle_pair_toi(a, b)` and that swapping the triangles gives
/// the same time with the swapped feature.
#[track_caller]
fn assert_pair(a: &[[Vec3; 3]; 2], b: &[[Vec3; 3]; 2], t: f64, feature: Feature, point: Vec3) {
    let hit = triangle_pair_toi(a, b).expect("missed contact");
    assert!((hit.t as f64 - t).abs() <= 1e-6, "t = {}, want {t}", hit.t);
    assert_eq!(hit.feature, feature);
    assert!(
        hit.point.distance(point) <= 1e-5,
        "point {}, want {point}",
        hit.point
    );
    let back = triangle_pair_toi(b, a).expect("missed contact after swap");
    assert!(
        (back.t - hit.t).abs() <= 1e-7,
        "t = {} after swap, {} before",
        back.t,
        hit.t
    );
    assert_eq!(back.feature, swapped(feature));
    assert!(back.point.distance(point) <= 1e-5);
}

#[test]
fn triangles_face_on() {
    let a = still(FLOOR);
    // A tetrahedron-like triangle above, its lowest corner (index 1) first
    // reaching the floor at t = 0.25.
    let b = moved(
        [v(0.5, 0.1, 2.0), v(0.2, 0.3, 1.0), v(0.1, 0.6, 1.5)],
        v(0.0, 0.0, -4.0),
    );
    assert_pair(
        &a,
        &b,
        0.25,
        Feature::FaceVertex { vertex: 1 },
        v(0.2, 0.3, 0.0),
    );
}

#[test]
fn triangles_edge_on() {
    // a stands in the plane y = 0 with its top edge (edge 0) on the x axis;
    // b lies across it and its edge 0 comes down onto that edge at t = 0.5.
    let a = still([v(-1.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(0.0, 0.0, -1.0)]);
    let b = moved(
        [v(0.25, -1.0, 1.0), v(0.25, 1.0, 1.0), v(0.25, 0.1, 2.0)],
        v(0.0, 0.0, -2.0),
    );
    assert_pair(
        &a,
        &b,
        0.5,
        Feature::EdgeEdge {
            edge_a: 0,
            edge_b: 0,
        },
        v(0.25, 0.0, 0.0),
    );
    // Turned the other way round, edge 1 of b is the one that hits.
    let b = moved(
        [v(0.25, 0.1, 2.0), v(0.25, -1.0, 1.0), v(0.25, 1.0, 1.0)],
        v(0.0, 0.0, -2.0),
    );
    assert_pair(
        &a,
        &b,
        0.5,
        Feature::EdgeEdge {
            edge_a: 0,
            edge_b: 1,
        },
        v(0.25, 0.0, 0.0),
    );
}

#[test]
fn triangles_earliest_of_several_contacts() {
    // b falls onto a tilted floor: its corner 2 hits the face of a first
    // (at t = 0.125), its edge 0 would cross edge 1 of a later.
    let a = still([v(0.0, 0.0, 0.0), v(2.0, 0.0, 1.0), v(0.0, 2.0, 0.0)]);
    let b = moved(
        [v(1.5, 0.25, 2.0), v(1.5, 1.0, 2.0), v(0.5, 0.5, 0.5)],
        v(0.0, 0.0, -2.0),
    );
    // Corner 2 is 0.5 - 0.25 above the plane z = x / 2 and falls at speed 2.
    let want = 0.125;
    let hit = triangle_pair_toi(&a, &b).unwrap();
    assert_eq!(hit.feature, Feature::FaceVertex { vertex: 2 });
    assert!((hit.t as f64 - want).abs() <= 1e-6, "t = {}", hit.t);
    let later = edge_edge_toi(
        [[a[0][1], a[0][2]]; 2],
        [[b[0][0], b[0][1]], [b[1][0], b[1][1]]],
    );
    assert!(later.is_some_and(|t| t as f64 > want));
}

#[test]
fn triangles_apart_or_static() {
    let a = still(FLOOR);
    // Falling beside the floor.
    let b = moved(
        [v(2.0, 2.0, 1.0), v(3.0, 2.0, 1.0), v(2.0, 3.0, 1.0)],
        v(0.0, 0.0, -2.0),
    );
    assert_eq!(triangle_pair_toi(&a, &b), None);
    // Static and touching: contact at t = 0.
    let b = still([v(0.25, 0.25, 0.0), v(0.25, 0.25, 1.0), v(0.5, 0.0, 1.0)]);
    let hit = triangle_pair_toi(&a, &b).unwrap();
    assert_eq!(
        (hit.t, hit.feature),
        (0.0, Feature::FaceVertex { vertex: 0 })
    );
    // Static and apart.
    let b = still([v(0.25, 0.25, 0.1), v(0.25, 0.25, 1.0), v(0.5, 0.0, 1.0)]);
    assert_eq!(triangle_pair_toi(&a, &b), None);
    assert_eq!(
        vertex_face_toi(still(v(0.25, 0.25, 0.1)), still(FLOOR)),
        None
    );
    assert_time(
        vertex_face_toi(still(v(0.25, 0.25, 0.0)), still(FLOOR)),
        0.0,
    );
    let e = still(seg(v(0.5, -1.0, 0.0), v(0.5, 1.0, 0.0)));
    assert_time(edge_edge_toi(still(X_AXIS), e), 0.0);
    let e = still(seg(v(0.5, -1.0, 1e-3), v(0.5, 1.0, 1e-3)));
    assert_eq!(edge_edge_toi(still(X_AXIS), e), None);
}

#[test]
fn non_finite_inputs_give_none() {
    let bad = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY];
    let p = [v(0.25, 0.25, 1.0), v(0.25, 0.25, -1.0)];
    let e1 = shifted(
        seg(v(0.25, -1.0, 1.0), v(0.25, 1.0, 1.0)),
        v(0.0, 0.0, -2.0),
    );
    let b = moved(
        [v(0.2, 0.2, 1.0), v(0.3, 0.2, 2.0), v(0.2, 0.3, 2.0)],
        v(0.0, 0.0, -2.0),
    );
    // Each contact is found with finite input...
    assert!(vertex_face_toi(p, still(FLOOR)).is_some());
    assert!(edge_edge_toi(still(X_AXIS), e1).is_some());
    assert!(triangle_pair_toi(&still(FLOOR), &b).is_some());
    // ... and poisoning any single coordinate gives None.
    for x in bad {
        for slot in 0..3 {
            let poison = |mut w: Vec3| {
                w[slot] = x;
                w
            };
            for i in 0..2 {
                let mut q = p;
                q[i] = poison(q[i]);
                assert_eq!(vertex_face_toi(q, still(FLOOR)), None);
                for j in 0..3 {
                    let mut tri = still(FLOOR);
                    tri[i][j] = poison(tri[i][j]);
                    assert_eq!(vertex_face_toi(p, tri), None);
                    let mut bb = b;
                    bb[i][j] = poison(bb[i][j]);
                    assert_eq!(triangle_pair_toi(&still(FLOOR), &bb), None);
                    assert_eq!(triangle_pair_toi(&bb, &still(FLOOR)), None);
                }
                for j in 0..2 {
                    let mut e = e1;
                    e[i][j] = poison(e[i][j]);
                    assert_eq!(edge_edge_toi(still(X_AXIS), e), None);
                    assert_eq!(edge_edge_toi(e, still(X_AXIS)), None);
                }
            }
        }
    }
}

#[test]
fn extreme_inputs_never_nan() {
    // Huge, tiny, subnormal and mixed magnitudes: any result must be a
    // finite time in [0, 1] with a finite point.
    let mut rng = SmallRng::seed_from_u64(7);
    let magnitudes = [0.0, 1e-38, 1e-30, 1e-7, 1.0, 1e4, 1e20, 1e38, f32::MAX];
    for _ in 0..3000 {
        let mut corner = || {
            Vec3::from_array(std::array::from_fn(|_| {
                let m = magnitudes[rng.random_range(0..magnitudes.len())];
                m * rng.random_range(-1.0f32..=1.0)
            }))
        };
        let a = [
            [corner(), corner(), corner()],
            [corner(), corner(), corner()],
        ];
        let b = [
            [corner(), corner(), corner()],
            [corner(), corner(), corner()],
        ];
        if let Some(hit) = triangle_pair_toi(&a, &b) {
            assert!((0.0..=1.0).contains(&hit.t), "{hit:?}");
            assert!(hit.point.is_finite(), "{hit:?}");
        }
        if let Some(t) = vertex_face_toi([a[0][0], a[1][0]], b) {
            assert!((0.0..=1.0).contains(&t));
        }
        if let Some(t) = edge_edge_toi(
            [[a[0][0], a[0][1]], [a[1][0], a[1][1]]],
            [[b[0][0], b[0][1]], [b[1][0], b[1][1]]],
        ) {
            assert!((0.0..=1.0).contains(&t));
        }
    }
}

// ------------------------------------------------- randomized property checks

type Tri64 = [DVec3; 3];

fn at(tri: &[[Vec3; 3]; 2], t: f64) -> Tri64 {
    std::array::from_fn(|i| {
        let (x0, x1) = (tri[0][i].as_dvec3(), tri[1][i].as_dvec3());
        x0 + (x1 - x0) * t
    })
}

fn orient(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> f64 {
    (b - a).cross(c - a).dot(d - a)
}

/// Whether segment `(p, q)` crosses triangle `t` (general position).
fn segment_crosses(p: DVec3, q: DVec3, t: &Tri64) -> bool {
    let (dp, dq) = (orient(t[0], t[1], t[2], p), orient(t[0], t[1], t[2], q));
    if dp * dq > 0.0 || (dp == 0.0 && dq == 0.0) {
        return false;
    }
    let o: [f64; 3] = std::array::from_fn(|i| orient(p, q, t[i], t[(i + 1) % 3]));
    o.iter().all(|&x| x >= 0.0) || o.iter().all(|&x| x <= 0.0)
}

/// Static triangle–triangle intersection for triangles in general position:
/// they intersect iff an edge of one crosses the other.
fn intersect(a: &Tri64, b: &Tri64) -> bool {
    (0..3).any(|i| {
        segment_crosses(a[i], a[(i + 1) % 3], b) || segment_crosses(b[i], b[(i + 1) % 3], a)
    })
}

/// Distance from `x` to the segment `(a, b)`.
fn point_segment_distance(x: DVec3, a: DVec3, b: DVec3) -> f64 {
    let d = b - a;
    let dd = d.length_squared();
    let u = if dd > 0.0 {
        ((x - a).dot(d) / dd).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (x - (a + d * u)).length()
}

/// Distance between segments: the endpoint–segment distances and, if the
/// common perpendicular of the lines falls inside both, its length.
fn segment_distance(p: DVec3, q: DVec3, r: DVec3, s: DVec3) -> f64 {
    let ends = [(p, r, s), (q, r, s), (r, p, q), (s, p, q)];
    let mut best = ends
        .map(|(x, a, b)| point_segment_distance(x, a, b))
        .into_iter()
        .fold(f64::INFINITY, f64::min);
    let (d1, d2) = (q - p, s - r);
    let n = d1.cross(d2);
    let nn = n.length_squared();
    if nn > 0.0 {
        let a = (r - p).cross(d2).dot(n) / nn;
        let b = (r - p).cross(d1).dot(n) / nn;
        if (0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b) {
            best = best.min((p + d1 * a - (r + d2 * b)).length());
        }
    }
    best
}

/// Distance between two disjoint triangles (over the 6 vertex–face and 9
/// edge–edge pairs).
fn triangle_distance(a: &Tri64, b: &Tri64) -> f64 {
    let mut d = f64::INFINITY;
    for i in 0..3 {
        d = d.min((a[i] - closest_on_triangle(a[i], *b)).length());
        d = d.min((b[i] - closest_on_triangle(b[i], *a)).length());
        for j in 0..3 {
            d = d.min(segment_distance(a[i], a[(i + 1) % 3], b[j], b[(j + 1) % 3]));
        }
    }
    d
}

fn longest_edge(t: &Tri64) -> f64 {
    (0..3)
        .map(|i| (t[i] - t[(i + 1) % 3]).length())
        .fold(0.0, f64::max)
}

/// A random moving triangle pair of the given scale around `center`, with
/// velocities up to `speed` times the scale. With `meet`, the triangles
/// share a point at t = 1 (so they intersect then).
fn random_pair(
    rng: &mut SmallRng,
    scale: f32,
    center: Vec3,
    speed: f32,
    meet: bool,
) -> ([[Vec3; 3]; 2], [[Vec3; 3]; 2]) {
    let mut offset = |r: f32| {
        scale * r * Vec3::from_array(std::array::from_fn(|_| rng.random_range(-1.0..=1.0)))
    };
    let a1 = [
        center + offset(1.0),
        center + offset(1.0),
        center + offset(1.0),
    ];
    let mut b1 = [
        center + offset(1.0),
        center + offset(1.0),
        center + offset(1.0),
    ];
    if meet {
        // Move b1 so that the point with barycentric weights `w` in b1
        // coincides with the point with weights `w` in a1.
        let w = [offset(1.0).abs(), offset(1.0).abs()].map(|x| x.x + 1e-3);
        let w = [w[0], w[1], 1.0].map(|x| x / (w[0] + w[1] + 1.0));
        let mix = |t: [Vec3; 3]| t[0] * w[0] + t[1] * w[1] + t[2] * w[2];
        let shift = mix(a1) - mix(b1);
        b1 = b1.map(|c| c + shift);
    }
    let (da, db) = (offset(speed), offset(speed));
    let a0 = a1.map(|c| c - da + offset(0.3));
    let b0 = b1.map(|c| c - db + offset(0.3));
    ([a0, a1], [b0, b1])
}

/// Dense check that the triangles neither intersect nor come within
/// `1e-9` of their size at any of `steps` samples of `[0, until)`.
fn assert_apart_until(
    case: usize,
    a: &[[Vec3; 3]; 2],
    b: &[[Vec3; 3]; 2],
    until: f64,
    steps: usize,
) {
    for k in 0..steps {
        let s = k as f64 / steps as f64;
        if s >= until {
            break;
        }
        let (ta, tb) = (at(a, s), at(b, s));
        let size = longest_edge(&ta).max(longest_edge(&tb));
        assert!(
            !intersect(&ta, &tb) && triangle_distance(&ta, &tb) > 1e-9 * size,
            "case {case}: contact at {s}, before {until}"
        );
    }
}

#[test]
fn random_trajectories_never_miss() {
    // Random moving pairs at several scales, offsets and speeds; two thirds
    // are built to intersect at t = 1. Whenever they are apart at t = 0 and
    // intersect at t = 1 a contact must be reported; a reported contact must
    // be a real one (gap within 1e-5 of the size) with no earlier contact on
    // a dense grid of 10_000 steps (500 cases) and none at all when nothing
    // is reported (2_000 steps, 500 cases).
    let mut rng = SmallRng::seed_from_u64(0x5eed);
    let (mut crossings, mut hits, mut dense_hits, mut dense_misses) = (0, 0, 0, 0);
    for case in 0..24_000 {
        let scale = [1e-3, 1.0, 1.0, 1e3][case % 4];
        let center = Vec3::splat([0.0, 0.0, 10.0, -1e3][(case / 4) % 4] * scale);
        let (a, b) = random_pair(&mut rng, scale, center, [0.5, 2.0][case % 2], case % 3 != 0);
        let hit = triangle_pair_toi(&a, &b);
        if intersect(&at(&a, 0.0), &at(&b, 0.0)) {
            continue; // already penetrating: not a continuous-collision question
        }
        if intersect(&at(&a, 1.0), &at(&b, 1.0)) {
            crossings += 1;
            assert!(hit.is_some(), "case {case}: missed crossing\n{a:?}\n{b:?}");
        }
        let Some(h) = hit else {
            if dense_misses < 500 {
                dense_misses += 1;
                assert_apart_until(case, &a, &b, 2.0, 2_000);
            }
            continue;
        };
        hits += 1;
        assert!((0.0..=1.0).contains(&h.t));
        let t = h.t as f64;
        let (ta, tb) = (at(&a, t), at(&b, t));
        let size = longest_edge(&ta).max(longest_edge(&tb));
        let gap = triangle_distance(&ta, &tb);
        assert!(
            gap <= 1e-5 * size,
            "case {case}: gap {gap} at t = {t} (size {size}), {h:?}"
        );
        if dense_hits < 500 {
            dense_hits += 1;
            assert_apart_until(case, &a, &b, t - 1e-4, 10_000);
        }
    }
    assert!(
        crossings > 10_000 && hits > crossings,
        "{crossings} crossings, {hits} hits"
    );
    assert!(dense_misses == 500, "{dense_misses} cases without contact");
}

fn random_vec(rng: &mut SmallRng) -> Vec3 {
    Vec3::from_array(std::array::from_fn(|_| rng.random_range(-1.0..=1.0)))
}

/// Barycentric coordinates of `p` projected on the plane of triangle `t`.
fn barycentric(p: DVec3, t: &Tri64) -> [f64; 3] {
    let n = (t[1] - t[0]).cross(t[2] - t[0]);
    let nn = n.length_squared();
    let l1 = (t[2] - t[1]).cross(p - t[1]).dot(n) / nn;
    let l2 = (t[0] - t[2]).cross(p - t[2]).dot(n) / nn;
    [l1, l2, 1.0 - l1 - l2]
}

#[test]
fn random_vertex_through_static_face() {
    // f(t) is linear here, so the crossing time of the face plane is
    // h0 / (h0 - h1) exactly; away from the face's boundary (1e-3 in
    // barycentric terms) the answer is known.
    let mut rng = SmallRng::seed_from_u64(11);
    let (mut hits, mut misses) = (0, 0);
    for case in 0..20_000 {
        let scale = [1e-3f32, 1.0, 1e3][case % 3];
        let travel = [1e-6f32, 1e-3, 1.0, 1e4][(case / 3) % 4] * scale;
        let center = scale * 10.0 * random_vec(&mut rng);
        let tri = [0; 3].map(|_| center + scale * random_vec(&mut rng));
        let w = [0; 3].map(|_| rng.random_range(-0.5f32..1.0));
        let cross = (tri[0] * w[0] + tri[1] * w[1] + tri[2] * w[2]) / (w[0] + w[1] + w[2]).max(0.1);
        let dir = random_vec(&mut rng) * travel;
        let alpha = rng.random_range(-0.2f32..1.2);
        let p = [cross - dir * alpha, cross + dir * (1.0 - alpha)];
        let t64 = tri.map(|c| c.as_dvec3());
        let n = (t64[1] - t64[0]).cross(t64[2] - t64[0]);
        let (h0, h1) = (
            n.dot(p[0].as_dvec3() - t64[0]),
            n.dot(p[1].as_dvec3() - t64[0]),
        );
        let got = vertex_face_toi(p, still(tri));
        let margin = 1e-3 * n.length() * (p[1].as_dvec3() - p[0].as_dvec3()).length();
        if h0 * h1 > 0.0 && h0.abs().min(h1.abs()) > margin {
            assert_eq!(got, None, "case {case}: stays on one side");
            continue;
        }
        if h0 == h1 {
            continue;
        }
        let t = h0 / (h0 - h1);
        let at = p[0].as_dvec3() + (p[1].as_dvec3() - p[0].as_dvec3()) * t;
        let bary = barycentric(at, &t64);
        if bary.iter().all(|&l| l > 1e-3) && (0.0..=1.0).contains(&t) {
            hits += 1;
            let got = got.unwrap_or_else(|| panic!("case {case}: missed crossing at {t}"));
            assert!(
                (got as f64 - t).abs() <= 1e-6,
                "case {case}: t = {got}, want {t} p={p:?} tri={tri:?}"
            );
        } else if bary.iter().any(|&l| l < -1e-3) {
            misses += 1;
            assert_eq!(got, None, "case {case}: passes beside the face");
        }
    }
    assert!(
        hits > 2_000 && misses > 2_000,
        "{hits} hits, {misses} misses"
    );
}

#[test]
fn random_edge_past_static_edge() {
    // e1 translates, so f(t) is linear and the lines meet at
    // t = f0 / (f0 - f1); away from the segment ends the answer is known.
    // Coordinates are quantized so that the translation is exact in f32.
    let mut rng = SmallRng::seed_from_u64(12);
    let (mut hits, mut misses) = (0, 0);
    for case in 0..20_000 {
        let scale = [1e-3f32, 1.0, 1e3][case % 3];
        let travel = [1e-6f32, 1e-3, 1.0, 1e4][(case / 3) % 4] * scale;
        let quantum = 2f32.powi(travel.min(scale).log2().floor() as i32 - 6);
        let grid = |x: Vec3| (x / quantum).round() * quantum;
        let e0 = [0; 2].map(|_| grid(scale * random_vec(&mut rng)));
        let e1 = [0; 2].map(|_| scale * random_vec(&mut rng));
        let d = grid(random_vec(&mut rng) * travel);
        let alpha = rng.random_range(-0.2f32..1.2);
        let start = e1.map(|x| grid(x - d * alpha));
        let e1 = [start, start.map(|x| x + d)];
        if e1[1][0] - e1[0][0] != d || e1[1][1] - e1[0][1] != d {
            continue; // not an exact translation in f32
        }
        let [p, q] = e0.map(|x| x.as_dvec3());
        let u = q - p;
        let f = |k: usize| {
            let [r, s] = e1[k].map(|x| x.as_dvec3());
            u.cross(s - r).dot(r - p)
        };
        let (f0, f1) = (f(0), f(1));
        let got = edge_edge_toi(still(e0), e1);
        if f0 * f1 > 0.0 || f0 == f1 {
            assert_eq!(got, None, "case {case}: never coplanar");
            continue;
        }
        let t = f0 / (f0 - f1);
        let [r, s] = e1[0].map(|x| x.as_dvec3() + d.as_dvec3() * t);
        // Line parameters of the crossing point on both segments.
        let (v, w) = (s - r, r - p);
        let n = u.cross(v);
        let a = w.cross(v).dot(n) / n.length_squared();
        let b = w.cross(u).dot(n) / n.length_squared();
        let inside = |x: f64| x > 1e-3 && x < 1.0 - 1e-3;
        let outside = |x: f64| !(-1e-3..=1.0 + 1e-3).contains(&x);
        if inside(a) && inside(b) {
            hits += 1;
            let got = got.unwrap_or_else(|| panic!("case {case}: missed crossing at {t}"));
            assert!(
                (got as f64 - t).abs() <= 1e-6,
                "case {case}: t = {got}, want {t}"
            );
        } else if outside(a) || outside(b) {
            misses += 1;
            assert_eq!(got, None, "case {case}: passes beside");
        }
    }
    assert!(
        hits > 1_000 && misses > 1_000,
        "{hits} hits, {misses} misses"
    );
}

/// Checks an elementary result against dense sampling of the exact
/// distance: no contact (distance ≤ 1e-12) at a sample before the reported
/// time, none at all if nothing is reported, and contact at the reported
/// time.
#[track_caller]
fn check_dense(case: usize, got: Option<f32>, dist: impl Fn(f64) -> f64) -> bool {
    let steps = 1000;
    let first = (0..=steps)
        .map(|k| k as f64 / steps as f64)
        .find(|&t| dist(t) <= 1e-12);
    match (got, first) {
        (None, None) => false,
        (None, Some(s)) => panic!("case {case}: contact at {s} missed"),
        (Some(t), first) => {
            let t = t as f64;
            assert!(
                dist(t) <= 1e-5,
                "case {case}: reported {t} at distance {}",
                dist(t)
            );
            if let Some(s) = first {
                assert!(
                    s >= t - 2.0 / steps as f64,
                    "case {case}: contact at {s} before reported {t}"
                );
            }
            true
        }
    }
}

#[test]
fn grid_configurations_against_dense_sampling() {
    // Corners on a coarse grid, shifted off the origin: many configurations
    // are coplanar, collinear, parallel or coincident for the whole frame,
    // or touch exactly at a corner or edge.
    let mut rng = SmallRng::seed_from_u64(13);
    let shift = v(0.1, 13.7, -5.3);
    let mut corner = || {
        shift
            + Vec3::from_array(std::array::from_fn(|_| {
                rng.random_range(-2i32..=2) as f32 * 0.3
            }))
    };
    let lerp = |x: [Vec3; 2], t: f64| x[0].as_dvec3() + (x[1].as_dvec3() - x[0].as_dvec3()) * t;
    let (mut vf, mut ee) = (0, 0);
    for case in 0..4_000 {
        let p = [corner(), corner()];
        let tri = [
            [corner(), corner(), corner()],
            [corner(), corner(), corner()],
        ];
        let dist = |t: f64| {
            let x = lerp(p, t);
            (x - closest_on_triangle(x, at(&tri, t))).length()
        };
        vf += check_dense(case, vertex_face_toi(p, tri), dist) as usize;
        let e0 = [[corner(), corner()], [corner(), corner()]];
        let e1 = [[corner(), corner()], [corner(), corner()]];
        let end = |e: [[Vec3; 2]; 2], i: usize, t: f64| lerp([e[0][i], e[1][i]], t);
        let dist =
            |t: f64| segment_distance(end(e0, 0, t), end(e0, 1, t), end(e1, 0, t), end(e1, 1, t));
        ee += check_dense(case, edge_edge_toi(e0, e1), dist) as usize;
    }
    assert!(
        vf > 300 && ee > 800,
        "{vf} vertex-face and {ee} edge-edge contacts"
    );
}

#[test]
fn pair_is_minimum_of_elementary_tests() {
    let mut rng = SmallRng::seed_from_u64(42);
    let corner = |tri: &[[Vec3; 3]; 2], i: usize| [tri[0][i], tri[1][i]];
    let edge = |tri: &[[Vec3; 3]; 2], i: usize| {
        let j = (i + 1) % 3;
        [[tri[0][i], tri[0][j]], [tri[1][i], tri[1][j]]]
    };
    let mut found = 0;
    for _ in 0..3_000 {
        let (a, b) = random_pair(&mut rng, 1.0, Vec3::ZERO, 1.0, true);
        let mut all = Vec::new();
        for i in 0..3u8 {
            let k = i as usize;
            all.push((
                vertex_face_toi(corner(&a, k), b),
                Feature::VertexFace { vertex: i },
            ));
            all.push((
                vertex_face_toi(corner(&b, k), a),
                Feature::FaceVertex { vertex: i },
            ));
            for j in 0..3u8 {
                let feature = Feature::EdgeEdge {
                    edge_a: i,
                    edge_b: j,
                };
                all.push((edge_edge_toi(edge(&a, k), edge(&b, j as usize)), feature));
            }
        }
        let min = all
            .iter()
            .filter_map(|x| x.0)
            .fold(None, |m: Option<f32>, t| Some(m.map_or(t, |m| m.min(t))));
        let hit = triangle_pair_toi(&a, &b);
        assert_eq!(hit.map(|h| h.t), min);
        if let Some(h) = hit {
            found += 1;
            assert!(
                all.contains(&(Some(h.t), h.feature)),
                "{h:?} not among {all:?}"
            );
            let back = triangle_pair_toi(&b, &a).unwrap();
            assert!((back.t - h.t).abs() <= 1e-6);
        }
    }
    assert!(found > 300);
}
