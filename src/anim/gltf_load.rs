//! Loading meshes, skins and animations from glTF 2.0 (`.gltf` with embedded data URIs or side files, and
//! `.glb`). Every accessor is checked against its buffer before it is read, so a malformed file is an
//! [`Error::Gltf`] naming what is wrong, never a panic.

use super::{
    Channel, CharacterAsset, Clip, Interpolation, Joint, MorphTargets, Property, Skeleton,
    SkinWeights, Transform,
};
use crate::{Error, Mesh, Result};
use glam::{Mat4, Quat, Vec3, Vec4};
use std::path::Path;
use std::sync::Arc;

mod uri;

/// One mesh instance of a glTF scene.
#[derive(Clone, Debug)]
pub struct GltfMesh {
    /// The node's name (or `node N`).
    pub name: String,
    /// All triangle primitives of the node's mesh, merged.
    pub mesh: Mesh,
    /// The node's world matrix. For a skinned mesh it only serves the bind pose: glTF skins place vertices
    /// with the joints, so skinned results are already in world space.
    pub world: Mat4,
    /// The skeleton, weights and animations, for a skinned mesh.
    pub character: Option<CharacterAsset>,
}

/// Loads a `.gltf` or `.glb` file. Buffers may be embedded (GLB chunk, base64 data URI) or side files named by
/// a relative, percent-decoded URI under the file's directory; a URI that would reach anywhere else (a scheme
/// other than `data:`, an absolute path, a `..` component) is an [`Error::Gltf`] naming it, so files from
/// untrusted sources (user mods) cannot read the rest of the machine. Images are never read. Cost: one read
/// of the file and each side file, and one pass over every accessor.
pub fn load_gltf(path: &Path) -> Result<Vec<GltfMesh>> {
    let bytes = std::fs::read(path).map_err(|e| Error::Io {
        path: path.display().to_string(),
        message: e.to_string(),
    })?;
    load_gltf_slice(&bytes, path.parent())
}

fn err(m: impl Into<String>) -> Error {
    Error::Gltf(m.into())
}

/// Loads glTF or GLB bytes already in memory; `base` is the directory relative buffer URIs are read under
/// (none allowed without it), with the same restrictions as [`load_gltf`].
pub fn load_gltf_slice(bytes: &[u8], base: Option<&Path>) -> Result<Vec<GltfMesh>> {
    // gltf's own validation indexes some arrays unchecked: what it would panic on is checked first.
    let gltf::Gltf { document, blob } =
        gltf::Gltf::from_slice_without_validation(bytes).map_err(|e| err(e.to_string()))?;
    check_before_validation(document.as_json())?;
    let document =
        gltf::Document::from_json(document.into_json()).map_err(|e| err(e.to_string()))?;
    let doc = gltf::Gltf { document, blob };
    let buffers = load_buffers(&doc, base)?;
    let nodes: Vec<_> = doc.nodes().collect();
    // Parents and world matrices of every node.
    let mut parent = vec![None; nodes.len()];
    for n in &nodes {
        for c in n.children() {
            parent[c.index()] = Some(n.index());
        }
    }
    let local: Vec<Mat4> = nodes
        .iter()
        .map(|n| Mat4::from_cols_array_2d(&n.transform().matrix()))
        .collect();
    let world = |mut i: usize| {
        let mut m = local[i];
        let mut guard = 0;
        while let Some(p) = parent[i] {
            m = local[p] * m;
            i = p;
            guard += 1;
            if guard > nodes.len() {
                break; // a cycle; validation rejects these, but never loop forever
            }
        }
        m
    };
    let mut out = Vec::new();
    for n in &nodes {
        let Some(m) = n.mesh() else { continue };
        let name = n
            .name()
            .map_or_else(|| format!("node {}", n.index()), str::to_string);
        let (mesh, skin_weights, morphs) = read_mesh(&m, &buffers, n.skin().is_some())?;
        let character = match n.skin() {
            None => None,
            Some(skin) => {
                let skeleton = read_skeleton(&skin, &buffers, &parent, &local, &world)?;
                let count = skeleton.joints.len();
                if let Some(v) = skin_weights
                    .joints
                    .iter()
                    .position(|j| j.iter().any(|&j| j as usize >= count))
                {
                    return Err(err(format!(
                        "mesh {}: vertex {v} uses joint {:?}, but skin {} has {count} joints",
                        m.index(),
                        skin_weights.joints[v],
                        skin.index()
                    )));
                }
                let weights = Arc::new(skin_weights);
                let node_to_joint: Vec<Option<usize>> = {
                    let mut v = vec![None; nodes.len()];
                    for (k, j) in skin.joints().enumerate() {
                        v[j.index()] = Some(k);
                    }
                    v
                };
                let clips = doc
                    .animations()
                    .map(|a| {
                        read_clip(
                            &a,
                            &buffers,
                            &node_to_joint,
                            n.index(),
                            morphs.as_ref().map_or(0, |m| m.deltas.len()),
                        )
                    })
                    .collect::<Result<Vec<_>>>()?;
                Some(CharacterAsset {
                    mesh: mesh.clone(),
                    skeleton,
                    weights,
                    clips,
                    morphs: morphs.map(Arc::new),
                })
            }
        };
        out.push(GltfMesh {
            name,
            mesh,
            world: world(n.index()),
            character,
        });
    }
    Ok(out)
}

/// The bytes of every buffer: the GLB binary chunk, a base64 data URI, or a file under the glTF's directory
/// (see [`uri`] for what is refused).
fn load_buffers(doc: &gltf::Gltf, base: Option<&Path>) -> Result<Vec<Vec<u8>>> {
    doc.buffers()
        .map(|b| {
            let data = match b.source() {
                gltf::buffer::Source::Bin => doc.blob.clone().ok_or_else(|| {
                    err(format!(
                        "buffer {} refers to a missing GLB binary chunk",
                        b.index()
                    ))
                })?,
                gltf::buffer::Source::Uri(uri) => {
                    uri::read_uri(uri, base, &format!("buffer {}", b.index()))?
                }
            };
            if data.len() < b.length() {
                return Err(err(format!(
                    "buffer {} holds {} bytes, but declares {}",
                    b.index(),
                    data.len(),
                    b.length()
                )));
            }
            Ok(data)
        })
        .collect()
}

/// Checks what gltf's validation (1.4) indexes or unwraps unchecked: every primitive's `POSITION`
/// accessor exists (its validation reads the accessor's bounds), and every animation channel targets a
/// node that exists with a known property (left unvalidated, unwrapped by its readers).
fn check_before_validation(root: &gltf::json::Root) -> Result<()> {
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            let position = gltf::json::validation::Checked::Valid(gltf::Semantic::Positions);
            if let Some(a) = prim.attributes.get(&position)
                && a.value() >= root.accessors.len()
            {
                return Err(err(format!(
                    "mesh {m} primitive {p}: POSITION accessor {} does not exist",
                    a.value()
                )));
            }
        }
    }
    for (a, anim) in root.animations.iter().enumerate() {
        for (c, ch) in anim.channels.iter().enumerate() {
            let node = ch.target.node.value();
            if node >= root.nodes.len() {
                return Err(err(format!(
                    "animation {a} channel {c}: target node {node} does not exist ({} nodes)",
                    root.nodes.len()
                )));
            }
            if !matches!(ch.target.path, gltf::json::validation::Checked::Valid(_)) {
                return Err(err(format!(
                    "animation {a} channel {c}: unknown target property"
                )));
            }
        }
    }
    Ok(())
}

/// Checks that an accessor can be read as `count` elements of `dims` components of one of `types`, entirely
/// inside its buffer: what gltf's readers assume.
fn check_accessor(
    a: &gltf::Accessor,
    buffers: &[Vec<u8>],
    dims: &[gltf::accessor::Dimensions],
    types: &[gltf::accessor::DataType],
    what: &str,
) -> Result<()> {
    let name = format!("accessor {} ({what})", a.index());
    if a.sparse().is_some() {
        return Err(err(format!("{name}: sparse accessors are not supported")));
    }
    if !dims.contains(&a.dimensions()) || !types.contains(&a.data_type()) {
        return Err(err(format!(
            "{name}: {:?} of {:?} is not a valid type here",
            a.dimensions(),
            a.data_type()
        )));
    }
    let Some(view) = a.view() else {
        return Err(err(format!("{name}: has no buffer view")));
    };
    let size = a.size();
    let stride = view.stride().unwrap_or(size);
    if stride < size {
        return Err(err(format!(
            "{name}: stride {stride} is smaller than an element ({size} bytes)"
        )));
    }
    // glTF requires at least one element, and gltf's readers compute `count - 1`.
    if a.count() == 0 {
        return Err(err(format!("{name}: has no elements")));
    }
    let need = (stride.checked_mul(a.count() - 1))
        .and_then(|n| n.checked_add(a.offset()))
        .and_then(|n| n.checked_add(size));
    if need.is_none_or(|need| need > view.length()) {
        return Err(err(format!(
            "{name}: {} elements overrun buffer view {} ({} bytes)",
            a.count(),
            view.index(),
            view.length()
        )));
    }
    let buf = &buffers[view.buffer().index()];
    if view.offset() + view.length() > buf.len() {
        return Err(err(format!(
            "buffer view {} overruns buffer {}",
            view.index(),
            view.buffer().index()
        )));
    }
    Ok(())
}

use gltf::accessor::{DataType as T, Dimensions as D};

/// Merged triangles of every primitive, with joints and weights (renormalised) when skinned.
/// Morph targets too, when the mesh has them.
fn read_mesh(
    m: &gltf::Mesh,
    buffers: &[Vec<u8>],
    skinned: bool,
) -> Result<(Mesh, SkinWeights, Option<MorphTargets>)> {
    let (mut pos, mut idx, mut joints, mut weights) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let targets = m.primitives().next().map_or(0, |p| p.morph_targets().len());
    let mut deltas: Vec<Vec<Vec3>> = vec![Vec::new(); targets];
    for p in m.primitives() {
        let what = format!("mesh {} primitive {}", m.index(), p.index());
        let reader = p.reader(|b| Some(&buffers[b.index()][..]));
        let acc = p
            .get(&gltf::Semantic::Positions)
            .ok_or_else(|| err(format!("{what}: no POSITION")))?;
        check_accessor(&acc, buffers, &[D::Vec3], &[T::F32], &what)?;
        let base = pos.len() as u32;
        let n = acc.count();
        pos.extend(
            reader
                .read_positions()
                .ok_or_else(|| err(format!("{what}: unreadable POSITION")))?
                .map(Vec3::from_array),
        );
        let local: Vec<u32> = match p.indices() {
            Some(ia) => {
                check_accessor(&ia, buffers, &[D::Scalar], &[T::U8, T::U16, T::U32], &what)?;
                reader
                    .read_indices()
                    .ok_or_else(|| err(format!("{what}: unreadable indices")))?
                    .into_u32()
                    .collect()
            }
            None => (0..n as u32).collect(),
        };
        if let Some(i) = local.iter().position(|&i| i as usize >= n) {
            return Err(err(format!(
                "{what}: index {i} is {}, but the primitive has {n} vertices",
                local[i]
            )));
        }
        let tris = match p.mode() {
            gltf::mesh::Mode::Triangles => local,
            gltf::mesh::Mode::TriangleStrip => (2..local.len())
                .flat_map(|k| {
                    if k % 2 == 0 {
                        [local[k - 2], local[k - 1], local[k]]
                    } else {
                        [local[k - 1], local[k - 2], local[k]]
                    }
                })
                .collect(),
            gltf::mesh::Mode::TriangleFan => (2..local.len())
                .flat_map(|k| [local[0], local[k - 1], local[k]])
                .collect(),
            other => {
                return Err(err(format!(
                    "{what}: {other:?} primitives are not triangles"
                )));
            }
        };
        idx.extend(tris.iter().map(|i| i + base));
        if p.morph_targets().len() != targets {
            return Err(err(format!(
                "{what}: {} morph targets, but the mesh's first primitive has {targets}",
                p.morph_targets().len()
            )));
        }
        for (k, (t, (read, _, _))) in p
            .morph_targets()
            .zip(reader.read_morph_targets())
            .enumerate()
        {
            match (t.positions(), read) {
                (Some(a), Some(r)) => {
                    check_accessor(&a, buffers, &[D::Vec3], &[T::F32], &what)?;
                    if a.count() != n {
                        return Err(err(format!(
                            "{what}: morph target {k} moves {} of {n} vertices",
                            a.count()
                        )));
                    }
                    deltas[k].extend(r.map(Vec3::from_array));
                }
                _ => deltas[k].extend(std::iter::repeat_n(Vec3::ZERO, n)),
            }
        }
        if skinned {
            let ja = p
                .get(&gltf::Semantic::Joints(0))
                .ok_or_else(|| err(format!("{what}: skinned but no JOINTS_0")))?;
            check_accessor(&ja, buffers, &[D::Vec4], &[T::U8, T::U16], &what)?;
            let wa = p
                .get(&gltf::Semantic::Weights(0))
                .ok_or_else(|| err(format!("{what}: skinned but no WEIGHTS_0")))?;
            check_accessor(&wa, buffers, &[D::Vec4], &[T::F32, T::U8, T::U16], &what)?;
            if ja.count() != n || wa.count() != n {
                return Err(err(format!(
                    "{what}: {} joints and {} weights for {n} vertices",
                    ja.count(),
                    wa.count()
                )));
            }
            joints.extend(
                reader
                    .read_joints(0)
                    .ok_or_else(|| err(format!("{what}: unreadable JOINTS_0")))?
                    .into_u16(),
            );
            for (v, w) in reader
                .read_weights(0)
                .ok_or_else(|| err(format!("{what}: unreadable WEIGHTS_0")))?
                .into_f32()
                .enumerate()
            {
                let sum: f32 = w.iter().sum();
                if !sum.is_finite() || sum <= 0.0 || w.iter().any(|x| *x < 0.0) {
                    return Err(err(format!("{what}: vertex {v} has weights {w:?}")));
                }
                weights.push(w.map(|x| x / sum)); // renormalised, as the spec asks of consumers
            }
        }
    }
    let mesh = Mesh::new(pos, idx).map_err(|e| err(format!("mesh {}: {e}", m.index())))?;
    if let Some((k, v)) = deltas
        .iter()
        .enumerate()
        .find_map(|(k, d)| d.iter().position(|v| !v.is_finite()).map(|v| (k, v)))
    {
        return Err(err(format!(
            "mesh {}: morph target {k} moves vertex {v} by a non-finite amount",
            m.index()
        )));
    }
    let morphs = (targets > 0).then(|| {
        let mut default_weights = m.weights().map(<[f32]>::to_vec).unwrap_or_default();
        default_weights.resize(targets, 0.0);
        MorphTargets {
            deltas,
            default_weights,
        }
    });
    Ok((mesh, SkinWeights { joints, weights }, morphs))
}

fn read_skeleton(
    skin: &gltf::Skin,
    buffers: &[Vec<u8>],
    parent: &[Option<usize>],
    local: &[Mat4],
    world: &dyn Fn(usize) -> Mat4,
) -> Result<Skeleton> {
    let nodes: Vec<usize> = skin.joints().map(|j| j.index()).collect();
    let index_of = |node: usize| nodes.iter().position(|&n| n == node);
    // Parents must come first: order the joints so, keeping glTF's order where it already is.
    let mut order: Vec<usize> = Vec::new();
    let mut placed = vec![false; nodes.len()];
    while order.len() < nodes.len() {
        let before = order.len();
        for (k, &n) in nodes.iter().enumerate() {
            let ready = parent[n].and_then(index_of).is_none_or(|p| placed[p]);
            if !placed[k] && ready {
                placed[k] = true;
                order.push(k);
            }
        }
        if order.len() == before {
            return Err(err(format!(
                "skin {}: joint hierarchy has a cycle",
                skin.index()
            )));
        }
    }
    if order.iter().enumerate().any(|(i, &k)| i != k) {
        return Err(err(format!(
            "skin {}: joints are listed after their children; reorder them",
            skin.index()
        )));
    }
    let ibm: Vec<Mat4> = match skin.inverse_bind_matrices() {
        Some(a) => {
            check_accessor(&a, buffers, &[D::Mat4], &[T::F32], "inverse bind matrices")?;
            if a.count() != nodes.len() {
                return Err(err(format!(
                    "skin {}: {} inverse bind matrices for {} joints",
                    skin.index(),
                    a.count(),
                    nodes.len()
                )));
            }
            let r = skin.reader(|b| Some(&buffers[b.index()][..]));
            r.read_inverse_bind_matrices()
                .ok_or_else(|| err("unreadable inverse bind matrices"))?
                .map(|m| Mat4::from_cols_array_2d(&m))
                .collect()
        }
        None => vec![Mat4::IDENTITY; nodes.len()], // the spec's default
    };
    if ibm.iter().any(|m| !m.is_finite()) {
        return Err(err(format!(
            "skin {}: non-finite inverse bind matrix",
            skin.index()
        )));
    }
    // The roots' parents are ordinary nodes: their world transform is the skeleton's root.
    let root = nodes
        .iter()
        .find_map(|&n| parent[n].filter(|p| index_of(*p).is_none()))
        .map_or(Mat4::IDENTITY, world);
    let joints = skin
        .joints()
        .map(|node| {
            let n = node.index();
            let (s, r, t) = local[n].to_scale_rotation_translation();
            Joint {
                name: node
                    .name()
                    .map_or_else(|| format!("joint {n}"), str::to_string),
                parent: parent[n].and_then(index_of),
                rest: Transform {
                    translation: t,
                    rotation: r,
                    scale: s,
                },
            }
        })
        .collect();
    Ok(Skeleton {
        joints,
        inverse_bind: ibm,
        root,
    })
}

/// The animation's channels on the skin's joints, and the morph target weights (`targets` per key) when
/// they drive the mesh node.
fn read_clip(
    a: &gltf::Animation,
    buffers: &[Vec<u8>],
    node_to_joint: &[Option<usize>],
    mesh_node: usize,
    targets: usize,
) -> Result<Clip> {
    let mut channels = Vec::new();
    let mut duration = 0f32;
    for ch in a.channels() {
        let what = format!("animation {} channel {}", a.index(), ch.index());
        let node = ch.target().node().index();
        let weights = ch.target().property() == gltf::animation::Property::MorphTargetWeights;
        let joint = match (weights, node_to_joint[node]) {
            (true, _) if node == mesh_node && targets > 0 => 0,
            (false, Some(j)) => j,
            _ => continue, // drives a node this character does not have
        };
        let sampler = ch.sampler();
        let interpolation = match sampler.interpolation() {
            gltf::animation::Interpolation::Step => Interpolation::Step,
            gltf::animation::Interpolation::Linear => Interpolation::Linear,
            gltf::animation::Interpolation::CubicSpline => Interpolation::CubicSpline,
        };
        check_accessor(&sampler.input(), buffers, &[D::Scalar], &[T::F32], &what)?;
        let (dims, types): (&[D], &[T]) = match ch.target().property() {
            gltf::animation::Property::Rotation => {
                (&[D::Vec4], &[T::F32, T::I8, T::U8, T::I16, T::U16])
            }
            gltf::animation::Property::MorphTargetWeights => {
                (&[D::Scalar], &[T::F32, T::I8, T::U8, T::I16, T::U16])
            }
            _ => (&[D::Vec3], &[T::F32]),
        };
        check_accessor(&sampler.output(), buffers, dims, types, &what)?;
        let reader = ch.reader(|b| Some(&buffers[b.index()][..]));
        let times: Vec<f32> = reader
            .read_inputs()
            .ok_or_else(|| err(format!("{what}: unreadable times")))?
            .collect();
        if let Some(k) = times.iter().position(|t| !t.is_finite()) {
            return Err(err(format!("{what}: key time {k} is {}", times[k])));
        }
        if let Some(k) = times.windows(2).position(|w| w[1] < w[0]) {
            return Err(err(format!("{what}: key times decrease at key {}", k + 1)));
        }
        let per_key = if interpolation == Interpolation::CubicSpline {
            3
        } else {
            1
        };
        // One channel per property, or per group of four morph targets: values as Vec4.
        let mut groups: Vec<(Property, Vec<Vec4>)> = match reader
            .read_outputs()
            .ok_or_else(|| err(format!("{what}: unreadable values")))?
        {
            gltf::animation::util::ReadOutputs::Translations(t) => vec![(
                Property::Translation,
                t.map(|v| Vec3::from_array(v).extend(0.0)).collect(),
            )],
            gltf::animation::util::ReadOutputs::Scales(s) => vec![(
                Property::Scale,
                s.map(|v| Vec3::from_array(v).extend(0.0)).collect(),
            )],
            gltf::animation::util::ReadOutputs::Rotations(r) => vec![(
                Property::Rotation,
                r.into_f32()
                    .map(|q| Vec4::from(Quat::from_array(q)))
                    .collect(),
            )],
            gltf::animation::util::ReadOutputs::MorphTargetWeights(w) => {
                let flat: Vec<f32> = w.into_f32().collect();
                if flat.len() != times.len() * per_key * targets {
                    return Err(err(format!(
                        "{what}: {} weights for {} keys of {targets} targets",
                        flat.len(),
                        times.len()
                    )));
                }
                (0..targets)
                    .step_by(4)
                    .map(|first| {
                        let values = flat
                            .chunks(targets)
                            .map(|key| {
                                let g = |k: usize| key.get(first + k).copied().unwrap_or(0.0);
                                Vec4::new(g(0), g(1), g(2), g(3))
                            })
                            .collect();
                        (Property::Weights { first }, values)
                    })
                    .collect()
            }
        };
        for (property, values) in groups.drain(..) {
            if let Some(k) = values.iter().position(|v| !v.is_finite()) {
                return Err(err(format!("{what}: value {k} is not finite")));
            }
            if values.len() != times.len() * per_key {
                return Err(err(format!(
                    "{what}: {} values for {} keys",
                    values.len(),
                    times.len()
                )));
            }
            channels.push(Channel {
                joint,
                property,
                interpolation,
                times: times.clone(),
                values,
            });
        }
        duration = duration.max(times.last().copied().unwrap_or(0.0));
    }
    Ok(Clip {
        name: a
            .name()
            .map_or_else(|| format!("animation {}", a.index()), str::to_string),
        duration,
        channels,
    })
}
