//! A plot axis that is linear, or base-10 logarithmic when its values span a decade or more (the
//! explosion's refit error, refit against rebuild times), with tick labels a reader can take in at a glance.

use plotters::coord::ranged1d::{KeyPointHint, NoDefaultFormatting, Ranged, ValueFormatter};
use plotters::coord::types::RangedCoordf64;
use std::ops::Range;

/// One axis of a figure: the values' range, padded, mapped linearly or by `log10`.
#[derive(Clone)]
pub struct Scale {
    range: Range<f64>,
    log: bool,
    /// The linear map over `range`, or over `ln` of it when `log`.
    inner: RangedCoordf64,
    /// Ticks fixed in advance (the slots of a categorical axis), instead of chosen to fit.
    ticks: Option<Vec<f64>>,
}

impl Scale {
    /// An axis that holds every finite value of `values`: logarithmic when `log_allowed`, all values are
    /// positive and the largest is ten times the smallest or more; linear otherwise.
    pub fn fit(values: impl IntoIterator<Item = f64>, log_allowed: bool) -> Scale {
        let finite = values.into_iter().filter(|v| v.is_finite());
        let (mut lo, mut hi) = finite.fold((f64::MAX, f64::MIN), |(l, h), v| (l.min(v), h.max(v)));
        if lo > hi {
            (lo, hi) = (0.0, 1.0);
        }
        if log_allowed && lo > 0.0 && hi >= 10.0 * lo {
            // 4% of the span in decades either side, so no point sits on the frame.
            let pad = 10f64.powf(0.04 * (hi / lo).log10());
            Scale::new(lo / pad, hi * pad, true)
        } else {
            let span = (hi - lo).max(0.02 * hi.abs().max(lo.abs())).max(1e-9);
            Scale::new(lo - 0.06 * span, hi + 0.06 * span, false)
        }
    }

    /// A linear axis over exactly `lo..hi`.
    pub fn linear(lo: f64, hi: f64) -> Scale {
        Scale::new(lo, hi, false)
    }

    /// A categorical axis of `n` slots, ticked at their centres `0, 1, … n - 1`.
    pub fn slots(n: usize) -> Scale {
        let ticks = (0..n).map(|i| i as f64).collect();
        Scale {
            ticks: Some(ticks),
            ..Scale::linear(-0.5, n.max(1) as f64 - 0.5)
        }
    }

    fn new(lo: f64, hi: f64, log: bool) -> Scale {
        let inner = if log { lo.ln()..hi.ln() } else { lo..hi };
        Scale {
            range: lo..hi,
            log,
            inner: inner.into(),
            ticks: None,
        }
    }

    /// Whether the axis is logarithmic, for its caption.
    pub fn is_log(&self) -> bool {
        self.log
    }

    /// Ticks at 1, 2 and 5 times the powers of ten inside the range, or at the powers alone, or every
    /// other power, whichever first fits in `max` labels.
    fn log_ticks(&self, max: usize) -> Vec<f64> {
        let (lo, hi) = (self.range.start, self.range.end);
        let first = lo.log10().floor() as i32;
        let last = hi.log10().ceil() as i32;
        let ticks = |mantissas: &[f64], every: i32| -> Vec<f64> {
            (first..=last)
                .filter(|e| e.rem_euclid(every) == 0)
                .flat_map(|e| mantissas.iter().map(move |m| m * 10f64.powi(e)))
                .filter(|v| (lo..=hi).contains(v))
                .collect()
        };
        [
            ticks(&[1.0, 2.0, 5.0], 1),
            ticks(&[1.0], 1),
            ticks(&[1.0], 2),
        ]
        .into_iter()
        .find(|t| t.len() <= max && !t.is_empty())
        .unwrap_or_else(|| vec![lo, hi])
    }
}

impl Ranged for Scale {
    type FormatOption = NoDefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        let v = if self.log {
            value.max(self.range.start).ln()
        } else {
            *value
        };
        self.inner.map(&v, limit)
    }

    fn key_points<Hint: KeyPointHint>(&self, hint: Hint) -> Vec<f64> {
        if let Some(ticks) = &self.ticks {
            ticks.clone()
        } else if self.log {
            self.log_ticks(hint.max_num_points())
        } else {
            self.inner.key_points(hint)
        }
    }

    fn range(&self) -> Range<f64> {
        self.range.clone()
    }
}

impl ValueFormatter<f64> for Scale {
    fn format(value: &f64) -> String {
        tick(*value)
    }
}

/// A tick label: four significant digits at most, no trailing zeros ("0.05", "1.25", "200").
pub fn tick(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return "0".into();
    }
    let decimals = (3 - v.abs().log10().floor() as i32).clamp(0, 9) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').into()
    } else {
        s
    }
}
