//! The crowd demo in a window: the scene ray traced on the CPU every frame and shown through a wgpu surface;
//! with `--gpu` the shadow map of the selective and map-only modes is rendered (and the hard selective
//! mode's pixels classified) on the GPU where the planner measures that faster (the same map and classes
//! either way; see the crowd's `sun_visibility`).
//!
//! ```text
//! cargo run --release --features viewer --example viewer -- [--characters 32] [--triangles 5000]
//! ```
//! Keys: 1 shaded, 2 traversal-cost heatmap, 3 BVH boxes; shadows: 4 shadow map alone, 5 selective ray
//! traced, 6 a ray per pixel, 7 hard / soft (a sun of 0.03 rad); arrows orbit and zoom; Escape quits. Where no
//! window can be opened (no display), it says so and exits; the `crowd` example writes the same images to
//! PNG files instead.

#[allow(dead_code)]
#[path = "crowd.rs"]
mod crowd;

use bevy_ecs::prelude::*;
use crowd::{Camera, View};
use glam::Vec3;
use kinetrace::shadows::ShadowMode;
use std::sync::Arc;
use winit::application::ApplicationHandler;
use winit::event::{ElementState, KeyEvent, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop};
use winit::keyboard::{Key, NamedKey};
use winit::window::{Window, WindowId};

/// Everything that exists while the window does.
struct Shown {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    device: wgpu::Device,
    queue: wgpu::Queue,
    config: wgpu::SurfaceConfiguration,
    frame: wgpu::Texture,
}

struct App {
    opt: crowd::Options,
    world: World,
    schedule: Schedule,
    view: View,
    yaw: f32,
    distance: f32,
    shown: Option<Shown>,
    error: Option<String>,
}

/// The image is traced at this fraction of the window's size and scaled up, to keep the frame rate usable.
const SCALE: u32 = 2;

impl App {
    fn open(&mut self, el: &ActiveEventLoop) -> Result<Shown, String> {
        let window = Arc::new(
            el.create_window(
                Window::default_attributes()
                    .with_title("kinetrace viewer — 1 shaded, 2 heatmap, 3 boxes"),
            )
            .map_err(|e| e.to_string())?,
        );
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_with_display_handle_from_env(
                Box::new(el.owned_display_handle()),
            ));
        let surface = instance
            .create_surface(window.clone())
            .map_err(|e| e.to_string())?;
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            compatible_surface: Some(&surface),
            ..Default::default()
        }))
        .map_err(|e| e.to_string())?;
        let (device, queue) = pollster::block_on(adapter.request_device(&Default::default()))
            .map_err(|e| e.to_string())?;
        let size = window.inner_size();
        let mut config = surface
            .get_default_config(&adapter, size.width.max(1), size.height.max(1))
            .ok_or("the surface does not fit this adapter")?;
        // The traced image is copied straight into the swap-chain image: no render pipeline needed.
        config.usage |= wgpu::TextureUsages::COPY_DST;
        config.format = config.format.remove_srgb_suffix();
        surface.configure(&device, &config);
        let frame = frame_texture(&device, &config);
        println!("viewer: {} ({:?})", adapter.get_info().name, config.format);
        Ok(Shown {
            window,
            surface,
            device,
            queue,
            config,
            frame,
        })
    }

    fn camera(&self) -> Camera {
        let (s, c) = self.yaw.sin_cos();
        Camera {
            eye: Vec3::new(s * self.distance, self.distance * 0.55, -c * self.distance),
            target: Vec3::new(0.0, 0.5, 0.0),
        }
    }

    fn draw(&mut self) {
        crowd::step(&mut self.world, &mut self.schedule);
        let camera = self.camera();
        let view = self.view;
        let Some(s) = &mut self.shown else { return };
        let (w, h) = (s.config.width, s.config.height);
        let img = crowd::render(
            &self.world,
            (w / SCALE).max(1),
            (h / SCALE).max(1),
            &camera,
            view,
        );
        let bgra = matches!(s.config.format, wgpu::TextureFormat::Bgra8Unorm);
        let mut pixels = vec![0u8; (w * h * 4) as usize];
        for y in 0..h {
            for x in 0..w {
                let p = img
                    .get_pixel(
                        (x / SCALE).min(img.width() - 1),
                        (y / SCALE).min(img.height() - 1),
                    )
                    .0;
                let o = ((y * w + x) * 4) as usize;
                pixels[o..o + 4].copy_from_slice(&if bgra {
                    [p[2], p[1], p[0], 255]
                } else {
                    [p[0], p[1], p[2], 255]
                });
            }
        }
        s.queue.write_texture(
            s.frame.as_image_copy(),
            &pixels,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(4 * w),
                rows_per_image: Some(h),
            },
            wgpu::Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            },
        );
        let target = match s.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t)
            | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                s.surface.configure(&s.device, &s.config);
                return;
            }
            _ => return,
        };
        let mut enc = s.device.create_command_encoder(&Default::default());
        enc.copy_texture_to_texture(
            s.frame.as_image_copy(),
            target.texture.as_image_copy(),
            wgpu::Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            },
        );
        s.queue.submit([enc.finish()]);
        s.queue.present(target);
        s.window.request_redraw();
    }
}

fn frame_texture(device: &wgpu::Device, config: &wgpu::SurfaceConfiguration) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some("traced frame"),
        size: wgpu::Extent3d {
            width: config.width,
            height: config.height,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: config.format,
        usage: wgpu::TextureUsages::COPY_DST | wgpu::TextureUsages::COPY_SRC,
        view_formats: &[],
    })
}

impl ApplicationHandler for App {
    fn resumed(&mut self, el: &ActiveEventLoop) {
        if self.shown.is_none() {
            match self.open(el) {
                Ok(s) => {
                    s.window.request_redraw();
                    self.shown = Some(s);
                }
                Err(e) => {
                    self.error = Some(e);
                    el.exit();
                }
            }
        }
    }

    fn window_event(&mut self, el: &ActiveEventLoop, _: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => el.exit(),
            WindowEvent::Resized(size) => {
                if let Some(s) = &mut self.shown
                    && size.width > 0
                    && size.height > 0
                {
                    s.config.width = size.width;
                    s.config.height = size.height;
                    s.surface.configure(&s.device, &s.config);
                    s.frame = frame_texture(&s.device, &s.config);
                }
            }
            WindowEvent::KeyboardInput {
                event:
                    KeyEvent {
                        logical_key,
                        state: ElementState::Pressed,
                        ..
                    },
                ..
            } => match logical_key.as_ref() {
                Key::Named(NamedKey::Escape) => el.exit(),
                Key::Named(NamedKey::ArrowLeft) => self.yaw -= 0.1,
                Key::Named(NamedKey::ArrowRight) => self.yaw += 0.1,
                Key::Named(NamedKey::ArrowUp) => self.distance = (self.distance * 0.9).max(3.0),
                Key::Named(NamedKey::ArrowDown) => self.distance = (self.distance * 1.1).min(80.0),
                Key::Character("1") => self.view = View::Shaded,
                Key::Character("2") => self.view = View::Heatmap,
                Key::Character("3") => self.view = View::Boxes,
                Key::Character("4") => {
                    *crowd::shadows_mut(&mut self.world).0 = ShadowMode::ShadowMap
                }
                Key::Character("5") => {
                    *crowd::shadows_mut(&mut self.world).0 = ShadowMode::Selective
                }
                Key::Character("6") => {
                    *crowd::shadows_mut(&mut self.world).0 = ShadowMode::RayTraced
                }
                Key::Character("7") => {
                    let angle = crowd::shadows_mut(&mut self.world).1;
                    *angle = if *angle > 0.0 { 0.0 } else { 0.03 };
                }
                _ => {}
            },
            WindowEvent::RedrawRequested => self.draw(),
            _ => {}
        }
    }
}

fn main() {
    let mut opt = crowd::Options {
        characters: 32,
        triangles: 5_000,
        gpu: false,
        ..Default::default()
    };
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        if a == "--gpu" {
            // Maintained and queried in the GPU-resident frame (the image is still ray traced on the CPU).
            (opt.gpu, opt.resident) = (true, true);
            continue;
        }
        let value = args.next().and_then(|v| v.parse().ok());
        match (a.as_str(), value) {
            ("--characters", Some(v)) => opt.characters = v,
            ("--triangles", Some(v)) => opt.triangles = v,
            _ => {
                eprintln!("usage: viewer [--characters N] [--triangles N] [--gpu]");
                std::process::exit(2);
            }
        }
    }
    let (world, schedule) = match crowd::setup(&opt) {
        Ok(x) => x,
        Err(e) => {
            eprintln!("viewer: {e}");
            std::process::exit(1);
        }
    };
    let event_loop = match EventLoop::new() {
        Ok(el) => el,
        Err(e) => {
            eprintln!(
                "viewer: no window can be opened here ({e}). The `crowd` example renders the same scene to PNG files."
            );
            std::process::exit(1);
        }
    };
    let mut app = App {
        opt,
        world,
        schedule,
        view: View::Shaded,
        yaw: 0.0,
        distance: 24.0,
        shown: None,
        error: None,
    };
    if let Err(e) = event_loop.run_app(&mut app) {
        eprintln!("viewer: {e}");
        std::process::exit(1);
    }
    if let Some(e) = app.error {
        eprintln!(
            "viewer: no window could be opened ({e}). The `crowd` example renders the same scene to PNG files."
        );
        std::process::exit(1);
    }
    let _ = app.opt;
}
