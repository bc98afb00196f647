//! Watertightness: rays from inside a closed mesh always hit it, also through shared edges and vertices.

mod common;
use common::*;
use glam::Vec3;
use kinetrace::bvh::{BuildOptions, Builder, TraversalStats};
use kinetrace::grid::{GridOptions, UniformGrid};
use kinetrace::{Hit, Mesh, MeshBvh, Ray};
use rand::Rng;

/// `n` rays from random points well inside the unit sphere in random directions; returns the misses.
fn misses_from_inside(bvh: &MeshBvh, seed: u64, n: usize) -> usize {
    let mut r = rng(seed);
    let rays: Vec<Ray> = (0..n)
        .map(|_| {
            let o = rand_dir(&mut r) * r.random_range(0.0f32..0.9);
            Ray::new(o, rand_dir(&mut r))
        })
        .collect();
    let mut hits = vec![None; n];
    bvh.closest_hits(&rays, &mut hits);
    hits.iter().filter(|h| h.is_none()).count()
}

fn closed_meshes() -> [(&'static str, Mesh); 2] {
    [
        ("icosphere", icosphere(4)),
        ("cube-sphere", cube_sphere(24)),
    ]
}

#[test]
fn a_million_rays_from_inside_never_miss() {
    for (name, m) in closed_meshes() {
        let bvh = MeshBvh::build(&m, &BuildOptions::new(Builder::SAH)).unwrap();
        assert_eq!(misses_from_inside(&bvh, 1, 1_000_000), 0, "{name}");
    }
    // The other builders on fewer rays: watertightness is the triangle test's, but traversal must not cull.
    for (name, m) in closed_meshes() {
        for b in [Builder::Median, Builder::LBVH, Builder::HYBRID] {
            let bvh = MeshBvh::build(&m, &BuildOptions::new(b).max_leaf_size(4)).unwrap();
            assert_eq!(misses_from_inside(&bvh, 2, 20_000), 0, "{name} {b:?}");
        }
    }
}

#[test]
fn rays_through_shared_vertices_and_edges_always_hit() {
    for (name, m) in closed_meshes() {
        let bvh = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
        let mut targets: Vec<Vec3> = m.positions().to_vec();
        // Directions through edge midpoints (a + b points at the midpoint's direction from the centre).
        for t in m.indices().chunks(3) {
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                targets.push(m.positions()[a as usize] + m.positions()[b as usize]);
            }
        }
        let mut r = rng(3);
        for (i, &p) in targets.iter().enumerate() {
            // From the centre: the ray passes exactly through a vertex (t = 1).
            let from_centre = Ray::new(Vec3::ZERO, p);
            let h = bvh.closest_hit(&from_centre);
            assert!(
                h.is_some(),
                "{name}: centre ray {i} through {p} slipped through"
            );
            let got = h.map(|h| (h.primitive, h.t));
            assert_brute_hit(&m, &from_centre, got, &format!("{name} {i}"));
            // From outside, aimed back at the centre through the same point.
            let outside = Ray::new(p.normalize() * 3.0, -p);
            assert!(
                bvh.any_hit(&outside),
                "{name}: outside ray {i} slipped through"
            );
            // From a random inside point towards the vertex or edge point.
            let o = rand_dir(&mut r) * r.random_range(0.0f32..0.5);
            let q = if i < m.positions().len() {
                p
            } else {
                p.normalize() * 0.999
            };
            assert!(
                bvh.any_hit(&Ray::new(o, q - o)),
                "{name}: inside ray {i} slipped through"
            );
        }
    }
}

#[test]
fn exactly_one_hit_through_a_shared_edge_of_a_grid() {
    // A flat 8x8 grid of unit squares at integer coordinates: rays straight down through grid lines and
    // grid vertices (exactly representable) must hit, and the reported triangle is the lowest index among
    // those containing the point, as brute force says.
    let n = 8u32;
    let mut pos = Vec::new();
    for y in 0..=n {
        for x in 0..=n {
            pos.push(Vec3::new(x as f32, y as f32, 0.0));
        }
    }
    let mut idx = Vec::new();
    for y in 0..n {
        for x in 0..n {
            let a = y * (n + 1) + x;
            idx.extend([a, a + 1, a + n + 2, a, a + n + 2, a + n + 1]);
        }
    }
    let m = Mesh::new(pos, idx).unwrap();
    for b in Builder::ALL {
        let bvh = MeshBvh::build(&m, &BuildOptions::new(b)).unwrap();
        for i in 1..(4 * n) {
            for j in 1..(4 * n) {
                let (x, y) = (i as f32 * 0.25, j as f32 * 0.25);
                for d in [
                    -Vec3::Z,
                    Vec3::new(0.0, 0.25, -1.0),
                    Vec3::new(-0.5, 0.0, -1.0),
                ] {
                    let ray = Ray::new(Vec3::new(x, y, 0.0) - d * 4.0, d);
                    let h = bvh.closest_hit(&ray);
                    assert!(h.is_some(), "{b:?}: ({x}, {y}) {d} slipped through");
                    // Every coordinate, shear factor and product here is a small dyadic number, so the
                    // crate's f32 arithmetic is exact and must give the exact answer, tie rule included.
                    let got = h.map(|h| (h.primitive, h.t));
                    assert_eq!(got, brute_closest(&m, &ray), "{b:?}: ({x}, {y}) {d}");
                }
            }
        }
    }
}

/// The closest hit does not depend on the tree: on tiles in axis-aligned planes, each triangle present
/// three times (as given, reversed, rotated — the same surface, whose `t` the watertight test rounds an
/// ulp or two apart), every builder, leaf size, binary or wide tree, and the uniform grid (without and with
/// its overlap test), single ray or packet, answers what brute force over every triangle with the same
/// triangle test answers (smallest `t`, then smallest index), bit for bit. The oracle shares the triangle test, not the traversal: what is checked is that
/// no traversal culls a box holding a nearer hit. Before boxes were tested against `tmax` moved outward
/// by `robust_far`'s slack, a leaf whose box face held the nearer copy was culled at the farther copy's
/// `t`, and the answer followed the visiting order.
#[test]
fn closest_hits_do_not_depend_on_the_tree() {
    use kinetrace::geometry::TriangleRay;
    let mut r = rng(19);
    let (mut pos, mut idx) = (Vec::new(), Vec::<u32>::new());
    let mut tris = Vec::new();
    for _ in 0..300 {
        // A triangle in a plane of constant x, y or z at a random height.
        let axis = r.random_range(0..3usize);
        let level = r.random_range(-2.0f32..2.0);
        let corner = |r: &mut rand::rngs::SmallRng| {
            let mut p = Vec3::new(
                r.random_range(-2.0f32..2.0),
                r.random_range(-2.0f32..2.0),
                r.random_range(-2.0f32..2.0),
            );
            p[axis] = level;
            p
        };
        let t = [corner(&mut r), corner(&mut r), corner(&mut r)];
        tris.extend([[t[0], t[1], t[2]], [t[0], t[2], t[1]], [t[1], t[2], t[0]]]);
    }
    // Copies scattered through the index order, so that they fall into different leaves.
    for i in (1..tris.len()).rev() {
        tris.swap(i, r.random_range(0..=i));
    }
    for t in &tris {
        idx.extend((0..3).map(|k| (pos.len() + k) as u32));
        pos.extend(t);
    }
    let m = Mesh::new(pos, idx).unwrap();
    let rays: Vec<Ray> = (0..4_000)
        .map(|_| {
            let o = rand_dir(&mut r) * 6.0;
            let target = Vec3::new(
                r.random_range(-2.0f32..2.0),
                r.random_range(-2.0f32..2.0),
                r.random_range(-2.0f32..2.0),
            );
            Ray::new(o, target - o)
        })
        .collect();
    let brute = |ray: &Ray| {
        let tr = TriangleRay::new(ray);
        let mut best: Option<(u32, f32)> = None;
        for (i, t) in tris.iter().enumerate() {
            if let Some(h) = tr.intersect(t[0], t[1], t[2], ray.tmin, ray.tmax)
                && best.is_none_or(|(_, bt)| h.t < bt)
            {
                best = Some((i as u32, h.t));
            }
        }
        best.map(|(i, t)| (i, t.to_bits()))
    };
    let want: Vec<_> = rays.iter().map(brute).collect();
    let hits = want.iter().filter(|w| w.is_some()).count();
    assert!(hits > rays.len() / 3, "{hits} of {} rays hit", rays.len());
    // A structure's single-ray answers (`single`) and packets of 16 (`packets`) against brute force.
    let check = |what: &str, single: &dyn Fn(&Ray) -> Option<Hit>, packets: &[Option<Hit>]| {
        let bits = |h: Option<Hit>| h.map(|h| (h.primitive, h.t.to_bits()));
        for (i, ray) in rays.iter().enumerate() {
            assert_eq!(bits(single(ray)), want[i], "{what} ray {i}: single ray");
            assert_eq!(bits(packets[i]), want[i], "{what} ray {i}: packet");
        }
    };
    for b in Builder::ALL {
        for (leaf, wide) in [(1, false), (4, false), (4, true), (8, true)] {
            let options = BuildOptions::new(b).max_leaf_size(leaf).wide(wide);
            let bvh = MeshBvh::build(&m, &options).unwrap();
            let mut packets = vec![None; rays.len()];
            bvh.closest_hits_packets(&rays, 16, &mut packets);
            let what = format!("{b:?} leaf {leaf} wide {wide}");
            check(&what, &|r| bvh.closest_hit(r), &packets);
        }
    }
    // The uniform grid, the structure the planner may choose instead, without and with its overlap test.
    for overlap_test in [false, true] {
        let options = GridOptions {
            overlap_test,
            ..Default::default()
        };
        let grid = UniformGrid::build(&m, &options).unwrap();
        let mut packets = vec![None; rays.len()];
        let mut stats = TraversalStats::default();
        for (r, out) in rays.chunks(16).zip(packets.chunks_mut(16)) {
            grid.closest_hits_packet(r, out, &mut stats);
        }
        let what = format!("grid, overlap test {overlap_test}");
        check(&what, &|r| grid.closest_hit(r), &packets);
    }
}
