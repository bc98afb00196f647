//! The report's animated scenes: a fixed topology whose vertex positions are a function of the frame.

use glam::{Mat4, Quat, Vec3};
use kinetrace::Mesh;
use kinetrace::anim::{CharacterAsset, humanoid, skin_positions};
use kinetrace::scenes::{SceneRng, cube_sphere, icosphere, soup};
use std::path::Path;
use std::sync::Arc;

/// One animated scene.
pub struct Scene {
    pub name: &'static str,
    /// Shared by every frame's mesh.
    indices: Arc<[u32]>,
    motion: Motion,
}

enum Motion {
    /// Skinned characters (rest mesh offsets per character), plus static triangles after them.
    Characters {
        asset: Box<CharacterAsset>,
        placements: Vec<Vec3>,
        arena: Vec<Vec3>,
    },
    /// A sheet waving in z.
    Cloth { rest: Vec<Vec3> },
    /// Triangles flying outward from the origin, each at its own velocity.
    Explosion {
        rest: Vec<Vec3>,
        velocity: Vec<Vec3>,
    },
    /// Triangles jittering around their rest place.
    Soup { rest: Vec<Vec3> },
    /// Bodies on circles, each turning.
    Rigid { body: Vec<Vec3>, count: usize },
}

fn concat(meshes: &[(Vec<Vec3>, &[u32])]) -> (Vec<Vec3>, Vec<u32>) {
    let (mut pos, mut idx) = (Vec::new(), Vec::new());
    for (p, i) in meshes {
        let base = pos.len() as u32;
        pos.extend_from_slice(p);
        idx.extend(i.iter().map(|&v| v + base));
    }
    (pos, idx)
}

impl Scene {
    /// The scenes at a size: about `triangles` triangles each (the shared asset keeps its own size).
    pub fn all(triangles: usize, assets: &Path) -> (Vec<Scene>, Vec<String>) {
        let mut skipped = Vec::new();
        let mut scenes = vec![
            Self::crowd(triangles),
            Self::cloth(triangles),
            Self::explosion(triangles),
            Self::teapot_in_stadium(triangles),
            Self::soup(triangles),
            Self::rigid(triangles),
        ];
        let figure = assets.join("RiggedFigure.gltf");
        match kinetrace::anim::load_gltf(&figure) {
            Ok(meshes) => {
                if let Some(asset) = meshes.into_iter().find_map(|m| m.character) {
                    scenes.push(Scene {
                        name: "rigged_figure",
                        indices: asset.mesh.indices().into(),
                        motion: Motion::Characters {
                            asset: Box::new(asset),
                            placements: vec![Vec3::ZERO],
                            arena: Vec::new(),
                        },
                    });
                }
            }
            Err(e) => skipped.push(format!("rigged_figure skipped: {e}")),
        }
        (scenes, skipped)
    }

    fn crowd(triangles: usize) -> Scene {
        let asset = humanoid((triangles / 8).max(1000));
        let placements: Vec<Vec3> = (0..8)
            .map(|i| Vec3::new((i % 4) as f32 * 1.5, 0.0, (i / 4) as f32 * 1.5))
            .collect();
        let rest = asset.mesh.positions().to_vec();
        let parts: Vec<(Vec<Vec3>, &[u32])> = placements
            .iter()
            .map(|_| (rest.clone(), asset.mesh.indices()))
            .collect();
        let indices = concat(&parts).1;
        Scene {
            name: "crowd",
            indices: indices.into(),
            motion: Motion::Characters {
                asset: Box::new(asset),
                placements,
                arena: Vec::new(),
            },
        }
    }

    fn cloth(triangles: usize) -> Scene {
        let n = ((triangles / 2) as f64).sqrt().max(2.0) as u32;
        let rest: Vec<Vec3> = (0..=n)
            .flat_map(|j| {
                (0..=n).map(move |i| Vec3::new(i as f32 / n as f32, j as f32 / n as f32, 0.0))
            })
            .collect();
        let mut indices = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let a = j * (n + 1) + i;
                indices.extend([a, a + 1, a + n + 1, a + 1, a + n + 2, a + n + 1]);
            }
        }
        Scene {
            name: "cloth",
            indices: indices.into(),
            motion: Motion::Cloth { rest },
        }
    }

    fn explosion(triangles: usize) -> Scene {
        let m = soup(21, triangles);
        let mut r = SceneRng::new(22);
        let rest: Vec<Vec3> = m.positions().iter().map(|&p| (p - 0.5) * 0.1).collect();
        let velocity = (0..triangles)
            .flat_map(|_| {
                let v = r.direction() * r.range(0.2, 3.0);
                [v, v, v]
            })
            .collect();
        Scene {
            name: "explosion",
            indices: m.indices().into(),
            motion: Motion::Explosion { rest, velocity },
        }
    }

    fn teapot_in_stadium(triangles: usize) -> Scene {
        let asset = humanoid((triangles * 9 / 10).max(1000));
        let stadium = cube_sphere(((triangles / 120) as f64).sqrt().max(2.0) as u32);
        let arena: Vec<Vec3> = stadium.positions().iter().map(|&p| p * 200.0).collect();
        let indices = concat(&[
            (asset.mesh.positions().to_vec(), asset.mesh.indices()),
            (arena.clone(), stadium.indices()),
        ])
        .1;
        Scene {
            name: "teapot_in_stadium",
            indices: indices.into(),
            motion: Motion::Characters {
                asset: Box::new(asset),
                placements: vec![Vec3::ZERO],
                arena,
            },
        }
    }

    fn soup(triangles: usize) -> Scene {
        let m = soup(31, triangles);
        Scene {
            name: "soup",
            indices: m.indices().into(),
            motion: Motion::Soup {
                rest: m.positions().to_vec(),
            },
        }
    }

    fn rigid(triangles: usize) -> Scene {
        let body = icosphere(3); // 1280 triangles
        let count = (triangles / body.triangle_count()).max(2);
        let parts: Vec<(Vec<Vec3>, &[u32])> = (0..count)
            .map(|_| (body.positions().to_vec(), body.indices()))
            .collect();
        Scene {
            name: "rigid",
            indices: concat(&parts).1.into(),
            motion: Motion::Rigid {
                body: body.positions().to_vec(),
                count,
            },
        }
    }

    /// The scene's positions at `frame` (60 frames per second) into `out`, resized as needed.
    pub fn positions(&self, frame: u32, out: &mut Vec<Vec3>) {
        let t = frame as f32 / 60.0;
        out.clear();
        match &self.motion {
            Motion::Characters {
                asset,
                placements,
                arena,
            } => {
                let clip = &asset.clips[0];
                let mut pose = asset.skeleton.rest_pose();
                let mut mats = vec![Mat4::IDENTITY; asset.skeleton.joints.len()];
                let rest = asset.mesh.positions();
                let mut skinned = vec![Vec3::ZERO; rest.len()];
                for (i, &at) in placements.iter().enumerate() {
                    clip.sample(t + 0.37 * i as f32, &mut pose);
                    asset.skeleton.skin_matrices(&pose, &mut mats);
                    skin_positions(rest, &asset.weights, &mats, &mut skinned).expect("valid asset");
                    let walk = Vec3::new(0.0, 0.0, 0.8 * t);
                    out.extend(skinned.iter().map(|&p| p + at + walk));
                }
                out.extend_from_slice(arena);
            }
            Motion::Cloth { rest } => out.extend(rest.iter().map(|&p| {
                let wave = (6.0 * p.x - 4.0 * t).sin() * (3.0 * p.y + t).cos();
                p + Vec3::new(0.0, 0.0, 0.15 * wave * p.x)
            })),
            Motion::Explosion { rest, velocity } => {
                out.extend(rest.iter().zip(velocity).map(|(&p, &v)| p + v * t))
            }
            Motion::Soup { rest } => {
                let mut r = SceneRng::new(frame as u64 + 1);
                out.extend(rest.iter().map(|&p| p + r.vec3(-0.01, 0.01) * (1.0 + t)))
            }
            Motion::Rigid { body, count } => {
                for b in 0..*count {
                    let phase = b as f32 * 2.399;
                    let radius = 3.0 + (b % 7) as f32;
                    let centre = Vec3::new(
                        radius * (t + phase).cos(),
                        (b % 5) as f32,
                        radius * (t + phase).sin(),
                    );
                    let m = Mat4::from_rotation_translation(
                        Quat::from_rotation_y(t * (1.0 + (b % 3) as f32) + phase),
                        centre,
                    );
                    out.extend(body.iter().map(|&p| m.transform_point3(p)));
                }
            }
        }
    }

    /// The mesh at a frame (for building and brute force).
    pub fn mesh(&self, positions: &[Vec3]) -> Mesh {
        Mesh::new(positions.to_vec(), self.indices.clone()).expect("finite scene")
    }
}
