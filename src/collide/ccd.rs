//! Continuous collision detection (CCD) for triangles whose corners move
//! linearly over one frame.
//!
//! Every corner moves on a straight line from its previous position (frame
//! parameter `t = 0`) to its current one (`t = 1`). [`triangle_pair_toi`]
//! reports the first time in `[0, 1]` at which two such triangles touch.
//!
//! # Method
//!
//! Following Provot (1997, "Collision and self-collision handling in cloth
//! model dedicated to design garments") and Bridson, Fedkiw & Anderson (2002,
//! "Robust treatment of collisions, contact and friction for cloth
//! animation"), a triangle pair is split into 15 elementary tests: each of
//! the 6 corners against the other triangle's face and each of the 9 edge
//! pairs. In every elementary test four points move linearly and can only
//! touch while they are coplanar, i.e. at a zero of the cubic
//!
//! ```text
//! f(t) = det[x1(t) − x0(t), x2(t) − x0(t), x3(t) − x0(t)]
//! ```
//!
//! Its coefficients are computed in `f64` from the `f32` inputs, relative to
//! one of the points and from two "element" vectors (the triangle's edges, or
//! the two edges) and one connecting vector, which keeps cancellation small.
//! The zeros are isolated without any closed-form cubic formula:
//!
//! 1. The critical points (roots of the quadratic `f'`, by the
//!    cancellation-free formula, which stays accurate when the leading
//!    coefficient is tiny relative to the others and degenerates to the
//!    linear and constant cases) split `[0, 1]` into at most three pieces on
//!    which `f` is monotone.
//! 2. On each piece, the sign change of `f` is refined to full `f64`
//!    precision (Illinois regula falsi safeguarded by bisection), and around
//!    it the *band* where `|f| ≤ ε_f` is bracketed, with `ε_f` an a-priori
//!    bound on the rounding error of `f` (`64 ε` times the product of the
//!    magnitudes of the three vectors and their velocities; its half-width
//!    is `ε_f / |f'|`, about `1e-13` for unit geometry moving a unit per
//!    frame and `1e-7` for a motion of `1e-7`). Every exact zero
//!    of `f` lies in a band. A zero where `f` only touches zero (double
//!    root) gives a band at a critical point, so it is not lost for lack of
//!    a sign change; when the points are coplanar throughout (`f ≡ 0`), the
//!    band is all of `[0, 1]`.
//! 3. In each band, candidate times are tested with the exact distance
//!    between the two elements, computed in `f64`; the first one within the
//!    tolerance is the contact. A band is skipped at once when the distance
//!    at its start exceeds the tolerance by more than the relative motion
//!    over the band can close (the distance changes at most at the largest
//!    relative speed of two corners); that settles most bands with one
//!    distance test. If `f` is beyond the noise at the band's start, the
//!    exact `f` has at most one zero in the band, so the refined root is
//!    tried first. Otherwise (the points are coplanar within noise at the
//!    start of the band: a contact at `t = 0`, a touching root, coplanar
//!    motion) the candidates in time order are the band's start, the
//!    *in-plane events* and the root. The events are the times at which the
//!    2D configuration inside the common plane can change: a point becoming
//!    collinear with an edge of the other element (every root of every
//!    component of the cross product, a quadratic in `t`) and two points
//!    meeting (closest approach of two linearly moving points, which covers
//!    points that stay collinear). In exactly coplanar motion the first
//!    contact is at the band's start or at one of these events.
//!
//! The contact tolerance is `1e-8` times the element size (the longest edge
//! over the frame) plus a rounding floor of `16 ε` times the magnitudes of
//! the relative positions and velocities (`ε = f64::EPSILON` throughout). It
//! decides *whether* the elements touch at a candidate time; *when* is
//! decided by the zero of `f`: the reported time is the refined zero for a
//! simple or touching root, accurate to rounding, and only where `f` is
//! within noise from the start of a piece (contact at `t = 0`, coplanar
//! motion) the first passing candidate of the band. A tolerance therefore
//! does not make contacts be reported early.
//!
//! Non-finite inputs give `None`. All arithmetic stays finite for finite
//! `f32` inputs (the largest products are around `1e235`), so no function
//! here returns NaN or panics.

use glam::{DVec3, Vec3};

/// Which elementary test found a contact.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Feature {
    /// Vertex `vertex` (0..3) of triangle a hits the face of triangle b.
    VertexFace {
        /// Corner of triangle a.
        vertex: u8,
    },
    /// Vertex `vertex` (0..3) of triangle b hits the face of triangle a.
    FaceVertex {
        /// Corner of triangle b.
        vertex: u8,
    },
    /// Edge `edge_a` of a (corners `edge_a`, `edge_a + 1 mod 3`) hits edge
    /// `edge_b` of b.
    EdgeEdge {
        /// Edge of triangle a.
        edge_a: u8,
        /// Edge of triangle b.
        edge_b: u8,
    },
}

/// The first time of contact of a moving triangle pair.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimeOfImpact {
    /// Frame parameter of the first contact, in `[0, 1]`.
    pub t: f32,
    /// The elementary test that found it.
    pub feature: Feature,
    /// Contact position at time `t`: the vertex for vertex–face contacts, the
    /// midpoint of the closest points of the two edges for edge–edge ones.
    pub point: Vec3,
}

/// Contact tolerance relative to the size of the elements.
const REL_TOL: f64 = 1e-8;
/// Rounding-error bound of `f(t)` relative to the product of the magnitudes
/// of its three vectors and their velocities: a worst-case count over the
/// relative vectors, the coefficients' triple products and Horner's scheme
/// gives about `16 ε`; four times that leaves a margin.
const COPLANAR_NOISE: f64 = 64.0 * f64::EPSILON;
/// Rounding floor of the distance computations, relative to the magnitudes of
/// the relative positions and velocities.
const DISTANCE_NOISE: f64 = 16.0 * f64::EPSILON;
/// Step limit of the root refinement; it includes at least 66 bisections,
/// which reach `1e-20`, far below the resolution of `f64` near 1.
const SOLVE_STEPS: usize = 200;
/// Capacity for in-plane events: at most 4 point–edge pairs × 3 components ×
/// 2 roots + 4 point pairs = 28.
const MAX_EVENTS: usize = 32;

/// Vertex `p` moving from `p[0]` to `p[1]` against the triangle moving from
/// `tri[0]` to `tri[1]`: the smallest `t` in `[0, 1]` at which `p` lies on the
/// closed triangle, or `None`. "On" allows a distance of `1e-8` times the
/// longest edge of the triangle; degenerate triangles are segments or points.
///
/// Use it for a single vertex–face query; [`triangle_pair_toi`] runs six of
/// these plus nine [`edge_edge_toi`]. Cost: about 200 flops to set up the
/// cubic, then per coplanarity time a root refinement (about ten cubic
/// evaluations) and one distance test, a few more when the vertex passes
/// within reach of the face: roughly 0.1 to 0.5 µs.
pub fn vertex_face_toi(p: [Vec3; 2], tri: [[Vec3; 3]; 2]) -> Option<f32> {
    let test = Elementary::vertex_face(p, tri)?;
    test.first_contact(1.0).map(|c| to_f32_time(c.t))
}

/// Edge `(p, q)` moving from `e0[0]` to `e0[1]` against edge `(r, s)` moving
/// from `e1[0]` to `e1[1]`: the smallest `t` in `[0, 1]` at which the closed
/// segments intersect (within `1e-8` times the longer edge), or `None`.
///
/// Use it for a single edge–edge query; the cost is that of
/// [`vertex_face_toi`].
pub fn edge_edge_toi(e0: [[Vec3; 2]; 2], e1: [[Vec3; 2]; 2]) -> Option<f32> {
    let test = Elementary::edge_edge(e0, e1)?;
    test.first_contact(1.0).map(|c| to_f32_time(c.t))
}

/// The earliest contact of two moving triangles, `a = [corners at t = 0,
/// corners at t = 1]` and likewise `b`, over the 15 elementary tests (6
/// vertex–face, 9 edge–edge), or `None` if they do not touch during the frame.
/// As in every test of this kind, contact means a vertex on a face or an
/// edge on an edge: triangles that already interpenetrate at `t = 0` are
/// reported only if such a contact happens during the frame.
///
/// Ties go to the first test in the order vertex–face (corners of a),
/// face–vertex (corners of b), edge–edge (edges of a major, edges of b
/// minor). Use it as the narrow phase after a broad phase over swept bounds.
/// Cost: nothing beyond a box test when the boxes swept by the triangles are
/// apart, otherwise 15 elementary tests (each later one stops looking past
/// the earliest contact found so far), typically 2 to 8 µs.
pub fn triangle_pair_toi(a: &[[Vec3; 3]; 2], b: &[[Vec3; 3]; 2]) -> Option<TimeOfImpact> {
    if !a.iter().chain(b).flatten().all(|v| v.is_finite()) || swept_boxes_apart(a, b) {
        return None;
    }
    let mut best: Option<(Contact, Feature, [DVec3; 2])> = None;
    let mut consider = |test: Elementary, feature: Feature| {
        let t_max = best.as_ref().map_or(1.0, |(c, _, _)| c.t);
        if let Some(c) = test.first_contact(t_max)
            && best.as_ref().is_none_or(|(b, _, _)| c.t < b.t)
        {
            best = Some((c, feature, test.origin));
        }
    };
    let corner = |tri: &[[Vec3; 3]; 2], i: usize| [tri[0][i], tri[1][i]];
    let edge = |tri: &[[Vec3; 3]; 2], i: usize| {
        let j = (i + 1) % 3;
        [[tri[0][i], tri[0][j]], [tri[1][i], tri[1][j]]]
    };
    for (i, vertex) in (0..3).zip(0u8..) {
        if let Some(test) = Elementary::vertex_face(corner(a, i), *b) {
            consider(test, Feature::VertexFace { vertex });
        }
    }
    for (i, vertex) in (0..3).zip(0u8..) {
        if let Some(test) = Elementary::vertex_face(corner(b, i), *a) {
            consider(test, Feature::FaceVertex { vertex });
        }
    }
    for (i, edge_a) in (0..3).zip(0u8..) {
        for (j, edge_b) in (0..3).zip(0u8..) {
            if let Some(test) = Elementary::edge_edge(edge(a, i), edge(b, j)) {
                consider(test, Feature::EdgeEdge { edge_a, edge_b });
            }
        }
    }
    best.map(|(c, feature, origin)| {
        let at = origin[0] + (origin[1] - origin[0]) * c.t + c.point;
        TimeOfImpact {
            t: to_f32_time(c.t),
            feature,
            point: at.as_vec3(),
        }
    })
}

/// Whether the boxes swept by the two triangles over the frame (the bounds
/// of their corners at `t = 0` and `t = 1`) are apart by more than
/// `1e-6` of their extent, far more than any contact tolerance: then no
/// elementary test can report a contact.
fn swept_boxes_apart(a: &[[Vec3; 3]; 2], b: &[[Vec3; 3]; 2]) -> bool {
    let bounds = |tri: &[[Vec3; 3]; 2]| {
        let corners = tri.iter().flatten().map(|c| c.as_dvec3());
        corners.fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), c| {
            (lo.min(c), hi.max(c))
        })
    };
    let ((a_lo, a_hi), (b_lo, b_hi)) = (bounds(a), bounds(b));
    let margin = 1e-6 * (a_hi.max(b_hi) - a_lo.min(b_lo)).max_element();
    (a_lo - b_hi).max(b_lo - a_hi).max_element() > margin
}

/// `f64` time to the public `f32`, kept inside `[0, 1]`.
fn to_f32_time(t: f64) -> f32 {
    (t as f32).clamp(0.0, 1.0)
}

/// A contact found by an elementary test: its time and the contact point
/// relative to the test's origin at that time.
#[derive(Clone, Copy, Debug)]
struct Contact {
    t: f64,
    point: DVec3,
}

/// A linearly moving vector `x(t) = x0 + t·dx` in `f64`.
#[derive(Clone, Copy, Debug, Default)]
struct Moving {
    x0: DVec3,
    dx: DVec3,
}

impl Moving {
    /// The trajectory of point `x` relative to point `origin`.
    fn relative(x: [Vec3; 2], origin: [Vec3; 2]) -> Self {
        let x0 = x[0].as_dvec3() - origin[0].as_dvec3();
        let x1 = x[1].as_dvec3() - origin[1].as_dvec3();
        Self { x0, dx: x1 - x0 }
    }

    fn at(self, t: f64) -> DVec3 {
        self.x0 + self.dx * t
    }

    /// Upper bound of `|x(t)|` over `[0, 1]`.
    fn magnitude(self) -> f64 {
        self.x0.length() + self.dx.length()
    }

    /// Larger of `|x(0)|` and `|x(1)|`, i.e. the maximum of `|x(t)|` on `[0, 1]`.
    fn max_length(self) -> f64 {
        self.x0.length().max((self.x0 + self.dx).length())
    }

    fn sub(self, o: Self) -> Self {
        Self {
            x0: self.x0 - o.x0,
            dx: self.dx - o.dx,
        }
    }

    fn add(self, o: Self) -> Self {
        Self {
            x0: self.x0 + o.x0,
            dx: self.dx + o.dx,
        }
    }
}

/// The two kinds of elementary test.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    /// Triangle `(0, u, v)` against the vertex `w`.
    VertexFace,
    /// Segment `(0, u)` against the segment `(w, w + v)`.
    EdgeEdge,
}

/// One elementary test: four linearly moving points expressed relative to
/// the first one (`origin`), as two element vectors `u`, `v` and the
/// connecting vector `w` (see [`Kind`]). Coplanarity is `det[u, v, w] = 0`.
#[derive(Clone, Copy, Debug)]
struct Elementary {
    kind: Kind,
    /// Absolute position of the origin point at `t = 0` and `t = 1`.
    origin: [DVec3; 2],
    u: Moving,
    v: Moving,
    w: Moving,
    /// Distance below which the elements are in contact.
    tol: f64,
    /// Largest relative speed of a point of one element against a point of
    /// the other: the Lipschitz constant of their distance in `t`.
    speed: f64,
}

impl Elementary {
    /// Vertex `p` against the face `tri`, relative to the face's first corner;
    /// `None` if an input is not finite.
    fn vertex_face(p: [Vec3; 2], tri: [[Vec3; 3]; 2]) -> Option<Self> {
        if !p.iter().chain(tri.iter().flatten()).all(|x| x.is_finite()) {
            return None;
        }
        let a = [tri[0][0], tri[1][0]];
        let u = Moving::relative([tri[0][1], tri[1][1]], a);
        let v = Moving::relative([tri[0][2], tri[1][2]], a);
        let w = Moving::relative(p, a);
        let size = u
            .max_length()
            .max(v.max_length())
            .max(v.sub(u).max_length());
        let speed =
            w.dx.length()
                .max((w.dx - u.dx).length())
                .max((w.dx - v.dx).length());
        Some(Self::new(Kind::VertexFace, a, u, v, w, size, speed))
    }

    /// Segment `e0` against segment `e1`, relative to the first endpoint of
    /// `e0`; `None` if an input is not finite.
    fn edge_edge(e0: [[Vec3; 2]; 2], e1: [[Vec3; 2]; 2]) -> Option<Self> {
        if !e0.iter().chain(&e1).flatten().all(|x| x.is_finite()) {
            return None;
        }
        let p = [e0[0][0], e0[1][0]];
        let r = [e1[0][0], e1[1][0]];
        let u = Moving::relative([e0[0][1], e0[1][1]], p);
        let v = Moving::relative([e1[0][1], e1[1][1]], r);
        let w = Moving::relative(r, p);
        let size = u.max_length().max(v.max_length());
        let s = w.dx + v.dx;
        let speed =
            w.dx.length()
                .max(s.length())
                .max((w.dx - u.dx).length())
                .max((s - u.dx).length());
        Some(Self::new(Kind::EdgeEdge, p, u, v, w, size, speed))
    }

    /// Shared constructor: the tolerance is `REL_TOL` times the element size
    /// plus the rounding floor of the relative positions.
    fn new(
        kind: Kind,
        origin: [Vec3; 2],
        u: Moving,
        v: Moving,
        w: Moving,
        size: f64,
        speed: f64,
    ) -> Self {
        let magnitude = u.magnitude().max(v.magnitude()).max(w.magnitude());
        Self {
            kind,
            origin: origin.map(Vec3::as_dvec3),
            u,
            v,
            w,
            tol: REL_TOL * size + DISTANCE_NOISE * magnitude,
            speed,
        }
    }

    /// Coefficients `[d0, d1, d2, d3]` of `f(t) = u(t) · (v(t) × w(t))`.
    fn cubic(&self) -> [f64; 4] {
        let (u0, du) = (self.u.x0, self.u.dx);
        let (v0, dv) = (self.v.x0, self.v.dx);
        let (w0, dw) = (self.w.x0, self.w.dx);
        [
            u0.dot(v0.cross(w0)),
            du.dot(v0.cross(w0)) + u0.dot(dv.cross(w0)) + u0.dot(v0.cross(dw)),
            u0.dot(dv.cross(dw)) + du.dot(v0.cross(dw)) + du.dot(dv.cross(w0)),
            du.dot(dv.cross(dw)),
        ]
    }

    /// Distance between the two elements at time `t` and the contact point
    /// (relative to the origin): the vertex for vertex–face, the midpoint of
    /// the closest points for edge–edge.
    fn distance(&self, t: f64) -> (f64, DVec3) {
        let (u, v, w) = (self.u.at(t), self.v.at(t), self.w.at(t));
        match self.kind {
            Kind::VertexFace => (point_triangle_distance(w, DVec3::ZERO, u, v), w),
            Kind::EdgeEdge => segment_segment_distance(DVec3::ZERO, u, w, w + v),
        }
    }

    /// The earliest contact, if it happens at a time in `[0, t_max]` (see the
    /// module documentation for the method). `t_max` only prunes work: the
    /// answer is the unbounded one, filtered.
    fn first_contact(&self, t_max: f64) -> Option<Contact> {
        let d = self.cubic();
        let eps = COPLANAR_NOISE * self.u.magnitude() * self.v.magnitude() * self.w.magnitude();
        let f = |t: f64| ((d[3] * t + d[2]) * t + d[1]) * t + d[0];
        let df = |t: f64| (3.0 * d[3] * t + 2.0 * d[2]) * t + d[1];
        // Critical points split [0, 1] into pieces on which f is monotone.
        let (mut crit, count) = quadratic_roots(3.0 * d[3], 2.0 * d[2], d[1]);
        crit[..count].sort_by(f64::total_cmp);
        let mut bounds = [0.0; 4];
        let mut n = 1;
        for &c in &crit[..count] {
            if c > bounds[n - 1] && c < 1.0 {
                bounds[n] = c;
                n += 1;
            }
        }
        bounds[n] = 1.0;
        let mut events = None;
        for piece in bounds[..=n].windows(2) {
            // Bands of later pieces start at or after this piece's end.
            if piece[0] > t_max {
                return None;
            }
            if let Some(band) = coplanar_band(&f, &df, piece[0], piece[1], eps)
                && let Some(c) = self.search_band(band, &mut events)
            {
                return (c.t <= t_max).then_some(c);
            }
        }
        None
    }

    /// The earliest contact inside one coplanarity band.
    fn search_band(&self, band: Band, events: &mut Option<Events>) -> Option<Contact> {
        let Band { lo, hi, root, open } = band;
        let (d_lo, point) = self.distance(lo);
        if open && d_lo <= self.tol {
            return Some(Contact { t: lo, point });
        }
        // Within the band the distance cannot drop faster than `speed`.
        if d_lo - self.tol > self.speed * (hi - lo) {
            return None;
        }
        // If f is beyond the noise at the start of the band, the exact f is
        // monotone and nonzero there, so it has at most one zero in the band,
        // near `root`: the contact, if any, is there.
        if !open {
            let (dist, point) = self.distance(root);
            if dist <= self.tol {
                return Some(Contact { t: root, point });
            }
        }
        // Otherwise the in-plane events, and the root of an open band, in
        // time order.
        let events = events.get_or_insert_with(|| self.events());
        let mut times = [0.0; MAX_EVENTS + 1];
        let mut count = 0;
        let root = if open { Some(root) } else { None };
        for t in events.times().iter().copied().chain(root) {
            if (lo..=hi).contains(&t) {
                times[count] = t;
                count += 1;
            }
        }
        times[..count].sort_by(f64::total_cmp);
        for &t in &times[..count] {
            let (dist, point) = self.distance(t);
            if dist <= self.tol {
                return Some(Contact { t, point });
            }
        }
        None
    }

    /// The in-plane events in `[0, 1]`, unsorted: times at which a point of one
    /// element is collinear with an edge of the other (per component of the
    /// cross product) and closest approaches of point pairs.
    fn events(&self) -> Events {
        let mut ev = Events::default();
        let origin = Moving::default();
        match self.kind {
            Kind::VertexFace => {
                let (a, b, c, p) = (origin, self.u, self.v, self.w);
                for (x, y) in [(a, b), (b, c), (c, a)] {
                    ev.collinear(p, x, y);
                    ev.approach(p, x);
                }
            }
            Kind::EdgeEdge => {
                let (p, q, r) = (origin, self.u, self.w);
                let s = r.add(self.v);
                for x in [p, q] {
                    ev.collinear(x, r, s);
                    ev.approach(x, r);
                    ev.approach(x, s);
                }
                for x in [r, s] {
                    ev.collinear(x, p, q);
                }
            }
        }
        ev
    }
}

/// Part of a monotone piece of `[0, 1]` where `|f| ≤ ε_f`, with the time of
/// the sign change of `f` in it (or of its smallest `|f|`).
#[derive(Clone, Copy, Debug)]
struct Band {
    lo: f64,
    hi: f64,
    root: f64,
    /// The band starts at the start of its piece, where `f` may vanish. If
    /// not, `lo` is where `|f|` fell to `ε_f`, so `f(lo) ≠ 0` exactly and
    /// `lo` itself is no contact time.
    open: bool,
}

/// The band of `|f| ≤ eps` on the piece `[s, e]`, on which `f` (derivative
/// `df`) is monotone; `None` if `f` stays away from zero there. The band is
/// widened to points found outside it, so it contains every exact zero of
/// `f`.
fn coplanar_band(
    f: &impl Fn(f64) -> f64,
    df: &impl Fn(f64) -> f64,
    s: f64,
    e: f64,
    eps: f64,
) -> Option<Band> {
    let sign = if f(s) <= f(e) { 1.0 } else { -1.0 };
    let g = |t: f64| sign * f(t);
    let (gs, ge) = (g(s), g(e));
    if gs > eps || ge < -eps {
        return None;
    }
    let root = if gs >= 0.0 {
        s
    } else if ge <= 0.0 {
        e
    } else {
        crossing(&g, 0.0, s, e).1
    };
    let open = gs >= -eps;
    // The band edges: first a guess from the slope at the root (twice the
    // linear estimate), checked; else the crossing itself.
    let slope = sign * df(root);
    let guess = |c: f64| root + 2.0 * (c - g(root)) / slope;
    let lo = if open {
        s
    } else {
        let t = guess(-eps);
        if t >= s && t < root && g(t) < -eps {
            t
        } else {
            crossing(&g, -eps, s, root).0
        }
    };
    let hi = if ge <= eps {
        e
    } else {
        let t = guess(eps);
        if t <= e && t > root && g(t) > eps {
            t
        } else {
            crossing(&g, eps, root, e).1
        }
    };
    Some(Band { lo, hi, root, open })
}

/// Where the increasing function `g` reaches `c` on `[a, b]`, given
/// `g(a) < c ≤ g(b)`: a bracket `(below, above)` with `g(below) < c ≤
/// g(above)` as narrow as `f64` allows (or with `g(above) = c` exactly).
///
/// Illinois variant of regula falsi (superlinear, usually under ten
/// evaluations). Safeguard: every third step, if the bracket has not halved
/// since the previous such check, the step is a bisection, so the bracket
/// halves at least every three steps even where `g` is flat or noisy.
fn crossing(g: &impl Fn(f64) -> f64, c: f64, mut a: f64, mut b: f64) -> (f64, f64) {
    let (mut ga, mut gb) = (g(a) - c, g(b) - c);
    let (mut kept_a, mut kept_b) = (0, 0); // how often in a row each end was kept
    let mut checked_width = b - a;
    for step in 0..SOLVE_STEPS {
        let mut x = a - ga * (b - a) / (gb - ga);
        if step % 3 == 2 {
            if b - a > 0.5 * checked_width {
                x = 0.5 * (a + b);
            }
            checked_width = b - a;
        }
        if !(x > a && x < b) {
            x = 0.5 * (a + b);
            if !(x > a && x < b) {
                break; // a and b are adjacent floats
            }
        }
        let gx = g(x) - c;
        if gx < 0.0 {
            (a, ga) = (x, gx);
            (kept_a, kept_b) = (0, kept_b + 1);
            if kept_b > 1 {
                gb *= 0.5;
            }
        } else {
            (b, gb) = (x, gx);
            if gx == 0.0 {
                break;
            }
            (kept_a, kept_b) = (kept_a + 1, 0);
            if kept_a > 1 {
                ga *= 0.5;
            }
        }
    }
    (a, b)
}

/// Real roots of `a t² + b t + c` by the cancellation-free formula
/// (`q = −(b + sign(b)√disc)/2`, roots `q/a` and `c/q`), which stays
/// accurate when `a` is tiny compared with `b` and `c`. A negative
/// discriminant gives the vertex `−b / 2a` instead (a near-double root; an
/// extra candidate is harmless to every caller). Degenerates to the linear
/// case and to no root for a constant.
fn quadratic_roots(a: f64, b: f64, c: f64) -> ([f64; 2], usize) {
    if a == 0.0 {
        return if b == 0.0 {
            ([0.0; 2], 0)
        } else {
            ([-c / b, 0.0], 1)
        };
    }
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 {
        return ([-b / (2.0 * a), 0.0], 1);
    }
    let q = -0.5 * (b + disc.sqrt().copysign(b));
    if q == 0.0 {
        ([0.0; 2], 1)
    } else {
        ([q / a, c / q], 2)
    }
}

/// A small set of event times in `[0, 1]` (no allocation).
#[derive(Clone, Copy, Debug)]
struct Events {
    t: [f64; MAX_EVENTS],
    n: usize,
}

impl Default for Events {
    fn default() -> Self {
        Self {
            t: [0.0; MAX_EVENTS],
            n: 0,
        }
    }
}

impl Events {
    fn times(&self) -> &[f64] {
        &self.t[..self.n]
    }

    fn push(&mut self, t: f64) {
        if (0.0..=1.0).contains(&t) && self.n < MAX_EVENTS {
            self.t[self.n] = t;
            self.n += 1;
        }
    }

    /// Times at which `p` is collinear with the line through `a` and `b`:
    /// every root of every component of the quadratic `(a − p) × (b − p)`.
    fn collinear(&mut self, p: Moving, a: Moving, b: Moving) {
        let (x, y) = (a.sub(p), b.sub(p));
        let c0 = x.x0.cross(y.x0);
        let c1 = x.x0.cross(y.dx) + x.dx.cross(y.x0);
        let c2 = x.dx.cross(y.dx);
        for k in 0..3 {
            let (roots, count) = quadratic_roots(c2[k], c1[k], c0[k]);
            for &t in &roots[..count] {
                self.push(t);
            }
        }
    }

    /// Time of closest approach of the points `p` and `a`.
    fn approach(&mut self, p: Moving, a: Moving) {
        let d = a.sub(p);
        let dd = d.dx.length_squared();
        if dd > 0.0 {
            self.push(-d.x0.dot(d.dx) / dd);
        }
    }
}

/// Distance from `p` to the closed triangle `(a, b, c)`, which may be
/// degenerate: the smaller of the distances to the three edges and, when the
/// projection of `p` falls inside, the distance to the plane.
fn point_triangle_distance(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let edges = point_segment(p, a, b)
        .0
        .min(point_segment(p, b, c).0)
        .min(point_segment(p, c, a).0);
    let n = (b - a).cross(c - a);
    let nn = n.length_squared();
    let inside = nn > 0.0
        && n.dot((b - a).cross(p - a)) >= 0.0
        && n.dot((c - b).cross(p - b)) >= 0.0
        && n.dot((a - c).cross(p - c)) >= 0.0;
    if inside {
        let h = n.dot(p - a);
        edges.min((h * h / nn).sqrt())
    } else {
        edges
    }
}

/// Distance from `p` to the segment `(a, b)` and the closest point.
fn point_segment(p: DVec3, a: DVec3, b: DVec3) -> (f64, DVec3) {
    let d = b - a;
    let dd = d.length_squared();
    let s = if dd > 0.0 {
        ((p - a).dot(d) / dd).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let x = a + d * s;
    ((p - x).length(), x)
}

/// Distance between the segments `(p, q)` and `(r, s)` and the midpoint of
/// the closest points: the best of the four endpoint–segment pairs and, when
/// the lines' common perpendicular lands inside both segments, of that pair.
/// The line parameters use cross products, so near-parallel segments lose no
/// more than rounding in the distance.
fn segment_segment_distance(p: DVec3, q: DVec3, r: DVec3, s: DVec3) -> (f64, DVec3) {
    let mut best = (f64::INFINITY, p);
    let mut consider = |x: DVec3, y: DVec3| {
        let d = (x - y).length();
        if d < best.0 {
            best = (d, 0.5 * (x + y));
        }
    };
    consider(p, point_segment(p, r, s).1);
    consider(q, point_segment(q, r, s).1);
    consider(r, point_segment(r, p, q).1);
    consider(s, point_segment(s, p, q).1);
    let (d1, d2, rp) = (q - p, s - r, r - p);
    let n = d1.cross(d2);
    let nn = n.length_squared();
    if nn > 0.0 {
        let a = rp.cross(d2).dot(n) / nn;
        let b = rp.cross(d1).dot(n) / nn;
        if (0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b) {
            consider(p + d1 * a, r + d2 * b);
        }
    }
    best
}
