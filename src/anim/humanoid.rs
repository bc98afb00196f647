//! A procedural skinned humanoid (so nothing external is needed for demos and tests): 20 joints, capsule
//! limbs tessellated to any triangle count, two-joint blends near the joints, and walk, run and flail
//! clips.

use super::{Channel, Clip, Interpolation, Joint, Property, Skeleton, SkinWeights, Transform};
use crate::Mesh;
use glam::{Mat4, Quat, Vec3, Vec4};
use std::f32::consts::TAU;
use std::sync::Arc;

/// A skinned character: rest mesh, skeleton, weights and clips, shared by every instance.
#[derive(Clone, Debug)]
pub struct CharacterAsset {
    /// The mesh in its bind pose.
    pub mesh: Mesh,
    /// The joints.
    pub skeleton: Skeleton,
    /// Joints and weights per vertex.
    pub weights: Arc<SkinWeights>,
    /// Animations.
    pub clips: Vec<Clip>,
    /// Morph targets (blend shapes), applied to the rest positions before skinning.
    pub morphs: Option<Arc<MorphTargets>>,
}

/// Morph targets of a mesh: per target, a displacement per vertex; and the mesh's default weights.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct MorphTargets {
    /// `deltas[target][vertex]`.
    pub deltas: Vec<Vec<Vec3>>,
    /// One per target.
    pub default_weights: Vec<f32>,
}

impl MorphTargets {
    /// `out[v] = rest[v] + Σ_k weights[k] · deltas[k][v]`.
    pub fn apply(&self, rest: &[Vec3], weights: &[f32], out: &mut [Vec3]) {
        out.copy_from_slice(rest);
        for (d, &w) in self.deltas.iter().zip(weights) {
            if w != 0.0 {
                for (o, dv) in out.iter_mut().zip(d) {
                    *o += *dv * w;
                }
            }
        }
    }
}

impl CharacterAsset {
    /// The index of the clip with this name.
    pub fn clip(&self, name: &str) -> Option<usize> {
        self.clips.iter().position(|c| c.name == name)
    }
}

/// Joint names, parents and bind-pose positions (metres, y up, facing +z).
const JOINTS: [(&str, Option<usize>, [f32; 3]); 20] = [
    ("hips", None, [0.0, 1.0, 0.0]),
    ("spine", Some(0), [0.0, 1.15, 0.0]),
    ("spine2", Some(1), [0.0, 1.3, 0.0]),
    ("chest", Some(2), [0.0, 1.45, 0.0]),
    ("neck", Some(3), [0.0, 1.6, 0.0]),
    ("head", Some(4), [0.0, 1.68, 0.0]),
    ("shoulder.L", Some(3), [0.12, 1.55, 0.0]),
    ("upper_arm.L", Some(6), [0.22, 1.52, 0.0]),
    ("forearm.L", Some(7), [0.25, 1.24, 0.0]),
    ("hand.L", Some(8), [0.27, 0.98, 0.0]),
    ("shoulder.R", Some(3), [-0.12, 1.55, 0.0]),
    ("upper_arm.R", Some(10), [-0.22, 1.52, 0.0]),
    ("forearm.R", Some(11), [-0.25, 1.24, 0.0]),
    ("hand.R", Some(12), [-0.27, 0.98, 0.0]),
    ("thigh.L", Some(0), [0.1, 0.95, 0.0]),
    ("shin.L", Some(14), [0.1, 0.52, 0.0]),
    ("foot.L", Some(15), [0.1, 0.09, 0.0]),
    ("thigh.R", Some(0), [-0.1, 0.95, 0.0]),
    ("shin.R", Some(17), [-0.1, 0.52, 0.0]),
    ("foot.R", Some(18), [-0.1, 0.09, 0.0]),
];

/// The capsules: (joint that drives it, end point, radius). A capsule runs from its joint to the end.
fn capsules() -> Vec<(usize, Vec3, f32)> {
    let at = |j: usize| Vec3::from_array(JOINTS[j].2);
    vec![
        (0, at(1), 0.15),
        (1, at(2), 0.14),
        (2, at(3), 0.15),
        (3, at(4), 0.16),
        (4, at(5), 0.05),
        (5, at(5) + Vec3::Y * 0.2, 0.11),
        (6, at(7), 0.06),
        (7, at(8), 0.055),
        (8, at(9), 0.045),
        (9, at(9) - Vec3::Y * 0.15, 0.04),
        (10, at(11), 0.06),
        (11, at(12), 0.055),
        (12, at(13), 0.045),
        (13, at(13) - Vec3::Y * 0.15, 0.04),
        (14, at(15), 0.08),
        (15, at(16), 0.06),
        (16, at(16) + Vec3::new(0.0, -0.05, 0.18), 0.05),
        (17, at(18), 0.08),
        (18, at(19), 0.06),
        (19, at(19) + Vec3::new(0.0, -0.05, 0.18), 0.05),
    ]
}

/// A humanoid of about `triangles` triangles (clamped to 500..=2,000,000).
pub fn humanoid(triangles: usize) -> CharacterAsset {
    let caps = capsules();
    // Each capsule has `around` = 2·`along` segments (square-ish quads), `along` + 1 rings on the cylinder
    // and `cap` rings per end cap, closed by a fan at each pole: 2·around·(along + 2·cap + 1) triangles.
    // Pick the `along` whose count is nearest the target.
    let per = triangles.clamp(500, 2_000_000) / caps.len();
    let count = |along: usize| 4 * along * (along + 2 * (along / 2).max(1) + 1);
    let along = (1..200)
        .min_by_key(|&a| count(a).abs_diff(per))
        .expect("non-empty range");
    let around = 2 * along;
    let cap = (along / 2).max(1);
    let mut pos = Vec::new();
    let mut idx = Vec::new();
    let mut joints = Vec::new();
    let mut weights = Vec::new();
    for &(j, end, radius) in &caps {
        let start = Vec3::from_array(JOINTS[j].2);
        let parent = JOINTS[j].1;
        let axis = (end - start).normalize_or(Vec3::Y);
        let side = if axis.y.abs() > 0.9 { Vec3::X } else { Vec3::Y }
            .cross(axis)
            .normalize();
        let up = axis.cross(side);
        // Rings from the bottom pole to the top pole: cap, cylinder, cap.
        let mut rings: Vec<(Vec3, f32, f32)> = Vec::new(); // (centre, radius, position along 0..1)
        for k in 1..=cap {
            let a = (k as f32 / (cap + 1) as f32) * std::f32::consts::FRAC_PI_2;
            rings.push((start - axis * radius * a.cos(), radius * a.sin(), 0.0));
        }
        for k in 0..=along {
            let u = k as f32 / along as f32;
            rings.push((start.lerp(end, u), radius, u));
        }
        for k in (1..=cap).rev() {
            let a = (k as f32 / (cap + 1) as f32) * std::f32::consts::FRAC_PI_2;
            rings.push((end + axis * radius * a.cos(), radius * a.sin(), 1.0));
        }
        let base = pos.len() as u32;
        let bottom = base;
        let mut add = |p: Vec3, u: f32| {
            pos.push(p);
            // Blend with the parent joint over the first quarter of the bone.
            match parent {
                Some(pj) if u < 0.25 => {
                    let wp = 0.5 * (1.0 - u / 0.25);
                    joints.push([j as u16, pj as u16, 0, 0]);
                    weights.push([1.0 - wp, wp, 0.0, 0.0]);
                }
                _ => {
                    joints.push([j as u16, 0, 0, 0]);
                    weights.push([1.0, 0.0, 0.0, 0.0]);
                }
            }
        };
        add(start - axis * radius, 0.0);
        for &(c, r, u) in &rings {
            for s in 0..around {
                let a = s as f32 / around as f32 * TAU;
                add(c + (side * a.cos() + up * a.sin()) * r, u);
            }
        }
        add(end + axis * radius, 1.0);
        let top = pos.len() as u32 - 1;
        let ring = |k: usize, s: usize| base + 1 + (k * around + s % around) as u32;
        for s in 0..around {
            idx.extend([bottom, ring(0, s + 1), ring(0, s)]);
        }
        for k in 0..rings.len() - 1 {
            for s in 0..around {
                let (a, b, c, d) = (
                    ring(k, s),
                    ring(k, s + 1),
                    ring(k + 1, s + 1),
                    ring(k + 1, s),
                );
                idx.extend([a, b, c, a, c, d]);
            }
        }
        let last = rings.len() - 1;
        for s in 0..around {
            idx.extend([top, ring(last, s), ring(last, s + 1)]);
        }
    }
    let mesh = Mesh::new(pos, idx).expect("finite by construction");
    let skeleton = skeleton();
    CharacterAsset {
        mesh,
        clips: vec![
            walk(&skeleton, 1.0, 1.0),
            walk(&skeleton, 0.62, 1.9),
            flail(&skeleton),
        ],
        skeleton,
        weights: Arc::new(SkinWeights { joints, weights }),
        morphs: None,
    }
}

fn skeleton() -> Skeleton {
    let joints = JOINTS
        .iter()
        .map(|&(name, parent, p)| {
            let here = Vec3::from_array(p);
            let local = parent.map_or(here, |q| here - Vec3::from_array(JOINTS[q].2));
            Joint {
                name: name.into(),
                parent,
                rest: Transform::from_translation(local),
            }
        })
        .collect();
    let inverse_bind = JOINTS
        .iter()
        .map(|j| Mat4::from_translation(-Vec3::from_array(j.2)))
        .collect();
    Skeleton {
        joints,
        inverse_bind,
        root: Mat4::IDENTITY,
    }
}

fn joint(name: &str) -> usize {
    JOINTS
        .iter()
        .position(|j| j.0 == name)
        .expect("known joint")
}

/// A looping rotation channel about `axis` with angle `f(phase)` (phase in 0..1), 16 LINEAR keys.
fn swing(j: usize, period: f32, axis: Vec3, f: impl Fn(f32) -> f32) -> Channel {
    let keys = 16;
    let times = (0..=keys)
        .map(|k| k as f32 / keys as f32 * period)
        .collect();
    let values = (0..=keys)
        .map(|k| Vec4::from(Quat::from_axis_angle(axis, f(k as f32 / keys as f32))))
        .collect();
    Channel {
        joint: j,
        property: Property::Rotation,
        interpolation: Interpolation::Linear,
        times,
        values,
    }
}

/// A gait: legs swing and bend, arms counter-swing, the hips bob. `amp` scales every amplitude (run ≈ 1.9).
fn walk(s: &Skeleton, period: f32, amp: f32) -> Clip {
    let sin = |p: f32, shift: f32| (TAU * (p + shift)).sin();
    let mut channels = vec![
        swing(joint("thigh.L"), period, Vec3::X, move |p| {
            -0.45 * amp * sin(p, 0.0)
        }),
        swing(joint("thigh.R"), period, Vec3::X, move |p| {
            -0.45 * amp * sin(p, 0.5)
        }),
        swing(joint("shin.L"), period, Vec3::X, move |p| {
            0.35 * amp * (1.0 + sin(p, 0.25)).max(0.0)
        }),
        swing(joint("shin.R"), period, Vec3::X, move |p| {
            0.35 * amp * (1.0 + sin(p, 0.75)).max(0.0)
        }),
        swing(joint("upper_arm.L"), period, Vec3::X, move |p| {
            0.35 * amp * sin(p, 0.0)
        }),
        swing(joint("upper_arm.R"), period, Vec3::X, move |p| {
            0.35 * amp * sin(p, 0.5)
        }),
        swing(joint("forearm.L"), period, Vec3::X, move |_| -0.3 * amp),
        swing(joint("forearm.R"), period, Vec3::X, move |_| -0.3 * amp),
        swing(joint("spine"), period, Vec3::X, move |_| 0.08 * (amp - 1.0)),
    ];
    let hips = joint("hips");
    let rest = s.joints[hips].rest.translation;
    let keys = 16;
    channels.push(Channel {
        joint: hips,
        property: Property::Translation,
        interpolation: Interpolation::Linear,
        times: (0..=keys)
            .map(|k| k as f32 / keys as f32 * period)
            .collect(),
        values: (0..=keys)
            .map(|k| {
                (rest + Vec3::Y * 0.03 * amp * (2.0 * TAU * k as f32 / keys as f32).cos())
                    .extend(0.0)
            })
            .collect(),
    });
    Clip {
        name: if amp > 1.5 { "run" } else { "walk" }.into(),
        duration: period,
        channels,
    }
}

/// Arms windmill, the head shakes, the torso twists: incoherent limb motion for refit stress tests.
fn flail(_: &Skeleton) -> Clip {
    let period = 0.8;
    let channels = vec![
        swing(joint("upper_arm.L"), period, Vec3::X, |p| {
            1.6 * (TAU * p).sin()
        }),
        swing(joint("upper_arm.R"), period, Vec3::Z, |p| {
            1.4 * (TAU * (p + 0.3)).sin()
        }),
        swing(joint("forearm.L"), period, Vec3::Z, |p| {
            1.2 * (2.0 * TAU * p).sin()
        }),
        swing(joint("forearm.R"), period, Vec3::X, |p| {
            -1.1 * (2.0 * TAU * p).cos()
        }),
        swing(joint("head"), period, Vec3::Y, |p| {
            0.6 * (3.0 * TAU * p).sin()
        }),
        swing(joint("chest"), period, Vec3::Y, |p| 0.4 * (TAU * p).sin()),
        swing(joint("thigh.L"), period, Vec3::X, |p| {
            -0.7 * (TAU * p).sin()
        }),
        swing(joint("shin.R"), period, Vec3::X, |p| {
            0.8 * (1.0 + (TAU * p).cos())
        }),
    ];
    Clip {
        name: "flail".into(),
        duration: period,
        channels,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_joints_and_weights() {
        for t in [1_000, 10_000, 200_000] {
            let h = humanoid(t);
            let n = h.mesh.triangle_count();
            assert!(
                n as f64 > 0.7 * t as f64 && (n as f64) < 1.3 * t as f64,
                "{t}: {n}"
            );
            assert_eq!(h.skeleton.joints.len(), 20);
            h.weights.check(h.mesh.positions().len(), 20).unwrap();
            for w in &h.weights.weights {
                assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn rest_pose_skinning_is_the_identity() {
        let h = humanoid(2_000);
        let mut m = vec![Mat4::ZERO; 20];
        h.skeleton.skin_matrices(&h.skeleton.rest_pose(), &mut m);
        for x in &m {
            assert!(x.abs_diff_eq(Mat4::IDENTITY, 1e-6), "{x}");
        }
    }
}
