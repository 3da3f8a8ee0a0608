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

use crate::filters::noise::measured::clean;
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

/// A pixel's variance as the blend reads it: the mean of its channels', not finite or negative
/// counting as 0.
pub(super) fn pixel_variance(v: &[f32]) -> f64 {
    v.iter().map(|&x| clean(x)).sum::<f64>() / 3.0
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
        let n = filtered.pixel_count();
        if n / BINS < MIN_BIN {
            return None;
        }
        let mut pairs: Vec<(f64, f64)> = (0..n)
            .into_par_iter()
            .map(|i| {
                let v = pixel_variance(variance.pixel(i));
                (ln_luminance(filtered.pixel(i)), v)
            })
            .collect();
        // Ties in both keys are equal pairs: the order is the same whatever the threads.
        pairs.par_sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
        let mut centres: Vec<f64> = Vec::with_capacity(BINS);
        let mut ranges: Vec<(usize, usize)> = Vec::with_capacity(BINS);
        for k in 0..BINS {
            let (start, end) = (k * n / BINS, (k + 1) * n / BINS);
            let centre = pairs[(start + end) / 2].0;
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
        Some(NoiseLevel { centres, levels })
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
pub(super) mod tests {
    use super::super::weights::keep_weights_metered;
    use super::*;
    use crate::filters::noise::from_image::tests::noisy_flat;
    use crate::kernels::simd::Kernel;
    use crate::meter::Meter;
    use crate::render_set::FeatureSet;

    const SIDE: usize = 48;
    /// The flat background's noise σ, and the level it sits at.
    const STD: f32 = 0.02;
    const FLAT: f32 = 0.2;
    /// The level of [`background`]'s bright right part, as noisy as the rest.
    const BRIGHT: f32 = 0.85;

    /// A grey background of noise σ `STD` (its own deterministic noise in every pixel, one value
    /// for all three channels), at `FLAT`, or at `BRIGHT` from column 32 on when `bright`.
    fn background(seed: u64, bright: bool) -> Image {
        let noise = noisy_flat(SIDE, SIDE, 0.0, STD, seed);
        Image::from_fn(SIDE, SIDE, 3, |x, y, _| {
            let level = if bright && x >= 32 { BRIGHT } else { FLAT };
            level + noise.pixel(y * SIDE + x)[0]
        })
    }

    /// The blend's keep weights (tolerance 2, leak 4) with the noise-level cap at `q` (0: off).
    fn keep(color: &Image, filtered: &Image, variance: &Image, q: f64) -> Vec<f32> {
        keep_weights_metered(
            Kernel::detect(),
            (color, filtered, variance),
            &FeatureSet::default(),
            (2.0, 4.0, q),
            &Meter::default(),
        )
    }

    /// The blurred band's filtered profile from column 20 to 26: a 3-pixel band (columns 22..=24)
    /// of input `BAND` on the 0.2 background, spread by the filter over 7 columns.
    const PROFILE: [f32; 7] = [0.25, 0.3, 0.75, 0.9, 0.75, 0.3, 0.25];
    const BAND: f32 = 0.95;
    /// The local estimate's variance around the band: above the background's, below the output's
    /// own variation at the band's edges.
    const BAND_VAR: f32 = 0.0125;

    /// A vertical band of light on the noisy background, which the filter blurred to `PROFILE`;
    /// the local estimate around it reads part of the band as noise (`BAND_VAR` over columns
    /// 18..=28), the background's is its true 0.0004, and so is that of the bright part, which
    /// gives the image's level at the band's brightness.
    pub(in crate::filters::blend) fn blurred_band() -> (Image, Image, Image) {
        let mut color = background(3, true);
        for y in 0..SIDE {
            for x in 22..=24 {
                color.pixel_mut(y * SIDE + x).fill(BAND);
            }
        }
        let filtered = Image::from_fn(SIDE, SIDE, 3, |x, _, _| match x {
            20..=26 => PROFILE[x - 20],
            32.. => BRIGHT,
            _ => FLAT,
        });
        let variance = Image::from_fn(SIDE, SIDE, 3, |x, _, _| {
            if (18..=28).contains(&x) {
                BAND_VAR
            } else {
                STD * STD
            }
        });
        (color, filtered, variance)
    }

    #[test]
    fn a_blurred_band_comes_back_at_its_edges() {
        let (color, filtered, variance) = blurred_band();
        let (off, on) = (
            keep(&color, &filtered, &variance, 0.0),
            keep(&color, &filtered, &variance, 0.75),
        );
        for y in [2, 24, SIDE - 3] {
            // The band's edge pixels, where the filter's output still shows the band: against the
            // inflated estimate the blur looks like noise removed and most of it is kept; against
            // the image's level for that brightness the input comes back.
            for x in [22, 24] {
                let i = y * SIDE + x;
                assert!(off[i] > 0.5, "off at ({x}, {y}): keep {}", off[i]);
                assert!(on[i] < 0.1, "on at ({x}, {y}): keep {}", on[i]);
            }
            // The halo, where the filter added light, and the background: as they were.
            for x in [0, 10, 21, 25, 40] {
                let i = y * SIDE + x;
                assert_eq!(off[i], on[i], "({x}, {y})");
            }
        }
    }

    #[test]
    fn the_same_bits_on_one_and_two_threads() {
        let (color, filtered, variance) = blurred_band();
        let on = |threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let keep = pool.install(|| keep(&color, &filtered, &variance, 0.75));
            keep.iter().map(|k| k.to_bits()).collect::<Vec<_>>()
        };
        assert_eq!(on(1), on(2));
    }

    #[test]
    fn a_spike_a_darker_input_or_a_small_change_is_not_handed_back() {
        let (mut color, filtered, variance) = blurred_band();
        // On the band's edges (filtered 0.75, estimate σ 0.11): one pixel 3σ above the filtered
        // value, one below it. Neither is light the filter took from the band.
        let (spike, dark) = (20 * SIDE + 22, 20 * SIDE + 24);
        color.pixel_mut(spike).fill(0.75 + 3.0 * BAND_VAR.sqrt());
        color.pixel_mut(dark).fill(0.55);
        // And one above it by 2σ of the image's level there: a change that level explains.
        let small = 16 * SIDE + 22;
        let level = NoiseLevel::fit(&filtered, &variance, 0.75).unwrap();
        let sigma = level.at(&[0.75; 3]).sqrt() as f32;
        color.pixel_mut(small).fill(0.75 + 2.0 * sigma);
        let (off, on) = (
            keep(&color, &filtered, &variance, 0.0),
            keep(&color, &filtered, &variance, 0.75),
        );
        assert_eq!(off[spike], on[spike], "spike");
        assert_eq!(off[dark], on[dark], "darker input");
        assert_eq!(off[small], on[small], "a change within the level's noise");
        // Their neighbours along the edge still come back.
        assert!(on[22 * SIDE + 22] < 0.1 && on[22 * SIDE + 24] < 0.1);
    }

    #[test]
    fn white_noise_removed_is_not_handed_back() {
        // The filter took the background's noise out, and in a 16×16 patch noise four times as
        // strong (its estimate right, and far above the image's level): the filtered image is flat
        // there, so nothing reads as structure and every weight is what it was without the cap.
        let loud = |x: usize, y: usize| (16..32).contains(&x) && (16..32).contains(&y);
        let quiet = background(5, false);
        let strong = noisy_flat(SIDE, SIDE, FLAT, 4.0 * STD, 6);
        let color = Image::from_fn(SIDE, SIDE, 3, |x, y, _| {
            let i = y * SIDE + x;
            if loud(x, y) {
                strong.pixel(i)[0]
            } else {
                quiet.pixel(i)[0]
            }
        });
        let filtered = Image::filled(SIDE, SIDE, 3, FLAT);
        let variance = Image::from_fn(SIDE, SIDE, 3, |x, y, _| {
            let s = if loud(x, y) { 4.0 * STD } else { STD };
            s * s
        });
        let off = keep(&color, &filtered, &variance, 0.0);
        let on = keep(&color, &filtered, &variance, 0.75);
        assert_eq!(off, on);
        // The loud patch does sit far above the image's level: only the flat output kept the
        // cap from acting there.
        let level = NoiseLevel::fit(&filtered, &variance, 0.75).unwrap();
        assert!(level.at(&[FLAT; 3]) < ((4.0 * STD).powi(2) / 4.0) as f64);
    }

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
}
