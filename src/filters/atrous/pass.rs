//! Edge-avoiding à-trous filtering with GSID's pixel difference (after Dammertz et al. 2010,
//! "Edge-avoiding À-Trous wavelet transform for fast global illumination filtering").
//!
//! Why: a GSID result averages each pixel over the few dozen pixels its walks reach, so flat
//! surfaces keep a fine speckle and faint blotches at the scale of a walk. One pass of this filter
//! averages every pixel with 5×5 taps 2^k pixels apart (B3-spline weights), each tap also weighted
//! by exp(−d(i, j)²/(2σ²)) with d the GSID difference of ALGORITHM.md §2. The colour feature is
//! taken from the image being filtered, so after GSID it is nearly noise-free and σ can be small:
//! the averaging stops at every edge of colour, albedo, normal, material, shadow or depth.
//! Two passes reach 13×13 pixels for 50 taps.
//!
//! Deterministic (no random numbers); every pixel's sums are formed in f64 in one fixed order, so
//! the result is the same bits on any thread count and with either kernel.

use std::ops::Range;

use rayon::prelude::*;

use crate::features::{distance_row, FeaturePlanes};
use crate::image::Image;
use crate::kernels::fastmath::exp_neg_row;
use crate::kernels::simd::{row_kernel, Kernel};
use crate::meter::Meter;

/// The features of image rows `rows` as planes padded by `pad` columns, and their depth weight, as
/// [`crate::features::Recipe::planes`] makes them: a pass asks for one band (plus halo)
/// at a time, so the image's features (56 bytes a pixel) never exist at once.
pub type Bands<'a> = dyn Fn(Range<usize>, usize) -> (FeaturePlanes, f32) + Sync + 'a;

/// The B3-spline taps of one axis (sum 1).
pub const TAPS: [f32; 5] = [1.0 / 16.0, 0.25, 0.375, 0.25, 1.0 / 16.0];

/// Output rows per parallel task; each task copies its rows plus a halo into planes.
const BAND_ROWS: usize = 32;

/// The 5×5 taps of a pass, in raster order; tap t mirrors tap ALL_TAPS − 1 − t.
const ALL_TAPS: usize = TAPS.len() * TAPS.len();
const CENTER: usize = ALL_TAPS / 2;
/// Taps after the centre, whose weights are kept for the mirrored ones.
const FORWARD: usize = CENTER;

/// One filter pass with taps `step` pixels apart and scale `sigma` of the difference.
///
/// `mask` (true = avoid) pixels give no weight to any pixel, themselves included; a pixel whose
/// taps all have weight 0 keeps its input value.
pub fn pass(
    color: &Image,
    features: &Bands,
    mask: Option<&[bool]>,
    step: usize,
    sigma: f32,
) -> Image {
    pass_with(Kernel::detect(), color, features, mask, step, sigma)
}

/// [`pass`] with a chosen row kernel (all give the same bits; an unavailable one falls back to
/// the portable one).
pub fn pass_with(
    kernel: Kernel,
    color: &Image,
    features: &Bands,
    mask: Option<&[bool]>,
    step: usize,
    sigma: f32,
) -> Image {
    pass_in(
        kernel,
        color,
        features,
        mask,
        (step, sigma),
        &Meter::default(),
    )
}

/// [`pass`] that skips its remaining bands of rows once `meter` is cancelled (the image is then
/// unfinished, for the caller to throw away), telling the rows done.
pub fn pass_metered(
    color: &Image,
    features: &Bands,
    mask: Option<&[bool]>,
    (step, sigma): (usize, f32),
    meter: &Meter,
) -> Image {
    pass_in(
        Kernel::detect(),
        color,
        features,
        mask,
        (step, sigma),
        meter,
    )
}

fn pass_in(
    kernel: Kernel,
    color: &Image,
    features: &Bands,
    mask: Option<&[bool]>,
    (step, sigma): (usize, f32),
    meter: &Meter,
) -> Image {
    let kernel = kernel.or_portable();
    let (w, h) = color.dims();
    let mut out = Image::new(w, h, 3);
    if w == 0 || h == 0 {
        return out;
    }
    let reach = 2 * step;
    let inv = 1.0 / (2.0 * sigma * sigma);
    meter.pass(h);
    out.data_mut()
        .par_chunks_mut(3 * w * BAND_ROWS)
        .enumerate()
        .for_each(|(band, rows_out)| {
            if meter.cancelled() {
                return;
            }
            let y_begin = band * BAND_ROWS;
            let y_end = (y_begin + BAND_ROWS).min(h);
            meter.rows(y_end - y_begin);
            let rows = y_begin.saturating_sub(reach)..(y_end + reach).min(h);
            // Padded so every run is computed in whole groups of 8 (the extra results are dropped);
            // taps that leave the image are skipped, so no run reaches further than its width.
            let pad = reach.min(w) + 8;
            let (feats, depth_weight) = features(rows.clone(), pad);
            // The planes' row 0 is image row `first`; `cols` keeps image rows.
            let first = rows.start;
            // Colour (3 lanes) and the keep weight (lane 3: 0 on masked pixels, else 1).
            let cols = FeaturePlanes::build(w, rows, pad, 4, |i, lane| {
                if lane < 3 {
                    color.data()[3 * i + lane]
                } else if mask.is_some_and(|m| m[i]) {
                    0.0
                } else {
                    1.0
                }
            });
            let mut acc = Acc::new(w);
            let mut scratch = vec![0.0f32; w + 8];
            // The weights of the taps after the centre (raster order), for the last reach + 1
            // rows. d is symmetric bit for bit, so a tap before the centre, from p to p + o, is
            // the weight of the tap after it, from p + o back to p, computed |o_y| rows earlier
            // (or in this row): half the distances, the same bits.
            let slots = reach + 1;
            let mut ring = vec![0.0f32; slots * FORWARD * (w + 8)];
            let ring_at = |y: usize, t: usize| (y % slots * FORWARD + t - CENTER - 1) * (w + 8);
            for y in y_begin.saturating_sub(reach)..y_end {
                for t in CENTER + 1..ALL_TAPS {
                    let Some((ny, lo, hi, dx)) = tap_run(t, y, step, w, h) else {
                        continue;
                    };
                    let center = feats.offset(lo as isize, y - first);
                    let other = feats.offset(lo as isize + dx, ny - first);
                    let at = ring_at(y, t) + lo;
                    let e = &mut ring[at..at + (hi - lo).next_multiple_of(8)];
                    distance_row(kernel, &feats, depth_weight, center, other, e);
                    weigh(kernel, &mut e[..hi - lo], inv);
                }
                if y < y_begin {
                    continue;
                }
                acc.clear();
                for t in 0..ALL_TAPS {
                    let Some((ny, lo, hi, dx)) = tap_run(t, y, step, w, h) else {
                        continue;
                    };
                    let center = feats.offset(lo as isize, y - first);
                    let other = feats.offset(lo as isize + dx, ny - first);
                    let e: &[f32] = match t.cmp(&CENTER) {
                        std::cmp::Ordering::Less => {
                            // The mirror tap of pixel (lo + dx, ny), which lies |o_y| rows up.
                            let at = ring_at(ny, ALL_TAPS - 1 - t);
                            let from = (at as isize + lo as isize + dx) as usize;
                            &ring[from..from + hi - lo]
                        }
                        std::cmp::Ordering::Equal => {
                            let e = &mut scratch[..(hi - lo).next_multiple_of(8)];
                            distance_row(kernel, &feats, depth_weight, center, other, e);
                            weigh(kernel, &mut e[..hi - lo], inv);
                            &e[..hi - lo]
                        }
                        std::cmp::Ordering::Greater => {
                            let at = ring_at(y, t);
                            &ring[at + lo..at + hi]
                        }
                    };
                    let tap = TAPS[t / TAPS.len()] * TAPS[t % TAPS.len()];
                    add_tap(kernel, &cols, center, other, tap, e, acc.range(lo, hi));
                }
                let row = &mut rows_out[3 * w * (y - y_begin)..3 * w * (y - y_begin + 1)];
                acc.write(&color.data()[3 * w * y..3 * w * (y + 1)], row);
            }
        });
    out
}

/// f64 sums of one output row: weighted colour and weight.
struct Acc {
    r: Vec<f64>,
    g: Vec<f64>,
    b: Vec<f64>,
    weight: Vec<f64>,
}

/// The same sums over columns lo..hi.
struct AccRange<'a> {
    r: &'a mut [f64],
    g: &'a mut [f64],
    b: &'a mut [f64],
    weight: &'a mut [f64],
}

impl Acc {
    fn new(w: usize) -> Acc {
        Acc {
            r: vec![0.0; w],
            g: vec![0.0; w],
            b: vec![0.0; w],
            weight: vec![0.0; w],
        }
    }

    fn clear(&mut self) {
        for v in [&mut self.r, &mut self.g, &mut self.b, &mut self.weight] {
            v.fill(0.0);
        }
    }

    fn range(&mut self, lo: usize, hi: usize) -> AccRange<'_> {
        AccRange {
            r: &mut self.r[lo..hi],
            g: &mut self.g[lo..hi],
            b: &mut self.b[lo..hi],
            weight: &mut self.weight[lo..hi],
        }
    }

    /// Weighted means into `out`; pixels without weight keep `input`.
    fn write(&self, input: &[f32], out: &mut [f32]) {
        for x in 0..self.weight.len() {
            let wsum = self.weight[x];
            let px = &mut out[3 * x..3 * x + 3];
            if wsum > 0.0 && wsum.is_finite() {
                px[0] = (self.r[x] / wsum) as f32;
                px[1] = (self.g[x] / wsum) as f32;
                px[2] = (self.b[x] / wsum) as f32;
            } else {
                px.copy_from_slice(&input[3 * x..3 * x + 3]);
            }
        }
    }
}

/// Tap t of the 5×5 (raster order) at row `y`: its row, the columns lo..hi whose tap lies inside
/// the image, and its column offset; None when it leaves the image.
fn tap_run(
    t: usize,
    y: usize,
    step: usize,
    w: usize,
    h: usize,
) -> Option<(usize, usize, usize, isize)> {
    let side = TAPS.len();
    let ny = y as isize + (t as isize / side as isize - 2) * step as isize;
    let dx = (t as isize % side as isize - 2) * step as isize;
    let lo = (-dx).max(0) as usize;
    let hi = (w as isize - dx).clamp(0, w as isize) as usize;
    (ny >= 0 && ny < h as isize && lo < hi).then_some((ny as usize, lo, hi, dx))
}

/// A run's differences `e` turned into exp(−d²·inv), in place.
fn weigh(kernel: Kernel, e: &mut [f32], inv: f32) {
    row_kernel!(wide kernel, scale_distances(e: &mut [f32], inv: f32));
    exp_neg_row(kernel, e);
}

/// Adds one tap's weighted colour to the sums of a run of a row: the tap's B3 weight `tap` times
/// the run's exp(−d²/(2σ²)) `e` times both pixels' keep weights.
fn add_tap(
    kernel: Kernel,
    cols: &FeaturePlanes,
    center: usize,
    other: usize,
    tap: f32,
    e: &[f32],
    acc: AccRange,
) {
    let n = e.len();
    let (red, green, blue) = (
        cols.lane(0, other, n),
        cols.lane(1, other, n),
        cols.lane(2, other, n),
    );
    let (keep, keep_center) = (cols.lane(3, other, n), cols.lane(3, center, n));
    let (colour, keep) = ([red, green, blue], [keep, keep_center]);
    row_kernel!(wide kernel, accumulate(e: &[f32], tap: f32, colour: [&[f32]; 3], keep: [&[f32]; 2], acc: AccRange))
}

/// −d²·inv in place: the exponent of a tap's weight.
#[inline(always)]
fn scale_distances(e: &mut [f32], inv: f32) {
    for v in e.iter_mut() {
        *v = -(*v * *v) * inv;
    }
}

/// Adds a tap's weighted colour to the sums: weight = `tap` · e · both pixels' keep weights.
#[inline(always)]
fn accumulate(
    e: &[f32],
    tap: f32,
    [red, green, blue]: [&[f32]; 3],
    [keep, keep_center]: [&[f32]; 2],
    acc: AccRange,
) {
    let n = e.len();
    let AccRange { r, g, b, weight } = acc;
    let (r, g, b, weight) = (&mut r[..n], &mut g[..n], &mut b[..n], &mut weight[..n]);
    for x in 0..n {
        let wgt = (tap * e[x] * keep[x] * keep_center[x]) as f64;
        r[x] += wgt * red[x] as f64;
        g[x] += wgt * green[x] as f64;
        b[x] += wgt * blue[x] as f64;
        weight[x] += wgt;
    }
}
