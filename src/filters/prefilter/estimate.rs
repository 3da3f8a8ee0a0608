//! The noise of a feature buffer, read from the buffer itself: trimmed adjacent differences in
//! a window, along the direction it varies least, or the larger of the two.

use rayon::prelude::*;

use super::params::{known, Kind};
use crate::filters::noise::trimmed_chi2_mean;
use crate::image::{par_vec, Image};
use crate::kernels::padded::{Margin, Padded};
use crate::kernels::simd::{row_kernel, Kernel};
use crate::kernels::trim::{self, LANES, MAX_PAIRS, PAIRS};
use crate::meter::Meter;

/// The planes [`variance`] and [`directional_variance`] read: the channels, then 1 where a pixel
/// takes part (inside the image and known), else 0; a margin of zeros as wide as their reach.
fn reading_planes(img: &Image, kind: Kind) -> Padded {
    let (w, h) = img.dims();
    let c = img.channels();
    let data = img.data();
    Padded::new(
        (w, h),
        c + 1,
        trim::RADIUS.max(DIRECTION_REACH) as usize,
        Margin::Zeros,
        |i, k| {
            if k < c {
                data[i * c + k] as f64
            } else {
                f64::from(u8::from(known(img, kind, i)))
            }
        },
    )
}

/// The variance of every pixel's feature mean (mean over channels), from the squared differences
/// of adjacent pixels in its 5×5 window: per channel the smallest `keep` share, so an edge or a
/// texture the feature shows cleanly (crossing fewer pairs than the rest) reads as no noise. A
/// pixel with fewer than two pairs reads 0.
pub fn variance(img: &Image, kind: Kind, keep: f64) -> Vec<f32> {
    variance_with(Kernel::detect(), img, kind, keep)
}

/// [`variance`] with a chosen kernel (all give the same bits).
pub fn variance_with(kernel: Kernel, img: &Image, kind: Kind, keep: f64) -> Vec<f32> {
    trimmed_of(
        kernel,
        &reading_planes(img, kind),
        img.dims(),
        keep,
        &Meter::default(),
    )
}

/// [`variance`] of the `w`×`h` image whose [`reading_planes`] are `planes`.
fn trimmed_of(
    kernel: Kernel,
    planes: &Padded,
    (w, h): (usize, usize),
    keep: f64,
    meter: &Meter,
) -> Vec<f32> {
    let unit = 2.0 * trimmed_chi2_mean(keep);
    let mut out = par_vec(0.0f32, w * h);
    out.par_chunks_mut(w.max(1)).enumerate().for_each(|(y, out)| {
        if meter.cancelled() {
            return;
        }
        row_kernel!(kernel, variance_row(planes: &Padded, keep: f64, unit: f64, y: usize, out: &mut [f32]))
    });
    out
}

/// How far along each direction [`directional_variance`] reads: its 2·REACH pairs.
const DIRECTION_REACH: isize = 2;
/// The directions it compares: along the rows, the columns and both diagonals.
const DIRECTIONS: [(isize, isize); 4] = [(1, 0), (0, 1), (1, 1), (1, -1)];

/// The variance of every pixel's feature mean read along the direction in which the buffer varies
/// least: per direction (rows, columns, both diagonals), the mean over channels of the squared
/// differences of the 2·2 adjacent pairs on the pixel's line, halved; the smallest direction with at
/// least two pairs counts. Along a line or an edge the feature shows, its pairs differ only by
/// noise, so a thin line whose few-sample coverage is noisy (a texture's mortar at 1–4 spp) reads
/// its noise, which [`variance`]'s trimmed window takes for structure; a clean line, edge or flat
/// area reads 0. On noise that is the same in every direction the smallest of four reads low (0.61
/// of white noise's variance with three channels), which is why the stage takes the larger of this
/// and [`variance`] ([`line_aware_variance`]).
/// Unknown normals take no part; a pixel without two pairs in any direction reads 0.
pub fn directional_variance(img: &Image, kind: Kind) -> Vec<f32> {
    directional_with(Kernel::detect(), img, kind)
}

/// [`directional_variance`] with a chosen kernel (all give the same bits).
pub fn directional_with(kernel: Kernel, img: &Image, kind: Kind) -> Vec<f32> {
    directional_of(
        kernel,
        &reading_planes(img, kind),
        img.dims(),
        &Meter::default(),
    )
}

/// [`directional_variance`] of the `w`×`h` image whose [`reading_planes`] are `planes`.
fn directional_of(
    kernel: Kernel,
    planes: &Padded,
    (w, h): (usize, usize),
    meter: &Meter,
) -> Vec<f32> {
    let mut out = par_vec(0.0f32, w * h);
    out.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, out)| {
            if meter.cancelled() {
                return;
            }
            row_kernel!(kernel, directional_row(planes: &Padded, y: usize, out: &mut [f32]))
        });
    out
}

/// [`directional_variance`] of row `y`, `LANES` pixels at a time.
#[inline(always)]
fn directional_row(planes: &Padded, y: usize, out: &mut [f32]) {
    trim::by_lanes!(out, |x| pixel_directional::<LANES>(planes, x, y), |x| {
        pixel_directional::<1>(planes, x, y)[0]
    },);
}

/// The directional variances of pixels (x..x + L, y). A pair with a cell that takes no part adds
/// 0 to its line's sum (exactly what leaving it out adds, as every term is ≥ 0).
#[inline(always)]
fn pixel_directional<const L: usize>(planes: &Padded, x: usize, y: usize) -> [f32; L] {
    let (values, ok) = planes.planes.split_at(planes.planes.len() - 1);
    let ok = &ok[0];
    let c = values.len();
    let mut least = [f64::INFINITY; L];
    for (dx, dy) in DIRECTIONS {
        let (mut sum, mut pairs) = ([0.0f64; L], [0usize; L]);
        for t in -DIRECTION_REACH..DIRECTION_REACH {
            let a = planes.at(x, y, (t * dx, t * dy));
            let b = planes.at(x, y, ((t + 1) * dx, (t + 1) * dy));
            let mut valid = [false; L];
            for l in 0..L {
                valid[l] = (ok[a + l] != 0.0) & (ok[b + l] != 0.0);
                pairs[l] += usize::from(valid[l]);
            }
            for plane in values {
                let (pa, pb) = (&plane[a..a + L], &plane[b..b + L]);
                for l in 0..L {
                    let d = pa[l] - pb[l];
                    sum[l] += if valid[l] { d * d } else { 0.0 };
                }
            }
        }
        for l in 0..L {
            if pairs[l] >= 2 {
                least[l] = least[l].min(sum[l] / (2 * pairs[l] * c) as f64);
            }
        }
    }
    let centre = planes.at(x, y, (0, 0));
    let mut out = [0.0f32; L];
    for l in 0..L {
        if ok[centre + l] != 0.0 && least[l].is_finite() {
            out[l] = least[l] as f32;
        }
    }
    out
}

/// Per pixel, the larger of [`variance`] (with `keep`) and [`directional_variance`]: the noise
/// either reading finds, the first where it is the same in every direction, the second along lines.
pub fn line_aware_variance(img: &Image, kind: Kind, keep: f64) -> Vec<f32> {
    line_aware_metered(img, kind, keep, &Meter::default())
}

/// [`line_aware_variance`] in a run: its rows are skipped once `meter` is cancelled (the result
/// is then unfinished, for the caller to throw away).
pub fn line_aware_metered(img: &Image, kind: Kind, keep: f64, meter: &Meter) -> Vec<f32> {
    let kernel = Kernel::detect();
    let planes = reading_planes(img, kind);
    let mut variance = trimmed_of(kernel, &planes, img.dims(), keep, meter);
    variance
        .par_iter_mut()
        .zip(directional_of(kernel, &planes, img.dims(), meter))
        .for_each(|(trimmed, along)| *trimmed = trimmed.max(along));
    variance
}

/// Most pairs [`variance`] leaves out with the default `keep` in one pass of short lists; a
/// smaller `keep` takes lists as long as the window.
const SHORT_LIST: usize = 14;

/// [`variance`] of row `y`, `LANES` pixels at a time.
#[inline(always)]
fn variance_row(planes: &Padded, keep: f64, unit: f64, y: usize, out: &mut [f32]) {
    let dropped = |n: usize| n - ((n as f64 * keep) as usize).max(1).min(n);
    let short = dropped(MAX_PAIRS) <= SHORT_LIST;
    trim::by_lanes!(
        out,
        |x| {
            if short {
                pixel_variance::<LANES, SHORT_LIST>(planes, &dropped, unit, x, y)
            } else {
                pixel_variance::<LANES, MAX_PAIRS>(planes, &dropped, unit, x, y)
            }
        },
        |x| pixel_variance::<1, MAX_PAIRS>(planes, &dropped, unit, x, y)[0],
    );
}

/// The variances of pixels (x..x + L, y), with at most `T` pairs dropped per pixel.
#[inline(always)]
fn pixel_variance<const L: usize, const T: usize>(
    planes: &Padded,
    dropped: &impl Fn(usize) -> usize,
    unit: f64,
    x: usize,
    y: usize,
) -> [f32; L] {
    let (c, ok) = (
        planes.planes.len() - 1,
        &planes.planes[planes.planes.len() - 1],
    );
    // Both cells' indices of every pair, for the mask and every channel.
    let mut cells = [(0usize, 0usize); MAX_PAIRS];
    for (cell, &[a, b]) in cells.iter_mut().zip(&PAIRS) {
        *cell = (planes.at(x, y, a), planes.at(x, y, b));
    }
    // Added to a pair's squared difference: NaN (left out of the trimmed means) where a cell
    // takes no part.
    let mut mask = [[0.0f64; L]; MAX_PAIRS];
    let mut n = [0usize; L];
    for (mask_p, &(ia, ib)) in mask.iter_mut().zip(&cells) {
        let (oa, ob) = (&ok[ia..ia + L], &ok[ib..ib + L]);
        for l in 0..L {
            let valid = (oa[l] != 0.0) & (ob[l] != 0.0);
            n[l] += usize::from(valid);
            mask_p[l] = trim::valid_or_nan(valid);
        }
    }
    let mut drop = [0usize; L];
    for l in 0..L {
        drop[l] = if n[l] >= 2 { dropped(n[l]) } else { 0 };
    }
    let mut total = [0.0f64; L];
    let mut d2 = [[0.0f64; L]; MAX_PAIRS];
    for plane in &planes.planes[..c] {
        for ((d2_p, mask_p), &(ia, ib)) in d2.iter_mut().zip(&mask).zip(&cells) {
            let (pa, pb) = (&plane[ia..ia + L], &plane[ib..ib + L]);
            for l in 0..L {
                let d = pa[l] - pb[l];
                d2_p[l] = d * d + mask_p[l];
            }
        }
        let mean = trim::lanes::<L, MAX_PAIRS, T>(&d2, drop);
        for l in 0..L {
            total[l] += mean[l] / unit;
        }
    }
    let centre = planes.at(x, y, (0, 0));
    let mut out = [0.0f32; L];
    for l in 0..L {
        if n[l] >= 2 && ok[centre + l] != 0.0 {
            out[l] = (total[l] / c as f64) as f32;
        }
    }
    out
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::kernels::trim::tests::xorshift;

    /// A flat 0.5 with near-Gaussian noise of standard deviation 0.05 (a sum of 12 uniforms).
    pub(crate) fn white_field(side: usize, seed: u64) -> Image {
        let mut bits = xorshift(seed);
        let mut uniform = move || (bits() >> 40) as f32 / (1u64 << 24) as f32;
        Image::from_fn(side, side, 3, |_, _, _| {
            0.5 + 0.05 * ((0..12).map(|_| uniform()).sum::<f32>() - 6.0)
        })
    }

    #[test]
    fn flat_noise_reads_its_variance() {
        let img = white_field(64, 7);
        let v = variance(&img, Kind::Plain, 0.5);
        let mean = v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64;
        assert!((mean.sqrt() - 0.05).abs() < 0.005, "std {}", mean.sqrt());
    }

    /// A 1-pixel line of value 0.9 ± 0.05 (its coverage sampled) across a flat 0.3 field.
    fn noisy_line(w: usize, h: usize, seed: u64) -> Image {
        let mut bits = xorshift(seed);
        let mut sign = move || if bits() >> 63 == 1 { 1.0 } else { -1.0 };
        let line: Vec<f32> = (0..w).map(|_| 0.9 + 0.05 * sign()).collect();
        Image::from_fn(w, h, 3, |x, y, _| if y == h / 2 { line[x] } else { 0.3 })
    }

    #[test]
    fn a_thin_noisy_line_reads_its_noise_along_it() {
        let (w, h) = (64, 9);
        for seed in 1..6 {
            let img = noisy_line(w, h, seed);
            let along = directional_variance(&img, Kind::Plain);
            let trimmed = variance(&img, Kind::Plain, 0.65);
            let mean = |v: &[f32]| {
                (3..w - 3).map(|x| v[h / 2 * w + x] as f64).sum::<f64>() / (w - 6) as f64
            };
            // ±0.05 steps: half the pairs along the line differ by 0.1, so 0.01 / 2 / 2 = 0.0025 = σ²
            // (±0.0004 over the line's pairs); across it the contrast 0.6 reads far more.
            let read = mean(&along);
            assert!(
                (0.0015..0.0035).contains(&read),
                "seed {seed}: along the line {read}"
            );
            // The trimmed window takes the line for structure: why the stage takes the larger.
            assert!(
                mean(&trimmed) < 0.0003,
                "seed {seed}: trimmed {}",
                mean(&trimmed)
            );
            // Off the line, along the rows, the field is flat.
            assert!(along[w + 5] == 0.0 && along[(h / 2 + 1) * w + 5] == 0.0);
        }
    }

    /// [`directional_variance`] as its doc states it, pixel by pixel: each line's cells looked up
    /// with bounds and known checks, pairs with an unknown cell left out.
    fn directional_textbook(img: &Image, kind: Kind) -> Vec<f32> {
        let (w, h) = img.dims();
        let c = img.channels();
        let index = |x: isize, y: isize| {
            (x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h)
                .then(|| y as usize * w + x as usize)
                .filter(|&i| known(img, kind, i))
        };
        let mut out = vec![0.0f32; w * h];
        for (i, o) in out.iter_mut().enumerate() {
            let (x, y) = ((i % w) as isize, (i / w) as isize);
            if index(x, y).is_none() {
                continue;
            }
            let mut least = f64::INFINITY;
            for (dx, dy) in DIRECTIONS {
                let (mut sum, mut pairs) = (0.0f64, 0usize);
                for t in -DIRECTION_REACH..DIRECTION_REACH {
                    let a = index(x + t * dx, y + t * dy);
                    let b = index(x + (t + 1) * dx, y + (t + 1) * dy);
                    if let (Some(a), Some(b)) = (a, b) {
                        for k in 0..c {
                            let d = img.pixel(a)[k] as f64 - img.pixel(b)[k] as f64;
                            sum += d * d;
                        }
                        pairs += 1;
                    }
                }
                if pairs >= 2 {
                    least = least.min(sum / (2 * pairs * c) as f64);
                }
            }
            if least.is_finite() {
                *o = least as f32;
            }
        }
        out
    }

    #[test]
    fn directional_gives_the_pixel_by_pixel_bits_with_either_kernel() {
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for (w, h) in [(1, 1), (2, 3), (5, 4), (9, 1), (23, 17), (41, 9)] {
            let noisy = white_field(w.max(h), 3);
            // Unknown (all-zero) normals on a diagonal stripe, noisy values elsewhere.
            let img = Image::from_fn(w, h, 3, |x, y, k| {
                if (x + 2 * y) % 7 == 0 {
                    0.0
                } else {
                    noisy.pixel(y * noisy.width() + x)[k]
                }
            });
            for kind in [Kind::Plain, Kind::Normal] {
                let want = bits(&directional_textbook(&img, kind));
                for kernel in [Kernel::Scalar, Kernel::detect()] {
                    let got = bits(&directional_with(kernel, &img, kind));
                    assert_eq!(got, want, "{w}x{h} {kind:?} {kernel:?}");
                }
            }
        }
    }

    #[test]
    fn directional_reads_nothing_on_clean_lines_edges_and_flat_fields() {
        for img in [
            Image::from_fn(17, 13, 3, |_, y, _| if y == 6 { 0.9 } else { 0.1 }),
            Image::from_fn(17, 13, 3, |x, _, _| if x < 8 { 0.9 } else { 0.1 }),
            Image::from_fn(17, 13, 3, |x, y, _| if x > y { 0.9 } else { 0.1 }),
            Image::from_fn(17, 13, 3, |_, _, k| 0.3 * k as f32),
            Image::from_fn(1, 1, 3, |_, _, _| 0.5),
        ] {
            let v = directional_variance(&img, Kind::Plain);
            assert!(v.iter().all(|&x| x == 0.0), "{:?}", img.dims());
        }
    }

    #[test]
    fn directional_reads_white_noise_low() {
        let img = white_field(96, 3);
        let v = directional_variance(&img, Kind::Plain);
        let mean = v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64;
        // The smallest of four directions: 0.61 of the variance (0.0025) with three channels.
        assert!((0.55..0.67).contains(&(mean / 0.0025)), "{}", mean / 0.0025);
    }

    #[test]
    fn a_clean_checker_reads_no_noise() {
        let img = Image::from_fn(16, 16, 3, |x, y, _| ((x / 2 + y / 2) % 2) as f32);
        assert!(variance(&img, Kind::Plain, 0.5).iter().all(|&v| v == 0.0));
    }
}
