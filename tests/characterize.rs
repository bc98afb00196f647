//! The scene characteriser on distributions whose answer is known.

use glam::Vec3;
use kinetrace::Mesh;
use kinetrace::characterize::profile_mesh;
use kinetrace::scenes::SceneRng;

/// Small triangles around the given centres.
fn mesh_at(centres: &[Vec3]) -> Mesh {
    let mut pos = Vec::new();
    for &c in centres {
        pos.extend([
            c,
            c + Vec3::new(1e-3, 0.0, 0.0),
            c + Vec3::new(0.0, 1e-3, 0.0),
        ]);
    }
    Mesh::new(pos, (0..3 * centres.len() as u32).collect::<Vec<_>>()).unwrap()
}

/// A standard normal sample (Box–Muller).
fn gauss(r: &mut SceneRng) -> f32 {
    let (u, v) = (r.unit().max(1e-7), r.unit());
    (-2.0 * u.ln()).sqrt() * (std::f32::consts::TAU * v).cos()
}

#[test]
fn uniform_soup_is_uniform() {
    let mut r = SceneRng::new(1);
    let n = 50_000;
    let centres: Vec<Vec3> = (0..n).map(|_| r.vec3(0.0, 1.0)).collect();
    let p = profile_mesh(&mesh_at(&centres));
    assert_eq!(p.primitives, n);
    assert!(p.bins as f64 >= 1.0 + (n as f64).log2(), "k = {}", p.bins);
    assert_eq!(p.histogram.iter().sum::<u32>() as usize, n);
    assert!(p.uniform, "χ² {} > {}", p.chi_square, p.chi_square_critical);
    assert_eq!(p.empty_bins, 0);
    assert!(p.size_spread < 0.01, "equal triangles: {}", p.size_spread);
}

#[test]
fn gaussian_clusters_are_not_uniform() {
    let mut r = SceneRng::new(2);
    let centres: Vec<Vec3> = (0..5).map(|_| r.vec3(0.2, 0.8)).collect();
    let pts: Vec<Vec3> = (0..40_000)
        .map(|i| centres[i % 5] + Vec3::new(gauss(&mut r), gauss(&mut r), gauss(&mut r)) * 0.04)
        .collect();
    let p = profile_mesh(&mesh_at(&pts));
    assert!(
        !p.uniform,
        "χ² {} ≤ {}",
        p.chi_square, p.chi_square_critical
    );
    assert!(p.overfull_bins > 0);
    assert!(p.bins as f64 >= 1.0 + (40_000f64).log2());
}

#[test]
fn two_distant_clusters_leave_empty_bins() {
    let mut r = SceneRng::new(3);
    let pts: Vec<Vec3> = (0..20_000)
        .map(|i| {
            let c = if i % 2 == 0 {
                Vec3::ZERO
            } else {
                Vec3::splat(100.0)
            };
            c + r.vec3(-0.5, 0.5)
        })
        .collect();
    let p = profile_mesh(&mesh_at(&pts));
    assert!(!p.uniform);
    assert!(p.empty_bins > 0, "{:?}", p.histogram);
    // Mixed triangle sizes are seen as spread.
    let mut big = pts.clone();
    big.truncate(100);
    let mut pos = Vec::new();
    for (i, c) in big.iter().enumerate() {
        let s = if i % 10 == 0 { 50.0 } else { 0.01 };
        pos.extend([*c, *c + Vec3::new(s, 0.0, 0.0), *c + Vec3::new(0.0, s, 0.0)]);
    }
    let mixed = Mesh::new(pos, (0..300u32).collect::<Vec<_>>()).unwrap();
    assert!(profile_mesh(&mixed).size_spread > 2.0);
}

#[test]
fn tiny_and_degenerate_inputs() {
    let empty = Mesh::new(Vec::<Vec3>::new(), Vec::<u32>::new()).unwrap();
    let p = profile_mesh(&empty);
    assert_eq!((p.primitives, p.bins, p.histogram.len()), (0, 1, 1));
    let same = mesh_at(&[Vec3::ONE; 10]);
    let p = profile_mesh(&same);
    assert_eq!(p.histogram.iter().sum::<u32>(), 10);
    assert!(p.chi_square.is_finite());
}
