//! How one mesh's query time per ray depends on its tree's SAH cost: a straight line fitted online, so
//! that the rent charges a degraded tree for the query time its extra cost really adds.
//!
//! The planner's first model was proportional (time per ray = rate × SAH cost), which charges a tree 23%
//! more query time for 23% more SAH cost. Measured, query time grows about half as fast: per ray there is
//! work no tree quality changes (ray set-up, the top level, the triangle a ray finally hits), and the SAH
//! cost overstates the traversal steps a degraded tree adds (the report's soup: SAH ratio 1.235, traversal
//! steps 1.149, query time 1.106). The proportional rent paid for rebuilds that could not repay
//! themselves (94 rebuilds of the soup in a 300-frame run, 2.1 ms a frame of updates for 0.27 ms of
//! queries saved). Fitting `time per ray = a + b · SAH` gives the marginal rate `b` that the rent needs.

use super::Estimate;

/// Weight of a new sample once the model has seen `1 / FORGET` samples: before that every frame weighs
/// the same; after it the fit follows the last hundred or so frames.
const FORGET: f64 = 1.0 / 64.0;

/// Frames before the fit is consulted at all.
const MIN_SAMPLES: u32 = 8;

/// A running weighted least-squares fit of query seconds per ray against the tree's SAH cost. Adding a
/// frame is a few operations; non-finite or non-positive samples are ignored.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct QueryModel {
    n: u32,
    mean_x: f64,
    mean_y: f64,
    /// Weighted (co)variances of the SAH cost `x` and the seconds per ray `y`.
    xx: f64,
    xy: f64,
    yy: f64,
}

impl QueryModel {
    /// Learns one frame: the tree's SAH cost and the measured query seconds per ray.
    pub fn add(&mut self, sah: f64, per_ray: f64) {
        if !(sah.is_finite() && sah > 0.0 && per_ray.is_finite() && per_ray >= 0.0) {
            return;
        }
        self.n = self.n.saturating_add(1);
        let a = (1.0 / self.n as f64).max(FORGET);
        let (dx, dy) = (sah - self.mean_x, per_ray - self.mean_y);
        self.mean_x += a * dx;
        self.mean_y += a * dy;
        self.xx = (1.0 - a) * (self.xx + a * dx * dx);
        self.xy = (1.0 - a) * (self.xy + a * dx * dy);
        self.yy = (1.0 - a) * (self.yy + a * dy * dy);
    }

    /// The marginal query seconds per ray per unit of SAH cost, and its standard deviation, given the
    /// `prior` (the proportional rate and its spread: what is known before this mesh's own frames say
    /// otherwise).
    ///
    /// The fit's slope `b` and its standard error combine with the prior by their precisions, the prior
    /// taken as uncertain by its whole value (the proportional model is the hypothesis under test, not a
    /// measurement); the result is kept within `[0, ȳ / x̄]`: more cost never makes queries faster, and a
    /// slope above the mean rate would mean negative time per ray at zero cost. While the SAH cost has not
    /// varied (a tree that has only ever been refitted by a rigid motion) the slope is unknown and the
    /// prior is returned as it is; so is it before [`MIN_SAMPLES`] frames.
    pub fn marginal(&self, prior: (f64, f64)) -> (f64, f64) {
        let (r0, s0) = prior;
        if self.n < MIN_SAMPLES || r0 <= 0.0 {
            return prior;
        }
        // The SAH cost must have varied by more than rounding for a slope to exist.
        if self.xx <= (1e-6 * self.mean_x).powi(2) {
            return prior;
        }
        let effective = (self.n as f64).min((2.0 - FORGET) / FORGET);
        let b = self.xy / self.xx;
        let residual = (self.yy - b * self.xy).max(0.0);
        let se2 = residual / ((effective - 2.0).max(1.0) * self.xx);
        let p0 = 1.0 / r0.max(s0).powi(2);
        let (mean, var) = if se2 > 0.0 {
            let p = 1.0 / se2;
            ((b * p + r0 * p0) / (p + p0), 1.0 / (p + p0))
        } else {
            (b, 0.0)
        };
        let ceiling = self.mean_y / self.mean_x;
        (mean.clamp(0.0, ceiling), var.sqrt())
    }
}

/// The proportional rate shared by all meshes of a table, as the prior of [`QueryModel::marginal`]: its
/// mean and the spread of that mean.
pub(crate) fn proportional(rate: &Estimate) -> (f64, f64) {
    (rate.mean().unwrap_or(0.0), rate.mean_spread())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Frames on an exact line `y = a + b·x` with the cost varying: the slope comes back (the residual
    /// is zero, so the fit's precision is infinite and the prior weighs nothing).
    #[test]
    fn an_exact_line_gives_its_slope() {
        let (a, b) = (2e-7, 3e-8);
        let mut m = QueryModel::default();
        for i in 0..40 {
            let x = 10.0 + (i % 7) as f64;
            m.add(x, a + b * x);
        }
        let (rate, spread) = m.marginal((1e-8, 1e-9));
        assert!((rate - b).abs() < 1e-9 * b, "{rate}");
        assert!(spread < 1e-15);
    }

    /// A purely proportional line (no intercept) gives the proportional rate, the ceiling.
    #[test]
    fn no_intercept_gives_the_proportional_rate() {
        let mut m = QueryModel::default();
        for i in 0..20 {
            let x = 5.0 + i as f64 * 0.5;
            m.add(x, 4e-8 * x);
        }
        let (rate, _) = m.marginal((4e-8, 0.0));
        assert!((rate - 4e-8).abs() < 1e-18, "{rate}");
    }

    /// Too few frames, or a cost that never varied: the prior as it is.
    #[test]
    fn without_evidence_the_prior_stands() {
        let mut m = QueryModel::default();
        for _ in 0..(MIN_SAMPLES - 1) {
            m.add(3.0, 1e-7);
        }
        assert_eq!(m.marginal((5e-8, 1e-9)), (5e-8, 1e-9));
        for _ in 0..100 {
            m.add(3.0, 1.1e-7);
        }
        assert_eq!(m.marginal((5e-8, 1e-9)), (5e-8, 1e-9));
    }

    /// A noisy line: the estimate is the precision-weighted mean of the fitted slope and the prior,
    /// computed here from the textbook formulas over the same samples (equal weights: fewer than 64).
    #[test]
    fn a_noisy_fit_blends_with_the_prior_by_precision() {
        let xs: Vec<f64> = (0..30).map(|i| 1.0 + (i % 5) as f64 * 0.1).collect();
        let ys: Vec<f64> = (0..30)
            .map(|i| 1.0 + 0.5 * xs[i] + if i % 2 == 0 { 0.01 } else { -0.01 })
            .collect();
        let mut m = QueryModel::default();
        for (x, y) in xs.iter().zip(&ys) {
            m.add(*x, *y);
        }
        let n = xs.len() as f64;
        let (mx, my) = (xs.iter().sum::<f64>() / n, ys.iter().sum::<f64>() / n);
        let sxx: f64 = xs.iter().map(|x| (x - mx).powi(2)).sum::<f64>() / n;
        let sxy: f64 = xs
            .iter()
            .zip(&ys)
            .map(|(x, y)| (x - mx) * (y - my))
            .sum::<f64>()
            / n;
        let syy: f64 = ys.iter().map(|y| (y - my).powi(2)).sum::<f64>() / n;
        let b = sxy / sxx;
        let se2 = (syy - b * sxy) / ((n - 2.0) * sxx);
        let prior = (0.9, 0.05);
        let p0 = 1.0 / 0.9f64.powi(2);
        let expect = (b / se2 + 0.9 * p0) / (1.0 / se2 + p0);
        let (rate, spread) = m.marginal(prior);
        assert!((rate - expect).abs() < 1e-9, "{rate} vs {expect}");
        assert!((spread - (1.0 / (1.0 / se2 + p0)).sqrt()).abs() < 1e-9);
        assert!((rate - 0.5).abs() < 0.05);
    }
}
