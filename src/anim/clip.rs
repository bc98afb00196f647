//! Animation clips: keyframed joint channels, sampled with glTF's interpolation rules.

use super::Transform;
use glam::{Quat, Vec3, Vec4};

/// How a channel interpolates between keys (glTF `sampler.interpolation`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interpolation {
    /// Hold the previous key.
    Step,
    /// Linear; rotations by spherical linear interpolation along the shorter arc.
    Linear,
    /// Cubic Hermite spline with per-key in/out tangents (values stored as in-tangent, value, out-tangent).
    CubicSpline,
}

/// Which property of a joint a channel drives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Property {
    /// Translation (xyz).
    Translation,
    /// Rotation (quaternion xyzw).
    Rotation,
    /// Scale (xyz).
    Scale,
    /// Morph target weights `first .. first + 4` (a channel per group of four targets).
    Weights {
        /// The group's first target.
        first: usize,
    },
}

/// One joint property over time. Values are `Vec4` (w unused for translation and scale); for
/// [`Interpolation::CubicSpline`] there are three per key.
#[derive(Clone, Debug, PartialEq)]
pub struct Channel {
    /// The joint driven.
    pub joint: usize,
    /// What is driven.
    pub property: Property,
    /// How.
    pub interpolation: Interpolation,
    /// Key times, increasing.
    pub times: Vec<f32>,
    /// Key values.
    pub values: Vec<Vec4>,
}

impl Channel {
    /// The value at `t`; before the first key the first value, after the last the last (glTF clamps). A
    /// NaN `t` gives the first value.
    pub fn sample(&self, t: f32) -> Vec4 {
        let n = self.times.len();
        let cubic = self.interpolation == Interpolation::CubicSpline;
        let value = |k: usize| {
            if cubic {
                self.values[3 * k + 1]
            } else {
                self.values[k]
            }
        };
        if n == 0 {
            return Vec4::ZERO;
        }
        if n == 1 || t.is_nan() || t <= self.times[0] {
            return value(0);
        }
        if t >= self.times[n - 1] {
            return value(n - 1);
        }
        // The key interval holding t: times[k] <= t < times[k + 1].
        let k = self.times.partition_point(|&x| x <= t) - 1;
        let (t0, t1) = (self.times[k], self.times[k + 1]);
        let dt = t1 - t0;
        let s = if dt > 0.0 { (t - t0) / dt } else { 0.0 };
        let rotation = self.property == Property::Rotation;
        match self.interpolation {
            Interpolation::Step => value(k),
            Interpolation::Linear if rotation => {
                let (a, b) = (Quat::from_vec4(value(k)), Quat::from_vec4(value(k + 1)));
                let b = if a.dot(b) < 0.0 { -b } else { b }; // the shorter arc
                Vec4::from(a.slerp(b, s))
            }
            Interpolation::Linear => value(k).lerp(value(k + 1), s),
            Interpolation::CubicSpline => {
                let (p0, m0) = (self.values[3 * k + 1], self.values[3 * k + 2] * dt);
                let (p1, m1) = (self.values[3 * (k + 1) + 1], self.values[3 * (k + 1)] * dt);
                let (s2, s3) = (s * s, s * s * s);
                let v = p0 * (2.0 * s3 - 3.0 * s2 + 1.0)
                    + m0 * (s3 - 2.0 * s2 + s)
                    + p1 * (-2.0 * s3 + 3.0 * s2)
                    + m1 * (s3 - s2);
                if rotation {
                    Vec4::from(Quat::from_vec4(v).normalize())
                } else {
                    v
                }
            }
        }
    }
}

/// A named set of channels.
#[derive(Clone, Debug, PartialEq)]
pub struct Clip {
    /// Name ("walk", "run", ...).
    pub name: String,
    /// The last key time of any channel.
    pub duration: f32,
    /// The channels.
    pub channels: Vec<Channel>,
}

impl Clip {
    /// Overwrites the driven properties of `pose` with their values at time `t` (a NaN `t` poses the
    /// first keys, see [`Channel::sample`]).
    pub fn sample(&self, t: f32, pose: &mut [Transform]) {
        for c in &self.channels {
            if matches!(c.property, Property::Weights { .. }) {
                continue;
            }
            let Some(j) = pose.get_mut(c.joint) else {
                continue;
            };
            let v = c.sample(t);
            match c.property {
                Property::Translation => j.translation = v.truncate(),
                Property::Rotation => j.rotation = Quat::from_vec4(v).normalize(),
                Property::Scale => j.scale = Vec3::new(v.x, v.y, v.z),
                Property::Weights { .. } => {}
            }
        }
    }

    /// Overwrites the animated morph target weights in `weights` with their values at time `t`.
    pub fn sample_weights(&self, t: f32, weights: &mut [f32]) {
        for c in &self.channels {
            if let Property::Weights { first } = c.property {
                let v = c.sample(t).to_array();
                for (k, w) in weights.iter_mut().skip(first).take(4).enumerate() {
                    *w = v[k];
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn channel(
        interpolation: Interpolation,
        property: Property,
        times: &[f32],
        values: &[Vec4],
    ) -> Channel {
        Channel {
            joint: 0,
            property,
            interpolation,
            times: times.to_vec(),
            values: values.to_vec(),
        }
    }

    #[test]
    fn step_linear_and_clamping_by_hand() {
        let v = [
            Vec4::new(0.0, 0.0, 0.0, 0.0),
            Vec4::new(10.0, 20.0, 0.0, 0.0),
            Vec4::new(20.0, 0.0, 0.0, 0.0),
        ];
        let step = channel(
            Interpolation::Step,
            Property::Translation,
            &[1.0, 2.0, 4.0],
            &v,
        );
        assert_eq!(step.sample(1.5).x, 0.0);
        assert_eq!(step.sample(2.0).x, 10.0);
        assert_eq!(step.sample(3.9).x, 10.0);
        let lin = channel(
            Interpolation::Linear,
            Property::Translation,
            &[1.0, 2.0, 4.0],
            &v,
        );
        assert!((lin.sample(1.25) - Vec4::new(2.5, 5.0, 0.0, 0.0)).length() < 1e-6);
        assert!((lin.sample(3.0) - Vec4::new(15.0, 10.0, 0.0, 0.0)).length() < 1e-6);
        // Before the first and after the last key: clamped.
        assert_eq!(lin.sample(-5.0), v[0]);
        assert_eq!(lin.sample(9.0), v[2]);
    }

    #[test]
    fn rotations_take_the_short_path() {
        // 350° about z is -10°: halfway between 0° and 350° must be -5°, not 175°.
        let a = Quat::IDENTITY;
        let b = Quat::from_rotation_z(350f32.to_radians());
        let c = channel(
            Interpolation::Linear,
            Property::Rotation,
            &[0.0, 1.0],
            &[Vec4::from(a), Vec4::from(b)],
        );
        let q = Quat::from_vec4(c.sample(0.5));
        let expect = Quat::from_rotation_z((-5f32).to_radians());
        assert!(q.dot(expect).abs() > 1.0 - 1e-6, "{q:?}");
    }

    #[test]
    fn cubic_spline_by_hand() {
        // Keys at t = 0 (value 0, out-tangent 1) and t = 2 (value 4, in-tangent 2): Hermite with tangents
        // scaled by the interval (2). At s = 0.5: p = 0·(0.5) + (1·2)·(0.125) + 4·(0.5) + (2·2)·(-0.125) = 1.75.
        let v = [
            Vec4::ZERO,
            Vec4::new(0.0, 0.0, 0.0, 0.0),
            Vec4::new(1.0, 0.0, 0.0, 0.0),
            Vec4::new(2.0, 0.0, 0.0, 0.0),
            Vec4::new(4.0, 0.0, 0.0, 0.0),
            Vec4::ZERO,
        ];
        let c = channel(
            Interpolation::CubicSpline,
            Property::Translation,
            &[0.0, 2.0],
            &v,
        );
        assert!((c.sample(1.0).x - 1.75).abs() < 1e-6, "{}", c.sample(1.0).x);
        assert_eq!(c.sample(0.0).x, 0.0);
        assert_eq!(c.sample(2.0).x, 4.0);
        assert_eq!(c.sample(3.0).x, 4.0);
    }
}
