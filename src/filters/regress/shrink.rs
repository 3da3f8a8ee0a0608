//! The mix: the filtered image moved towards the fit by each pixel's James–Stein (Wiener)
//! weight, so the fit only replaces the filter where the filter is biased.

use rayon::prelude::*;

use super::fit::{regress_in, regress_with};
use super::params::{Fit, Inputs, Params};
use crate::image::Image;
use crate::kernels::simd::Kernel;
use crate::meter::Meter;

/// Relative size of the fit's rounding error: a fit this close to the filtered value leaves it.
const ROUNDING: f64 = 1e-5;

/// The refined image: the filtered one moved towards the fit by each pixel's Wiener weight.
pub fn refine(inputs: Inputs, p: &Params) -> Image {
    refine_with(Kernel::detect(), inputs, p)
}

/// [`refine`] with a chosen row kernel (all give the same bits).
pub fn refine_with(kernel: Kernel, inputs: Inputs, p: &Params) -> Image {
    let fit = regress_with(kernel, inputs, p);
    mix(inputs.filtered, &fit)
}

/// [`refine`] in a run: the fit's bands tell `meter` and stop once it is cancelled (the result is
/// then unfinished, for the caller to throw away).
pub fn refine_metered(inputs: Inputs, p: &Params, meter: &Meter) -> Image {
    let fit = regress_in(Kernel::detect(), inputs, p, meter);
    mix(inputs.filtered, &fit)
}

/// How far each pixel moves from the filtered value f towards the fit g: κ = b² / (b² + s²),
/// the Wiener weight, with s² the fit's variance and b² = max(0, |g − f|² − s²) the filter's
/// squared bias read from this pixel alone (|g − f|² estimates b² + s²). That is
/// κ = max(0, 1 − s² / |g − f|²), the positive-part James–Stein shrinkage of g towards f: a
/// difference the fit's own noise explains leaves f; one far beyond it takes g.
pub fn keep(filtered: &[f32], fit: &[f32], fit_variance: f32) -> f32 {
    let (mut d2, mut f2) = (0.0f64, 0.0f64);
    for k in 0..3 {
        let (f, g) = (filtered[k] as f64, fit[k] as f64);
        d2 += (g - f) * (g - f);
        f2 += f * f;
    }
    // A difference within the fit's rounding (its f32 row sums) is not a bias.
    if d2 <= ROUNDING * ROUNDING * f2 {
        return 0.0;
    }
    let k = 1.0 - fit_variance as f64 / (d2 / 3.0);
    if k > 0.0 && k.is_finite() {
        k as f32
    } else {
        0.0
    }
}

/// The filtered image moved towards the fit (clamped at 0) by each pixel's [`keep`] weight, so a
/// non-negative filtered image stays non-negative. A filtered value that is not finite is
/// replaced by the fit (which always is).
pub fn mix(filtered: &Image, fit: &Fit) -> Image {
    let mut out = filtered.par_clone();
    out.data_mut()
        .par_chunks_mut(3)
        .zip(fit.color.data().par_chunks(3))
        .zip(fit.variance.par_iter())
        .for_each(|((px, g), &s2)| {
            // Radiance is not negative: a plane fitted across an edge or into a dark corner can
            // extrapolate below 0, and the mix must not follow it there.
            let g = [g[0].max(0.0), g[1].max(0.0), g[2].max(0.0)];
            if !px.iter().all(|v| v.is_finite()) {
                px.copy_from_slice(&g);
                return;
            }
            let k = keep(px, &g, s2);
            for c in 0..3 {
                let v = px[c] + k * (g[c] - px[c]);
                if v.is_finite() {
                    px[c] = v;
                }
            }
        });
    out
}
