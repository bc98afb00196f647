//! Writing a character as binary glTF (`.glb`): mesh, skin, joint hierarchy and animations, in one file
//! that [`load_gltf`](super::load_gltf) (and any glTF viewer) reads back.

use super::{CharacterAsset, Interpolation, Property};
use crate::{Error, Result};
use serde_json::{Value, json};

/// The bytes of a `.glb` file holding the character. Use it to look at a procedural character in a glTF
/// viewer or to save one; cost: one copy of the mesh, weights and keys, plus the JSON.
///
/// Layout: joints are nodes 0..n with their names and rest translation/rotation/scale; node n holds the mesh
/// and the skin; one scene holds the root joints and the mesh node. Positions f32, indices u32, JOINTS_0 u16,
/// WEIGHTS_0 f32, one animation per clip, named like it. Names are written as JSON strings, so any text
/// (quotes, backslashes, control characters) loads back unchanged. Morph targets are not written.
///
/// Errors: [`Error::Gltf`] when a rest transform, inverse bind matrix, weight or animation key is not finite
/// (glTF has no way to write it), or when the file would exceed the 4 GiB a GLB header can describe.
pub fn character_to_glb(c: &CharacterAsset) -> Result<Vec<u8>> {
    check_finite(c)?;
    let mut chunks = Chunks::default();
    let pos = c.mesh.positions();
    let (lo, hi) = pos.iter().fold(
        (glam::Vec3::splat(f32::MAX), glam::Vec3::splat(f32::MIN)),
        |(a, b), p| (a.min(*p), b.max(*p)),
    );
    let bounds = (lo.to_array().to_vec(), hi.to_array().to_vec());
    let a_pos = chunks.add(
        bytemuck::cast_slice(pos),
        pos.len(),
        F32,
        "VEC3",
        Some(bounds),
    );
    let idx = c.mesh.indices();
    let a_idx = chunks.add(bytemuck::cast_slice(idx), idx.len(), U32, "SCALAR", None);
    let w = &c.weights;
    let a_joints = chunks.add(
        bytemuck::cast_slice(&w.joints),
        w.joints.len(),
        U16,
        "VEC4",
        None,
    );
    let a_weights = chunks.add(
        bytemuck::cast_slice(&w.weights),
        w.weights.len(),
        F32,
        "VEC4",
        None,
    );
    let ibm: Vec<[f32; 16]> = c
        .skeleton
        .inverse_bind
        .iter()
        .map(|m| m.to_cols_array())
        .collect();
    let a_ibm = chunks.add(bytemuck::cast_slice(&ibm), ibm.len(), F32, "MAT4", None);
    let animations: Vec<Value> = c
        .clips
        .iter()
        .map(|clip| {
            let (mut channels, mut samplers) = (Vec::new(), Vec::new());
            for ch in &clip.channels {
                let (path, kind, values): (_, _, Vec<f32>) = match ch.property {
                    Property::Weights { .. } => continue, // morph targets are not written
                    Property::Rotation => (
                        "rotation",
                        "VEC4",
                        ch.values.iter().flat_map(|v| v.to_array()).collect(),
                    ),
                    Property::Translation | Property::Scale => (
                        if ch.property == Property::Scale {
                            "scale"
                        } else {
                            "translation"
                        },
                        "VEC3",
                        ch.values
                            .iter()
                            .flat_map(|v| v.truncate().to_array())
                            .collect(),
                    ),
                };
                let range = (
                    vec![ch.times.first().copied().unwrap_or(0.0)],
                    vec![ch.times.last().copied().unwrap_or(0.0)],
                );
                let t = &ch.times;
                let input =
                    chunks.add(bytemuck::cast_slice(t), t.len(), F32, "SCALAR", Some(range));
                let output = chunks.add(
                    bytemuck::cast_slice(&values),
                    ch.values.len(),
                    F32,
                    kind,
                    None,
                );
                let interpolation = match ch.interpolation {
                    Interpolation::Step => "STEP",
                    Interpolation::Linear => "LINEAR",
                    Interpolation::CubicSpline => "CUBICSPLINE",
                };
                channels.push(json!({
                    "sampler": samplers.len(),
                    "target": { "node": ch.joint, "path": path },
                }));
                samplers.push(
                    json!({ "input": input, "output": output, "interpolation": interpolation }),
                );
            }
            json!({ "name": clip.name, "channels": channels, "samplers": samplers })
        })
        .collect();
    let joints = &c.skeleton.joints;
    let mut nodes: Vec<Value> = joints
        .iter()
        .enumerate()
        .map(|(i, j)| {
            let (t, r, s) = (j.rest.translation, j.rest.rotation, j.rest.scale);
            let mut node = json!({
                "name": j.name,
                "translation": t.to_array(),
                "rotation": r.to_array(),
                "scale": s.to_array(),
            });
            let children: Vec<usize> = (0..joints.len())
                .filter(|&k| joints[k].parent == Some(i))
                .collect();
            if !children.is_empty() {
                node["children"] = json!(children);
            }
            node
        })
        .collect();
    nodes.push(json!({ "name": "character", "mesh": 0, "skin": 0 }));
    let mut scene_nodes: Vec<usize> = (0..joints.len())
        .filter(|&i| joints[i].parent.is_none())
        .collect();
    scene_nodes.push(joints.len());
    chunks.pad();
    let json = json!({
        "asset": { "version": "2.0", "generator": "kinetrace" },
        "scene": 0,
        "scenes": [{ "nodes": scene_nodes }],
        "nodes": nodes,
        "meshes": [{ "primitives": [{
            "attributes": { "POSITION": a_pos, "JOINTS_0": a_joints, "WEIGHTS_0": a_weights },
            "indices": a_idx,
            "mode": 4,
        }]}],
        "skins": [{ "inverseBindMatrices": a_ibm, "joints": (0..joints.len()).collect::<Vec<_>>() }],
        "animations": animations,
        "buffers": [{ "byteLength": chunks.bin.len() }],
        "bufferViews": chunks.views,
        "accessors": chunks.accessors,
    });
    glb(json.to_string().into_bytes(), &chunks.bin)
}

const F32: u32 = 5126;
const U32: u32 = 5125;
const U16: u32 = 5123;

/// The binary chunk being written, with its buffer views and accessors (one view per accessor, so both
/// share an index).
#[derive(Default)]
struct Chunks {
    bin: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Chunks {
    /// Appends raw bytes, 4-aligned, as a buffer view and an accessor of `count` elements over it, with
    /// optional `(min, max)`; returns their index.
    fn add(
        &mut self,
        bytes: &[u8],
        count: usize,
        component: u32,
        kind: &str,
        bounds: Option<(Vec<f32>, Vec<f32>)>,
    ) -> usize {
        self.pad();
        let n = self.views.len();
        self.views.push(json!({
            "buffer": 0,
            "byteOffset": self.bin.len(),
            "byteLength": bytes.len(),
        }));
        self.bin.extend_from_slice(bytes);
        let mut accessor = json!({
            "bufferView": n,
            "componentType": component,
            "count": count,
            "type": kind,
        });
        if let Some((min, max)) = bounds {
            accessor["min"] = json!(min);
            accessor["max"] = json!(max);
        }
        self.accessors.push(accessor);
        n
    }

    /// Zero bytes up to the next multiple of 4, as GLB chunks and glTF accessors require.
    fn pad(&mut self) {
        self.bin.resize(self.bin.len().next_multiple_of(4), 0);
    }
}

/// The GLB container: header, the JSON chunk (space-padded) and the binary chunk (already 4-aligned).
fn glb(mut json: Vec<u8>, bin: &[u8]) -> Result<Vec<u8>> {
    json.resize(json.len().next_multiple_of(4), b' ');
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let len = |n: usize| {
        u32::try_from(n)
            .map(u32::to_le_bytes)
            .map_err(|_| Error::Gltf(format!("a GLB of {total} bytes exceeds the format's 4 GiB")))
    };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&len(total)?);
    out.extend_from_slice(&len(json.len())?);
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(&len(bin.len())?);
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(bin);
    Ok(out)
}

/// Every float the file would hold is finite (positions are, by [`Mesh`](crate::Mesh)'s own check).
fn check_finite(c: &CharacterAsset) -> Result<()> {
    let bad = |what: String| Err(Error::Gltf(format!("cannot export: {what} is not finite")));
    for (i, j) in c.skeleton.joints.iter().enumerate() {
        let r = &j.rest;
        if !(r.translation.is_finite() && r.rotation.is_finite() && r.scale.is_finite()) {
            return bad(format!("the rest transform of joint {i} ({:?})", j.name));
        }
    }
    if let Some(i) = c.skeleton.inverse_bind.iter().position(|m| !m.is_finite()) {
        return bad(format!("inverse bind matrix {i}"));
    }
    if let Some(v) = c
        .weights
        .weights
        .iter()
        .position(|w| w.iter().any(|x| !x.is_finite()))
    {
        return bad(format!("the weights of vertex {v}"));
    }
    for clip in &c.clips {
        for (k, ch) in clip.channels.iter().enumerate() {
            let times = ch.times.iter().all(|t| t.is_finite());
            if !times || !ch.values.iter().all(|v| v.is_finite()) {
                return bad(format!("a key of clip {:?} channel {k}", clip.name));
            }
        }
    }
    Ok(())
}
