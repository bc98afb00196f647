//! Scene characterisation (after Olivares Pinto 2014, research seed 003): a histogram of the primitives'
//! Morton codes and a few statistics that tell how primitives are distributed — the input of a structure
//! and rebuild policy.
//!
//! Choices the thesis leaves open, made here and documented:
//! - codes are 30-bit Morton codes of triangle centroids in the centroids' box (the LBVH's codes);
//! - the bin count is Doane's `k = ⌈1 + log2 N + log2(1 + |g1| / σ_g1)⌉` with Doane's own
//!   `σ_g1 = sqrt(6 (N − 2) / ((N + 1)(N + 3)))` (the standard error of the skewness), at least 1;
//! - bins have integer edges: width `⌈(max − min + 1) / k⌉` codes, the last bin possibly narrower, and the
//!   χ² expectation of each bin is proportional to its width (so a GPU histogram can match exactly);
//! - uniform iff χ² ≤ the critical value of χ² with k − 1 degrees of freedom at upper-tail α = 0.005 (the
//!   thesis's Algorithm 2 states the opposite; its text and standard statistics say this);
//! - "over-full" bins hold more than the expected count (the thesis's concentration rule).
//!
//! On the GPU, `GpuMeshBvh::record_histogram` (feature `gpu`) counts the codes a GPU build sorted anyway,
//! equal bin for bin to [`profile`]'s histogram for the same bin count; the moments and the test stay here.

use crate::Mesh;
use crate::geometry::{Aabb, morton30};

/// Upper-tail probability of the uniformity test.
pub const ALPHA: f64 = 0.005;

/// What the characteriser found about one mesh.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneProfile {
    /// Primitives characterised.
    pub primitives: usize,
    /// Doane's bin count.
    pub bins: usize,
    /// Smallest and largest Morton code.
    pub code_range: (u32, u32),
    /// Primitives per bin.
    pub histogram: Vec<u32>,
    /// Mean, standard deviation (population) and skewness of the codes.
    pub mean: f64,
    /// Standard deviation of the codes.
    pub std_dev: f64,
    /// Skewness g1 of the codes.
    pub skewness: f64,
    /// χ² against a uniform distribution over the code range.
    pub chi_square: f64,
    /// The critical value at α = 0.005 with `bins − 1` degrees of freedom.
    pub chi_square_critical: f64,
    /// χ² ≤ critical.
    pub uniform: bool,
    /// Bins with no primitive.
    pub empty_bins: usize,
    /// Bins holding more than their expected count.
    pub overfull_bins: usize,
    /// Spread of triangle sizes: standard deviation over mean of the triangles' box diagonals (0 for equal
    /// sizes, large when a few huge triangles sit among many small ones).
    pub size_spread: f64,
}

/// Characterises a mesh's triangles.
pub fn profile_mesh(mesh: &Mesh) -> SceneProfile {
    let bounds = mesh.triangle_bounds();
    let cb = bounds.iter().fold(Aabb::EMPTY, |mut a, b| {
        a.grow(b.center());
        a
    });
    let codes: Vec<u32> = bounds.iter().map(|b| morton30(b.center(), &cb)).collect();
    let sizes: Vec<f64> = bounds.iter().map(|b| b.extent().length() as f64).collect();
    profile(&codes, &sizes)
}

/// Characterises primitives given by their Morton codes and sizes (any positive measure).
pub fn profile(codes: &[u32], sizes: &[f64]) -> SceneProfile {
    let n = codes.len();
    let (mean, std_dev, skewness) = moments(codes.iter().map(|&c| c as f64), n);
    let bins = doane_bins(n, skewness);
    let (lo, hi) = codes
        .iter()
        .fold((u32::MAX, 0), |(l, h), &c| (l.min(c), h.max(c)));
    let (lo, hi) = if n == 0 { (0, 0) } else { (lo, hi) };
    let width = bin_width(lo, hi, bins);
    let mut histogram = vec![0u32; bins];
    for &c in codes {
        histogram[bin_of(c, lo, width, bins)] += 1;
    }
    let range = (hi - lo) as f64 + 1.0;
    let (mut chi_square, mut overfull) = (0.0, 0);
    for (i, &o) in histogram.iter().enumerate() {
        let start = i as u64 * width as u64;
        let w = (width as u64).min((range as u64).saturating_sub(start)) as f64;
        let expected = n as f64 * w / range;
        if expected > 0.0 {
            chi_square += (o as f64 - expected).powi(2) / expected;
        }
        overfull += (o as f64 > expected) as usize;
    }
    let chi_square_critical = chi_square_critical(bins.saturating_sub(1).max(1) as f64, ALPHA);
    let (size_mean, size_std, _) = moments(sizes.iter().copied(), sizes.len());
    SceneProfile {
        primitives: n,
        bins,
        code_range: (lo, hi),
        empty_bins: histogram.iter().filter(|&&c| c == 0).count(),
        overfull_bins: overfull,
        histogram,
        mean,
        std_dev,
        skewness,
        chi_square,
        chi_square_critical,
        uniform: chi_square <= chi_square_critical,
        size_spread: if size_mean > 0.0 {
            size_std / size_mean
        } else {
            0.0
        },
    }
}

/// Mean, population standard deviation and skewness g1 (0 when undefined).
fn moments(values: impl Iterator<Item = f64> + Clone, n: usize) -> (f64, f64, f64) {
    if n == 0 {
        return (0.0, 0.0, 0.0);
    }
    let mean = values.clone().sum::<f64>() / n as f64;
    let (m2, m3) = values.fold((0.0, 0.0), |(a, b), v| {
        let d = v - mean;
        (a + d * d, b + d * d * d)
    });
    let (m2, m3) = (m2 / n as f64, m3 / n as f64);
    let skew = if m2 > 0.0 { m3 / m2.powf(1.5) } else { 0.0 };
    (mean, m2.sqrt(), skew)
}

/// Doane's bin count, at least 1.
pub fn doane_bins(n: usize, skewness: f64) -> usize {
    if n < 3 {
        return 1;
    }
    let nf = n as f64;
    let sigma_g1 = (6.0 * (nf - 2.0) / ((nf + 1.0) * (nf + 3.0))).sqrt();
    (1.0 + nf.log2() + (1.0 + skewness.abs() / sigma_g1).log2()).ceil() as usize
}

/// Codes per bin: `⌈(hi − lo + 1) / bins⌉`.
pub fn bin_width(lo: u32, hi: u32, bins: usize) -> u32 {
    ((hi as u64 - lo as u64 + 1).div_ceil(bins as u64)).max(1) as u32
}

/// The bin of a code.
#[inline]
pub fn bin_of(code: u32, lo: u32, width: u32, bins: usize) -> usize {
    (((code - lo) / width) as usize).min(bins - 1)
}

/// The value x with P(χ²_df > x) = alpha, by bisection on the regularised lower incomplete gamma function.
pub fn chi_square_critical(df: f64, alpha: f64) -> f64 {
    let cdf = |x: f64| lower_gamma_regularized(df / 2.0, x / 2.0);
    let (mut lo, mut hi) = (0.0, df.max(1.0));
    while cdf(hi) < 1.0 - alpha {
        hi *= 2.0;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if cdf(mid) < 1.0 - alpha {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// P(a, x): series for x < a + 1, Lentz's continued fraction otherwise (Numerical Recipes §6.2).
fn lower_gamma_regularized(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    let ln_prefix = a * x.ln() - x - ln_gamma(a);
    if x < a + 1.0 {
        let (mut sum, mut term, mut ap) = (1.0 / a, 1.0 / a, a);
        for _ in 0..10_000 {
            ap += 1.0;
            term *= x / ap;
            sum += term;
            if term.abs() < sum.abs() * 1e-16 {
                break;
            }
        }
        (sum.ln() + ln_prefix).exp()
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-16 {
                break;
            }
        }
        1.0 - (ln_prefix.exp() * h)
    }
}

/// ln Γ(x) for x > 0 (Lanczos, g = 7, n = 9).
fn ln_gamma(x: f64) -> f64 {
    const G: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        return (std::f64::consts::PI / (std::f64::consts::PI * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let t = x + 7.5;
    let s = G[1..]
        .iter()
        .enumerate()
        .fold(G[0], |s, (i, g)| s + g / (x + i as f64 + 1.0));
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + s.ln()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn critical_values_match_published_tables() {
        // χ² upper 0.5% points (NIST/SEMATECH e-Handbook, table 1.3.6.7.4).
        for (df, expect) in [
            (1.0, 7.879),
            (2.0, 10.597),
            (5.0, 16.750),
            (10.0, 25.188),
            (30.0, 53.672),
            (100.0, 140.169),
        ] {
            let got = chi_square_critical(df, ALPHA);
            assert!((got - expect).abs() < 2e-3, "df {df}: {got} vs {expect}");
        }
    }

    #[test]
    fn doane_is_at_least_sturges() {
        for n in [3usize, 100, 69_451, 2_210_673] {
            for g in [0.0, 0.5, 5.0] {
                assert!(
                    doane_bins(n, g) as f64 >= 1.0 + (n as f64).log2(),
                    "{n} {g}"
                );
            }
        }
        assert_eq!(doane_bins(0, 0.0), 1);
    }

    #[test]
    fn bins_partition_the_code_range() {
        for (lo, hi, k) in [
            (0u32, 0u32, 1usize),
            (5, 5, 3),
            (0, 99, 7),
            (10, (1 << 30) - 1, 23),
        ] {
            let w = bin_width(lo, hi, k);
            assert_eq!(bin_of(lo, lo, w, k), 0);
            assert!(bin_of(hi, lo, w, k) < k);
            assert!(
                w as u64 * k as u64 > hi as u64 - lo as u64,
                "the bins cover the range"
            );
        }
    }
}
