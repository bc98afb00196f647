//! 32-bit ray keys: rays with equal keys start near each other and point the same way.
//!
//! Layouts, most significant field first, packed into the low bits of the key (unused high bits are zero):
//!
//! - shadow: `light (light_bits) | direction (2 · shadow_direction_bits)`
//! - reflection: `origin (3 · origin_bits) | direction (2 · reflection_direction_bits)`
//!
//! The direction field interleaves the bits of a polar step and an azimuth step (the polar step's bit first
//! in each pair: a 2D Morton code). The polar step cuts `cos θ` (θ ∈ [0, π], the polar angle from +z) into
//! `2^bits` equal steps from +z (step 0) to -z: bands of equal solid angle. The azimuth step cuts the
//! diamond angle of `(x, y)` — a piecewise-linear stand-in for φ ∈ (-π, π], the azimuth from +x, that rises
//! with φ and meets it at every multiple of π/2 — into `2^bits` equal steps from φ = -π (step 0, the -x
//! axis, y = ±0 alike) on. Both steps rise with their angle, so the keys sort rays as θ and φ would; only
//! the step boundaries differ from equal angle steps. A direction along ±z (x = y = 0) takes azimuth step 0.
//! The origin field interleaves x, y, z (a 3D Morton code) of the origin's cell in a grid of
//! `2^origin_bits` cells per axis over the batch's origin bounds (the virtual grid of Garanzha & Loop). The
//! seed gives neither the bit counts nor the order of the fields; ours interleave because a θ-major key
//! sorts a run of rays into a thin ring of directions around the whole circle of φ, a cone wider than the
//! request order's (measured in `bench raysort`: 1.75× RAH's tests for one light before, fewer after). The
//! defaults fill 32 bits per kind. Cost: one square root and two divisions per ray, and bit spreads by
//! masks (no `acos`/`atan2`, no loop over bits): a few ns.

use crate::geometry::{Aabb, spread10};
use crate::{Error, Result};
use glam::Vec3;

use super::{RayKind, SecondaryRay};

/// Bit counts of the key fields (see the module docs for the layout).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct KeyLayout {
    /// Bits of the light index in shadow keys.
    pub light_bits: u32,
    /// Bits of each spherical angle in shadow keys.
    pub shadow_direction_bits: u32,
    /// Bits of each origin coordinate in reflection keys.
    pub origin_bits: u32,
    /// Bits of each spherical angle in reflection keys.
    pub reflection_direction_bits: u32,
}

impl Default for KeyLayout {
    /// 16 lights and 14 bits per angle for shadow rays; 16 cells per axis and 10 bits per angle for
    /// reflection rays.
    fn default() -> Self {
        Self {
            light_bits: 4,
            shadow_direction_bits: 14,
            origin_bits: 4,
            reflection_direction_bits: 10,
        }
    }
}

impl KeyLayout {
    /// `Error::InvalidOption` unless each kind's fields fit in 32 bits and each angle has at least one bit.
    pub fn validate(&self) -> Result<()> {
        let shadow = self.light_bits as u64 + 2 * self.shadow_direction_bits as u64;
        let reflection = 3 * self.origin_bits as u64 + 2 * self.reflection_direction_bits as u64;
        if shadow > 32 || reflection > 32 {
            return Err(Error::InvalidOption(format!(
                "ray key layout needs {shadow} bits for shadow and {reflection} for reflection rays, at most 32"
            )));
        }
        if self.shadow_direction_bits == 0 || self.reflection_direction_bits == 0 {
            return Err(Error::InvalidOption(
                "ray key layout: each angle needs at least one bit".into(),
            ));
        }
        Ok(())
    }

    /// The key of a valid ray; `origins` bounds the origins of the batch's reflection rays.
    pub fn key(&self, r: &SecondaryRay, origins: &Aabb) -> u32 {
        let d = r.ray.dir();
        match r.kind {
            RayKind::Shadow { light } => {
                let light = light as u64 & mask(self.light_bits);
                let dir = direction(d, self.shadow_direction_bits);
                ((light << (2 * self.shadow_direction_bits)) | dir) as u32
            }
            RayKind::Reflection => {
                let b = self.origin_bits;
                // Each axis's cell, its bits spread to every third place.
                let cell = |axis: usize| {
                    let extent = origins.max[axis] - origins.min[axis];
                    let f = if extent > 0.0 {
                        (r.ray.origin[axis] - origins.min[axis]) / extent
                    } else {
                        0.0
                    };
                    u64::from(spread10(quantise(f, b) as u32))
                };
                let origin = (cell(0) << 2) | (cell(1) << 1) | cell(2);
                let dir = direction(d, self.reflection_direction_bits);
                ((origin << (2 * self.reflection_direction_bits)) | dir) as u32
            }
        }
    }
}

fn mask(bits: u32) -> u64 {
    (1u64 << bits) - 1
}

/// `f ∈ [0, 1]` in `2^bits` equal steps (out-of-range values clamp to the ends, NaN to step 0: `max`
/// returns its other operand). Clamped in `f32` (the last step, at most `2^16 − 1`, is exact; `max` and
/// `min` rather than `clamp`, which checks its bounds on every call) and converted to `u32`: a saturating
/// conversion to `u64` costs x86-64 a branch and twice the instructions, on five fields of every key.
fn quantise(f: f32, bits: u32) -> u64 {
    let last = mask(bits) as f32;
    u64::from((f * (last + 1.0)).max(0.0).min(last) as u32)
}

/// The low 16 bits of `x` moved to the even bit places (bit `i` to bit `2i`).
fn spread2(x: u64) -> u64 {
    let mut x = x & 0xffff;
    x = (x | x << 8) & 0x00ff_00ff;
    x = (x | x << 4) & 0x0f0f_0f0f;
    x = (x | x << 2) & 0x3333_3333;
    (x | x << 1) & 0x5555_5555
}

/// The polar and azimuth steps of a non-zero direction, `bits` each (at most 16), interleaved.
fn direction(d: Vec3, bits: u32) -> u64 {
    let cos_theta = d.z / d.length();
    let polar = quantise((1.0 - cos_theta) * 0.5, bits);
    // The diamond angle from -x, in [0, 4] (one unit per quarter turn): with x' = x / (|x| + |y|), 1 + x'
    // on the half turn y ≤ 0 and 3 - x' on y > 0. Along ±z, x' = -1: step 0.
    let s = d.x.abs() + d.y.abs();
    let x = if s > 0.0 { d.x / s } else { -1.0 };
    let diamond = if d.y <= 0.0 { 1.0 + x } else { 3.0 - x };
    let azimuth = quantise(diamond * 0.25, bits);
    (spread2(polar) << 1) | spread2(azimuth)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Ray;

    fn ray(o: Vec3, d: Vec3, kind: RayKind) -> SecondaryRay {
        SecondaryRay {
            ray: Ray::new(o, d),
            kind,
            tag: 0,
        }
    }

    #[test]
    fn fields_land_where_documented() {
        let l = KeyLayout::default();
        let b = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let key = |o: Vec3, d: Vec3, kind| l.key(&ray(o, d, kind), &b);
        // +z: polar step 0; x = y = 0: azimuth step 0.
        assert_eq!(
            key(Vec3::ZERO, Vec3::Z, RayKind::Shadow { light: 3 }),
            3 << 28
        );
        // -z: the last polar step, in the odd bits; light 19 keeps its low 4 bits.
        let k = key(Vec3::ZERO, -Vec3::Z, RayKind::Shadow { light: 19 });
        assert_eq!(k, (3 << 28) | 0x0aaa_aaaa);
        // +x: cos θ = 0, the middle polar step (bit 13, interleaved to bit 27); φ = 0, half a turn from
        // -x: the middle azimuth step (bit 13, to bit 26).
        let k = key(Vec3::ZERO, Vec3::X, RayKind::Shadow { light: 0 });
        assert_eq!(k, (1 << 27) | (1 << 26));
        // +y: φ = π/2, three quarter turns from -x: azimuth bits 13 and 12, to bits 26 and 24.
        let k = key(Vec3::ZERO, Vec3::Y, RayKind::Shadow { light: 1 });
        assert_eq!(k, (1 << 28) | (1 << 27) | (1 << 26) | (1 << 24));
        // -x: azimuth step 0.
        let k = key(Vec3::ZERO, -Vec3::X, RayKind::Shadow { light: 0 });
        assert_eq!(k, 1 << 27);
        // Origin at the box's max corner: the last cell on each axis.
        assert_eq!(key(Vec3::ONE, Vec3::Z, RayKind::Reflection) >> 20, 0xfff);
        // Origin cell (1, 0, 1) of 16 per axis at bit 0 of each coordinate: bits 2 and 0 of the field.
        let o = Vec3::new(1.5, 0.2, 1.5) / 16.0;
        assert_eq!(key(o, Vec3::Z, RayKind::Reflection) >> 20, 0b101);
    }

    /// The steps rise with θ and φ, against f64 `acos` and `atan2`: sorted by the true angle, a step
    /// never falls, except between directions within rounding (1e-5 rad) of each other; the azimuth
    /// step lies in the quarter turn that `atan2` gives, and the polar step is `(1 - cos θ) / 2` in
    /// 2^14 steps, up to one step where that value lies within rounding of a boundary.
    #[test]
    fn steps_rise_with_the_angles() {
        let bits = 14;
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let mut dirs: Vec<(f64, f64, u64, u64)> = (0..20_000)
            .map(|i| {
                let mut d = Vec3::new(next() as f32, next() as f32, next() as f32);
                // Some directions in the planes of the axes, where a quarter turn ends.
                match i % 7 {
                    0 => d.x = 0.0,
                    1 => d.y = 0.0,
                    2 => d.z = 0.0,
                    _ => {}
                }
                let (x, y, z) = (d.x as f64, d.y as f64, d.z as f64);
                let theta = (z / (x * x + y * y + z * z).sqrt()).acos();
                // φ = π (y = +0, x < 0) is the -x axis, which the key counts from -π.
                let phi = y.atan2(x);
                let phi = if phi == std::f64::consts::PI {
                    -phi
                } else {
                    phi
                };
                let k = direction(d, bits);
                let (mut polar, mut azimuth) = (0, 0);
                for b in 0..bits {
                    azimuth |= ((k >> (2 * b)) & 1) << b;
                    polar |= ((k >> (2 * b + 1)) & 1) << b;
                }
                (theta, phi, polar, azimuth)
            })
            .filter(|d| d.0.is_finite())
            .collect();
        let steps = (1u64 << bits) as f64;
        for &(theta, phi, polar, azimuth) in &dirs {
            let exact = (1.0 - theta.cos()) / 2.0 * steps;
            let near_edge = (exact - exact.round()).abs() < 1e-2;
            let want = (exact as u64).min(steps as u64 - 1);
            assert!(
                polar == want || (near_edge && polar.abs_diff(want) <= 1),
                "θ {theta}: step {polar}, want {want}"
            );
            let quarter = ((phi + std::f64::consts::PI) / std::f64::consts::FRAC_PI_2).floor();
            let on_edge =
                ((phi + std::f64::consts::PI) / std::f64::consts::FRAC_PI_2 - quarter) < 1e-6;
            let got = (azimuth as f64 / (steps / 4.0)).floor();
            assert!(
                got == quarter.min(3.0) || (on_edge && (got - quarter).abs() <= 1.0),
                "φ {phi}: step {azimuth} in quarter {got}, atan2's quarter {quarter}"
            );
        }
        for (angle, step) in [(0usize, 2usize), (1, 3)] {
            let key = |d: &(f64, f64, u64, u64)| [d.0, d.1][angle];
            let step_of = |d: &(f64, f64, u64, u64)| [0, 0, d.2, d.3][step];
            dirs.sort_by(|a, b| key(a).total_cmp(&key(b)));
            for w in dirs.windows(2) {
                assert!(
                    step_of(&w[1]) >= step_of(&w[0]) || key(&w[1]) - key(&w[0]) < 1e-5,
                    "angle {angle}: {:?} then {:?}",
                    w[0],
                    w[1]
                );
            }
        }
    }

    #[test]
    fn layouts_over_32_bits_are_errors() {
        let mut l = KeyLayout::default();
        assert!(l.validate().is_ok());
        l.light_bits = 5;
        assert!(matches!(l.validate(), Err(Error::InvalidOption(_))));
        l = KeyLayout {
            origin_bits: 5,
            ..Default::default()
        };
        assert!(l.validate().is_err());
    }
}
