//! The main demo until the skinned crowd arrives: a mesh that deforms every frame, kept current by refit
//! with Lauterbach's rebuild criterion, and ray traced to the terminal.
//!
//! ```text
//! cargo run --release --example quickstart -- [--frames N] [--triangles N]
//! ```
//! Each frame the torus is twisted and rippled; the BVH is refitted, and rebuilt with LBVH when the
//! degradation metric passes 0.40. Every 20 frames a small image is ray traced (closest hit + a shadow
//! ray to the sun per pixel) and printed as text, with the frame's timings.

use glam::Vec3;
use kinetrace::prelude::*;
use kinetrace::scenes::bumpy_torus;
use std::time::Instant;

const REBUILD_THRESHOLD: f32 = 0.40;

fn main() -> Result<()> {
    let mut frames = 120;
    let mut triangles = 200_000;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let value = args.next().and_then(|v| v.parse().ok());
        match (a.as_str(), value) {
            ("--frames", Some(v)) => frames = v,
            ("--triangles", Some(v)) => triangles = v,
            _ => {
                eprintln!("usage: quickstart [--frames N] [--triangles N]");
                std::process::exit(2);
            }
        }
    }
    let rest = bumpy_torus(triangles);
    let mut mesh = rest.clone();
    let t0 = Instant::now();
    let mut bvh = MeshBvh::build(&mesh, &BuildOptions::new(Builder::SAH))?;
    println!(
        "{} triangles, SAH build {:.1} ms",
        mesh.triangle_count(),
        t0.elapsed().as_secs_f64() * 1e3
    );
    let (mut refits, mut rebuilds) = (0, 0);
    for frame in 0..frames {
        let time = frame as f32 / 30.0;
        let pos: Vec<Vec3> = rest.positions().iter().map(|&p| deform(p, time)).collect();
        let t = Instant::now();
        let degradation = bvh.refit(&pos)?;
        refits += 1;
        let mut action = "refit";
        if degradation > REBUILD_THRESHOLD {
            mesh = mesh.with_positions(pos)?;
            bvh = MeshBvh::build(&mesh, &BuildOptions::new(Builder::LBVH))?;
            rebuilds += 1;
            action = "rebuild";
        }
        let update_ms = t.elapsed().as_secs_f64() * 1e3;
        if frame % 20 == 0 || frame + 1 == frames {
            let t = Instant::now();
            let image = render(&bvh, 64, 28);
            println!(
                "\nframe {frame}: {action} {update_ms:.2} ms (degradation {degradation:.3}), render {:.1} ms",
                t.elapsed().as_secs_f64() * 1e3
            );
            println!("{image}");
        }
    }
    println!("{frames} frames: {refits} refits, {rebuilds} rebuilds");
    Ok(())
}

/// Twist about the y axis growing with time, plus a travelling ripple.
fn deform(p: Vec3, time: f32) -> Vec3 {
    let angle = 0.6 * (time * 0.7).sin() * p.x;
    let (s, c) = angle.sin_cos();
    let q = Vec3::new(p.x, p.y * c - p.z * s, p.y * s + p.z * c);
    q + Vec3::Y * 0.06 * (4.0 * p.x + 3.0 * time).sin()
}

/// Closest hit per pixel, Lambert shading, and a shadow ray towards the sun.
fn render(bvh: &MeshBvh, w: usize, h: usize) -> String {
    let sun = Vec3::new(0.4, 1.0, 0.3).normalize();
    let eye = Vec3::new(0.0, 1.6, -2.6);
    let fwd = (-eye).normalize();
    let right = fwd.cross(Vec3::Y).normalize();
    let up = right.cross(fwd);
    let rays: Vec<Ray> = (0..w * h)
        .map(|i| {
            let x = (i % w) as f32 / w as f32 - 0.5;
            let y = 0.5 - (i / w) as f32 / h as f32;
            Ray::new(eye, fwd + right * x * 1.4 + up * y * 1.2)
        })
        .collect();
    let mut hits = vec![None; rays.len()];
    bvh.closest_hits(&rays, &mut hits);
    let ramp = b" .:-=+*#%@";
    let mut out = String::new();
    for (i, (ray, hit)) in rays.iter().zip(&hits).enumerate() {
        let c = match hit {
            None => b' ',
            Some(hit) => {
                let p = ray.at(hit.t);
                let n = if hit.normal.dot(ray.dir()) > 0.0 {
                    -hit.normal
                } else {
                    hit.normal
                };
                let shadowed = bvh.any_hit(&Ray::with_range(p + n * 1e-4, sun, 0.0, 10.0));
                let light = if shadowed {
                    0.1
                } else {
                    0.1 + 0.9 * n.dot(sun).max(0.0)
                };
                ramp[((light * (ramp.len() - 1) as f32).round() as usize).min(ramp.len() - 1)]
            }
        };
        out.push(c as char);
        if i % w == w - 1 {
            out.push('\n');
        }
    }
    out
}
