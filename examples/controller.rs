//! A capsule character controller on a waving cloth: sweep and slide, gravity, steps — every move is a
//! capsule cast against the cloth's BVH, refitted each frame by the plugin.
//!
//! ```text
//! cargo run --release --example controller -- [--frames N] [--out DIR]
//! ```
//! The cloth (a 20 m sheet of 64 × 64 quads) waves under the character, who walks a circle of 6 m at
//! 3 m/s and climbs onto a platform (its top 0.3 m above the cloth's rest height) on the way. Writes
//! `top.png` (path over the cloth's height map) and `side.png` (height of the feet and of the ground below
//! them over time) into `DIR` (default `target/controller`), and prints how far the capsule ever sank into
//! the surface.

use bevy_ecs::prelude::*;
use glam::{Affine3A, Vec3};
use kinetrace::ecs::*;
use kinetrace::queries::Shape;
use kinetrace::{Mesh, Ray};

const CLOTH: u32 = 64;
const SIZE: f32 = 20.0;
const DT: f32 = 1.0 / 60.0;
const RADIUS: f32 = 0.4;
/// Capsule core from the feet sphere's centre up.
const HEIGHT: f32 = 1.0;
const SKIN: f32 = 0.01;
const STEP: f32 = 0.5;
const GRAVITY: f32 = 9.81;

/// The cloth's height at `(x, z)` and time `t`: two travelling waves.
fn wave(x: f32, z: f32, t: f32) -> f32 {
    0.25 * (0.6 * x - 1.5 * t).sin() + 0.15 * (0.8 * z + 0.5 * x + 1.1 * t).cos()
}

fn cloth(t: f32) -> Vec<Vec3> {
    let n = CLOTH + 1;
    (0..n * n)
        .map(|k| {
            let (i, j) = (k % n, k / n);
            let x = (i as f32 / CLOTH as f32 - 0.5) * SIZE;
            let z = (j as f32 / CLOTH as f32 - 0.5) * SIZE;
            Vec3::new(x, wave(x, z, t), z)
        })
        .collect()
}

fn cloth_mesh() -> Mesh {
    let n = CLOTH + 1;
    let mut idx = Vec::new();
    for j in 0..CLOTH {
        for i in 0..CLOTH {
            let a = j * n + i;
            idx.extend([a, a + n, a + 1, a + 1, a + n, a + n + 1]);
        }
    }
    Mesh::new(cloth(0.0), idx).expect("finite")
}

#[derive(Resource, Default)]
struct Character {
    /// Centre of the feet sphere.
    feet: Vec3,
    vertical_speed: f32,
    grounded: bool,
    time: f32,
    /// Per frame: feet centre, ground height below, deepest penetration found after the move.
    path: Vec<(Vec3, f32, f32)>,
}

#[derive(Resource)]
struct Cloth(Entity);

fn capsule(feet: Vec3) -> Shape {
    Shape::capsule(feet, feet + Vec3::Y * HEIGHT, RADIUS)
}

/// Moves the capsule by `motion`, sliding along what it touches: cast, stop `SKIN` short, drop the part of
/// the rest of the motion that points into the surface, repeat (at most four contacts per move).
fn slide(rays: &SpatialRays, mut feet: Vec3, mut motion: Vec3) -> (Vec3, Option<ShapeHit>) {
    let mut last = None;
    for _ in 0..4 {
        let len = motion.length();
        if len < 1e-6 {
            break;
        }
        let dir = motion / len;
        let filter = QueryFilter::default();
        match rays.cast_shape(&capsule(feet), dir, len + SKIN, &filter) {
            None => return (feet + motion, last),
            Some(hit) => {
                let advance = (hit.distance - SKIN).max(0.0).min(len);
                feet += dir * advance;
                motion = dir * (len - advance);
                motion -= hit.normal * motion.dot(hit.normal).min(0.0);
                last = Some(hit);
            }
        }
    }
    (feet, last)
}

/// Pushes the capsule out of a surface that moved into it (the cloth rises): the feet sphere away from
/// its nearest point until it is `SKIN` clear.
fn depenetrate(rays: &SpatialRays, mut feet: Vec3) -> Vec3 {
    for _ in 0..4 {
        match rays.closest_point(feet, RADIUS + SKIN, &QueryFilter::default()) {
            Some(near) if near.distance < RADIUS + SKIN * 0.5 => {
                let away = (feet - near.point).normalize_or(Vec3::Y);
                feet += away * (RADIUS + SKIN - near.distance);
            }
            _ => break,
        }
    }
    feet
}

fn walk(rays: SpatialRays, mut ch: ResMut<Character>) {
    ch.time += DT;
    let mut feet = depenetrate(&rays, ch.feet);
    // Walk tangentially along a circle of 6 m, pulled back onto it.
    let flat = Vec3::new(feet.x, 0.0, feet.z);
    let tangent = Vec3::new(-flat.z, 0.0, flat.x).normalize_or(Vec3::X);
    let pull = (6.0 - flat.length()) * flat.normalize_or(Vec3::X);
    let step = (tangent * 3.0 + pull) * DT;
    // Step up: try the move from `STEP` higher, then settle down onto what is below.
    let (low, blocked) = slide(&rays, feet, step);
    let (up, _) = slide(&rays, feet, Vec3::Y * STEP);
    let (high, _) = slide(&rays, up, step);
    let (high, _) = slide(&rays, high, -Vec3::Y * (up.y - feet.y));
    let steep = blocked.is_some_and(|h| h.normal.y < 0.7);
    let across = |p: Vec3| (p - feet).with_y(0.0).length_squared();
    feet = if steep && across(high) > across(low) {
        high
    } else {
        low
    };
    // Gravity: fall, landing on what the downward cast meets.
    ch.vertical_speed -= GRAVITY * DT;
    let fall = Vec3::Y * (ch.vertical_speed * DT).min(-SKIN);
    let (landed, ground) = slide(&rays, feet, fall);
    ch.grounded = ground.is_some_and(|h| h.normal.y > 0.5);
    if ch.grounded {
        ch.vertical_speed = 0.0;
    }
    feet = landed;
    ch.feet = feet;
    let below = rays
        .cast_ray(
            &Ray::new(feet + Vec3::Y * 5.0, -Vec3::Y),
            20.0,
            &QueryFilter::default(),
        )
        .map_or(f32::NAN, |h| h.point.y);
    let sink = rays
        .closest_point(feet, RADIUS, &QueryFilter::default())
        .map_or(0.0, |n| (RADIUS - n.distance).max(0.0));
    ch.path.push((feet, below, sink));
}

fn wave_cloth(sheet: Res<Cloth>, ch: Res<Character>, mut q: Query<&mut VertexPositions>) {
    if let Ok(mut vp) = q.get_mut(sheet.0) {
        vp.0 = cloth(ch.time);
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut frames = 900;
    let mut out = std::path::PathBuf::from("target/controller");
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match (a.as_str(), args.next()) {
            ("--frames", Some(v)) => frames = v.parse()?,
            ("--out", Some(v)) => out = v.into(),
            _ => {
                eprintln!("usage: controller [--frames N] [--out DIR]");
                std::process::exit(2);
            }
        }
    }
    let mut world = World::new();
    let mut schedule = Schedule::default();
    KinetracePlugin::default().build(&mut world, &mut schedule);
    let sheet = cloth_mesh();
    let e = world
        .spawn((TraceMesh(sheet.clone()), VertexPositions(cloth(0.0))))
        .id();
    let platform = Vec3::new(1.5, 0.15, 1.5);
    world.spawn((
        TraceMesh(kinetrace::scenes::shoebox(-platform, platform)),
        MotionHint::Rigid,
        TraceTransform(Affine3A::from_translation(Vec3::new(0.0, 0.15, 6.0))),
    ));
    world.insert_resource(Cloth(e));
    world.insert_resource(Character {
        feet: Vec3::new(6.0, 2.0, 0.0),
        ..Default::default()
    });
    schedule.add_systems((
        wave_cloth.before(TraceSystems::Maintain),
        walk.after(TraceSystems::TopLevel)
            .before(TraceSystems::Queries),
    ));
    let start = std::time::Instant::now();
    for _ in 0..frames {
        schedule.run(&mut world);
        world.clear_trackers();
    }
    let elapsed = start.elapsed();
    let ch = world.resource::<Character>();
    let deepest = ch.path.iter().map(|p| p.2).fold(0.0, f32::max);
    let clearance = ch
        .path
        .iter()
        .filter(|p| p.1.is_finite())
        .map(|p| p.0.y - RADIUS - p.1)
        .fold(f32::INFINITY, f32::min);
    println!(
        "{frames} frames in {:.1} ms ({:.3} ms/frame, cloth {} triangles refitted each frame)",
        elapsed.as_secs_f64() * 1e3,
        elapsed.as_secs_f64() * 1e3 / frames as f64,
        sheet.triangle_count()
    );
    println!(
        "deepest penetration after a move {deepest:.4} m; least feet clearance above the ground below \
         {clearance:.4} m; grounded at the end: {}",
        ch.grounded
    );
    std::fs::create_dir_all(&out)?;
    plot(&ch.path, &out)?;
    println!("wrote {0}/top.png and {0}/side.png", out.display());
    Ok(())
}

/// Top view (x right, z down) of the path over the final cloth's heights, and side view (time right,
/// height up) of the feet and of the ground below them.
fn plot(path: &[(Vec3, f32, f32)], out: &std::path::Path) -> image::ImageResult<()> {
    use image::{Rgb, RgbImage};
    let px = 512u32;
    let mut top = RgbImage::new(px, px);
    let t_end = path.len() as f32 * DT;
    let to_px = |v: f32| ((v / SIZE + 0.5) * px as f32) as i64;
    for (x, y, p) in top.enumerate_pixels_mut() {
        let (wx, wz) = (
            (x as f32 / px as f32 - 0.5) * SIZE,
            (y as f32 / px as f32 - 0.5) * SIZE,
        );
        let h = ((wave(wx, wz, t_end) + 0.45) / 0.9 * 200.0) as u8;
        *p = Rgb([h / 3, h / 2, h]);
    }
    for (k, (feet, ..)) in path.iter().enumerate() {
        let (x, y) = (to_px(feet.x), to_px(feet.z));
        let c = (k * 255 / path.len().max(1)) as u8;
        for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            if let Some(p) = top.get_pixel_mut_checked((x + dx) as u32, (y + dy) as u32) {
                *p = Rgb([255, c, 255 - c]);
            }
        }
    }
    top.save(out.join("top.png"))?;
    let (w, h) = (1024u32, 256u32);
    let mut side = RgbImage::from_pixel(w, h, Rgb([20, 20, 30]));
    let ys = path
        .iter()
        .flat_map(|p| [p.0.y - RADIUS, p.1])
        .filter(|v| v.is_finite());
    let (lo, hi) = ys.fold((f32::MAX, f32::MIN), |(a, b), v| (a.min(v), b.max(v)));
    let to_y = |v: f32| (h as f32 - 1.0 - (v - lo) / (hi - lo).max(1e-3) * (h as f32 - 1.0)) as u32;
    for (k, (feet, below, _)) in path.iter().enumerate() {
        let x = (k as u64 * w as u64 / path.len().max(1) as u64) as u32;
        if below.is_finite() {
            side.put_pixel(x, to_y(*below).min(h - 1), Rgb([80, 160, 255]));
        }
        side.put_pixel(x, to_y(feet.y - RADIUS).min(h - 1), Rgb([255, 200, 40]));
    }
    side.save(out.join("side.png"))
}
