//! glTF loading: the shared Khronos assets (when ../shared/assets exists) and hand-made malformed files.

mod common;
use base64::Engine;
use bevy_ecs::prelude::*;
use common::*;
use glam::{Mat4, Vec3};
use kinetrace::anim::{load_gltf, load_gltf_slice, skin_positions};
use kinetrace::ecs::*;
use kinetrace::{Error, Ray};
use std::path::PathBuf;
use std::sync::Arc;

#[test]
fn shared_assets_rest_pose_animation_and_queries() {
    for (name, joints, tris) in [
        ("RiggedSimple.gltf", 2, 188),
        ("RiggedFigure.gltf", 19, 256),
    ] {
        let Some(path) = shared_asset_or_skip(name) else {
            continue;
        };
        let meshes = load_gltf(&path).unwrap();
        assert_eq!(meshes.len(), 1, "{name}");
        let m = &meshes[0];
        assert_eq!(m.mesh.triangle_count(), tris, "{name}");
        let ch = m.character.as_ref().expect("skinned");
        assert_eq!(ch.skeleton.joints.len(), joints);
        assert_eq!(ch.clips.len(), 1);
        // Rest pose: skinned positions equal the mesh positions through the mesh node's world matrix.
        let mut mats = vec![Mat4::IDENTITY; joints];
        ch.skeleton
            .skin_matrices(&ch.skeleton.rest_pose(), &mut mats);
        let mut skinned = vec![Vec3::ZERO; m.mesh.positions().len()];
        skin_positions(m.mesh.positions(), &ch.weights, &mats, &mut skinned).unwrap();
        if name == "RiggedFigure.gltf" {
            // Its joints' world × inverse bind equals the mesh node's world (checked in the assets' README).
            for (s, p) in skinned.iter().zip(m.mesh.positions()) {
                let expect = m.world.transform_point3(*p);
                assert!((*s - expect).length() <= 1e-4, "{name}: {s} vs {expect}");
            }
        } else {
            // RiggedSimple's inverse bind matrices are relative to its Armature node, so glTF's skinning
            // formula (which ignores the mesh node's transform) places it without the Armature's -90° turn
            // about z (both joints' world × inverse bind equal the Z_UP node's matrix; verified outside this
            // crate). What must hold: the rest pose is a rigid placement of the mesh.
            for t in m.mesh.indices().chunks(3) {
                for (a, b) in [(t[0], t[1]), (t[1], t[2])] {
                    let (a, b) = (a as usize, b as usize);
                    let rest = (m.mesh.positions()[a] - m.mesh.positions()[b]).length();
                    assert!(
                        ((skinned[a] - skinned[b]).length() - rest).abs() <= 1e-4,
                        "{name}: edge {a}-{b}"
                    );
                }
            }
        }
        // During the animation: the tree bounds the skinned triangles and answers like brute force.
        let asset = Arc::new(ch.clone());
        let mut world = World::new();
        let mut schedule = Schedule::default();
        KinetracePlugin::default().build(&mut world, &mut schedule);
        let e = world.spawn(AnimationPlayer::bundle(&asset, 0, 0.0)).id();
        let bounds = m
            .mesh
            .triangle_bounds()
            .iter()
            .fold(kinetrace::Aabb::EMPTY, |a, b| a.union(b));
        let size = bounds.extent().length();
        let mut r = rng(8);
        let mut moved = 0f32;
        for f in 0..80 {
            world.resource_mut::<AnimationClock>().delta = 1.0 / 30.0;
            schedule.run(&mut world);
            world.clear_trackers();
            let vp = world.get::<VertexPositions>(e).unwrap().0.clone();
            moved = moved.max(
                vp.iter()
                    .zip(&skinned)
                    .map(|(a, b)| (*a - *b).length())
                    .fold(0.0, f32::max),
            );
            let current = m.mesh.with_positions(vp).unwrap();
            let tw = world.resource::<TraceWorld>();
            tw.blas(e)
                .unwrap()
                .bvh()
                .validate(Some(&current.triangle_bounds()))
                .unwrap_or_else(|x| panic!("{name} frame {f}: {x}"));
            let c = current
                .triangle_bounds()
                .iter()
                .fold(kinetrace::Aabb::EMPTY, |a, b| a.union(b))
                .center();
            for i in 0..20 {
                let o = c + rand_dir(&mut r) * size * 2.0;
                let ray = Ray::new(o, c + rand_vec(&mut r, -0.3, 0.3) * size - o);
                let got = tw
                    .blas(e)
                    .unwrap()
                    .closest_hit(&ray)
                    .map(|h| (h.primitive, h.t));
                assert_brute_hit(&current, &ray, got, &format!("{name} frame {f} ray {i}"));
            }
        }
        assert!(
            moved > 0.01 * size,
            "{name}: the animation moved vertices by {moved}"
        );
        // CPU and GPU skinning agree on an animated pose.
        #[cfg(feature = "gpu")]
        if let Some(g) = gpu_or_skip() {
            let mut pose = ch.skeleton.rest_pose();
            ch.clips[0].sample(ch.clips[0].duration * 0.6, &mut pose);
            ch.skeleton.skin_matrices(&pose, &mut mats);
            let mut cpu = vec![Vec3::ZERO; skinned.len()];
            skin_positions(m.mesh.positions(), &ch.weights, &mats, &mut cpu).unwrap();
            let bvh = kinetrace::gpu::GpuMeshBvh::new(&g, &m.mesh).unwrap();
            let gs =
                kinetrace::gpu::GpuSkin::new(&g, m.mesh.positions(), &ch.weights, joints, &bvh)
                    .unwrap();
            let mut enc = g.encoder();
            gs.record(&g, &mut enc, &mats).unwrap();
            g.submit(enc);
            let gpu = bvh.read_positions(&g).unwrap();
            for (a, b) in gpu.iter().zip(&cpu) {
                assert!(
                    (*a - *b).abs().max_element() <= 1e-5 * size.max(1.0),
                    "{name}: {a} vs {b}"
                );
            }
        }
    }
}

/// A small skinned, animated glTF built by hand, with knobs to break it.
struct Doc {
    positions: Vec<[f32; 3]>,
    indices: Vec<u16>,
    joints: Vec<[u8; 4]>,
    weights: Vec<[f32; 4]>,
    times: Vec<f32>,
    rotations: Vec<[f32; 4]>,
    mode: u32,
    index_count_extra: usize,
    /// One morph target's displacement per vertex (none when empty), with weights keyed at `times`.
    morph: Vec<[f32; 3]>,
    morph_weights: Vec<f32>,
}

impl Doc {
    fn new() -> Self {
        Self {
            positions: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [1.0, 1.0, 0.0],
            ],
            indices: vec![0, 1, 2, 2, 1, 3],
            joints: vec![[0, 1, 0, 0]; 4],
            weights: vec![[0.5, 0.25, 0.0, 0.0]; 4], // sums to 0.75: the loader renormalises
            times: vec![0.0, 1.0],
            rotations: vec![
                [0.0, 0.0, 0.0, 1.0],
                [
                    0.0,
                    0.0,
                    std::f32::consts::FRAC_1_SQRT_2,
                    std::f32::consts::FRAC_1_SQRT_2,
                ],
            ],
            mode: 4,
            index_count_extra: 0,
            morph: Vec::new(),
            morph_weights: Vec::new(),
        }
    }

    fn json(&self) -> String {
        let mut bin = Vec::new();
        let mut views = Vec::new();
        let mut push = |bytes: &[u8]| {
            while !bin.len().is_multiple_of(4) {
                bin.push(0);
            }
            views.push((bin.len(), bytes.len()));
            bin.extend_from_slice(bytes);
        };
        push(bytemuck::cast_slice(&self.positions));
        push(bytemuck::cast_slice(&self.indices));
        push(bytemuck::cast_slice(&self.joints));
        push(bytemuck::cast_slice(&self.weights));
        push(bytemuck::cast_slice(&self.times));
        push(bytemuck::cast_slice(&self.rotations));
        let morphed = !self.morph.is_empty();
        if morphed {
            push(bytemuck::cast_slice(&self.morph));
            push(bytemuck::cast_slice(&self.morph_weights));
        }
        let b64 = base64::engine::general_purpose::STANDARD.encode(&bin);
        let views_json: Vec<String> = views
            .iter()
            .map(|(o, l)| format!(r#"{{"buffer":0,"byteOffset":{o},"byteLength":{l}}}"#))
            .collect();
        let (lo, hi) = self
            .positions
            .iter()
            .fold(([f32::MAX; 3], [f32::MIN; 3]), |(lo, hi), p| {
                (
                    [lo[0].min(p[0]), lo[1].min(p[1]), lo[2].min(p[2])],
                    [hi[0].max(p[0]), hi[1].max(p[1]), hi[2].max(p[2])],
                )
            });
        let t = |x: f32| {
            if x.is_finite() {
                format!("{x}")
            } else {
                "0".into()
            }
        };
        let json = format!(
            r#"{{"asset":{{"version":"2.0"}},
"buffers":[{{"byteLength":{},"uri":"data:application/octet-stream;base64,{b64}"}}],
"bufferViews":[{}],
"accessors":[
 {{"bufferView":0,"componentType":5126,"count":{},"type":"VEC3","min":[{},{},{}],"max":[{},{},{}]}},
 {{"bufferView":1,"componentType":5123,"count":{},"type":"SCALAR"}},
 {{"bufferView":2,"componentType":5121,"count":{},"type":"VEC4"}},
 {{"bufferView":3,"componentType":5126,"count":{},"type":"VEC4"}},
 {{"bufferView":4,"componentType":5126,"count":{},"type":"SCALAR","min":[{}],"max":[{}]}},
 {{"bufferView":5,"componentType":5126,"count":{},"type":"VEC4"}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"JOINTS_0":2,"WEIGHTS_0":3}},"indices":1,"mode":{}}}]}}],
"skins":[{{"joints":[1,2]}}],
"nodes":[{{"mesh":0,"skin":0}},{{"name":"root","children":[2]}},{{"name":"tip","translation":[0,0.5,0]}}],
"animations":[{{"channels":[{{"sampler":0,"target":{{"node":2,"path":"rotation"}}}}],"samplers":[{{"input":4,"output":5,"interpolation":"LINEAR"}}]}}],
"scenes":[{{"nodes":[0,1]}}],"scene":0}}"#,
            bin.len(),
            views_json.join(","),
            self.positions.len(),
            lo[0],
            lo[1],
            lo[2],
            hi[0],
            hi[1],
            hi[2],
            self.indices.len() + self.index_count_extra,
            self.joints.len(),
            self.weights.len(),
            self.times.len(),
            t(self.times.first().copied().unwrap_or(0.0)),
            t(self.times.last().copied().unwrap_or(0.0)),
            self.rotations.len(),
            self.mode
        );
        if !morphed {
            return json;
        }
        // Accessors 6 (the target's displacements) and 7 (its weight per key), the target on the primitive,
        // a default weight on the mesh, and a weights channel on the mesh node.
        let (dl, dh) = self
            .morph
            .iter()
            .fold((f32::MAX, f32::MIN), |(l, h), d| (l.min(d[2]), h.max(d[2])));
        let extra = format!(
            r#"}},
 {{"bufferView":6,"componentType":5126,"count":{},"type":"VEC3","min":[0,0,{dl}],"max":[0,0,{dh}]}},
 {{"bufferView":7,"componentType":5126,"count":{},"type":"SCALAR"}}],
"meshes""#,
            self.morph.len(),
            self.morph_weights.len()
        );
        json.replacen("}],\n\"meshes\"", &extra, 1)
            .replacen("\"mode\":", "\"targets\":[{\"POSITION\":6}],\"mode\":", 1)
            .replacen("]}],\n\"skins\"", "],\"weights\":[0]}],\n\"skins\"", 1)
            .replacen("\"path\":\"rotation\"}}]", "\"path\":\"rotation\"}},{\"sampler\":1,\"target\":{\"node\":0,\"path\":\"weights\"}}]", 1)
            .replacen("\"interpolation\":\"LINEAR\"}]", "\"interpolation\":\"LINEAR\"},{\"input\":4,\"output\":7,\"interpolation\":\"LINEAR\"}]", 1)
    }

    fn load(&self) -> kinetrace::Result<Vec<kinetrace::anim::GltfMesh>> {
        load_gltf_slice(self.json().as_bytes(), None)
    }

    /// The document with its buffer moved to a side file named by `uri` (written as a JSON string): the
    /// JSON, and the bytes that file must hold.
    fn with_buffer_file(&self, uri: &str) -> (String, Vec<u8>) {
        let json = self.json();
        let start = json.find("\"data:").unwrap();
        let end = start + 1 + json[start + 1..].find('"').unwrap() + 1;
        let (_, b64) = json[start + 1..end - 1].split_once(";base64,").unwrap();
        let bin = base64::engine::general_purpose::STANDARD
            .decode(b64)
            .unwrap();
        let uri = serde_json::to_string(uri).unwrap();
        (format!("{}{uri}{}", &json[..start], &json[end..]), bin)
    }
}

fn expect_gltf_error<T>(r: kinetrace::Result<T>, needle: &str) {
    match r {
        Err(Error::Gltf(m)) => assert!(m.contains(needle), "{m:?} lacks {needle:?}"),
        Err(e) => panic!("{e:?} is not a glTF error mentioning {needle:?}"),
        Ok(_) => panic!("succeeded; expected an error mentioning {needle:?}"),
    }
}

#[test]
fn a_hand_made_file_loads_and_animates() {
    let m = Doc::new().load().unwrap();
    let ch = m[0].character.as_ref().unwrap();
    assert_eq!(m[0].mesh.triangle_count(), 2);
    assert_eq!(
        ch.weights.weights[0],
        [2.0 / 3.0, 1.0 / 3.0, 0.0, 0.0],
        "renormalised"
    );
    assert_eq!(ch.clips[0].duration, 1.0);
    // Halfway, the tip joint has turned 45° about z.
    let mut pose = ch.skeleton.rest_pose();
    ch.clips[0].sample(0.5, &mut pose);
    let angle = pose[1].rotation.to_axis_angle().1;
    assert!(
        (angle - std::f32::consts::FRAC_PI_4).abs() < 1e-5,
        "{angle}"
    );
    // Strips and fans become triangle lists.
    let mut d = Doc::new();
    d.indices = vec![0, 1, 2, 3];
    d.mode = 5;
    assert_eq!(d.load().unwrap()[0].mesh.indices(), &[0, 1, 2, 2, 1, 3]);
    d.mode = 6;
    assert_eq!(d.load().unwrap()[0].mesh.indices(), &[0, 1, 2, 0, 2, 3]);
}

#[test]
fn malformed_files_are_errors_naming_the_problem() {
    let good = Doc::new().json();
    // Truncated.
    assert!(matches!(
        load_gltf_slice(&good.as_bytes()[..good.len() / 2], None),
        Err(Error::Gltf(_))
    ));
    assert!(matches!(load_gltf_slice(b"", None), Err(Error::Gltf(_))));
    assert!(matches!(
        load_gltf_slice(b"glTF\x02\x00\x00\x00\xff\xff", None),
        Err(Error::Gltf(_))
    ));
    // Index out of range.
    let mut d = Doc::new();
    d.indices[4] = 9;
    expect_gltf_error(d.load(), "index 4 is 9");
    // Joint beyond the skin.
    let mut d = Doc::new();
    d.joints[2] = [0, 7, 0, 0];
    expect_gltf_error(d.load(), "vertex 2 uses joint");
    // Accessor overrun: more indices declared than stored.
    let mut d = Doc::new();
    d.index_count_extra = 30;
    expect_gltf_error(d.load(), "overrun");
    // NaN key time and value.
    let mut d = Doc::new();
    d.times[1] = f32::NAN;
    expect_gltf_error(d.load(), "key time 1");
    let mut d = Doc::new();
    d.rotations[0][1] = f32::NAN;
    expect_gltf_error(d.load(), "value 0 is not finite");
    // Decreasing key times.
    let mut d = Doc::new();
    d.times = vec![1.0, 0.5];
    expect_gltf_error(d.load(), "decrease");
    // Points and lines are not triangles.
    for mode in [0, 1] {
        let mut d = Doc::new();
        d.mode = mode;
        expect_gltf_error(d.load(), "not triangles");
    }
    // Zero weights.
    let mut d = Doc::new();
    d.weights[1] = [0.0; 4];
    expect_gltf_error(d.load(), "vertex 1 has weights");
    // A missing file is an I/O error.
    assert!(matches!(
        load_gltf(std::path::Path::new("/nonexistent/x.gltf")),
        Err(Error::Io { .. })
    ));
}

#[test]
fn the_procedural_character_round_trips_through_glb() {
    let h = kinetrace::anim::humanoid(3_000);
    let bytes = kinetrace::anim::character_to_glb(&h).unwrap();
    let loaded = load_gltf_slice(&bytes, None).expect("our own GLB loads");
    assert_eq!(loaded.len(), 1);
    let back = loaded[0].character.as_ref().expect("skinned");
    assert_eq!(loaded[0].mesh.indices(), h.mesh.indices());
    assert_eq!(loaded[0].mesh.positions(), h.mesh.positions());
    assert_eq!(back.weights.joints, h.weights.joints);
    assert_eq!(back.skeleton.inverse_bind, h.skeleton.inverse_bind);
    assert_eq!(back.clips.len(), h.clips.len());
    // Every clip poses the skeleton identically at any time.
    let (mut a, mut b) = (h.skeleton.rest_pose(), back.skeleton.rest_pose());
    let (mut ma, mut mb) = (vec![Mat4::IDENTITY; a.len()], vec![Mat4::IDENTITY; b.len()]);
    for (ca, cb) in h.clips.iter().zip(&back.clips) {
        assert_eq!(ca.name, cb.name);
        for k in 0..13 {
            let t = k as f32 / 12.0 * ca.duration * 1.1;
            ca.sample(t, &mut a);
            cb.sample(t, &mut b);
            h.skeleton.skin_matrices(&a, &mut ma);
            back.skeleton.skin_matrices(&b, &mut mb);
            for (x, y) in ma.iter().zip(&mb) {
                assert!(x.abs_diff_eq(*y, 1e-5), "{} at {t}: {x} vs {y}", ca.name);
            }
        }
    }
}

#[test]
fn morph_target_weights_animate_the_rest_pose() {
    let plain = Doc::new();
    let mut morphing = Doc::new();
    morphing.morph = vec![[0.0, 0.0, 1.0]; 4];
    morphing.morph_weights = vec![0.0, 1.0];
    let run = |d: &Doc| {
        let m = d.load().unwrap();
        let asset = Arc::new(m[0].character.clone().unwrap());
        let mut world = World::new();
        let mut schedule = Schedule::default();
        KinetracePlugin::default().build(&mut world, &mut schedule);
        world.resource_mut::<AnimationClock>().delta = 0.25;
        let e = world.spawn(AnimationPlayer::bundle(&asset, 0, 0.0)).id();
        let mut out = Vec::new();
        for _ in 0..3 {
            schedule.run(&mut world);
            world.clear_trackers();
            out.push(world.get::<VertexPositions>(e).unwrap().0.clone());
        }
        (asset, out)
    };
    let (asset, with) = run(&morphing);
    let (_, without) = run(&plain);
    let morphs = asset.morphs.as_ref().expect("the target was loaded");
    assert_eq!(morphs.deltas, vec![vec![Vec3::Z; 4]]);
    // The joints only turn about z, which keeps z: the morph adds exactly (0, 0, weight), weight = time.
    for (frame, (a, b)) in with.iter().zip(&without).enumerate() {
        let w = 0.25 * (frame + 1) as f32;
        for (p, q) in a.iter().zip(b) {
            assert!(
                (*p - *q - Vec3::Z * w).length() < 1e-5,
                "frame {frame}: {p} vs {q}"
            );
        }
    }
}

/// A fresh, empty directory for one test's files.
fn scratch(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn side_file_uris_are_percent_decoded() {
    let dir = scratch("gltf_uri_legal");
    let d = Doc::new();
    // (URI as written in the file, the file it names, relative to the .gltf)
    for (uri, file) in [
        ("my%20mesh.bin", "my mesh.bin"),
        ("./sub/%C3%A9t%C3%A9.bin", "sub/\u{e9}t\u{e9}.bin"),
        ("100%25.bin", "100%.bin"),
        ("plain.bin", "plain.bin"),
    ] {
        let (json, bin) = d.with_buffer_file(uri);
        let path = dir.join(file);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, &bin).unwrap();
        let gltf = dir.join("doc.gltf");
        std::fs::write(&gltf, json).unwrap();
        let m = load_gltf(&gltf).unwrap_or_else(|e| panic!("{uri}: {e}"));
        let expect: Vec<Vec3> = d.positions.iter().map(|p| Vec3::from_array(*p)).collect();
        assert_eq!(m[0].mesh.positions(), &expect[..], "{uri}");
        let expect: Vec<u32> = d.indices.iter().map(|&i| u32::from(i)).collect();
        assert_eq!(m[0].mesh.indices(), &expect[..], "{uri}");
        std::fs::remove_file(&path).unwrap();
    }
}

#[test]
fn uris_reaching_outside_the_asset_directory_are_refused() {
    // root/secret.bin holds a valid buffer: a loader that followed any of these URIs there would load.
    let root = scratch("gltf_uri_hostile");
    let assets = root.join("a/b");
    std::fs::create_dir_all(&assets).unwrap();
    let d = Doc::new();
    let (_, bin) = d.with_buffer_file("x");
    let secret = root.join("secret.bin");
    std::fs::write(&secret, &bin).unwrap();
    std::fs::write(assets.join("ok.bin"), &bin).unwrap();
    let (json, _) = d.with_buffer_file("ok.bin");
    load_gltf_slice(json.as_bytes(), Some(&assets)).expect("the same buffer, inside, loads");
    let abs = secret.to_str().unwrap().to_string();
    let hostile = [
        // Parent components, plain and encoded, with either separator.
        "../../secret.bin".to_string(),
        "x/../../../secret.bin".into(),
        "./../../secret.bin".into(),
        "%2e%2e/%2e%2e/secret.bin".into(),
        "%2E%2E%2F%2E%2E%2Fsecret.bin".into(),
        ".%2e/%2E./secret.bin".into(),
        "..\\..\\secret.bin".into(),
        "..%5C..%5Csecret.bin".into(),
        "..%5c..%2fsecret.bin".into(),
        // Windows drops trailing dots and spaces: `.. ` is the parent there.
        "..%20/..%20/secret.bin".into(),
        // Absolute paths, plain and encoded.
        abs.clone(),
        format!("%2F{}", &abs[1..]),
        format!("//{abs}"),
        "C:\\secret.bin".into(),
        "C:/secret.bin".into(),
        "c:secret.bin".into(),
        "C%3A%5Csecret.bin".into(),
        "\\secret.bin".into(),
        "\\\\server\\share\\secret.bin".into(),
        "%5C%5Cserver%5Cshare%5Csecret.bin".into(),
        "//server/share/secret.bin".into(),
        // Schemes other than data:.
        format!("file://{abs}"),
        format!("file:{abs}"),
        format!("FILE:///{}", &abs[1..]),
        "http://example.com/secret.bin".into(),
        "https://example.com/secret.bin".into(),
        "ftp:secret.bin".into(),
        // Windows devices, malformed escapes, control characters, non-UTF-8, nothing.
        "CON".into(),
        "sub/lpt1.bin".into(),
        "%zz.bin".into(),
        "secret.bin%2".into(),
        "secret%00.bin".into(),
        "%FF.bin".into(),
        "./".into(),
    ];
    for uri in &hostile {
        let (json, _) = d.with_buffer_file(uri);
        expect_gltf_error(
            load_gltf_slice(json.as_bytes(), Some(&assets)),
            &format!("{uri:?}"),
        );
    }
    // Through a file on disk too.
    let (json, _) = d.with_buffer_file("../../secret.bin");
    let evil = assets.join("evil.gltf");
    std::fs::write(&evil, json).unwrap();
    expect_gltf_error(load_gltf(&evil), "\"../../secret.bin\"");
}

#[test]
fn names_with_quotes_backslashes_and_control_characters_round_trip_through_glb() {
    let nasty =
        "say \"hi\" \\ C:\\x\n\t\r\u{0}\u{1}\u{1f}\u{7f}\u{80}\u{2028} \u{e9}\u{1f600} </script>";
    let mut h = kinetrace::anim::humanoid(500);
    for (i, j) in h.skeleton.joints.iter_mut().enumerate() {
        j.name = format!("{nasty}{i}");
    }
    for (i, c) in h.clips.iter_mut().enumerate() {
        c.name = format!("{i}{nasty}");
    }
    let bytes = kinetrace::anim::character_to_glb(&h).unwrap();
    let loaded = load_gltf_slice(&bytes, None).expect("our own GLB loads");
    let back = loaded[0].character.as_ref().unwrap();
    let names = |c: &kinetrace::anim::CharacterAsset| {
        let joints: Vec<String> = c.skeleton.joints.iter().map(|j| j.name.clone()).collect();
        let clips: Vec<String> = c.clips.iter().map(|c| c.name.clone()).collect();
        (joints, clips)
    };
    assert_eq!(names(back), names(&h));
}

#[test]
fn exporting_a_non_finite_value_is_an_error() {
    let mut h = kinetrace::anim::humanoid(500);
    h.skeleton.joints[3].rest.translation.y = f32::NAN;
    expect_gltf_error(kinetrace::anim::character_to_glb(&h), "joint 3");
    let mut h = kinetrace::anim::humanoid(500);
    h.clips[0].channels[0].times[0] = f32::INFINITY;
    expect_gltf_error(kinetrace::anim::character_to_glb(&h), "channel 0");
}
