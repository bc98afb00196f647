//! Sound propagation in a room with 16 walking characters, through the ECS: per frame the characters'
//! entities move, the plugin updates the top level, and its sound system traces the specular paths up to
//! order 3 from the [`SoundSource`] to the [`Listener`] into [`SoundPaths`]. Prints the
//! paths and the time per update, and writes the per-band impulse response as a PNG.
//!
//! `cargo run --release --example sound -- [--frames N] [--sampling N] [--primary M] [--out PATH]`
//! (defaults: 10 frames, [`SoundConfig::default`]'s sampling and primary frusta, `sound_ir.png`).

use bevy_ecs::prelude::*;
use glam::{Affine3A, Quat, Vec3};
use kinetrace::ecs::{
    AcousticSurface, KinetracePlugin, Listener, SoundPaths, SoundSettings, SoundSource, TraceMesh,
    TraceTransform,
};
use kinetrace::scenes;
use kinetrace::sound::{AcousticMaterial, BAND_HZ, BANDS, SoundConfig, SoundPath};
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};
use std::time::Instant;

const ROOM: Vec3 = Vec3::new(10.0, 8.0, 3.5);
const CHARACTERS: usize = 16;

/// Where character `k` stands at time `t` seconds (a body scaled into a 0.5 × 0.3 × 1.8 m ellipsoid).
fn character_at(k: usize, t: f32) -> Affine3A {
    let phase = k as f32 * 0.7;
    let home = Vec3::new(1.5 + (k % 4) as f32 * 2.3, 1.3 + (k / 4) as f32 * 1.8, 0.9);
    let at = home + 0.6 * Vec3::new((t + phase).cos(), (1.3 * t + phase).sin(), 0.0);
    Affine3A::from_scale_rotation_translation(Vec3::new(0.25, 0.15, 0.9), Quat::IDENTITY, at)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut frames = 10;
    let mut out = String::from("sound_ir.png");
    let mut config = SoundConfig::default();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--frames" => frames = args.next().ok_or("--frames N")?.parse()?,
            "--out" => out = args.next().ok_or("--out PATH")?,
            "--sampling" => config.sampling = args.next().ok_or("--sampling N")?.parse()?,
            "--primary" => config.primary = args.next().ok_or("--primary M")?.parse()?,
            _ => return Err(format!("unknown argument {a}").into()),
        }
    }
    let plaster =
        AcousticMaterial::new([0.01, 0.01, 0.02, 0.02, 0.03, 0.04, 0.05, 0.06, 0.07, 0.08])?;
    let cloth = AcousticMaterial::new([0.02, 0.05, 0.1, 0.2, 0.35, 0.5, 0.6, 0.65, 0.7, 0.7])?;
    let mut world = World::new();
    let mut schedule = Schedule::default();
    schedule.set_executor(bevy_ecs::schedule::SingleThreadedExecutor::new());
    KinetracePlugin::default().try_build(&mut world, &mut schedule)?;
    world.insert_resource(SoundSettings {
        config,
        ..Default::default()
    });
    // The room (plaster) and the characters (clothing): one shared body mesh, each its own entity.
    let room = scenes::shoebox(Vec3::ZERO, ROOM);
    let body = scenes::cube_sphere(11);
    world.spawn((TraceMesh(room.clone()), AcousticSurface(plaster)));
    let characters: Vec<Entity> = (0..CHARACTERS)
        .map(|k| {
            let t = TraceTransform(character_at(k, 0.0));
            world
                .spawn((TraceMesh(body.clone()), t, AcousticSurface(cloth)))
                .id()
        })
        .collect();
    let (source, listener) = (Vec3::new(0.8, 0.7, 1.7), Vec3::new(9.1, 7.2, 1.6));
    world.spawn(SoundSource(source));
    world.spawn(Listener(listener));
    println!(
        "{} triangles, {CHARACTERS} characters, order {}, {}² primary frusta per face, {}² samples",
        room.triangle_count() + CHARACTERS * body.triangle_count(),
        config.max_order,
        config.primary,
        config.sampling
    );
    for f in 0..frames {
        for (k, &e) in characters.iter().enumerate() {
            world.get_mut::<TraceTransform>(e).ok_or("character")?.0 =
                character_at(k, f as f32 * 0.1);
        }
        let start = Instant::now();
        schedule.run(&mut world);
        world.clear_trackers();
        let ms = start.elapsed().as_secs_f64() * 1e3;
        let pair = &world.resource::<SoundPaths>().pairs[0];
        println!(
            "frame {f}: {} paths from {} frusta in {ms:.1} ms (whole frame)",
            pair.paths.len(),
            pair.frusta
        );
    }
    let Some(pair) = world.resource::<SoundPaths>().pairs.first() else {
        return Ok(());
    };
    for p in &pair.paths {
        println!(
            "order {} delay {:6.2} ms from ({:+.2} {:+.2} {:+.2}) level {:6.1} dB @1 kHz, surfaces {:?}",
            p.order,
            p.delay * 1e3,
            p.direction.x,
            p.direction.y,
            p.direction.z,
            10.0 * p.attenuation[6].log10(),
            p.surfaces
        );
    }
    plot(&out, &pair.paths)?;
    println!("wrote {out}");
    Ok(())
}

/// One panel per band: each path a stem at its delay, its height the level in dB.
fn plot(path: &str, paths: &[SoundPath]) -> Result<(), Box<dyn std::error::Error>> {
    register_font(
        "sans-serif",
        FontStyle::Normal,
        include_bytes!("report/fonts/Go-Regular.ttf"),
    )
    .map_err(|_| "embedded font")?;
    let size = (1400u32, 1500u32);
    let mut pixels = vec![0u8; (size.0 * size.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, size).into_drawing_area();
        root.fill(&WHITE)?;
        let root = root.titled(
            "Impulse response per octave band (specular paths, order ≤ 3)",
            ("sans-serif", 26),
        )?;
        let t_max = paths.iter().map(|p| p.delay * 1e3).fold(1.0f32, f32::max) * 1.05;
        let db = |p: &SoundPath, b: usize| 10.0 * p.attenuation[b].max(1e-12).log10();
        let lo = (0..BANDS)
            .flat_map(|b| paths.iter().map(move |p| db(p, b)))
            .fold(0.0f32, f32::min)
            - 3.0;
        let hi = (0..BANDS)
            .flat_map(|b| paths.iter().map(move |p| db(p, b)))
            .fold(lo, f32::max)
            + 3.0;
        for (b, area) in root.split_evenly((5, 2)).iter().enumerate() {
            let mut chart = ChartBuilder::on(area)
                .caption(format!("{} Hz", BAND_HZ[b]), ("sans-serif", 18))
                .margin(8)
                .x_label_area_size(36)
                .y_label_area_size(56)
                .build_cartesian_2d(0f32..t_max, lo..hi)?;
            chart
                .configure_mesh()
                .x_desc("delay (ms)")
                .y_desc("level (dB re 1 m)")
                .label_style(("sans-serif", 13))
                .draw()?;
            let colour = Palette99::pick(b).to_rgba();
            chart.draw_series(paths.iter().map(|p| {
                let t = p.delay * 1e3;
                PathElement::new(vec![(t, lo), (t, db(p, b))], colour.stroke_width(2))
            }))?;
        }
        root.present()?;
    }
    image::RgbImage::from_raw(size.0, size.1, pixels)
        .ok_or("buffer size")?
        .save(path)?;
    Ok(())
}
