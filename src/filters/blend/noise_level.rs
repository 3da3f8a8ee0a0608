//! A second opinion on the noise for the blend's test: the image's noise-level function (how
//! noisy pixels of each brightness are, read robustly from the local estimates of the whole
//! image) caps a pixel's local estimate where that estimate may be reading structure as noise.
//!
//! The local estimate counts a reflected highlight, a light's anti-aliased rim or a sharp texture
//! edge that the features do not explain as noise; the blend then keeps the filter's blur there.
//! Where a pixel's estimate sits far above what pixels as bright show across the image, the filter
//! took light away from it, the pixel is no spike by its own estimate, and the filtered image
//! itself still shows structure around it, the change is tested against the image's level instead,
//! so the input comes back in proportion. At few samples a pixel's noise does vary that much, but
//! there the filtered image is smooth, or the input is below it (a path-traced pixel's noise is
//! skewed: most samples land below the mean), and nothing changes.

use rayon::prelude::*;

use super::error_estimate::BLEND_TAPS;
use crate::filters::noise::measured::pixel_variance;
use crate::image::Image;

/// How many equal-count brightness bins the noise-level function is read in.
const BINS: usize = 16;
/// Fewest pixels a bin needs for its quantile to be a reading: smaller images get no cap.
const MIN_BIN: usize = 21;
/// Darkest luminance the function tells apart (its bins are in log luminance).
const DARK: f64 = 1e-4;
/// A pixel whose input is further above the filtered value than this many of its own noise σ
/// is a spike the filter rightly took out: its estimate is not capped.
const SPIKE_SIGMAS: f64 = 2.0;
/// How many σ of the image's level a change must exceed to be tested against it: a smaller one
/// the level's own noise explains, and the local estimate is not doubted.
const SIGNIFICANT: f64 = 3.0;
/// How many times the estimate the filtered image's own 3×3 variance must be for the estimate to
/// count as possibly reading structure (its σ twice the estimate's): beside an emitter or a
/// highlight the output still shows, not on a surface the filter left merely uneven.
const STRUCTURE: f64 = 4.0;

/// The image's noise-level function: per brightness bin (log luminance of the filtered image), a
/// quantile of the local variance estimates, interpolated in log-log between the bins' centres.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct NoiseLevel {
    /// Each bin's median ln luminance, increasing.
    centres: Vec<f64>,
    /// Each bin's ln variance at the quantile.
    levels: Vec<f64>,
}

/// ln of a pixel's luminance, floored at `DARK`; anything not finite counts as dark.
fn ln_luminance(p: &[f32]) -> f64 {
    let l = 0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64;
    if l.is_finite() {
        l.max(DARK).ln()
    } else {
        DARK.ln()
    }
}

/// The order of (ln luminance, variance) pairs: by brightness, ties by variance.
fn by_pair(a: &(f64, f64), b: &(f64, f64)) -> std::cmp::Ordering {
    a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1))
}

/// Reorders `pairs` so that each run between consecutive `bounds` (increasing indices inside it)
/// holds the pairs a sort by [`by_pair`] would put there: the middle bound selected, then both
/// sides in parallel.
fn into_bins(pairs: &mut [(f64, f64)], bounds: &[usize]) {
    if bounds.is_empty() {
        return;
    }
    let mid = bounds.len() / 2;
    let at = bounds[mid];
    pairs.select_nth_unstable_by(at, by_pair);
    let (left, right) = pairs.split_at_mut(at);
    let above: Vec<usize> = bounds[mid + 1..].iter().map(|b| b - at).collect();
    rayon::join(
        || into_bins(left, &bounds[..mid]),
        || into_bins(right, &above),
    );
}

/// The `q` quantile of `values` (linear between order statistics, as numpy's default), which it
/// reorders.
fn quantile(values: &mut [f64], q: f64) -> f64 {
    let at = q * (values.len() - 1) as f64;
    let lo = at.floor() as usize;
    let (_, &mut low, above) = values.select_nth_unstable_by(lo, f64::total_cmp);
    let high = above.iter().copied().min_by(f64::total_cmp).unwrap_or(low);
    low + (at - lo as f64) * (high - low)
}

impl NoiseLevel {
    /// The function of `filtered`'s brightness against `variance`'s local estimates at quantile
    /// `q` (0..=1); `None` when the image has too few pixels for every bin to be a reading.
    pub(super) fn fit(filtered: &Image, variance: &Image, q: f64) -> Option<NoiseLevel> {
        Self::fit_over(filtered, variance, q, false)
    }

    /// [`NoiseLevel::fit`] over the pixels with some noise only: where a few samples all missed
    /// the light, black pixels of no measured noise fill the dark bins and would read their
    /// level as 0, which the leak test must not believe.
    pub(super) fn fit_noisy(filtered: &Image, variance: &Image, q: f64) -> Option<NoiseLevel> {
        Self::fit_over(filtered, variance, q, true)
    }

    fn fit_over(filtered: &Image, variance: &Image, q: f64, noisy: bool) -> Option<NoiseLevel> {
        let mut pairs: Vec<(f64, f64)> = (0..filtered.pixel_count())
            .into_par_iter()
            .map(|i| {
                let v = pixel_variance(variance.pixel(i));
                (ln_luminance(filtered.pixel(i)), v)
            })
            .filter(|&(_, v)| !noisy || v > 0.0)
            .collect();
        let n = pairs.len();
        if n / BINS < MIN_BIN {
            return None;
        }
        // Each bin holds the pixels a sort would put there, in some order: only the bins'
        // boundaries and middles are ever read, so they are selected, not the whole image sorted.
        // Ties in both keys are equal pairs: the bins are the same whatever the threads.
        let bounds: Vec<usize> = (1..BINS).map(|k| k * n / BINS).collect();
        into_bins(&mut pairs, &bounds);
        Some(Self::from_bins(&mut pairs, q, |bin| {
            let (_, middle, _) = bin.select_nth_unstable_by(bin.len() / 2, by_pair);
            middle.0
        }))
    }

    /// The function at quantile `q` from `pairs` already in their bins (the run from k·n/BINS to
    /// (k+1)·n/BINS holds bin k's pairs, in any order), `centre` reading a bin's middle brightness.
    fn from_bins(
        pairs: &mut [(f64, f64)],
        q: f64,
        mut centre: impl FnMut(&mut [(f64, f64)]) -> f64,
    ) -> NoiseLevel {
        let n = pairs.len();
        let mut centres: Vec<f64> = Vec::with_capacity(BINS);
        let mut ranges: Vec<(usize, usize)> = Vec::with_capacity(BINS);
        for k in 0..BINS {
            let (start, end) = (k * n / BINS, (k + 1) * n / BINS);
            let centre = centre(&mut pairs[start..end]);
            // Bins of one brightness (a black background) are one reading.
            match (centres.last(), ranges.last_mut()) {
                (Some(&last), Some(range)) if last == centre => range.1 = end,
                _ => {
                    centres.push(centre);
                    ranges.push((start, end));
                }
            }
        }
        let levels = ranges
            .iter()
            .map(|&(start, end)| {
                let mut v: Vec<f64> = pairs[start..end].iter().map(|p| p.1).collect();
                quantile(&mut v, q).max(f64::MIN_POSITIVE).ln()
            })
            .collect();
        NoiseLevel { centres, levels }
    }

    /// The function's variance at the brightness of filtered pixel `f`: held at the end bins'
    /// levels beyond them.
    pub(super) fn at(&self, f: &[f32]) -> f64 {
        let x = ln_luminance(f);
        let (c, l) = (&self.centres, &self.levels);
        let above = c.partition_point(|&centre| centre < x);
        let ln = if above == 0 {
            l[0]
        } else if above == c.len() {
            l[c.len() - 1]
        } else {
            let t = (x - c[above - 1]) / (c[above] - c[above - 1]);
            l[above - 1] + t * (l[above] - l[above - 1])
        };
        ln.exp()
    }
}

/// The variance the blend tests pixel (x, y)'s change against: its own estimate `var`, or the
/// image's level where that is lower and the pixel passes the three checks of the module's
/// comment. `color`, `filtered` are whole images (RGB).
pub(super) fn tested_variance(
    level: &NoiseLevel,
    (color, filtered): (&[f32], &[f32]),
    (w, h): (usize, usize),
    (x, y): (usize, usize),
    var: f64,
) -> f64 {
    let i = y * w + x;
    let (c, f) = (&color[3 * i..3 * i + 3], &filtered[3 * i..3 * i + 3]);
    let cap = level.at(f);
    if cap >= var {
        return var;
    }
    let (mut rise, mut change2) = (0.0, 0.0);
    for k in 0..3 {
        let d = c[k] as f64 - f[k] as f64;
        rise += d;
        change2 += d * d;
    }
    // The filter took light away (the input above it on average), more than the image's level
    // explains but not a spike's worth by the pixel's own estimate; and the filtered image's own
    // variation over the 3×3 window (edges clamped) is well above the estimate: structure the
    // estimate may have read. Anything not finite keeps the estimate.
    let change2 = change2 / 3.0;
    let took_light = rise > 0.0
        && change2 > SIGNIFICANT * SIGNIFICANT * cap
        && change2 <= SPIKE_SIGMAS * SPIKE_SIGMAS * var;
    if took_light && window_variance(filtered, (w, h), (x, y)) >= STRUCTURE * var {
        cap
    } else {
        var
    }
}

/// How far under a pixel's brightness the image's level σ must be for the leak test to trust it:
/// where a pixel's noise is that small against its mean, its input is about as likely above the
/// mean as below, so a rise beyond the level is light moved in, not the skew of a few samples.
const SYMMETRIC: f64 = 0.1;

/// The variance the leak test holds a pixel's rise against (`leak_level`): the image's level at
/// its brightness where that is below its own estimate `var`, the filter made it brighter, and
/// the level's σ is under a tenth of both its input's and its filtered brightness (the noise
/// nearly symmetric), else
/// `var`. Where the local estimate reads a reflection's or a refraction's structure as noise, a
/// dark pixel beside a highlight takes the highlight's light through the filter and `var` lets it.
pub(super) fn leak_variance(level: &NoiseLevel, (c, f): (&[f32], &[f32]), var: f64) -> f64 {
    // The rise first: it is cheap, and a pixel the filter made darker keeps `var` whatever the
    // level (about half of them).
    let rise: f64 = (0..3).map(|k| f[k] as f64 - c[k] as f64).sum();
    if rise.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return var;
    }
    let cap = level.at(f);
    if cap.partial_cmp(&var) != Some(std::cmp::Ordering::Less) {
        return var;
    }
    // Both the input's and the filtered brightness: an input of a few samples that all missed
    // the light (0, or far below its mean) is the skew itself, whatever the filtered value.
    let bright = ln_luminance(f).min(ln_luminance(c)).exp();
    if cap.sqrt() < SYMMETRIC * bright {
        cap
    } else {
        var
    }
}

/// The leak test's variance `leak_var` for pixel `ci` of `color`, whose rise to the filtered `fi`
/// the test would take back, raised where that rise is the skew of a few samples: where the image's
/// level σ at `fi` is at least a tenth of its surface-mates' median input (most samples missing the
/// light: fog's scattered paths at 1 spp), a rise up to that median, per channel, is explained. A
/// dark dot among a surface's brighter pixels then keeps the filtered value instead of its speck;
/// an emitter's rim, whose surface-mates are as dark as it, or any pixel where the noise is nearly
/// symmetric (many samples), is tested as before.
pub(super) fn skew_variance(
    level: &NoiseLevel,
    (color, ci, fi): (&[f32], &[f32], &[f32]),
    mates: impl Iterator<Item = usize>,
    leak_var: f64,
) -> f64 {
    // The mates' inputs per channel, on the stack: at most the blend window's cells.
    let mut values = [[0.0f32; BLEND_TAPS]; 3];
    let mut n = 0;
    for j in mates {
        for (k, v) in values.iter_mut().enumerate() {
            v[n] = color[3 * j + k];
        }
        n += 1;
    }
    if n == 0 {
        return leak_var;
    }
    let median = values.map(|mut v| *v[..n].select_nth_unstable_by(n / 2, f32::total_cmp).1 as f64);
    let bright = (median[0] + median[1] + median[2]) / 3.0;
    if level.at(fi).sqrt() < SYMMETRIC * bright {
        return leak_var;
    }
    let explained = (0..3)
        .map(|k| (median[k] - ci[k] as f64).max(0.0).powi(2))
        .sum::<f64>()
        / 3.0;
    leak_var.max(explained)
}

/// The mean over channels of the variance of `image`'s 3×3 window around (x, y), its edges
/// clamped.
fn window_variance(image: &[f32], (w, h): (usize, usize), (x, y): (usize, usize)) -> f64 {
    let mut sum = [0.0f64; 3];
    let mut sum2 = [0.0f64; 3];
    for dy in -1isize..=1 {
        let yy = (y as isize + dy).clamp(0, h as isize - 1) as usize;
        for dx in -1isize..=1 {
            let xx = (x as isize + dx).clamp(0, w as isize - 1) as usize;
            let p = &image[3 * (yy * w + xx)..3 * (yy * w + xx) + 3];
            for k in 0..3 {
                let v = p[k] as f64;
                sum[k] += v;
                sum2[k] += v * v;
            }
        }
    }
    (0..3)
        .map(|k| (sum2[k] / 9.0 - (sum[k] / 9.0).powi(2)).max(0.0))
        .sum::<f64>()
        / 3.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_level_follows_brightness_and_needs_enough_pixels() {
        // Variance proportional to brightness, one brightness a pixel: the function reads it
        // back between the bins and holds it beyond them.
        let (w, h) = (64, 32);
        let brightness = |i: usize| 1e-3 * (i + 1) as f32;
        let filtered = Image::from_fn(w, h, 3, |x, y, _| brightness(y * w + x));
        let variance = Image::from_fn(w, h, 3, |x, y, _| 1e-3 * brightness(y * w + x));
        let level = NoiseLevel::fit(&filtered, &variance, 0.5).unwrap();
        for i in [200usize, 700, 1111, 1900] {
            let l = brightness(i);
            let got = level.at(&[l; 3]);
            assert!((got / (1e-3 * l as f64) - 1.0).abs() < 0.05, "{l}: {got}");
        }
        let top = level.at(&[100.0; 3]);
        assert!(top > 1e-3 * 1.9 && top < 1e-3 * 2.048, "{top}");
        // Bad values read as dark and as no noise, not as NaN.
        assert!(level.at(&[f32::NAN; 3]).is_finite());
        let small = Image::filled(18, 18, 3, 1.0);
        assert_eq!(NoiseLevel::fit(&small, &small, 0.5), None);
    }

    /// The fit as it was made before the bins were selected: the whole image sorted.
    fn sorted_fit(filtered: &Image, variance: &Image, q: f64) -> NoiseLevel {
        let mut pairs: Vec<(f64, f64)> = (0..filtered.pixel_count())
            .map(|i| {
                let v = pixel_variance(variance.pixel(i));
                (ln_luminance(filtered.pixel(i)), v)
            })
            .collect();
        pairs.sort_by(by_pair);
        // Sorted, every bin is in place, and its middle is the sorted order's (start + end) / 2.
        NoiseLevel::from_bins(&mut pairs, q, |bin| bin[bin.len() / 2].0)
    }

    #[test]
    fn selected_bins_read_the_same_levels_as_a_sort() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::Xoshiro256PlusPlus::seed_from_u64(7);
        for (w, h) in [(17, 20), (40, 33), (101, 57)] {
            // A black background (one brightness, ties), a few brightness levels repeated, and
            // a continuum.
            let lum = |rng: &mut rand::rngs::Xoshiro256PlusPlus| match rng.random_range(0..4) {
                0 => 0.0,
                1 => [0.25f32, 0.5][rng.random_range(0..2)],
                _ => rng.random::<f32>() * 4.0,
            };
            let mut f = Image::new(w, h, 3);
            for px in f.data_mut().chunks_exact_mut(3) {
                px.fill(lum(&mut rng));
            }
            // Noise that grows with brightness, so the pixel at a bin's edge is its extreme.
            let mut variance = f.clone();
            for px in variance.data_mut().chunks_exact_mut(3) {
                let v = 1e-3 * px[0] + [0.0, 1e-6][rng.random_range(0..2)];
                px.fill(v);
            }
            for q in [0.0, 0.5, 0.75, 1.0] {
                let got = NoiseLevel::fit(&f, &variance, q).unwrap();
                assert_eq!(got, sorted_fit(&f, &variance, q), "{w}x{h} q {q}");
            }
        }
    }
}
