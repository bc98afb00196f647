//! The main demo: a crowd of skinned, animated characters walking on a ground, their trees kept current
//! every frame, queried by gameplay systems, and ray traced to PNG.
//!
//! ```text
//! cargo run --release --example crowd -- [--characters 64] [--triangles 10000] [--frames 600]
//!                                         [--cpu] [--png-every 120] [--out target/crowd]
//!                                         [--shadows map|selective|traced] [--soft RAD]
//! ```
//! Gameplay each frame: every character checks line of sight (shadow rays, batched) to its two nearest
//! neighbours and probes the ground under it (immediate ray); a turret sweeps the crowd and reports which
//! character, triangle and joint its ray hits. Characters are colliders: when two bump into each other
//! (their skinned meshes touch), a gameplay system reads the `CollisionStarted` message and the contacts
//! (triangles, point, depth). A probe camera of 48×27 rays casts, from every primary hit, a shadow ray
//! toward each of two lights and one reflection ray, queued as secondary kinds: the planner picks per
//! batch how they are traced (BVH, sorted BVH or CRSH, see `SecondaryRays`), printed once per simulated
//! second with the table line. Once per simulated second a table line shows the frame time by
//! phase, refits, rebuilds and queries; every `--png-every` frames the scene is ray traced from a camera with
//! shadows from the sun (`--shadows`: shadow map alone, selective ray-traced — the default — or a shadow
//! ray per pixel, see `kinetrace::shadows`; `--soft RAD` makes the sun a disc of that angular radius with soft
//! shadows), the turret's hits marked red; camera rays go as 8×8 packets or ray by ray, whichever the
//! planner measured faster on this scene (see `primary_hits`), and with a GPU the shadow map is rendered
//! (and the hard selective pass's pixels classified) there or on the CPU, the same map and classes,
//! whichever the planner measured faster (see `sun_visibility`). Batched queries run on the GPU when one
//! is found (`--cpu` keeps them on the CPU).

use bevy_ecs::prelude::*;
use glam::{Affine3A, Quat, Vec2, Vec3};
use kinetrace::adaptive::Choice;
use kinetrace::anim::humanoid;
use kinetrace::ecs::*;
use kinetrace::shadows::{
    CpuMap, GBuffer, HardShadows, Interleaved, MapRenderer, Occluders, Packets, ShadowMode,
    ShadowSettings,
};
use kinetrace::{Mesh, Ray};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// What to run.
#[derive(Clone, Debug)]
pub struct Options {
    /// Characters in the crowd.
    pub characters: usize,
    /// Triangles per character.
    pub triangles: usize,
    /// Frames to simulate (at 60 per simulated second).
    pub frames: usize,
    /// Batched queries on the GPU when there is one.
    pub gpu: bool,
    /// The GPU-resident frame (`TraceConfig::resident`; implies `gpu`).
    pub resident: bool,
    /// Write a PNG every this many frames (0: never), and after the last frame.
    pub png_every: usize,
    /// Where the PNGs go.
    pub out: PathBuf,
    /// Image size.
    pub width: u32,
    /// Image size.
    pub height: u32,
    /// How the images' shadows are computed.
    pub shadows: ShadowMode,
    /// The sun's angular radius in radians: 0 casts hard shadows, above 0 soft ones (at most 0.5).
    pub sun_angle: f32,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            characters: 64,
            triangles: 10_000,
            frames: 600,
            gpu: true,
            resident: false,
            png_every: 120,
            out: PathBuf::from("target/crowd"),
            width: 480,
            height: 270,
            shadows: ShadowMode::Selective,
            sun_angle: 0.0,
        }
    }
}

/// What a run did, for the caller (and the integration test).
#[derive(Debug, Default)]
pub struct Summary {
    /// PNG files written.
    pub pngs: Vec<PathBuf>,
    /// Frames whose ground probe found the ground under every character.
    pub grounded_frames: usize,
    /// Turret rays that hit a character.
    pub turret_hits: usize,
    /// Line-of-sight checks answered.
    pub sight_checks: usize,
    /// Secondary requests (shadow rays toward the two lights, reflection rays) answered.
    pub secondary_rays: usize,
    /// Rebuilds and refits over the run.
    pub rebuilds: usize,
    /// Refits over the run.
    pub refits: usize,
    /// Collision episodes between characters (a `CollisionStarted` message each).
    pub bumps: usize,
}

const CHARACTERS: u32 = 1 << 0;
const GROUND: u32 = 1 << 1;
const DT: f32 = 1.0 / 60.0;
/// Tags of the probe's secondary requests start here (line-of-sight tags are below).
const SECONDARY: u64 = 1 << 32;
/// The probe camera's rays across and down.
const PROBE: (u32, u32) = (48, 27);
/// The two lights of the probe's shadow rays: a high sun-like light and a lamp over the crowd.
const LIGHTS: [Vec3; 2] = [Vec3::new(20.0, 40.0, -10.0), Vec3::new(-6.0, 6.0, 4.0)];

/// A character's own state, its placement included: the plugin follows it into the trace transform
/// (`sync_transforms`), so gameplay never writes `TraceTransform`.
#[derive(Component)]
struct Walker {
    pos: Vec2,
    heading: f32,
    speed: f32,
    turn: f32,
}

impl Walker {
    /// Standing at `pos` on the ground, facing `heading`.
    fn affine(&self) -> Affine3A {
        Affine3A::from_rotation_translation(
            Quat::from_rotation_y(self.heading),
            Vec3::new(self.pos.x, 0.0, self.pos.y),
        )
    }
}

/// The GPU's shadow-map renderer (without the `gpu` feature there is none, and this type is never made).
#[cfg(feature = "gpu")]
type GpuMap = kinetrace::gpu::GpuShadowMap;
#[cfg(not(feature = "gpu"))]
type GpuMap = CpuMap;

/// The GPU's shadow-map renderer where the queries found a GPU whose kernels round as the CPU does (its
/// map then equals the CPU's, so the planner may switch between them without the image changing).
fn gpu_map(world: &World) -> Option<Mutex<GpuMap>> {
    #[cfg(feature = "gpu")]
    return (world.get_resource::<GpuQueries>())
        .map(GpuQueries::context)
        .filter(|ctx| ctx.contraction_free())
        .map(|ctx| Mutex::new(GpuMap::new(ctx)));
    #[cfg(not(feature = "gpu"))]
    {
        let _ = world;
        None
    }
}

#[derive(Resource)]
struct Crowd {
    summary: Summary,
    turret_marks: Vec<Vec3>,
    shadows: ShadowMode,
    sun_angle: f32,
    /// Whether camera rays go as 8×8 packets or ray by ray: the planner's choice, learned from the
    /// seconds per ray each way measured on groups of the images' tiles (see [`primary_hits`]).
    camera_packets: Mutex<Choice<bool>>,
    /// Whether a pass's shadow rays go as packets (the rays of one 8×8 block of pixels together) or as
    /// single rays (walked four at a time, interleaved): the planner's choice, learned from the seconds
    /// per pixel that got rays each way measured on the passes so far, one for each of a selective
    /// pass's marked pixels and a ray-traced pass's pixels, hard and soft (see [`sun_visibility_with`]).
    ray_packets: Mutex<[PassRays; 4]>,
    /// With a GPU: its shadow-map renderer, and whether a pass renders its map there or on the CPU —
    /// the planner's choice, learned from the seconds per occluder triangle each way (see
    /// [`sun_visibility`]).
    gpu_map: Option<Mutex<GpuMap>>,
    map_on_gpu: Mutex<Choice<bool>>,
}

/// The images' shadow mode and the sun's angular radius (see [`Options`]), to switch them between frames.
pub fn shadows_mut(world: &mut World) -> (&mut ShadowMode, &mut f32) {
    let crowd = world.resource_mut::<Crowd>().into_inner();
    (&mut crowd.shadows, &mut crowd.sun_angle)
}

/// Moves every walker: forward along its heading, turning gently, pushed apart from near neighbours and
/// kept inside the arena.
fn walk(mut q: Query<(Entity, &mut Walker)>) {
    let snapshot: Vec<(Entity, Vec2)> = q.iter().map(|(e, w)| (e, w.pos)).collect();
    for (e, mut w) in &mut q {
        let mut push = Vec2::ZERO;
        for &(o, p) in &snapshot {
            let d = w.pos - p;
            if o != e && d.length_squared() < 0.8 * 0.8 && d.length_squared() > 1e-8 {
                push += d.normalize() * (0.8 - d.length());
            }
        }
        let home = -w.pos * (w.pos.length() - 12.0).max(0.0) * 0.05;
        w.heading += w.turn * DT;
        let dir = Vec2::new(w.heading.sin(), w.heading.cos());
        let step = dir * w.speed * DT + push * 0.5 + home * DT;
        w.pos += step;
    }
}

/// Line of sight to the two nearest neighbours (batched occlusion) and a ground probe (immediate).
fn look_and_probe(
    walkers: Query<(Entity, &Walker)>,
    rays: SpatialRays,
    mut queue: ResMut<RayQueue>,
    mut crowd: ResMut<Crowd>,
) {
    let all: Vec<(Entity, Vec2)> = walkers.iter().map(|(e, w)| (e, w.pos)).collect();
    let mut grounded = true;
    for (i, &(e, p)) in all.iter().enumerate() {
        let mut near: Vec<(f32, Vec2)> = all
            .iter()
            .filter(|(o, _)| *o != e)
            .map(|(_, q)| ((*q - p).length_squared(), *q))
            .collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0));
        let eye = Vec3::new(p.x, 1.7, p.y);
        for (k, (_, q)) in near.iter().take(2).enumerate() {
            let target = Vec3::new(q.x, 1.7, q.y);
            // Stop short of the neighbour's head: we ask whether anyone else is in between.
            let to = target - (target - eye).normalize_or_zero() * 0.35;
            queue.shadow(
                (i * 2 + k) as u64,
                eye,
                to,
                QueryFilter::default().layers(CHARACTERS).exclude(e),
            );
        }
        let probe = Ray::new(Vec3::new(p.x, 1.0, p.y), -Vec3::Y);
        grounded &= rays
            .cast_ray(&probe, 5.0, &QueryFilter::default().layers(GROUND))
            .is_some_and(|h| (h.distance - 1.0).abs() < 0.01);
    }
    crowd.summary.grounded_frames += grounded as usize;
}

/// The probe camera's primary hits (immediate rays) and, from each, a shadow ray from each light to the
/// hit and a reflection ray, queued as secondary kinds (starting 1 mm off the surface, on the camera's
/// side).
fn secondary_probe(rays: SpatialRays, mut queue: ResMut<RayQueue>) {
    let all = QueryFilter::default();
    let camera = Camera::default();
    let ray_at = pixel_ray(PROBE.0, PROBE.1, &camera);
    for i in 0..PROBE.0 * PROBE.1 {
        let ray = ray_at(i % PROBE.0, i / PROBE.0);
        let Some(hit) = rays.cast_ray(&ray, 200.0, &all) else {
            continue;
        };
        let facing = -hit.normal * ray.dir().dot(hit.normal).signum();
        let point = hit.point + 1e-3 * facing;
        let tag = SECONDARY + 3 * i as u64;
        for (k, &light) in LIGHTS.iter().enumerate() {
            let kind = RequestKind::Shadow { light: k as u32 };
            queue.shadow_kind(tag + k as u64, light, point, kind, all.clone());
        }
        let d = ray.dir() - 2.0 * ray.dir().dot(hit.normal) * hit.normal;
        queue.cast_kind(
            tag + 2,
            Ray::new(point, d),
            RequestKind::Reflection,
            all.clone(),
        );
    }
}

/// The turret sweeps the crowd; a hit reports character, triangle and the joint that moves it most.
fn turret(
    rays: SpatialRays,
    stats: Res<TraceStats>,
    mut crowd: ResMut<Crowd>,
    players: Query<&AnimationPlayer>,
) {
    let a = stats.frame as f32 * 0.02;
    let origin = Vec3::new(0.0, 3.0, -16.0);
    let aim = Vec3::new(10.0 * a.sin(), 1.2, 6.0 * (0.7 * a).cos());
    let Some(hit) = rays.cast_ray(
        &Ray::new(origin, (aim - origin).normalize()),
        60.0,
        &QueryFilter::default().layers(CHARACTERS),
    ) else {
        return;
    };
    let Ok(player) = players.get(hit.entity) else {
        return;
    };
    let mesh = &player.asset.mesh;
    let v = mesh.indices()[3 * hit.triangle as usize] as usize;
    let (joints, weights) = (
        &player.asset.weights.joints[v],
        &player.asset.weights.weights[v],
    );
    let k = (0..4)
        .max_by(|&i, &j| weights[i].total_cmp(&weights[j]))
        .unwrap_or(0);
    let joint = &player.asset.skeleton.joints[joints[k] as usize].name;
    if stats.frame.is_multiple_of(60) {
        println!(
            "    turret: {} triangle {} ({joint}) at {:.2} m",
            hit.entity, hit.triangle, hit.distance
        );
    }
    crowd.summary.turret_hits += 1;
    crowd.turret_marks.push(hit.point);
    if crowd.turret_marks.len() > 240 {
        crowd.turret_marks.remove(0);
    }
}

/// Characters that bumped into each other this frame: the first few are reported with their deepest
/// contact.
fn bumps(
    mut started: MessageReader<CollisionStarted>,
    contacts: Res<Contacts>,
    stats: Res<TraceStats>,
    mut crowd: ResMut<Crowd>,
) {
    for m in started.read() {
        crowd.summary.bumps += 1;
        if crowd.summary.bumps > 5 {
            continue;
        }
        let Some(pair) = contacts.between(m.a, m.b) else {
            continue;
        };
        if let Some(deepest) = contacts
            .contacts(pair)
            .iter()
            .max_by(|x, y| x.depth.total_cmp(&y.depth))
        {
            println!(
                "    frame {}: {} bumped into {}: {} touching triangle pairs, deepest {:.3} m at {:.2}",
                stats.frame,
                m.a,
                m.b,
                contacts.contacts(pair).len(),
                deepest.depth,
                deepest.point
            );
        }
    }
}

/// Runs the demo.
pub fn run(opt: &Options) -> Result<Summary, Box<dyn std::error::Error>> {
    std::fs::create_dir_all(&opt.out)?;
    let (mut world, mut schedule) = setup(opt)?;
    println!(
        "  second |  frame ms | animate+skin | maintain | top level | queries | refits rebuilds | rays"
    );
    run_frames(opt, &mut world, &mut schedule)
}

/// The world and schedule of the demo: plugin, ground, characters and the gameplay systems.
pub fn setup(opt: &Options) -> Result<(World, Schedule), Box<dyn std::error::Error>> {
    let mut world = World::new();
    let mut schedule = Schedule::default();
    schedule.set_executor(bevy_ecs::schedule::SingleThreadedExecutor::new());
    let mode = if opt.gpu {
        TraceMode::GpuWhenAvailable
    } else {
        TraceMode::Cpu
    };
    KinetracePlugin {
        config: TraceConfig {
            mode,
            resident: opt.resident,
            ..Default::default()
        },
        ..Default::default()
    }
    .sync_transforms(Walker::affine)
    .try_build(&mut world, &mut schedule)?;
    let device = world
        .get_resource::<GpuQueries>()
        .map_or("the CPU".to_string(), |g| {
            format!("the GPU ({})", g.adapter_name())
        });
    let asset = Arc::new(humanoid(opt.triangles));
    println!(
        "crowd: {} characters x {} triangles ({} in all), batched queries on {device}",
        opt.characters,
        asset.mesh.triangle_count(),
        opt.characters * asset.mesh.triangle_count()
    );
    let ground = Mesh::new(
        vec![
            Vec3::new(-30.0, 0.0, -30.0),
            Vec3::new(30.0, 0.0, -30.0),
            Vec3::new(30.0, 0.0, 30.0),
            Vec3::new(-30.0, 0.0, 30.0),
        ],
        vec![0, 2, 1, 0, 3, 2],
    )?;
    world.spawn((TraceMesh(ground), MotionHint::Static, QueryLayers(GROUND)));
    let walk_clip = asset.clip("walk").unwrap_or(0);
    let run_clip = asset.clip("run").unwrap_or(0);
    let flail_clip = asset.clip("flail").unwrap_or(0);
    for i in 0..opt.characters {
        let a = i as f32 * 2.399; // golden-angle spiral
        let r = 1.5 * (i as f32 + 1.0).sqrt();
        let clip = match i % 7 {
            0 => flail_clip,
            1 | 2 => run_clip,
            _ => walk_clip,
        };
        let speed = if clip == run_clip {
            3.0
        } else if clip == flail_clip {
            0.3
        } else {
            1.4
        };
        world.spawn((
            AnimationPlayer::bundle(&asset, clip, i as f32 * 0.13),
            QueryLayers(CHARACTERS),
            Collider {
                layers: CollisionLayers::new(CHARACTERS, CHARACTERS),
                ..Default::default()
            },
            Walker {
                pos: Vec2::new(r * a.cos(), r * a.sin()),
                heading: a,
                speed,
                turn: 0.3 * ((i % 5) as f32 - 2.0) / 2.0,
            },
        ));
    }
    world.insert_resource(Crowd {
        summary: Summary::default(),
        turret_marks: Vec::new(),
        shadows: opt.shadows,
        sun_angle: opt.sun_angle,
        camera_packets: Mutex::new(Choice::packets()),
        ray_packets: Mutex::new([
            PassRays::new(Choice::sparse_packets()),
            PassRays::new(Choice::packets()),
            PassRays::new(Choice::sparse_packets()),
            PassRays::new(Choice::packets()),
        ]),
        gpu_map: gpu_map(&world),
        map_on_gpu: Mutex::new(Choice::map_on_gpu()),
    });
    schedule.add_systems((
        walk.before(TraceSystems::TopLevel),
        (look_and_probe, turret, secondary_probe)
            .after(TraceSystems::TopLevel)
            .before(TraceSystems::Queries),
        bumps.after(TraceSystems::Queries),
    ));
    Ok((world, schedule))
}

/// Simulates one frame.
pub fn step(world: &mut World, schedule: &mut Schedule) {
    schedule.run(world);
    world.clear_trackers();
}

fn run_frames(
    opt: &Options,
    world: &mut World,
    schedule: &mut Schedule,
) -> Result<Summary, Box<dyn std::error::Error>> {
    let (mut acc, mut phases, mut work) = (
        Duration::ZERO,
        [Duration::ZERO; 4],
        (0usize, 0usize, 0usize),
    );
    for f in 0..opt.frames {
        let t = Instant::now();
        step(world, schedule);
        acc += t.elapsed();
        let s = world.resource::<TraceStats>().clone();
        for (p, d) in
            phases
                .iter_mut()
                .zip([s.skin_time, s.maintain_time, s.top_level_time, s.query_time])
        {
            *p += d;
        }
        work.0 += s.refits;
        work.1 += s.rebuilds;
        work.2 += s.batched_rays;
        {
            let results = world.resource::<RayResults>();
            let sight = (results.shadows.iter()).filter(|s| s.0 < SECONDARY).count();
            let secondary = results.hits.len() + results.shadows.len() - sight;
            let mut crowd = world.resource_mut::<Crowd>();
            crowd.summary.refits += s.refits;
            crowd.summary.rebuilds += s.rebuilds;
            crowd.summary.sight_checks += sight;
            crowd.summary.secondary_rays += secondary;
        }
        if (f + 1) % 60 == 0 {
            let ms = |d: Duration| d.as_secs_f64() * 1e3 / 60.0;
            println!(
                "  {:>6} | {:>9.2} | {:>12.2} | {:>8.2} | {:>9.2} | {:>7.2} | {:>6} {:>8} | {}",
                (f + 1) / 60,
                ms(acc),
                ms(phases[0]),
                ms(phases[1]),
                ms(phases[2]),
                ms(phases[3]),
                work.0,
                work.1,
                work.2
            );
            let picks: Vec<String> = (s.options.iter())
                .filter_map(|o| match o.option {
                    PlannedOption::Secondary(batch, strategy) => Some(format!(
                        "{batch:?} via {strategy:?}{}",
                        if o.tried { " (tried)" } else { "" }
                    )),
                    _ => None,
                })
                .collect();
            if picks.is_empty() {
                println!(
                    "    secondary rays: on the GPU, in request order (the planner is CPU only)"
                );
            } else {
                println!("    secondary rays: {}", picks.join(", "));
            }
            (acc, phases, work) = (Duration::ZERO, [Duration::ZERO; 4], (0, 0, 0));
        }
        if (opt.png_every > 0 && (f + 1) % opt.png_every == 0) || f + 1 == opt.frames {
            let path = opt.out.join(format!("crowd_{:05}.png", f + 1));
            render(
                world,
                opt.width,
                opt.height,
                &Camera::default(),
                View::Shaded,
            )
            .save(&path)?;
            let crowd = world.resource_mut::<Crowd>().into_inner();
            let packets = lock(&crowd.camera_packets).current();
            // A shadow map alone traces no shadow rays.
            let soft = crowd.sun_angle > 0.0;
            let marked = match crowd.shadows {
                ShadowMode::ShadowMap => "",
                mode if lock(&crowd.ray_packets)[planner(mode, soft)]
                    .choice
                    .current() =>
                {
                    ", shadow rays as packets"
                }
                _ => ", shadow rays single, interleaved",
            };
            // The shadow map's device, where there is a choice.
            let map = match crowd.gpu_map {
                Some(_) if lock(&crowd.map_on_gpu).current() => {
                    ", shadow map (and classification) on the GPU"
                }
                Some(_) => ", shadow map on the CPU",
                None => "",
            };
            println!(
                "    {}: camera rays {}{marked}{map} (the planner's picks)",
                path.display(),
                if packets {
                    "as 8x8 packets"
                } else {
                    "ray by ray"
                }
            );
            crowd.summary.pngs.push(path);
        }
    }
    let crowd = world.remove_resource::<Crowd>().expect("inserted");
    let s = &crowd.summary;
    println!(
        "{} frames: {} refits, {} rebuilds, {} line-of-sight checks, {} secondary rays, turret hit a character {} times, {} bumps between characters, ground found under everyone in {} frames; images: {}",
        opt.frames,
        s.refits,
        s.rebuilds,
        s.sight_checks,
        s.secondary_rays,
        s.turret_hits,
        s.bumps,
        s.grounded_frames,
        s.pngs
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    );
    Ok(crowd.summary)
}

/// Where the images are taken from.
#[derive(Clone, Copy, Debug)]
pub struct Camera {
    /// The eye.
    pub eye: Vec3,
    /// The point looked at.
    pub target: Vec3,
}

impl Default for Camera {
    fn default() -> Self {
        Self {
            eye: Vec3::new(0.0, 14.0, -24.0),
            target: Vec3::new(0.0, 0.5, 0.0),
        }
    }
}

/// What an image shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum View {
    /// Lambert shading, hard shadows from the sun, the turret's hits in red.
    Shaded,
    /// Nodes visited and triangles tested per primary ray, blue (little) to red (much).
    Heatmap,
    /// Shaded, with every entity's world box and its tree's top two levels drawn in yellow.
    Boxes,
}

/// The direction towards the sun.
pub fn sun() -> Vec3 {
    Vec3::new(0.4, 1.0, -0.3).normalize()
}

/// The camera's primary ray through the centre of pixel `(x, y)` of a `w`×`h` image.
fn pixel_ray(w: u32, h: u32, camera: &Camera) -> impl Fn(u32, u32) -> Ray {
    let eye = camera.eye;
    let fwd = (camera.target - eye).normalize();
    let right = fwd.cross(Vec3::Y).normalize();
    let up = right.cross(fwd);
    let aspect = w as f32 / h as f32;
    move |x, y| {
        let (u, v) = (
            (x as f32 + 0.5) / w as f32 - 0.5,
            0.5 - (y as f32 + 0.5) / h as f32,
        );
        Ray::new(
            eye,
            (fwd + right * u * aspect * 0.9 + up * v * 0.9).normalize(),
        )
    }
}

/// Groups of tiles an image is traced in, each a planner's frame (see [`primary_hits`]).
const GROUPS: u32 = 8;

/// The primary hit of every pixel, and the G-buffer of those hits (normals turned towards the camera)
/// that the shadow pass reads.
///
/// The image is traced in tiles of 8×8 pixels, in [`GROUPS`] groups of every `GROUPS`-th tile (so that
/// each group samples the whole image and costs per ray compare between groups; bands of rows did not:
/// sky and crowd differ too much). Each group goes either as packets ([`TraceWorld::cast_packet`]) or
/// ray by ray ([`TraceWorld::cast_ray`]) — the same hits either way — as the planner's
/// [`Choice::packets`] picks from the seconds per ray each way measured on the groups traced so far
/// (kept from image to image). Which is faster depends on the scene: on the 4-wide trees single rays
/// measured 1.3× packets' speed on the default crowd (64 characters of 10,880 triangles), the two within
/// 5% of each other on 8 characters of 1,500 (docs/BENCHMARKS.md). The same choice serves any coherent
/// batch: `decide` before the batch with its ray count, `served` after with its rays and seconds. The
/// seconds are wall-clock: on a machine busy with other work a try can measure the faster way slower
/// and keep the other for a while.
pub fn primary_hits(
    world: &World,
    w: u32,
    h: u32,
    camera: &Camera,
) -> (Vec<Option<RayHit>>, GBuffer) {
    let tw = world.resource::<TraceWorld>();
    let mut planner = lock(&world.resource::<Crowd>().camera_packets);
    let all = QueryFilter::default();
    let ray_at = pixel_ray(w, h, camera);
    let mut g = GBuffer::new(w as usize, h as usize);
    let mut hits = vec![None; (w * h) as usize];
    let (mut tile, mut idx, mut out) = (Vec::new(), Vec::new(), Vec::new());
    let (across, down) = (w.div_ceil(8), h.div_ceil(8));
    let (tiles, groups) = (across * down, GROUPS.min(across * down));
    for group in 0..groups {
        let packets = planner.decide(f64::from(w * h) / f64::from(groups));
        let (mut traced, mut rays) = (Duration::ZERO, 0);
        for k in (group..tiles).step_by(groups as usize) {
            let (tx, ty) = (8 * (k % across), 8 * (k / across));
            tile.clear();
            idx.clear();
            for y in ty..(ty + 8).min(h) {
                for x in tx..(tx + 8).min(w) {
                    tile.push(ray_at(x, y));
                    idx.push((y * w + x) as usize);
                }
            }
            out.clear();
            out.resize(tile.len(), None);
            let t = Instant::now();
            if packets {
                tw.cast_packet(&tile, 200.0, &all, &mut out);
            } else {
                for (ray, hit) in tile.iter().zip(out.iter_mut()) {
                    *hit = tw.cast_ray(ray, 200.0, &all);
                }
            }
            traced += t.elapsed();
            rays += tile.len();
            for ((ray, &i), hit) in tile.iter().zip(&idx).zip(&out) {
                if let Some(hit) = hit {
                    let n = if hit.normal.dot(ray.dir()) > 0.0 {
                        -hit.normal
                    } else {
                        hit.normal
                    };
                    g.set(i, hit.point, n);
                }
                hits[i] = *hit;
            }
        }
        planner.served(packets, rays as f64, traced.as_secs_f64());
    }
    (hits, g)
}

/// The traversal work (inner nodes visited plus triangles tested) of every pixel's primary ray, traced
/// one by one: what the heatmap view shows.
fn primary_work(world: &World, w: u32, h: u32, camera: &Camera) -> Vec<u32> {
    let tw = world.resource::<TraceWorld>();
    let all = QueryFilter::default();
    let ray_at = pixel_ray(w, h, camera);
    (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| {
            let mut work = kinetrace::bvh::TraversalStats::default();
            tw.cast_ray_counted(&ray_at(x, y), 200.0, &all, &mut work);
            (work.inner_visits + work.prim_tests) as u32
        })
        .collect()
}

/// Sun visibility per pixel of `g` (1 lit, 0 shadowed), computed as `settings.mode` says, with the
/// shadow map rendered straight from the world's meshes and the shadow-ray queries of their trees. With
/// a GPU the map is rendered (and a hard selective pass's pixels classified) there or on the CPU — the
/// same map and classes — as the planner's [`Choice::map_on_gpu`] picks from the seconds of both phases
/// per occluder triangle each way measured on the passes so far.
pub fn sun_visibility<'a>(
    world: &World,
    g: &GBuffer,
    settings: &ShadowSettings,
    pass: &'a mut HardShadows,
) -> kinetrace::Result<&'a [f32]> {
    let crowd = world.resource::<Crowd>();
    // A ray per pixel renders no map.
    let gpu_map = crowd.gpu_map.as_ref();
    let Some(gpu_map) = gpu_map.filter(|_| settings.mode != ShadowMode::RayTraced) else {
        return sun_visibility_with(world, g, settings, pass, &mut CpuMap);
    };
    let mut planner = lock(&crowd.map_on_gpu);
    let all = QueryFilter::default();
    let occluders = world.resource::<TraceWorld>().occluders(&all);
    let triangles = occluders.triangle_count() as f64;
    let on_gpu = planner.decide(triangles);
    if on_gpu {
        sun_visibility_with(world, g, settings, pass, &mut *lock(gpu_map))?;
    } else {
        sun_visibility_with(world, g, settings, pass, &mut CpuMap)?;
    }
    let s = pass.stats();
    planner.served(
        on_gpu,
        triangles,
        (s.map_time + s.classify_time).as_secs_f64(),
    );
    Ok(pass.visibility())
}

/// `m` locked, whether or not a thread panicked holding it (the planners' state stays usable).
fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// The planner's choice between packets and single rays for one kind of pass's shadow rays, and how
/// many pixels got rays in its last pass (what the next likely gives them).
struct PassRays {
    choice: Choice<bool>,
    pixels: f64,
}

impl PassRays {
    fn new(choice: Choice<bool>) -> Self {
        Self {
            choice,
            pixels: 0.0,
        }
    }
}

/// [`sun_visibility`] with the map rendered by `renderer`.
///
/// A pass's shadow rays go as packets (a block of 8×8 pixels' rays together: a node visit serves the
/// whole packet) or as single rays walked four at a time, interleaved (`TraceWorld::occluded_interleaved`:
/// one walk's wait for memory overlaps the others' work) ([`sun_visibility_rays`]), as the planner picks
/// from the seconds per pixel that got rays each way measured on the passes so far (kept from pass to
/// pass; the same answers either way), one planner per kind of pass. For hard shadows,
/// [`Choice::sparse_packets`]: single rays first, since on the crowd they measured faster both for a
/// selective pass's few scattered marked pixels (a block's often a handful along a shadow's edge) and
/// for a ray per pixel (docs/BENCHMARKS.md, stops 46 and 47); soft shadows send each pixel's rays
/// across the light's disc together (16 from one point, close in direction), dense batches, and start
/// with packets ([`Choice::packets`]). A shadow map alone traces no rays and consults no planner.
pub fn sun_visibility_with<'a>(
    world: &World,
    g: &GBuffer,
    settings: &ShadowSettings,
    pass: &'a mut HardShadows,
    renderer: &mut impl MapRenderer,
) -> kinetrace::Result<&'a [f32]> {
    if settings.mode == ShadowMode::ShadowMap {
        return sun_visibility_rays(world, g, settings, pass, renderer, false);
    }
    let mut planners = lock(&world.resource::<Crowd>().ray_packets);
    let rays = &mut planners[planner(settings.mode, settings.light_angle > 0.0)];
    let as_packets = rays.choice.decide(rays.pixels);
    sun_visibility_rays(world, g, settings, pass, renderer, as_packets)?;
    let s = pass.stats();
    rays.pixels = s.rays as f64;
    (rays.choice).served(as_packets, rays.pixels, s.trace_time.as_secs_f64());
    Ok(pass.visibility())
}

/// [`sun_visibility_with`] with the shadow rays as packets (`as_packets`: each batch the pass gives,
/// up to 64 rays of one 8×8 block, traced together; a lone ray alone) or as single rays (batches of up
/// to 64 across blocks, four walked at a time interleaved), whatever the planner would pick.
pub fn sun_visibility_rays<'a>(
    world: &World,
    g: &GBuffer,
    settings: &ShadowSettings,
    pass: &'a mut HardShadows,
    renderer: &mut impl MapRenderer,
    as_packets: bool,
) -> kinetrace::Result<&'a [f32]> {
    let tw = world.resource::<TraceWorld>();
    let all = QueryFilter::default();
    let occluders = tw.occluders(&all);
    let single = |from, to| tw.occluded(from, to, &all);
    if as_packets {
        let packets = Packets(
            |segments: &[(Vec3, Vec3)], out: &mut [bool]| match segments {
                &[(from, to)] => out[0] = single(from, to),
                _ => tw.occluded_packet(segments, &all, out),
            },
        );
        pass.run_with(settings, &occluders, g, packets, renderer)
    } else {
        let interleaved = Interleaved(|segments: &[(Vec3, Vec3)], out: &mut [bool]| {
            tw.occluded_interleaved(segments, &all, out)
        });
        pass.run_with(settings, &occluders, g, interleaved, renderer)
    }
}

/// Whether the planner sends the shadow rays of a pass in `mode` (selective: its marked pixels'; ray
/// traced: every pixel's) as packets now, for hard shadows or soft (see [`sun_visibility_with`]).
pub fn rays_as_packets(world: &World, mode: ShadowMode, soft: bool) -> bool {
    lock(&world.resource::<Crowd>().ray_packets)[planner(mode, soft)]
        .choice
        .current()
}

/// Which of the crowd's shadow-ray planners a pass in `mode` consults: the selective pass's or the
/// ray-traced one's, hard or soft. A shadow map alone traces no rays and consults none (the caller
/// does not ask; it is given the selective one's).
fn planner(mode: ShadowMode, soft: bool) -> usize {
    (mode == ShadowMode::RayTraced) as usize * 2 + soft as usize
}

/// Ray traces the world from `camera`: primary rays as packets or ray by ray as the planner picks (see
/// [`primary_hits`]), sun shadows as the
/// crowd's shadow mode says (selective by default).
pub fn render(world: &World, w: u32, h: u32, camera: &Camera, view: View) -> image::RgbImage {
    let tw = world.resource::<TraceWorld>();
    let marks = &world.resource::<Crowd>().turret_marks;
    let sun = sun();
    let eye = camera.eye;
    let fwd = (camera.target - eye).normalize();
    let right = fwd.cross(Vec3::Y).normalize();
    let up = right.cross(fwd);
    let aspect = w as f32 / h as f32;
    let (hits, g) = primary_hits(world, w, h, camera);
    let work = match view {
        View::Heatmap => primary_work(world, w, h, camera),
        _ => vec![0; hits.len()],
    };
    let settings = ShadowSettings {
        mode: world.resource::<Crowd>().shadows,
        light_angle: world.resource::<Crowd>().sun_angle,
        towards_light: sun,
        ..Default::default()
    };
    let mut pass = HardShadows::new();
    let visibility = match view {
        View::Heatmap => vec![1.0; hits.len()],
        _ => sun_visibility(world, &g, &settings, &mut pass)
            .expect("valid settings")
            .to_vec(),
    };
    let mut img = image::RgbImage::new(w, h);
    for ((((px, hit), cost), vis), i) in img
        .pixels_mut()
        .zip(hits)
        .zip(work)
        .zip(visibility)
        .zip(0..)
    {
        let v = 0.5 - ((i / w) as f32 + 0.5) / h as f32;
        if view == View::Heatmap {
            let k = (cost as f32 / 150.0).min(1.0);
            let c = Vec3::new(0.1, 0.2, 0.9).lerp(Vec3::new(1.0, 0.15, 0.05), k);
            *px = image::Rgb(c.to_array().map(|x| (x * 255.0) as u8));
            continue;
        }
        let c = match hit {
            None => Vec3::new(0.55, 0.7, 0.9) * (0.8 + 0.2 * v),
            Some(hit) => {
                let n = g.normals[i as usize];
                let albedo = if hit.point.y.abs() < 1e-3 && hit.normal.y.abs() > 0.99 {
                    let check = ((hit.point.x.floor() + hit.point.z.floor()) as i32 & 1) as f32;
                    Vec3::splat(0.55 + 0.1 * check)
                } else {
                    let k = hit.entity.index_u32() as f32;
                    Vec3::new(
                        0.6 + 0.3 * (k * 1.3).sin(),
                        0.5 + 0.3 * (k * 2.1).sin(),
                        0.5 + 0.3 * (k * 0.7).cos(),
                    )
                };
                let near_mark = marks.iter().any(|m| (*m - hit.point).length() < 0.06);
                if near_mark {
                    Vec3::new(1.0, 0.1, 0.1)
                } else {
                    albedo * (0.25 + vis * 0.75 * n.dot(sun).max(0.0))
                }
            }
        };
        *px = image::Rgb(c.to_array().map(|x| (x.clamp(0.0, 1.0) * 255.0) as u8));
    }
    if view == View::Boxes {
        let project = |p: Vec3| -> Option<(f32, f32)> {
            let d = p - eye;
            let z = d.dot(fwd);
            (z > 0.1).then(|| {
                let (u, v) = (d.dot(right) / z / (aspect * 0.9), d.dot(up) / z / 0.9);
                ((u + 0.5) * w as f32, (0.5 - v) * h as f32)
            })
        };
        let yellow = image::Rgb([255, 220, 40]);
        let mut boxes = Vec::new();
        for e in tw.tlas().prim_indices().iter().map(|&p| tw.tlas_entity(p)) {
            let Some(blas) = tw.blas(e) else { continue };
            let t = world
                .get::<TraceTransform>(e)
                .map_or(glam::Affine3A::IDENTITY, |t| t.0);
            let nodes = blas.bvh().nodes();
            let top: Vec<usize> = match nodes.first() {
                Some(r) if !r.is_leaf() => vec![0, r.left(), r.left() + 1],
                Some(_) => vec![0],
                None => vec![],
            };
            boxes.extend(top.into_iter().map(|i| (t, nodes[i].aabb())));
        }
        for (t, b) in boxes {
            let corner = |i: usize| {
                t.transform_point3(Vec3::new(
                    if i & 1 == 0 { b.min.x } else { b.max.x },
                    if i & 2 == 0 { b.min.y } else { b.max.y },
                    if i & 4 == 0 { b.min.z } else { b.max.z },
                ))
            };
            for (a, c) in [
                (0, 1),
                (2, 3),
                (4, 5),
                (6, 7),
                (0, 2),
                (1, 3),
                (4, 6),
                (5, 7),
                (0, 4),
                (1, 5),
                (2, 6),
                (3, 7),
            ] {
                if let (Some(p), Some(q)) = (project(corner(a)), project(corner(c))) {
                    let steps = ((q.0 - p.0).abs().max((q.1 - p.1).abs()) as usize)
                        .clamp(1, 4 * (w + h) as usize);
                    for k in 0..=steps {
                        let f = k as f32 / steps as f32;
                        let (x, y) = (p.0 + (q.0 - p.0) * f, p.1 + (q.1 - p.1) * f);
                        if x >= 0.0 && y >= 0.0 && (x as u32) < w && (y as u32) < h {
                            img.put_pixel(x as u32, y as u32, yellow);
                        }
                    }
                }
            }
        }
    }
    img
}

#[allow(dead_code)] // the integration test uses `run` only
fn main() {
    let mut opt = Options::default();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut num = |what: &str| -> usize {
            args.next().and_then(|v| v.parse().ok()).unwrap_or_else(|| {
                eprintln!("{a} needs a number ({what})");
                std::process::exit(2)
            })
        };
        match a.as_str() {
            "--characters" => opt.characters = num("characters"),
            "--triangles" => opt.triangles = num("triangles per character"),
            "--frames" => opt.frames = num("frames"),
            "--png-every" => opt.png_every = num("frames between images"),
            "--cpu" => opt.gpu = false,
            "--shadows" => {
                opt.shadows = match args.next().as_deref() {
                    Some("map") => ShadowMode::ShadowMap,
                    Some("selective") => ShadowMode::Selective,
                    Some("traced") => ShadowMode::RayTraced,
                    _ => {
                        eprintln!("--shadows needs map, selective or traced");
                        std::process::exit(2)
                    }
                }
            }
            "--soft" => {
                opt.sun_angle = match args.next().and_then(|a| a.parse().ok()) {
                    Some(a) if (0.0..=0.5).contains(&a) => a,
                    _ => {
                        eprintln!("--soft needs the sun's angular radius in radians, 0 to 0.5");
                        std::process::exit(2)
                    }
                }
            }
            // The GPU path is the GPU-resident frame; `--resident` is kept as its older name.
            "--gpu" | "--resident" => (opt.gpu, opt.resident) = (true, true),
            "--out" => {
                opt.out = PathBuf::from(args.next().unwrap_or_else(|| "target/crowd".into()))
            }
            _ => {
                eprintln!(
                    "usage: crowd [--characters N] [--triangles N] [--frames N] [--png-every N] [--cpu|--gpu] [--out DIR] [--shadows map|selective|traced] [--soft RAD]"
                );
                std::process::exit(2);
            }
        }
    }
    if let Err(e) = run(&opt) {
        eprintln!("crowd: {e}");
        std::process::exit(1);
    }
}
