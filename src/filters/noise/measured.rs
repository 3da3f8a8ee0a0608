//! The noise the renderer measured, smoothed over the same surface as the estimate is: from its
//! variance buffer, or from the half-sample colours `color_a`/`color_b`.

use super::smooth::{plain_spread, smooth, SMOOTH_RADIUS};
use super::surface::Surface;
use crate::image::Image;
use crate::meter::Meter;
use crate::render_set::FeatureSet;

/// Smooths a variance the renderer measured (a `variance` buffer, noisy itself at few samples)
/// over the same surface, as the estimate is.
pub fn smooth_measured(color: &Image, features: &FeatureSet, variance: &Image) -> Image {
    let surface = Surface::new(features, color.dims());
    let raw: Vec<([f64; 3], usize)> = variance
        .data()
        .chunks_exact(3)
        .enumerate()
        .map(|(i, v)| {
            (
                surface.demodulate_variance(i, v.iter().map(|&x| clean(x))),
                1,
            )
        })
        .collect();
    smooth_measured_raw(color, &surface, &raw)
}

/// The variance of the full-sample mean from two half-sample means: E[(a − b)²] / 4, smoothed.
pub fn from_halves(color: &Image, features: &FeatureSet, a: &Image, b: &Image) -> Image {
    let surface = Surface::new(features, color.dims());
    let raw: Vec<([f64; 3], usize)> = a
        .data()
        .chunks_exact(3)
        .zip(b.data().chunks_exact(3))
        .enumerate()
        .map(|(i, (p, q))| {
            let var = (0..3).map(|k| {
                let d = p[k] as f64 - q[k] as f64;
                clean((d * d / 4.0) as f32)
            });
            (surface.demodulate_variance(i, var), 1)
        })
        .collect();
    smooth_measured_raw(color, &surface, &raw)
}

/// [`smooth`] of per-pixel measured variances, with the surface-mates found here.
fn smooth_measured_raw(color: &Image, surface: &Surface, raw: &[([f64; 3], usize)]) -> Image {
    let (w, h) = color.dims();
    smooth(
        color,
        surface,
        &surface.mates(w, h, SMOOTH_RADIUS as usize),
        |j| raw[j],
        |i| plain_spread(color, i),
        &Meter::default(),
    )
}

/// A measured variance sample as used here: non-finite or negative counts as 0.
pub(crate) fn clean(v: f32) -> f64 {
    if v.is_finite() && v > 0.0 {
        v as f64
    } else {
        0.0
    }
}

/// A pixel's variance as one number: the mean of its RGB channels' (each [`clean`]ed).
pub(crate) fn pixel_variance(v: &[f32]) -> f64 {
    v.iter().map(|&x| clean(x)).sum::<f64>() / 3.0
}
