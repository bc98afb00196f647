//! A running mean and variance of a measured quantity: what every learned constant of the planner is.

/// Weight of a new sample once the estimate has seen `1 / LEARN` samples: before that every sample weighs
/// the same (Welford's running mean), after it the estimate forgets at this rate (West's exponentially
/// weighted mean and variance), so it follows a scene whose costs drift.
const LEARN: f64 = 0.2;

/// Samples below which the spread is not trusted alone: a prior relative spread is assumed instead.
const TRUSTED_AFTER: u32 = 3;

/// The relative spread assumed while fewer than [`TRUSTED_AFTER`] samples were seen (a single timing on a
/// busy machine is easily 25% off).
const PRIOR_SPREAD: f64 = 0.25;

/// Running mean and variance of one measured quantity (seconds per triangle, seconds per ray, …). Adding a
/// sample is a few operations; non-finite samples are ignored.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Estimate {
    n: u32,
    mean: f64,
    var: f64,
}

impl Estimate {
    /// Learns one sample (ignored unless finite).
    pub fn add(&mut self, x: f64) {
        if !x.is_finite() {
            return;
        }
        self.n = self.n.saturating_add(1);
        let a = (1.0 / self.n as f64).max(LEARN);
        let d = x - self.mean;
        let step = a * d;
        self.mean += step;
        self.var = (1.0 - a) * (self.var + d * step);
    }

    /// The mean, once a sample was seen.
    pub fn mean(&self) -> Option<f64> {
        (self.n > 0).then_some(self.mean)
    }

    /// Samples seen.
    pub fn samples(&self) -> u32 {
        self.n
    }

    /// The standard deviation of the mean itself: [`spread`](Self::spread) over the square root of the
    /// samples it rests on (at most `(2 − w) / w` = 9 once old samples are forgotten at weight `w` = 0.2).
    pub fn mean_spread(&self) -> f64 {
        self.spread() / self.effective_samples().max(1.0).sqrt()
    }

    /// The number of equally weighted samples the mean is worth: the samples seen, at most
    /// `(2 − w) / w` = 9 once old samples are forgotten at weight `w` = 0.2 (the variance of an
    /// exponentially weighted mean is `w / (2 − w)` of one sample's).
    pub fn effective_samples(&self) -> f64 {
        (self.n as f64).min((2.0 - LEARN) / LEARN)
    }

    /// Whether the mean rests on as many samples as it ever will ([`effective_samples`](Self::effective_samples)
    /// at its bound): more frames of the same quantity no longer make it surer.
    pub fn saturated(&self) -> bool {
        self.n as f64 >= (2.0 - LEARN) / LEARN
    }

    /// The standard deviation of one sample: the measured one, and while fewer than three samples were
    /// seen at least a prior 25% of the mean (0 before any sample).
    pub fn spread(&self) -> f64 {
        let measured = self.var.max(0.0).sqrt();
        if self.n < TRUSTED_AFTER {
            measured.max(PRIOR_SPREAD * self.mean.abs())
        } else {
            measured
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The first five samples give the plain mean and population variance (an analytic answer).
    #[test]
    fn equal_weights_first() {
        let mut e = Estimate::default();
        for x in [1.0, 2.0, 3.0, 4.0, 5.0] {
            e.add(x);
        }
        e.add(f64::NAN);
        assert_eq!(e.samples(), 5);
        assert!((e.mean().unwrap() - 3.0).abs() < 1e-12);
        assert!((e.spread() - 2f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn a_single_sample_has_the_prior_spread() {
        let mut e = Estimate::default();
        assert_eq!((e.mean(), e.spread()), (None, 0.0));
        e.add(8.0);
        assert_eq!((e.mean(), e.spread()), (Some(8.0), 2.0));
    }
}
