//! The blend's error estimate: per pixel, the trimmed mean of (f − c)² over its surface-mates in
//! a small window, and what that mean reads on noise alone for each count of values (exact χ²).

use crate::filters::noise::chi2::{erf, TRIM};
use crate::filters::noise::surface::Mates;
use crate::kernels::padded::Padded;
use crate::kernels::trim::{self, LANES};

/// Radius of the window the blend's error estimate averages over (5×5).
pub(super) const BLEND_RADIUS: isize = trim::RADIUS;
const BLEND_SIDE: usize = 2 * BLEND_RADIUS as usize + 1;
pub(super) const BLEND_TAPS: usize = BLEND_SIDE * BLEND_SIDE;
/// Most values the blend's trimmed mean takes (its 5×5 window).
const MAX_TRIMMED: usize = BLEND_TAPS;

/// E[mean of the `n − ⌊n·TRIM⌋` smallest of n iid χ²₁], for n = 0..=MAX_TRIMMED: the blend's
/// trimmed mean of n values (f − c)² is this times v + b². Exact for every n, unlike the large-n
/// limit `TRIMMED_CHI2_MEAN`: with fewer than 5 values nothing is trimmed and the mean is
/// unbiased as it is (1, not 0.44).
pub(super) fn trimmed_chi2(n: usize) -> f64 {
    static TABLE: std::sync::OnceLock<[f64; MAX_TRIMMED + 1]> = std::sync::OnceLock::new();
    TABLE
        .get_or_init(|| std::array::from_fn(|n| trimmed_chi2_of(n, n - (n as f64 * TRIM) as usize)))
        [n.min(MAX_TRIMMED)]
}

/// E[mean of the `kept` smallest of n iid χ²₁] by its order-statistics integral: with X = Z²,
/// E[Σ of the kept smallest] = n ∫ z² · 2φ(z) · P(Binomial(n − 1, P(|Z| < z)) < kept) dz, by
/// Simpson's rule on [0, 12] (the integrand is below 1e-29 beyond).
fn trimmed_chi2_of(n: usize, kept: usize) -> f64 {
    if n == 0 || kept == 0 {
        return 1.0;
    }
    // ln of the pmf's ratio from term j to j + 1, apart from p: the same for every z.
    let ratio: Vec<f64> = (0..kept.min(n))
        .map(|j| ((n - 1 - j) as f64 / (j + 1) as f64).ln())
        .collect();
    let mut sum = 0.0;
    for node in simpson_nodes() {
        // P(Binomial(n − 1, p) ≤ kept − 1), its terms by the pmf's recurrence in the log domain
        // (the first term, (1 − p)^(n−1), underflows for large n).
        let cdf = if node.p >= 1.0 {
            if kept >= n {
                1.0
            } else {
                0.0
            }
        } else {
            let mut log_term = (n - 1) as f64 * node.lq;
            let mut cdf = 0.0;
            for r in &ratio {
                cdf += log_term.exp();
                log_term += r + node.lp - node.lq;
            }
            cdf
        };
        sum += node.weight * cdf.min(1.0);
    }
    n as f64 * sum * SIMPSON_H / 3.0 / kept as f64
}

/// Simpson steps of [`trimmed_chi2_of`]'s integral over [0, 12].
const SIMPSON_STEPS: usize = 4096;
const SIMPSON_H: f64 = 12.0 / SIMPSON_STEPS as f64;

/// One node of that integral: what depends on z alone, computed once for every n.
struct SimpsonNode {
    /// Simpson weight · z² · 2φ(z).
    weight: f64,
    /// P(|Z| < z), and its ln and ln(1 − p).
    p: f64,
    lp: f64,
    lq: f64,
}

fn simpson_nodes() -> &'static [SimpsonNode] {
    static NODES: std::sync::OnceLock<Vec<SimpsonNode>> = std::sync::OnceLock::new();
    NODES.get_or_init(|| {
        (0..=SIMPSON_STEPS)
            .map(|s| {
                let z = s as f64 * SIMPSON_H;
                let p = erf(z / std::f64::consts::SQRT_2);
                let density = 2.0 * (-0.5 * z * z).exp() / (2.0 * std::f64::consts::PI).sqrt();
                let weight = if s == 0 || s == SIMPSON_STEPS {
                    1.0
                } else if s % 2 == 1 {
                    4.0
                } else {
                    2.0
                };
                SimpsonNode {
                    weight: weight * z * z * density,
                    p,
                    lp: p.ln(),
                    lq: (-p).ln_1p(),
                }
            })
            .collect()
    })
}

/// Most of the blend's values trimmed: `TRIM` of its window.
const BLEND_TRIMMED: usize = (BLEND_TAPS as f64 * TRIM) as usize;

/// The blend's error estimates along row `y`: per pixel, the trimmed mean of `diff2` over its
/// surface-mates (trimmed as the estimate is, so edges the features miss and fireflies stay out)
/// and how many finite values it had.
#[inline(always)]
pub(super) fn blend_error_row(diff2: &Padded, mates: &Mates, y: usize, out: &mut [(f64, usize)]) {
    let w = out.len();
    trim::by_lanes!(out, |x| blend_errors::<LANES>(diff2, mates, x, y, w), |x| {
        blend_errors::<1>(diff2, mates, x, y, w)[0]
    },);
}

/// [`blend_error_row`] at pixels (x..x + L, y).
#[inline(always)]
fn blend_errors<const L: usize>(
    diff2: &Padded,
    mates: &Mates,
    x: usize,
    y: usize,
    w: usize,
) -> [(f64, usize); L] {
    let r = BLEND_RADIUS;
    debug_assert_eq!(
        mates.side, BLEND_SIDE,
        "the blend's mates are of its own window"
    );
    let mut bits = [0u64; L];
    bits.copy_from_slice(&mates.bits[y * w + x..y * w + x + L]);
    let plane = &diff2.planes[0];
    // A cell that is not a surface-mate reads NaN, which the trimmed mean leaves out.
    let mut values = [[0.0f64; L]; BLEND_TAPS];
    let mut n = [0usize; L];
    for (cell, value) in values.iter_mut().enumerate() {
        // A constant side: the cell's offset costs no division.
        let (dx, dy) = (
            (cell % BLEND_SIDE) as isize - r,
            (cell / BLEND_SIDE) as isize - r,
        );
        let at = diff2.at(x, y, (dx, dy));
        for l in 0..L {
            let v = plane[at + l] + trim::valid_or_nan(bits[l] >> cell & 1 == 1);
            n[l] += usize::from(v <= f64::MAX);
            value[l] = v;
        }
    }
    let mut dropped = [0usize; L];
    for l in 0..L {
        dropped[l] = (n[l] as f64 * TRIM) as usize;
    }
    let mean = trim::lanes::<L, BLEND_TAPS, BLEND_TRIMMED>(&values, dropped);
    let mut out = [(0.0, 0); L];
    for l in 0..L {
        out[l] = (mean[l], n[l]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filters::noise::chi2::trimmed_chi2_mean;
    use crate::kernels::trim::tests::xorshift;

    #[test]
    fn finite_trimmed_chi2_means_are_exact() {
        // Nothing trimmed: the plain mean of χ²₁, whatever n.
        for n in 1..5 {
            assert!(
                (trimmed_chi2(n) - 1.0).abs() < 1e-9,
                "n = {n}: {}",
                trimmed_chi2(n)
            );
        }
        // n = 2, the smaller of two: E[min(Z₁², Z₂²)] = 1 − 2/π.
        assert!((trimmed_chi2_of(2, 1) - (1.0 - 2.0 / std::f64::consts::PI)).abs() < 1e-9);
        // Large n tends to the quantile formula.
        let big = trimmed_chi2_of(2000, 1600);
        assert!((big - trimmed_chi2_mean(0.8)).abs() < 2e-3, "{big}");
        // Against simulation: 4 smallest of 5, and the 25-tap blend window (20 kept).
        let mut next = xorshift(2);
        let mut normal = move || {
            let mut u = || ((next() >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
            let (a, b) = (u(), u());
            (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
        };
        for n in [5usize, 25] {
            let kept = n - (n as f64 * TRIM) as usize;
            let trials = 200_000 / n * 5;
            let mut total = 0.0;
            for _ in 0..trials {
                let mut x: Vec<f64> = (0..n).map(|_| normal().powi(2)).collect();
                x.sort_by(f64::total_cmp);
                total += x[..kept].iter().sum::<f64>() / kept as f64;
            }
            let simulated = total / trials as f64;
            assert!(
                (simulated - trimmed_chi2(n)).abs() < 0.01,
                "n = {n}: simulated {simulated}, exact {}",
                trimmed_chi2(n)
            );
        }
    }
}
