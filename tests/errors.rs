//! Bad input is a clear error naming the offending entry, never a panic.

use glam::Vec3;
use kinetrace::bvh::{BuildOptions, Builder, Bvh};
use kinetrace::{Aabb, Error, Mesh, MeshBvh};

#[test]
fn mesh_errors_name_the_offending_entry() {
    let p = vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::ONE];
    let e = Mesh::new(p.clone(), vec![0, 1, 2, 0, 4, 1]).unwrap_err();
    assert_eq!(
        e,
        Error::IndexOutOfRange {
            position: 4,
            index: 4,
            vertex_count: 4
        }
    );
    assert!(
        e.to_string().contains("index 4 of the index buffer is 4"),
        "{e}"
    );

    let e = Mesh::new(p.clone(), vec![0, 1, 2, 3]).unwrap_err();
    assert_eq!(e, Error::IndexCountNotMultipleOfThree { count: 4 });

    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let mut q = p.clone();
        q[2].z = bad;
        let e = Mesh::new(q, vec![0, 1, 2]).unwrap_err();
        assert!(matches!(e, Error::NonFiniteVertex { vertex: 2, .. }), "{e}");
    }
    // Degenerate triangles are legal.
    let m = Mesh::new(p.clone(), vec![0, 0, 0, 1, 1, 2, 0, 1, 2]).unwrap();
    for b in Builder::ALL {
        MeshBvh::build(&m, &BuildOptions::new(b)).unwrap();
    }
    // with_positions checks too.
    let mut q = p.clone();
    q[0].x = f32::NAN;
    assert!(matches!(
        m.with_positions(q),
        Err(Error::NonFiniteVertex { vertex: 0, .. })
    ));
    assert!(matches!(
        m.with_positions(vec![Vec3::ZERO]),
        Err(Error::VertexCountMismatch { .. })
    ));
}

#[test]
fn option_and_box_errors() {
    let boxes = vec![Aabb::from_point(Vec3::ZERO); 4];
    for opt in [
        BuildOptions::default().max_leaf_size(0),
        BuildOptions::default().max_leaf_size(16),
        BuildOptions::new(Builder::Sah { bins: 1 }),
        BuildOptions::new(Builder::Sah { bins: 65 }),
    ] {
        assert!(
            matches!(Bvh::build(&boxes, &opt), Err(Error::InvalidOption(_))),
            "{opt:?}"
        );
    }
    let mut bad = boxes.clone();
    bad[2] = Aabb::new(Vec3::ZERO, Vec3::new(1.0, f32::INFINITY, 1.0));
    assert_eq!(
        Bvh::build(&bad, &BuildOptions::default()),
        Err(Error::NonFiniteBounds { primitive: 2 })
    );
    bad[2] = Aabb::EMPTY;
    assert_eq!(
        Bvh::build(&bad, &BuildOptions::default()),
        Err(Error::NonFiniteBounds { primitive: 2 })
    );
}
