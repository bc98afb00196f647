//! The four-sided frustum (thesis §6.1.2): an apex and four corner rays, optionally cut by a near plane
//! (the reflector a reflected frustum starts on), with the geometric tests tracing needs.

use super::material::BANDS;
use crate::geometry::Aabb;
use glam::{Affine3A, Vec3};

/// A plane `n · x = c`; the positive side is `n · x > c`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Plane {
    pub n: Vec3,
    pub c: f32,
}

impl Plane {
    pub fn signed(&self, p: Vec3) -> f32 {
        self.n.dot(p) - self.c
    }
}

/// A frustum with its propagation history.
///
/// Corner directions are in the bilinear order `(0,0), (1,0), (1,1), (0,1)` of the frustum's parameter
/// square: the direction at `(u, v)` is the bilinear blend of the four (not normalised). Directions are
/// never normalised, so sub-frusta sharing a boundary compute it from identical numbers.
#[derive(Clone, Debug)]
pub(crate) struct Frustum {
    pub apex: Vec3,
    pub dirs: [Vec3; 4],
    /// Only points on the positive side are inside (the reflector's side the sound travels into).
    pub near: Option<Plane>,
    /// Surfaces reflected from so far, first reflection first.
    pub chain: Vec<u32>,
    /// Energy kept per band by the reflections so far.
    pub gain: [f32; BANDS],
}

/// The bilinear blend of four corner values at `(u, v)`.
#[inline]
pub(crate) fn bilerp<T>(c: [T; 4], u: f32, v: f32) -> T
where
    T: Copy + std::ops::Mul<f32, Output = T> + std::ops::Add<Output = T>,
{
    (c[0] * (1.0 - u) + c[1] * u) * (1.0 - v) + (c[3] * (1.0 - u) + c[2] * u) * v
}

impl Frustum {
    /// Frusta covering every direction around `source`: each cube face split into `m × m` cells.
    pub fn around(source: Vec3, m: usize) -> Vec<Frustum> {
        let mut out = Vec::with_capacity(6 * m * m);
        let g = |i: usize| -1.0 + 2.0 * i as f32 / m as f32;
        for axis in 0..3 {
            for sign in [1.0f32, -1.0] {
                let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
                let at = |i: usize, j: usize| {
                    let mut p = Vec3::ZERO;
                    p[axis] = sign;
                    p[b] = g(i);
                    p[c] = g(j);
                    p
                };
                for j in 0..m {
                    for i in 0..m {
                        out.push(Frustum {
                            apex: source,
                            dirs: [at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)],
                            near: None,
                            chain: Vec::new(),
                            gain: [1.0; BANDS],
                        });
                    }
                }
            }
        }
        out
    }

    /// Direction at `(u, v)` of the parameter square.
    #[inline]
    pub fn dir_at(&self, u: f32, v: f32) -> Vec3 {
        bilerp(self.dirs, u, v)
    }

    /// Inward normals of the four side planes through the apex (side `i` joins corners `i` and `i + 1`).
    pub fn side_normals(&self) -> [Vec3; 4] {
        let centre = self.dir_at(0.5, 0.5);
        std::array::from_fn(|i| {
            let n = self.dirs[i].cross(self.dirs[(i + 1) % 4]);
            if n.dot(centre) < 0.0 { -n } else { n }
        })
    }

    /// True when `p` lies inside the four side planes and beyond the near plane. Half-open: the `v = 0` and
    /// `u = 0` sides count as inside, the other two not, so neighbouring sub-frusta never both claim a point.
    pub fn contains(&self, p: Vec3) -> bool {
        let d = p - self.apex;
        let s = self.side_normals().map(|n| n.dot(d));
        s[0] >= 0.0
            && s[3] >= 0.0
            && s[1] > 0.0
            && s[2] > 0.0
            && self.near.is_none_or(|pl| pl.signed(p) > 0.0)
    }

    /// What culling needs of the frustum traced with `n × n` centre samples: with `n` up to
    /// [`SAMPLE_PLANES`], also the planes through the apex holding each column and each row of sample rays.
    pub fn cull(&self, n: usize) -> Cull {
        let mut cols = [Vec3::ZERO; SAMPLE_PLANES];
        let mut rows = [Vec3::ZERO; SAMPLE_PLANES];
        let planes = if n <= SAMPLE_PLANES { n } else { 0 };
        for k in 0..planes {
            let t = (k as f32 + 0.5) / n as f32;
            // Column u = t: d(t, v) = (1 − v)·A + v·B; row v = t: d(u, t) = (1 − u)·L + u·R.
            cols[k] = self.dir_at(t, 0.0).cross(self.dir_at(t, 1.0));
            rows[k] = self.dir_at(0.0, t).cross(self.dir_at(1.0, t));
        }
        Cull {
            apex: self.apex,
            sides: self.side_normals(),
            near: self.near,
            cols,
            rows,
            planes,
        }
    }

    /// The sub-frustum over the parameter rectangle `[u0, u1] × [v0, v1]`, reflected in `plane` (unit
    /// normal) of surface `surface`, its gain multiplied by `reflectance`.
    pub fn reflected(
        &self,
        (u0, v0, u1, v1): (f32, f32, f32, f32),
        plane: Plane,
        surface: u32,
        reflectance: &[f32; BANDS],
    ) -> Frustum {
        let mirror = |d: Vec3| d - 2.0 * d.dot(plane.n) * plane.n;
        let side = plane.signed(self.apex);
        let near = if side >= 0.0 {
            plane
        } else {
            Plane {
                n: -plane.n,
                c: -plane.c,
            }
        };
        let mut chain = self.chain.clone();
        chain.push(surface);
        let mut gain = self.gain;
        for (g, r) in gain.iter_mut().zip(reflectance) {
            *g *= r;
        }
        Frustum {
            apex: self.apex - 2.0 * side * plane.n,
            dirs: [
                mirror(self.dir_at(u0, v0)),
                mirror(self.dir_at(u1, v0)),
                mirror(self.dir_at(u1, v1)),
                mirror(self.dir_at(u0, v1)),
            ],
            near: Some(near),
            chain,
            gain,
        }
    }
}

/// The most sample rays per frustum side whose planes [`Cull`] keeps; finer sampling culls by the
/// frustum's planes alone.
pub(crate) const SAMPLE_PLANES: usize = 16;

/// The planes bounding a frustum, for culling boxes: the apex, the inward normals of the four side planes
/// through it, the near plane, and the planes through the apex holding each column and each row of the
/// centre sample rays (tracing only ever asks what those rays hit).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Cull {
    pub apex: Vec3,
    pub sides: [Vec3; 4],
    pub near: Option<Plane>,
    /// Normals of the column planes, `planes` of them.
    pub cols: [Vec3; SAMPLE_PLANES],
    /// Normals of the row planes, `planes` of them.
    pub rows: [Vec3; SAMPLE_PLANES],
    /// Sample planes kept per direction (0: none, the sampling is finer than [`SAMPLE_PLANES`]).
    pub planes: usize,
}

impl Cull {
    /// Conservative frustum–box test: false only when the box lies wholly outside one side plane, wholly
    /// behind the near plane, or strictly between two neighbouring columns or rows of sample rays (so no
    /// sample ray meets it, a node small against the samples' spacing). Cost: about 30 flops, plus two dot
    /// products per sample plane for boxes inside the frustum.
    pub fn may_overlap(&self, b: &Aabb) -> bool {
        let far_corner = |n: Vec3| Vec3::select(n.cmpge(Vec3::ZERO), b.max, b.min);
        if !(self
            .sides
            .iter()
            .all(|&n| n.dot(far_corner(n) - self.apex) >= 0.0)
            && self
                .near
                .is_none_or(|pl| pl.signed(far_corner(pl.n)) >= 0.0))
        {
            return false;
        }
        if self.planes == 0 {
            return true;
        }
        let (centre, half) = ((b.min + b.max) * 0.5 - self.apex, (b.max - b.min) * 0.5);
        meets_a_plane(&self.cols[..self.planes], centre, half)
            && meets_a_plane(&self.rows[..self.planes], centre, half)
    }

    /// The same planes in the object space of an instance placed by `to_world` (`p = M q + t`), whose
    /// inverse is `to_object`: a plane `n · p = c` becomes `(Mᵀn) · q = c − n · t`, so inside stays inside.
    pub fn in_object_space(&self, to_world: &Affine3A, to_object: &Affine3A) -> Cull {
        let mt = to_world.matrix3.transpose();
        Cull {
            apex: to_object.transform_point3(self.apex),
            sides: self.sides.map(|n| mt * n),
            near: self.near.map(|pl| Plane {
                n: mt * pl.n,
                c: pl.c - pl.n.dot(Vec3::from(to_world.translation)),
            }),
            cols: self.cols.map(|n| mt * n),
            rows: self.rows.map(|n| mt * n),
            planes: self.planes,
        }
    }
}

/// True when the box of centre `centre` (from the apex) and half-extents `half` touches one of the planes
/// through the apex with these normals, with a relative slack of 1e-5 so rounding never culls a box a
/// sample ray reaches. Two dot products a plane.
#[inline]
fn meets_a_plane(normals: &[Vec3], centre: Vec3, half: Vec3) -> bool {
    normals.iter().any(|&n| {
        let (c, r) = (n.dot(centre).abs(), n.abs().dot(half));
        c - r <= 1e-5 * (c + r)
    })
}

/// Distance from `p` to the nearest point of `b` (0 inside).
pub(crate) fn box_distance(p: Vec3, b: &Aabb) -> f32 {
    (b.min - p).max(p - b.max).max(Vec3::ZERO).length()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whether the ray `o + t·d`, `t ≥ 0`, meets the box: a slab test in f64, written here.
    fn ray_meets(o: Vec3, d: Vec3, b: &Aabb) -> bool {
        let (mut lo, mut hi) = (0.0f64, f64::INFINITY);
        for a in 0..3 {
            let (o, d) = (o[a] as f64, d[a] as f64);
            let (p, q) = (b.min[a] as f64, b.max[a] as f64);
            if d == 0.0 {
                if o < p || o > q {
                    return false;
                }
                continue;
            }
            let (t0, t1) = ((p - o) / d, (q - o) / d);
            lo = lo.max(t0.min(t1));
            hi = hi.min(t0.max(t1));
        }
        lo <= hi
    }

    #[test]
    fn sample_plane_culling_keeps_every_box_a_sample_ray_meets() {
        let mut seed = 0x2545_f491u64;
        let mut rand = move || {
            seed = seed
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (seed >> 40) as f32 / (1u64 << 24) as f32
        };
        let centre = |i: usize, n: usize| (i as f32 + 0.5) / n as f32;
        for (k, f) in Frustum::around(Vec3::new(0.3, -0.2, 0.1), 2)
            .iter()
            .enumerate()
            .step_by(5)
        {
            let n = 4;
            let cull = f.cull(n);
            let sides_only = Cull { planes: 0, ..cull };
            let (mut met, mut culled) = (0, 0);
            for _ in 0..4000 {
                let at = f.apex + f.dir_at(rand(), rand()) * (0.5 + 4.0 * rand());
                let half = Vec3::new(rand(), rand(), rand()) * 0.15 + Vec3::splat(0.005);
                let b = Aabb {
                    min: at - half,
                    max: at + half,
                };
                let hit = (0..n).any(|j| {
                    (0..n).any(|i| ray_meets(f.apex, f.dir_at(centre(i, n), centre(j, n)), &b))
                });
                if hit {
                    met += 1;
                    assert!(
                        cull.may_overlap(&b),
                        "frustum {k}: {b:?} culled, a sample ray meets it"
                    );
                }
                culled += usize::from(sides_only.may_overlap(&b) && !cull.may_overlap(&b));
            }
            // Both outcomes occur: the test is not vacuous and the sample planes do cull.
            assert!(
                met > 400 && culled > 400,
                "frustum {k}: {met} met, {culled} culled"
            );
        }
    }
}
