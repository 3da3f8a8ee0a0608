//! The blend's Wiener keep weights: per pixel, how much of the filtered image to keep over the
//! colour it came from, from its error estimate and its noise variance.

use rayon::prelude::*;

use super::error_estimate::{blend_error_row, trimmed_chi2, BLEND_RADIUS};
use super::noise_level::{leak_variance, skew_variance, tested_variance, NoiseLevel};
use crate::filters::noise::from_image::MIN_MATES;
use crate::filters::noise::measured::pixel_variance;
use crate::filters::noise::surface::{Mates, Surface};
use crate::image::{par_vec, Image};
use crate::kernels::padded::{Margin, Padded};
use crate::kernels::simd::{row_kernel, Kernel};
use crate::kernels::trim;
use crate::meter::Meter;
use crate::render_set::FeatureSet;

/// Per pixel, how much of `filtered` to keep over `color` (0..1): the Wiener weight
/// v / (v + b²) of a filter with bias b on a pixel of noise variance v. E[(f − c)²] ≈ b² + v, so
/// b² + v is estimated by the mean of (f − c)² over the pixel's surface-mates, and the weight is
/// v / max(that, v): where the filter removed only noise it is kept, where it also removed
/// signal (texture, a sharp highlight) the input comes back in proportion. `kernel` runs the
/// error estimates (every kernel gives the same bits).
pub fn keep_weights(
    kernel: Kernel,
    color: &Image,
    filtered: &Image,
    variance: &Image,
    features: &FeatureSet,
    tolerance: f64,
    leak: f64,
) -> Vec<f32> {
    let inputs = (color, filtered, variance);
    keep_weights_metered(
        kernel,
        inputs,
        features,
        (tolerance, leak, 0.0, 0.0),
        None,
        &Meter::default(),
    )
}

/// [`keep_weights`] of (colour, filtered, variance) with (tolerance, leak, noise_level, leak_level),
/// skipping its remaining rows once `meter` is cancelled (the weights are then unfinished, for the
/// caller to throw away). `noise_level` above 0 is the quantile of the image's noise-level function
/// that caps the tested variance where the estimate may read structure (`noise_level`);
/// `leak_level` above 0 the quantile that caps the leak test's variance (`leak_level`); 0 leaves
/// each alone.
pub fn keep_weights_metered(
    kernel: Kernel,
    (color, filtered, variance): (&Image, &Image, &Image),
    features: &FeatureSet,
    (tolerance, leak, noise_level, leak_level): (f64, f64, f64, f64),
    normal_reliability: Option<&[f32]>,
    meter: &Meter,
) -> Vec<f32> {
    let (w, h) = color.dims();
    let level = (noise_level > 0.0)
        .then(|| NoiseLevel::fit(filtered, variance, noise_level))
        .flatten();
    let leak_cap = (leak_level > 0.0)
        .then(|| NoiseLevel::fit_noisy(filtered, variance, leak_level))
        .flatten();
    let surface = Surface::new(features, (w, h));
    let (c, f, v) = (color.data(), filtered.data(), variance.data());
    let mates = surface.mates_metered(w, h, BLEND_RADIUS as usize, meter);
    let diff2 = Padded::new((w, h), 1, trim::RADIUS as usize, Margin::Zeros, |i, _| {
        (0..3)
            .map(|k| {
                let d = f[3 * i + k] as f64 - c[3 * i + k] as f64;
                d * d
            })
            .sum::<f64>()
            / 3.0
    });
    // Row by row, the error estimates into a row of the thread's own, then the weights: no
    // whole-image table of them (16 bytes a pixel) when the blend is the run's last stage.
    let mut keep = par_vec(0.0f32, w * h);
    meter.pass(h);
    keep.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each_init(Vec::new, |row, (y, keep)| {
            if meter.cancelled() {
                return;
            }
            meter.rows(1);
            row.resize(keep.len(), (0.0, 0));
            let (diff2, mates, out) = (&diff2, &mates, row.as_mut_slice());
            row_kernel!(kernel, blend_error_row(diff2: &Padded, mates: &Mates, y: usize, out: &mut [(f64, usize)]));
            for (x, (keep, &(err, n))) in keep.iter_mut().zip(row.iter()).enumerate() {
                let i = y * w + x;
                let var = pixel_variance(&v[3 * i..3 * i + 3]);
                // A pixel with few surface-mates has the noise stage's estimate of a lone pixel
                // (its window's adjacent pairs, one direction's across an edge), which reads
                // structure less: the image's level, fitted on surfaces, is not its noise.
                let tested = match &level {
                    Some(level) if n >= MIN_MATES => tested_variance(level, (c, f), (w, h), (x, y), var),
                    _ => var,
                };
                let (ci, fi) = (&c[3 * i..3 * i + 3], &f[3 * i..3 * i + 3]);
                // Held against the image's level where the estimate may read structure, and
                // raised where the rise is the skew of a few samples (`skew_variance`).
                let leak_var = match &leak_cap {
                    Some(level) => {
                        let held = leak_variance(level, (ci, fi), var);
                        // Cheapest first: most pixels' rise passes the leak test as it is.
                        match normal_reliability {
                            Some(rho)
                                if rise2(ci, fi) > leak * held
                                    && unreliable_around(rho, mates.of(i)) =>
                            {
                                skew_variance(level, (c, ci, fi), mates.of(i), held)
                            }
                            _ => held,
                        }
                    }
                    None => var,
                };
                *keep = keep_weight(ci, fi, (var, tested, leak_var), (err, n), tolerance, leak);
            }
        });
    keep
}

/// The mean over channels of the squared rise from colour `c` to filtered `f` (falls count 0):
/// what the leak test holds against its variance.
fn rise2(c: &[f32], f: &[f32]) -> f64 {
    (0..3)
        .map(|k| (f[k] as f64 - c[k] as f64).max(0.0).powi(2))
        .sum::<f64>()
        / 3.0
}

/// Whether the normal's mean reliability over a pixel's surface-mates is under a half: the
/// geometry there is mostly noise (fog, where Blender writes a camera-facing normal for a sample
/// that scattered), not one clean surface. The albedo's would not do: a lone dark texel reads as
/// its noise over the whole gate window around it.
fn unreliable_around(rho: &[f32], mates: impl Iterator<Item = usize>) -> bool {
    let (mut sum, mut n) = (0.0f64, 0usize);
    for j in mates {
        sum += rho[j] as f64;
        n += 1;
    }
    n > 0 && sum < 0.5 * n as f64
}

/// One pixel's weight of [`keep_weights`]: its colour `c`, filtered value `f`, noise variance
/// `var`, the variances its change and its rise are tested against (`tested`, `leak_var`, each
/// at most `var`), and the trimmed mean `err` of (f − c)² over its `n` surface-mates.
fn keep_weight(
    c: &[f32],
    f: &[f32],
    (var, tested, leak_var): (f64, f64, f64),
    (err, n): (f64, usize),
    tolerance: f64,
    leak: f64,
) -> f32 {
    if var <= 0.0 || n == 0 {
        return 0.0;
    }
    // Divided by the constant of its own n: with few mates, as at a geometric edge, little is
    // trimmed.
    let err = err / trimmed_chi2(n);
    let keep = (tolerance * tested / err.max(f64::MIN_POSITIVE)).min(1.0);
    // A pixel the filter made far brighter than its own noise allows took light from a neighbour
    // the features could not tell apart (an emitter beside the ceiling it lies in): trimmed away
    // above, so checked alone. Darker is left alone: that is a firefly removed.
    let leak = leak * leak_var / rise2(c, f).max(f64::MIN_POSITIVE);
    keep.min(leak).min(1.0) as f32
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::filters::noise::from_image::tests::noisy_flat;
    use crate::render_set::Feature;

    /// A 9×9 flat image of colour 1 and noise variance 0.01 (σ 0.1), with a 2×2 patch of its own
    /// albedo at (4..6, 4..6): the patch's pixels have 4 surface-mates each, the rest many.
    pub(crate) fn blend_case() -> (Image, Image, FeatureSet) {
        let (w, h) = (9, 9);
        let patch = |x: usize, y: usize| (4..6).contains(&x) && (4..6).contains(&y);
        let mut set = FeatureSet::default();
        let albedo = Image::from_fn(w, h, 3, |x, y, _| if patch(x, y) { 0.2 } else { 0.8 });
        set.set(Feature::Albedo, albedo).unwrap();
        (
            Image::filled(w, h, 3, 1.0),
            Image::filled(w, h, 3, 0.01),
            set,
        )
    }

    /// The blend's keep weights of `filtered` over [`blend_case`] (tolerance 2).
    pub(crate) fn blend_case_keep(filtered: &Image, leak: f64) -> Vec<f32> {
        let (color, variance, set) = blend_case();
        keep_weights(
            Kernel::detect(),
            &color,
            filtered,
            &variance,
            &set,
            2.0,
            leak,
        )
    }

    /// Where the filter hit the mean of a flat surface it removed only noise: the trimmed mean of
    /// (f − c)², divided by its own χ² constant, reads the noise variance v, so with tolerance 0.5
    /// the weight is about 0.5 · v / v. Without the constant it reads under half of v, and the
    /// weight 1. The channels share one noise value per pixel, as a render's mostly do.
    #[test]
    fn a_noise_only_change_reads_the_noise_variance() {
        let (w, h, std) = (64, 64, 0.1f32);
        let shared = noisy_flat(w, h, 1.0, std, 5);
        let color = Image::from_fn(w, h, 3, |x, y, _| shared.pixel(y * w + x)[0]);
        let filtered = Image::filled(w, h, 3, 1.0);
        let variance = Image::filled(w, h, 3, std * std);
        let set = FeatureSet::default();
        let mut keep = keep_weights(
            Kernel::detect(),
            &color,
            &filtered,
            &variance,
            &set,
            0.5,
            1e9,
        );
        keep.sort_by(f32::total_cmp);
        let median = keep[keep.len() / 2];
        assert!((0.4..=0.65).contains(&median), "median weight {median}");
    }

    #[test]
    fn few_surface_mates_keep_a_noise_only_change() {
        // The filter moved every pixel by exactly σ, what removing noise alone does on average. On
        // the 2×2 patch nothing of 4 mates is trimmed, so their mean of (f − c)² is v itself and all
        // of the change is kept; the large-n constant read it as 2.3 v and gave an eighth back.
        let filtered = Image::filled(9, 9, 3, 1.1);
        let keep = blend_case_keep(&filtered, 4.0);
        for (x, y) in [(4, 4), (5, 4), (4, 5), (5, 5)] {
            let k = keep[y * 9 + x];
            assert!(k > 0.999, "patch pixel ({x}, {y}): keep {k}");
        }
    }

    #[test]
    fn bad_variance_keeps_nothing() {
        let black = Image::new(4, 4, 3);
        for bad in [f32::INFINITY, f32::NAN, -1.0] {
            let v = Image::filled(4, 4, 3, bad);
            let keep = keep_weights(
                Kernel::detect(),
                &black,
                &black,
                &v,
                &FeatureSet::default(),
                1.5,
                4.0,
            );
            assert!(keep.iter().all(|k| *k == 0.0));
        }
    }
}
