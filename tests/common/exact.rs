//! Exact arithmetic on `f32` inputs: floating-point expansions (Shewchuk, "Adaptive Precision
//! Floating-Point Arithmetic and Fast Robust Geometric Predicates", 1997). A value is the exact sum of its
//! non-overlapping `f64` components, smallest magnitude first, so sums, differences and products of `f32`
//! data are exact and their signs decidable. Slow (allocating, quadratic products): the ray oracle uses it
//! only where an `f64` filter cannot decide.

/// `a + b` as `(rounded sum, exact error)`.
fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let x = a + b;
    let bv = x - a;
    let av = x - bv;
    (x, (a - av) + (b - bv))
}

/// `a · b` as `(rounded product, exact error)`, through a fused multiply-add.
fn two_product(a: f64, b: f64) -> (f64, f64) {
    let x = a * b;
    (x, a.mul_add(b, -x))
}

/// An exact real number: the sum of its components (no overflow or underflow assumed: products of at most
/// six `f32` factors stay far inside `f64`'s range).
#[derive(Clone, Debug, Default)]
pub struct Exact(Vec<f64>);

impl Exact {
    pub fn from_f32(x: f32) -> Self {
        Exact(if x == 0.0 { vec![] } else { vec![x as f64] })
    }

    /// `self + b` for one `f64` (Shewchuk's GROW-EXPANSION with zero elimination).
    fn grow(&mut self, b: f64) {
        let mut q = b;
        let mut out = Vec::with_capacity(self.0.len() + 1);
        for &e in &self.0 {
            let (s, h) = two_sum(q, e);
            if h != 0.0 {
                out.push(h);
            }
            q = s;
        }
        if q != 0.0 {
            out.push(q);
        }
        self.0 = out;
    }

    pub fn add(&self, other: &Exact) -> Exact {
        let mut r = self.clone();
        for &c in &other.0 {
            r.grow(c);
        }
        r
    }

    pub fn neg(&self) -> Exact {
        Exact(self.0.iter().map(|c| -c).collect())
    }

    pub fn sub(&self, other: &Exact) -> Exact {
        self.add(&other.neg())
    }

    pub fn mul(&self, other: &Exact) -> Exact {
        let mut r = Exact::default();
        for &a in &self.0 {
            for &b in &other.0 {
                let (x, y) = two_product(a, b);
                r.grow(y);
                r.grow(x);
            }
        }
        r
    }

    /// The exact sign: that of the largest component, which is the last one.
    pub fn signum(&self) -> i32 {
        match self.0.last() {
            None => 0,
            Some(&c) if c > 0.0 => 1,
            Some(_) => -1,
        }
    }
}

/// An exact 3-vector.
#[derive(Clone, Debug)]
pub struct Exact3([Exact; 3]);

impl Exact3 {
    pub fn from_vec3(v: glam::Vec3) -> Self {
        Exact3([v.x, v.y, v.z].map(Exact::from_f32))
    }

    pub fn sub(&self, o: &Exact3) -> Exact3 {
        Exact3([0, 1, 2].map(|i| self.0[i].sub(&o.0[i])))
    }

    pub fn dot(&self, o: &Exact3) -> Exact {
        self.0[0]
            .mul(&o.0[0])
            .add(&self.0[1].mul(&o.0[1]))
            .add(&self.0[2].mul(&o.0[2]))
    }

    pub fn cross(&self, o: &Exact3) -> Exact3 {
        let c = |i: usize, j: usize| self.0[i].mul(&o.0[j]).sub(&self.0[j].mul(&o.0[i]));
        Exact3([c(1, 2), c(2, 0), c(0, 1)])
    }
}
