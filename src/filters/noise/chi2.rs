//! The share of squared differences the trimmed means leave out, and what such a mean of χ²₁
//! values reads in the large-n limit: the unit of the noise estimate and of the prefilter's.

/// The share of the largest squared differences left out: pairs across an edge the features do
/// not show (a light's rim, a shadow's) and fireflies, which are not the noise a filter should
/// follow.
pub(crate) const TRIM: f64 = 0.2;
/// E[χ²₁ | below its 80th percentile], the large-n limit of the blend's exact means
/// (`filters/blend/error_estimate.rs`): the estimate's unit.
/// Its adjacent pairs share pixels, so the iid finite-n value is not exact for them either, and the
/// noise laws were measured on this one: the finite-n value (4 % lower variance at 40 pairs) cost
/// `cycles-studio` 0.006 SSIM at 1 spp (docs/RESULTS.md "Noise-aware strengths").
pub(super) const TRIMMED_CHI2_MEAN: f64 = 0.437_724_594_903_639;

/// The mean of the smallest `keep` share of χ²₁ samples, E[χ²₁ | below its `keep` quantile]: the
/// kept pairs' mean of (x_j − x_k)² is this times 2·variance. With z the quantile of |Z|,
/// E[Z² | |Z| < z] = 1 − 2zφ(z)/keep, and z solves erf(z/√2) = keep (by bisection).
pub(crate) fn trimmed_chi2_mean(keep: f64) -> f64 {
    let (mut lo, mut hi) = (0.0f64, 10.0f64);
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if erf(mid / std::f64::consts::SQRT_2) < keep {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let z = 0.5 * (lo + hi);
    let phi = (-0.5 * z * z).exp() / (2.0 * std::f64::consts::PI).sqrt();
    1.0 - 2.0 * z * phi / keep
}

/// erf by its Maclaurin series (1 above z = 4, where it is within 2e-8 of it), summed in f64.
pub(crate) fn erf(z: f64) -> f64 {
    if z > 4.0 {
        return 1.0;
    }
    let (mut term, mut sum) = (z, z);
    for n in 1..200 {
        term *= -z * z / n as f64;
        sum += term / (2 * n + 1) as f64;
    }
    (2.0 / std::f64::consts::PI.sqrt() * sum).clamp(-1.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trimmed_chi2_means_match_the_tabulated_ones() {
        assert!((trimmed_chi2_mean(0.5) - 0.142_651_835_488_518_54).abs() < 1e-9);
        assert!((trimmed_chi2_mean(0.8) - 0.437_724_594_903_639).abs() < 1e-9);
        assert!((trimmed_chi2_mean(1.0 - 1e-12) - 1.0).abs() < 1e-6);
        // The estimate's constant is the same quantity at its own trim.
        assert!((trimmed_chi2_mean(1.0 - TRIM) - TRIMMED_CHI2_MEAN).abs() < 1e-12);
    }
}
