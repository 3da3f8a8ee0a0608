//! How noisy every pixel is (docs/ALGORITHM.md §8): the variance of each pixel's colour mean,
//! estimated from the image alone or taken from what the renderer measured, and the per-pixel
//! colour scale that makes the stages' colour difference count in units of that noise.
//!
//! Why from the image: most users have colour, albedo, normal and depth only. Pixels of one
//! surface (same albedo, normal and depth) see nearly the same radiance, so their spread around
//! the local mean is noise; bringing each neighbour to the pixel's own albedo first keeps texture
//! out of it. Raw estimates from one 5×5 window are themselves noisy, so they are averaged over a
//! 7×7 window of the same surface, weighted by their degrees of freedom. A pixel that finds no
//! surface-mates (a lone pixel, a 1×1 image) takes the plain 3×3 spread, or 0 when it has none.
//!
//! Every pixel's sums run in f64 in a fixed order, so the result is the same bits on any thread
//! count. Variance is per RGB channel; it scales with the square of the exposure, so everything
//! derived from it here is exposure-invariant.

use rayon::prelude::*;

use crate::image::Image;
use crate::render_set::{Feature, FeatureSet};

/// Radius of the window of the raw estimate (5×5).
const RAW_RADIUS: isize = 2;
const RAW_TAPS: usize = (2 * RAW_RADIUS as usize + 1).pow(2);
/// Radius of the window the raw estimates are averaged over (7×7).
const SMOOTH_RADIUS: isize = 3;
/// Fewest surface-mates (the pixel included) a raw estimate needs.
const MIN_MATES: usize = 4;
/// Keeps remodulation finite on black albedo.
const ALBEDO_EPS: f32 = 0.02;

/// When two pixels are taken to lie on one surface. Loose enough for the few-sample features of
/// a 1 spp render, tight enough to keep texture, creases and silhouettes apart.
const ALBEDO_TOLERANCE: f32 = 0.1;
const NORMAL_COS: f32 = 0.9;
const DEPTH_TOLERANCE: f32 = 0.05;

/// The features that decide "same surface".
struct Surface<'a> {
    albedo: Option<&'a [f32]>,
    normal: Option<&'a [f32]>,
    depth: Option<&'a [f32]>,
}

impl<'a> Surface<'a> {
    fn new(features: &'a FeatureSet, dims: (usize, usize)) -> Self {
        let get = |f: Feature| {
            features
                .get(f)
                .filter(|img| img.dims() == dims)
                .map(Image::data)
        };
        Surface {
            albedo: get(Feature::Albedo),
            normal: get(Feature::Normal),
            depth: get(Feature::Depth),
        }
    }

    #[inline]
    fn same(&self, i: usize, j: usize) -> bool {
        if let Some(a) = self.albedo {
            let (p, q) = (&a[3 * i..3 * i + 3], &a[3 * j..3 * j + 3]);
            if (0..3).any(|k| (p[k] - q[k]).abs() > ALBEDO_TOLERANCE) {
                return false;
            }
        }
        if let Some(n) = self.normal {
            let (p, q) = (&n[3 * i..3 * i + 3], &n[3 * j..3 * j + 3]);
            let dot = p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
            let known = |v: &[f32]| v.iter().any(|&x| x != 0.0);
            // Two unknown normals (misses, or renderers without a normal) match.
            if known(p) != known(q) || (known(p) && dot < NORMAL_COS) {
                return false;
            }
        }
        if let Some(z) = self.depth {
            let (zi, zj) = (z[i], z[j]);
            let scale = zi.max(zj);
            if scale > 0.0 && (zi - zj).abs() > DEPTH_TOLERANCE * scale {
                return false;
            }
        }
        true
    }

    /// Pixel i's albedo + ε per channel (1 without albedo): colour divided by it is demodulated.
    #[inline]
    fn scale(&self, i: usize) -> [f64; 3] {
        match self.albedo {
            Some(a) => std::array::from_fn(|k| (a[3 * i + k].max(0.0) + ALBEDO_EPS) as f64),
            None => [1.0; 3],
        }
    }

    /// A variance of pixel i's colour, demodulated.
    fn demodulate_variance(&self, i: usize, v: impl Iterator<Item = f64>) -> [f64; 3] {
        let s = self.scale(i);
        let mut out = [0.0; 3];
        for (k, v) in v.take(3).enumerate() {
            out[k] = v / (s[k] * s[k]);
        }
        out
    }
}

/// Neighbours of pixel (x, y) within `radius`, inside a `w`×`h` image, in raster order.
fn window(x: usize, y: usize, w: usize, h: usize, radius: isize) -> impl Iterator<Item = usize> {
    let (x, y) = (x as isize, y as isize);
    let rows = (y - radius).max(0)..=(y + radius).min(h as isize - 1);
    rows.flat_map(move |ny| {
        let cols = (x - radius).max(0)..=(x + radius).min(w as isize - 1);
        cols.map(move |nx| ny as usize * w + nx as usize)
    })
}

/// Sample variance (per channel) of the colours of `members`, and its degrees of freedom
/// (members − 1).
fn spread(color: &[f32], members: &[usize]) -> ([f64; 3], usize) {
    let mut n = 0usize;
    let mut sum = [0.0f64; 3];
    let mut sum2 = [0.0f64; 3];
    for &j in members {
        for k in 0..3 {
            let v = color[3 * j + k] as f64;
            sum[k] += v;
            sum2[k] += v * v;
        }
        n += 1;
    }
    if n < 2 {
        return ([0.0; 3], 0);
    }
    let nf = n as f64;
    let var = std::array::from_fn(|k| ((sum2[k] - sum[k] * sum[k] / nf) / (nf - 1.0)).max(0.0));
    (var, n - 1)
}

/// Estimates the variance of every pixel's colour mean (RGB) from the colour and the features.
pub fn estimate(color: &Image, features: &FeatureSet) -> Image {
    let (w, h) = color.dims();
    let surface = Surface::new(features, (w, h));
    let c = color.data();
    // Demodulated once: bringing j to i's albedo is then one factor per pixel i, applied in `smooth`.
    let flat: Vec<[f64; 3]> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let s = surface.scale(i);
            std::array::from_fn(|k| c[3 * i + k] as f64 / s[k])
        })
        .collect();
    let raw: Vec<([f64; 3], usize)> = (0..w * h)
        .into_par_iter()
        .map(|i| pair_spread(&flat, &surface, i, w, h))
        .collect();
    smooth(color, &surface, &raw)
}

/// Pairs of adjacent pixels a raw estimate uses: all horizontal and vertical pairs of the window.
const MAX_PAIRS: usize = 2 * RAW_TAPS;
/// The share of the largest squared differences left out: pairs across an edge the features do
/// not show (a light's rim, a shadow's) and fireflies, which are not the noise a filter should
/// follow.
const TRIM: f64 = 0.2;
/// E[χ²₁ | below its 80th percentile]: a trimmed mean of (x_j − x_k)² is this times 2·variance.
const TRIMMED_CHI2_MEAN: f64 = 0.437_724_594_903_639;

/// Raw estimate at pixel `i`: a trimmed mean of the squared differences of adjacent surface-mates
/// in its window (brought to `i`'s albedo), which a smooth change of light barely enters; with
/// its number of pairs kept (0: too few mates).
fn pair_spread(
    flat: &[[f64; 3]],
    surface: &Surface,
    i: usize,
    w: usize,
    h: usize,
) -> ([f64; 3], usize) {
    let (x, y) = ((i % w) as isize, (i / w) as isize);
    let r = RAW_RADIUS;
    let inside = |nx: isize, ny: isize| {
        (x - r..=x + r).contains(&nx)
            && (y - r..=y + r).contains(&ny)
            && nx >= 0
            && ny >= 0
            && (nx as usize) < w
            && (ny as usize) < h
    };
    let mut mate = [false; RAW_TAPS];
    let side = 2 * r + 1;
    let slot = |nx: isize, ny: isize| ((ny - y + r) * side + (nx - x + r)) as usize;
    let mut mates = 0;
    for ny in y - r..=y + r {
        for nx in x - r..=x + r {
            if inside(nx, ny) && surface.same(i, ny as usize * w + nx as usize) {
                mate[slot(nx, ny)] = true;
                mates += 1;
            }
        }
    }
    if mates < MIN_MATES {
        return ([0.0; 3], 0);
    }
    let mut d2 = [[0.0f64; MAX_PAIRS]; 3];
    let mut n = 0;
    for ny in y - r..=y + r {
        for nx in x - r..=x + r {
            if !inside(nx, ny) || !mate[slot(nx, ny)] {
                continue;
            }
            let j = ny as usize * w + nx as usize;
            for (qx, qy) in [(nx + 1, ny), (nx, ny + 1)] {
                if !inside(qx, qy) || !mate[slot(qx, qy)] {
                    continue;
                }
                let q = qy as usize * w + qx as usize;
                for (k, row) in d2.iter_mut().enumerate() {
                    let d = flat[j][k] - flat[q][k];
                    row[n] = d * d;
                }
                n += 1;
            }
        }
    }
    if n < 2 {
        return ([0.0; 3], 0);
    }
    let kept = n - ((n as f64 * TRIM) as usize);
    let var =
        std::array::from_fn(|k| trimmed_mean(&mut d2[k][..n], kept) / (2.0 * TRIMMED_CHI2_MEAN));
    (var, kept)
}

/// The mean of the `kept` smallest values (reorders `values`).
pub(crate) fn trimmed_mean(values: &mut [f64], kept: usize) -> f64 {
    if kept < values.len() {
        values.select_nth_unstable_by(kept, f64::total_cmp);
    }
    values[..kept].iter().sum::<f64>() / kept as f64
}

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
    smooth(color, &surface, &raw)
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
    smooth(color, &surface, &raw)
}

/// A measured variance sample as used here: non-finite or negative counts as 0.
fn clean(v: f32) -> f64 {
    if v.is_finite() && v > 0.0 {
        v as f64
    } else {
        0.0
    }
}

/// Averages raw per-pixel estimates (demodulated variance, degrees of freedom; 0 = none) over the
/// same surface, and brings the result to each pixel's albedo.
fn smooth(color: &Image, surface: &Surface, raw: &[([f64; 3], usize)]) -> Image {
    let (w, h) = color.dims();
    let c = color.data();
    let mut out = Image::new(w, h, 3);
    out.data_mut()
        .par_chunks_mut(3)
        .enumerate()
        .for_each(|(i, px)| {
            let (x, y) = (i % w, i / w);
            let mut acc = [0.0f64; 3];
            let mut dof = 0usize;
            for j in window(x, y, w, h, SMOOTH_RADIUS) {
                let (v, d) = raw[j];
                if d == 0 || !surface.same(i, j) {
                    continue;
                }
                for k in 0..3 {
                    acc[k] += d as f64 * v[k];
                }
                dof += d;
            }
            let var = if dof > 0 {
                let s = surface.scale(i);
                std::array::from_fn(|k| acc[k] / dof as f64 * s[k] * s[k])
            } else {
                let mut near = [0usize; 9];
                let mut n = 0;
                for j in window(x, y, w, h, 1) {
                    near[n] = j;
                    n += 1;
                }
                spread(c, &near[..n]).0
            };
            for k in 0..3 {
                px[k] = var[k] as f32;
            }
        });
    out
}

/// The image's typical noise as the colour feature sees it: the median over pixels of the noise
/// standard deviation (root of the mean channel variance) through the derivative of the
/// Reinhard tone curve at the pixel, e / (1 + e·c)², with the exposure e taken relative to the
/// image's own robust brightness (so the level does not change with the render's exposure). One
/// number per image (and pyramid level), so a stage's σ can follow the sample count.
pub fn tone_level(color: &Image, variance: &Image, exposure: f32) -> f64 {
    let brightness = crate::condition::robust_brightness(color);
    if brightness.is_nan() || brightness <= 0.0 {
        return 0.0;
    }
    let e = exposure as f64 * crate::condition::UNIT_BRIGHTNESS / brightness;
    let mut levels: Vec<f64> = color
        .data()
        .par_chunks_exact(3)
        .zip(variance.data().par_chunks_exact(3))
        .map(|(c, v)| {
            let mean = c.iter().map(|&x| x.max(0.0) as f64).sum::<f64>() / 3.0;
            let var = v.iter().map(|&x| clean(x)).sum::<f64>() / 3.0;
            var.sqrt() * e / (1.0 + e * mean).powi(2)
        })
        .collect();
    if levels.is_empty() {
        return 0.0;
    }
    let mid = levels.len() / 2;
    let (_, &mut median, _) = levels.select_nth_unstable_by(mid, f64::total_cmp);
    median
}

/// Radius of the window the blend's error estimate averages over (5×5).
const BLEND_RADIUS: isize = 2;
/// How many noise variances above its input a pixel's filtered value may rise before it counts as leakage.
const LEAK: f64 = 25.0;
const BLEND_TAPS: usize = (2 * BLEND_RADIUS as usize + 1).pow(2);

/// Per pixel, how much of `filtered` to keep over `color` (0..1): the Wiener weight
/// v / (v + b²) of a filter with bias b on a pixel of noise variance v. E[(f − c)²] ≈ b² + v, so
/// b² + v is estimated by the mean of (f − c)² over the pixel's surface-mates, and the weight is
/// v / max(that, v): where the filter removed only noise it is kept, where it also removed
/// signal (texture, a sharp highlight) the input comes back in proportion.
pub fn keep_weights(
    color: &Image,
    filtered: &Image,
    variance: &Image,
    features: &FeatureSet,
    tolerance: f64,
) -> Vec<f32> {
    let (w, h) = color.dims();
    let surface = Surface::new(features, (w, h));
    let (c, f, v) = (color.data(), filtered.data(), variance.data());
    let diff2: Vec<f64> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            (0..3)
                .map(|k| {
                    let d = f[3 * i + k] as f64 - c[3 * i + k] as f64;
                    d * d
                })
                .sum::<f64>()
                / 3.0
        })
        .collect();
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let mut near = [0.0f64; BLEND_TAPS];
            let mut n = 0;
            for j in window(x, y, w, h, BLEND_RADIUS) {
                if surface.same(i, j) && diff2[j].is_finite() {
                    near[n] = diff2[j];
                    n += 1;
                }
            }
            let var = (0..3).map(|k| clean(v[3 * i + k])).sum::<f64>() / 3.0;
            if var <= 0.0 || n == 0 {
                return 0.0;
            }
            // Trimmed as the estimate is, so that where the filter removed only noise the two agree.
            let kept = n - ((n as f64 * TRIM) as usize);
            let err = trimmed_mean(&mut near[..n], kept) / TRIMMED_CHI2_MEAN;
            let keep = (tolerance * var / err.max(f64::MIN_POSITIVE)).min(1.0);
            // A pixel the filter made far brighter than its own noise allows took light from a
            // neighbour the features could not tell apart (an emitter beside the ceiling it lies
            // in): trimmed away above, so checked alone. Darker is left alone: that is a firefly
            // removed.
            let gain = (0..3)
                .map(|k| (f[3 * i + k] as f64 - c[3 * i + k] as f64).max(0.0).powi(2))
                .sum::<f64>()
                / 3.0;
            let leak = LEAK * var / gain.max(f64::MIN_POSITIVE);
            keep.min(leak).min(1.0) as f32
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noisy_flat(w: usize, h: usize, level: f32, std: f32, seed: u64) -> Image {
        let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let mut uniform = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        Image::from_fn(w, h, 3, |_, _, _| {
            // Sum of 12 uniforms: near Gaussian, variance std².
            let u: f32 = (0..12).map(|_| uniform()).sum::<f32>() - 6.0;
            level + std * u
        })
    }

    #[test]
    fn flat_noise_is_measured() {
        let img = noisy_flat(64, 64, 1.0, 0.1, 3);
        let v = estimate(&img, &FeatureSet::default());
        let mean = v.data().iter().map(|&x| x as f64).sum::<f64>() / v.data().len() as f64;
        assert!((mean.sqrt() - 0.1).abs() < 0.01, "std {}", mean.sqrt());
    }

    #[test]
    fn texture_in_the_albedo_is_not_noise() {
        let (w, h) = (32, 32);
        let albedo = Image::from_fn(
            w,
            h,
            3,
            |x, y, _| if (x / 4 + y / 4) % 2 == 0 { 0.9 } else { 0.1 },
        );
        let color = Image::from_fn(w, h, 3, |x, y, k| albedo.at(x, y)[k]);
        let mut set = FeatureSet::default();
        set.set(Feature::Albedo, albedo).unwrap();
        let v = estimate(&color, &set);
        assert!(
            v.data().iter().all(|&x| x < 1e-10),
            "texture taken for noise"
        );
        let unguided = estimate(&color, &FeatureSet::default());
        assert!(unguided.data().iter().any(|&x| x > 0.01));
    }

    #[test]
    fn scales_with_the_square_of_exposure() {
        let img = noisy_flat(16, 16, 0.5, 0.05, 4);
        let bright =
            Image::from_vec(16, 16, 3, img.data().iter().map(|v| v * 1024.0).collect()).unwrap();
        let (a, b) = (
            estimate(&img, &FeatureSet::default()),
            estimate(&bright, &FeatureSet::default()),
        );
        for (x, y) in a.data().iter().zip(b.data()) {
            assert!((x * 1024.0 * 1024.0 - y).abs() <= 1e-4 * y.abs().max(1e-12));
        }
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
            let keep = keep_weights(&black, &black, &v, &FeatureSet::default(), 1.5);
            assert!(keep.iter().all(|k| *k == 0.0));
        }
    }
}
