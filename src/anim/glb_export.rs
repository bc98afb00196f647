//! Writing a character as binary glTF (`.glb`): mesh, skin, joint hierarchy and animations, in one file
//! that [`load_gltf`](super::load_gltf) (and any glTF viewer) reads back.

use super::{CharacterAsset, Interpolation, Property};
use std::fmt::Write;

/// The bytes of a `.glb` file holding the character.
///
/// Layout: joints are nodes 0..n with their rest translation/rotation/scale; node n holds the mesh and the
/// skin; one scene holds the root joints and the mesh node. Positions f32, indices u32, JOINTS_0 u16,
/// WEIGHTS_0 f32, one animation per clip. Morph targets are not written.
pub fn character_to_glb(c: &CharacterAsset) -> Vec<u8> {
    let mut bin: Vec<u8> = Vec::new();
    let mut views = String::new();
    let mut accessors = String::new();
    // Appends raw bytes as a buffer view and an accessor over it (one view per accessor, so both share an
    // index); returns that index.
    let mut next = 0usize;
    let mut add = |bytes: &[u8], count: usize, component: u32, kind: &str, extra: &str| -> usize {
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        let (n, sep) = (next, if next == 0 { "" } else { "," });
        next += 1;
        let _ = write!(
            views,
            "{sep}{{\"buffer\":0,\"byteOffset\":{},\"byteLength\":{}}}",
            bin.len(),
            bytes.len()
        );
        bin.extend_from_slice(bytes);
        let _ = write!(
            accessors,
            "{sep}{{\"bufferView\":{n},\"componentType\":{component},\"count\":{count},\"type\":\"{kind}\"{extra}}}"
        );
        n
    };
    const F32: u32 = 5126;
    const U32: u32 = 5125;
    const U16: u32 = 5123;
    let pos = c.mesh.positions();
    let (lo, hi) = pos.iter().fold(
        (glam::Vec3::splat(f32::MAX), glam::Vec3::splat(f32::MIN)),
        |(a, b), p| (a.min(*p), b.max(*p)),
    );
    let minmax = format!(
        ",\"min\":[{},{},{}],\"max\":[{},{},{}]",
        lo.x, lo.y, lo.z, hi.x, hi.y, hi.z
    );
    let a_pos = add(bytemuck::cast_slice(pos), pos.len(), F32, "VEC3", &minmax);
    let a_idx = add(
        bytemuck::cast_slice(c.mesh.indices()),
        c.mesh.indices().len(),
        U32,
        "SCALAR",
        "",
    );
    let a_joints = add(
        bytemuck::cast_slice(&c.weights.joints),
        c.weights.joints.len(),
        U16,
        "VEC4",
        "",
    );
    let a_weights = add(
        bytemuck::cast_slice(&c.weights.weights),
        c.weights.weights.len(),
        F32,
        "VEC4",
        "",
    );
    let ibm: Vec<[f32; 16]> = c
        .skeleton
        .inverse_bind
        .iter()
        .map(|m| m.to_cols_array())
        .collect();
    let a_ibm = add(bytemuck::cast_slice(&ibm), ibm.len(), F32, "MAT4", "");
    let mut animations = String::new();
    for (k, clip) in c.clips.iter().enumerate() {
        let (mut channels, mut samplers) = (String::new(), String::new());
        for (i, ch) in clip
            .channels
            .iter()
            .filter(|c| !matches!(c.property, Property::Weights { .. }))
            .enumerate()
        {
            let (tmin, tmax) = (
                ch.times.first().copied().unwrap_or(0.0),
                ch.times.last().copied().unwrap_or(0.0),
            );
            let input = add(
                bytemuck::cast_slice(&ch.times),
                ch.times.len(),
                F32,
                "SCALAR",
                &format!(",\"min\":[{tmin}],\"max\":[{tmax}]"),
            );
            let (path, values): (&str, Vec<f32>) = match ch.property {
                Property::Weights { .. } => unreachable!("filtered out above"),
                Property::Rotation => (
                    "rotation",
                    ch.values.iter().flat_map(|v| v.to_array()).collect(),
                ),
                Property::Translation => (
                    "translation",
                    ch.values
                        .iter()
                        .flat_map(|v| v.truncate().to_array())
                        .collect(),
                ),
                Property::Scale => (
                    "scale",
                    ch.values
                        .iter()
                        .flat_map(|v| v.truncate().to_array())
                        .collect(),
                ),
            };
            let kind = if ch.property == Property::Rotation {
                "VEC4"
            } else {
                "VEC3"
            };
            let output = add(
                bytemuck::cast_slice(&values),
                ch.values.len(),
                F32,
                kind,
                "",
            );
            let interp = match ch.interpolation {
                Interpolation::Step => "STEP",
                Interpolation::Linear => "LINEAR",
                Interpolation::CubicSpline => "CUBICSPLINE",
            };
            let sep = if i == 0 { "" } else { "," };
            let _ = write!(
                channels,
                "{sep}{{\"sampler\":{i},\"target\":{{\"node\":{},\"path\":\"{path}\"}}}}",
                ch.joint
            );
            let _ = write!(
                samplers,
                "{sep}{{\"input\":{input},\"output\":{output},\"interpolation\":\"{interp}\"}}"
            );
        }
        let sep = if k == 0 { "" } else { "," };
        let _ = write!(
            animations,
            "{sep}{{\"name\":{:?},\"channels\":[{channels}],\"samplers\":[{samplers}]}}",
            clip.name
        );
    }
    let n = c.skeleton.joints.len();
    let mut nodes = String::new();
    for (i, j) in c.skeleton.joints.iter().enumerate() {
        let children: Vec<String> = c
            .skeleton
            .joints
            .iter()
            .enumerate()
            .filter(|(_, x)| x.parent == Some(i))
            .map(|(k, _)| k.to_string())
            .collect();
        let (t, r, s) = (j.rest.translation, j.rest.rotation, j.rest.scale);
        let _ = write!(
            nodes,
            "{{\"name\":{:?},\"translation\":[{},{},{}],\"rotation\":[{},{},{},{}],\"scale\":[{},{},{}]{}}},",
            j.name,
            t.x,
            t.y,
            t.z,
            r.x,
            r.y,
            r.z,
            r.w,
            s.x,
            s.y,
            s.z,
            if children.is_empty() {
                String::new()
            } else {
                format!(",\"children\":[{}]", children.join(","))
            }
        );
    }
    let _ = write!(nodes, "{{\"name\":\"character\",\"mesh\":0,\"skin\":0}}");
    let roots: Vec<String> = c
        .skeleton
        .joints
        .iter()
        .enumerate()
        .filter(|(_, j)| j.parent.is_none())
        .map(|(i, _)| i.to_string())
        .collect();
    let joint_list: Vec<String> = (0..n).map(|i| i.to_string()).collect();
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let json = format!(
        "{{\"asset\":{{\"version\":\"2.0\",\"generator\":\"kinetrace\"}},\"scene\":0,\"scenes\":[{{\"nodes\":[{},{n}]}}],\"nodes\":[{nodes}],\
\"meshes\":[{{\"primitives\":[{{\"attributes\":{{\"POSITION\":{a_pos},\"JOINTS_0\":{a_joints},\"WEIGHTS_0\":{a_weights}}},\"indices\":{a_idx},\"mode\":4}}]}}],\
\"skins\":[{{\"inverseBindMatrices\":{a_ibm},\"joints\":[{}]}}],\"animations\":[{animations}],\
\"buffers\":[{{\"byteLength\":{}}}],\"bufferViews\":[{views}],\"accessors\":[{accessors}]}}",
        roots.join(","),
        joint_list.join(","),
        bin.len()
    );
    let mut json = json.into_bytes();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out
}
