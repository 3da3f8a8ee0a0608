//! The noise as the tone-mapped colour sees it: the image's typical level, which a stage's σ
//! follows, and per-pixel colour scales that put colour differences in units of a pixel's noise.

use rayon::prelude::*;

use super::measured::pixel_variance;
use crate::image::Image;

/// Most a pixel's colour scale departs from 1 (either way).
const MAX_SCALE: f64 = 4.0;

/// Per pixel, the factor that brings colour differences to units of the pixel's own noise:
/// (typical level / local level)^γ within [1/4, 4], the local level being the noise standard
/// deviation through the tone curve's derivative at the 3×3 mean colour (a firefly's own value
/// would make its noise look tiny), and the typical level their median, so the image's σ keeps
/// its meaning. γ = `power` · min(1, typical / `reference`): the less noise there is, the more of
/// an estimate's variation from pixel to pixel is structure it read as noise (an edge, a
/// texture), so the less it is followed.
pub fn color_scales(
    color: &Image,
    variance: &Image,
    exposure: f32,
    power: f64,
    reference: f64,
) -> Vec<f32> {
    let (w, h) = color.dims();
    let Some(e) = tone_exposure(color, exposure).filter(|_| w * h > 0) else {
        return vec![1.0; w * h];
    };
    let means: Vec<f64> = color.data().par_chunks_exact(3).map(channel_mean).collect();
    let v = variance.data();
    let levels: Vec<f64> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let (mut sum, mut n) = (0.0, 0.0);
            for yy in y.saturating_sub(1)..(y + 2).min(h) {
                for &m in &means[yy * w + x.saturating_sub(1)..yy * w + (x + 2).min(w)] {
                    if m.is_finite() {
                        sum += m;
                        n += 1.0;
                    }
                }
            }
            let m = if n > 0.0 { sum / n } else { 0.0 };
            tone_sd(&v[3 * i..3 * i + 3], m, e)
        })
        .collect();
    let typical = median(&mut levels.clone());
    if typical.is_nan() || typical <= 0.0 {
        return vec![1.0; w * h];
    }
    let power = power * (typical / reference).min(1.0);
    levels
        .par_iter()
        .map(|&l| {
            let ratio = if l > 0.0 { typical / l } else { f64::INFINITY };
            ratio.powf(power).clamp(1.0 / MAX_SCALE, MAX_SCALE) as f32
        })
        .collect()
}

/// The exposure the tone curve's derivative is taken at: `exposure` relative to the image's own
/// robust brightness, so no level moves with the render's exposure; none for a black image.
fn tone_exposure(color: &Image, exposure: f32) -> Option<f64> {
    let brightness = crate::condition::robust_brightness(color);
    (brightness > 0.0).then(|| exposure as f64 * crate::condition::UNIT_BRIGHTNESS / brightness)
}

/// A pixel's mean over its channels, negative values counted as 0.
fn channel_mean(c: &[f32]) -> f64 {
    c.iter().map(|&x| x.max(0.0) as f64).sum::<f64>() / 3.0
}

/// The noise standard deviation of a pixel of variance `v` (its channels' mean) through the
/// Reinhard curve's derivative e / (1 + e·m)² at mean colour `m`.
fn tone_sd(v: &[f32], m: f64, e: f64) -> f64 {
    let var = pixel_variance(v);
    var.sqrt() * e / (1.0 + e * m).powi(2)
}

/// The upper median (element len / 2 in order); 0 for no values.
fn median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let mid = values.len() / 2;
    *values.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// The image's typical noise as the colour feature sees it: the median over pixels of the noise
/// standard deviation (root of the mean channel variance) through the derivative of the
/// Reinhard tone curve at the pixel, e / (1 + e·c)², with the exposure e taken relative to the
/// image's own robust brightness (so the level does not change with the render's exposure). One
/// number per image (and pyramid level), so a stage's σ can follow the sample count.
pub fn tone_level(color: &Image, variance: &Image, exposure: f32) -> f64 {
    let Some(e) = tone_exposure(color, exposure) else {
        return 0.0;
    };
    let mut levels: Vec<f64> = color
        .data()
        .par_chunks_exact(3)
        .zip(variance.data().par_chunks_exact(3))
        .map(|(c, v)| tone_sd(v, channel_mean(c), e))
        .collect();
    median(&mut levels)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filters::noise::from_image::{estimate, tests::noisy_flat};
    use crate::render_set::FeatureSet;

    /// The colour scales: 1 at the typical level, below 1 where a pixel is noisier, above where
    /// cleaner, within [1/4, 4]; followed less when the image's level is below the reference;
    /// all 1 with power 0, without noise, or on a black image.
    #[test]
    fn color_scales_follow_each_pixels_noise() {
        let (w, h) = (16, 16);
        let color = Image::filled(w, h, 3, 0.1);
        let variance = Image::from_fn(w, h, 3, |x, _, _| match x {
            0..=3 => 4e-4,
            4..=11 => 1e-4,
            _ => 1e-6,
        });
        let scales = color_scales(&color, &variance, 1.0, 1.0, 1e-6);
        let at = |x: usize| scales[3 * w + x];
        assert!((at(8) - 1.0).abs() < 1e-6, "typical pixel {}", at(8));
        assert!((at(1) - 0.5).abs() < 1e-4, "4× the variance: {}", at(1));
        assert_eq!(at(14), 4.0, "clamped at 4");
        // Power 2 at a reference twice the level: γ = 1 again.
        let faded = color_scales(
            &color,
            &variance,
            1.0,
            2.0,
            2.0 * tone_level(&color, &variance, 1.0),
        );
        assert!(
            (faded[3 * w + 1] - 0.5).abs() < 1e-3,
            "faded {}",
            faded[3 * w + 1]
        );
        assert!(color_scales(&color, &variance, 1.0, 0.0, 1.0)
            .iter()
            .all(|&s| s == 1.0));
        let black = Image::new(w, h, 3);
        assert!(color_scales(&black, &variance, 1.0, 1.0, 1.0)
            .iter()
            .all(|&s| s == 1.0));
        for bad in [f32::NAN, f32::INFINITY, -1.0, 0.0] {
            let v = Image::filled(w, h, 3, bad);
            assert!(color_scales(&color, &v, 1.0, 1.0, 1.0)
                .iter()
                .all(|&s| s == 1.0));
        }
        let mut partly = variance.clone();
        partly.pixel_mut(0).fill(f32::NAN);
        let s = color_scales(&color, &partly, 1.0, 1.0, 1.0);
        assert!(s.iter().all(|s| (0.25..=4.0).contains(s)));
    }

    #[test]
    fn tiny_images_and_bad_variance_stay_finite() {
        for (w, h) in [(1, 1), (1, 5), (2, 3)] {
            let img = noisy_flat(w, h, 0.5, 0.1, 5);
            let v = estimate(&img, &FeatureSet::default());
            assert!(v.all_finite());
            assert!(tone_level(&img, &v, 1.0).is_finite());
        }
        let black = Image::new(4, 4, 3);
        assert_eq!(tone_level(&black, &Image::new(4, 4, 3), 1.0), 0.0);
        for bad in [f32::INFINITY, f32::NAN, -1.0] {
            let v = Image::filled(4, 4, 3, bad);
            assert_eq!(tone_level(&black, &v, 1.0), 0.0);
        }
    }
}
