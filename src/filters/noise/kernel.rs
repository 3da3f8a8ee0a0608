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

use std::ops::Range;

use rayon::prelude::*;

use crate::image::{par_vec, Image};
use crate::kernels::padded::{Margin, Padded};
use crate::kernels::simd::{row_kernel, Kernel};
use crate::kernels::trim::{self, LANES, MAX_PAIRS, PAIRS};
use crate::kernels::window_bits;
use crate::render_set::{Feature, FeatureSet};

/// Radius of the window of the raw estimate (5×5): the adjacent pairs are `trim::PAIRS`.
const RAW_RADIUS: isize = trim::RADIUS;
/// Radius of the window the raw estimates are averaged over (7×7).
const SMOOTH_RADIUS: isize = 3;
/// Fewest surface-mates (the pixel included) a raw estimate needs.
const MIN_MATES: usize = 4;
/// Features compared per pixel by `same_key`.
const KEYS: usize = 8;
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

    /// The features `same_key` compares for the `w`-pixel rows `rows`, one plane each: albedo (3),
    /// normal (3), depth, normal known (1/0). A missing feature is zeros, which every pair passes,
    /// as when it is not compared.
    fn planes(&self, rows: Range<usize>, w: usize) -> [Vec<f32>; KEYS] {
        let (first, n) = (rows.start * w, rows.len() * w);
        let plane = |src: Option<&[f32]>, stride: usize, k: usize| match src {
            Some(v) => v[stride * first..stride * (first + n)]
                .chunks_exact(stride)
                .map(|px| px[k])
                .collect(),
            None => vec![0.0; n],
        };
        let (a, nrm, z) = (self.albedo, self.normal, self.depth);
        let mut planes: [Vec<f32>; KEYS] = [
            plane(a, 3, 0),
            plane(a, 3, 1),
            plane(a, 3, 2),
            plane(nrm, 3, 0),
            plane(nrm, 3, 1),
            plane(nrm, 3, 2),
            plane(z, 1, 0),
            Vec::new(),
        ];
        planes[7] = (0..n)
            .map(|i| {
                let known = planes[3][i] != 0.0 || planes[4][i] != 0.0 || planes[5][i] != 0.0;
                if known {
                    1.0
                } else {
                    0.0
                }
            })
            .collect();
        planes
    }

    /// For every pixel, which pixels of its window of `radius` (at most 3) lie on its surface:
    /// `same_key` over runs of pixels, each pair once (`window_bits`).
    fn mates(&self, w: usize, h: usize, radius: usize) -> Mates {
        let mut mates = Mates::new(w, radius);
        let kernel = Kernel::detect();
        mates.bits = window_bits::window_bits(
            w,
            h,
            radius,
            true,
            |rows| self.planes(rows, w),
            |planes, i0, j0, bit, out| row_kernel!(kernel, same_key_run(planes: &[Vec<f32>; KEYS], i0: usize, j0: usize, bit: u32, out: &mut [u64])),
        );
        mates
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

/// Sets `bit` of `out[t]` where pixels i0 + t and j0 + t lie on one surface (`same_key`), over
/// a run of pixels, so the tests run in vector lanes.
#[inline(always)]
fn same_key_run(planes: &[Vec<f32>; KEYS], i0: usize, j0: usize, bit: u32, out: &mut [u64]) {
    let n = out.len();
    let p: [&[f32]; KEYS] = std::array::from_fn(|k| &planes[k][i0..i0 + n]);
    let q: [&[f32]; KEYS] = std::array::from_fn(|k| &planes[k][j0..j0 + n]);
    for (x, b) in out.iter_mut().enumerate() {
        let mut a = [0.0f32; KEYS];
        let mut c = [0.0f32; KEYS];
        for k in 0..KEYS {
            a[k] = p[k][x];
            c[k] = q[k][x];
        }
        *b |= (same_key(&a, &c) as u64) << bit;
    }
}

/// Whether two pixels lie on one surface (their `Surface::planes`): albedo within
/// `ALBEDO_TOLERANCE` per channel, normals both unknown or both known and within `NORMAL_COS`,
/// depth within `DEPTH_TOLERANCE` of the larger. Symmetric in its arguments.
#[inline(always)]
fn same_key(p: &[f32; KEYS], q: &[f32; KEYS]) -> bool {
    // `|` and `&`, not `||` and `&&`: no branches, so runs of pixels are tested in vector lanes.
    let albedo = ((p[0] - q[0]).abs() > ALBEDO_TOLERANCE)
        | ((p[1] - q[1]).abs() > ALBEDO_TOLERANCE)
        | ((p[2] - q[2]).abs() > ALBEDO_TOLERANCE);
    let dot = p[3] * q[3] + p[4] * q[4] + p[5] * q[5];
    let known = p[7] != 0.0;
    // Two unknown normals (misses, or renderers without a normal) match.
    let normal = (known != (q[7] != 0.0)) | (known & (dot < NORMAL_COS));
    let (zi, zj) = (p[6], q[6]);
    let scale = zi.max(zj);
    let depth = (scale > 0.0) & ((zi - zj).abs() > DEPTH_TOLERANCE * scale);
    !(albedo | normal | depth)
}

/// Per pixel, a bit per cell of its (2·radius + 1)² window, in raster order: set when that pixel
/// is inside the image and on the same surface. Computed once, read by every window loop.
struct Mates {
    bits: Vec<u64>,
    side: usize,
    /// Pixel index offset of every bit's cell.
    offset: Vec<isize>,
}

impl Mates {
    fn new(w: usize, radius: usize) -> Self {
        Mates {
            bits: Vec::new(),
            side: 2 * radius + 1,
            offset: window_bits::offsets(w, radius),
        }
    }

    /// Pixel i's surface-mates, in raster order of its window.
    #[inline]
    fn of(&self, i: usize) -> impl Iterator<Item = usize> + '_ {
        let mut m = self.bits[i];
        std::iter::from_fn(move || {
            (m != 0).then(|| {
                let b = m.trailing_zeros();
                m &= m - 1;
                (i as isize + self.offset[b as usize]) as usize
            })
        })
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
    estimate_with(Kernel::detect(), color, features)
}

/// [`estimate`] with a chosen kernel for the raw estimates (all give the same bits).
pub fn estimate_with(kernel: Kernel, color: &Image, features: &FeatureSet) -> Image {
    let (w, h) = color.dims();
    let surface = Surface::new(features, (w, h));
    // Brought to albedo 1: bringing a neighbour to a pixel's albedo is then one factor per
    // pixel, applied in `smooth`.
    let c = color.data();
    let flat = Padded::new((w, h), 3, trim::RADIUS as usize, Margin::Zeros, |i, k| {
        c[3 * i + k] as f64 / surface.scale(i)[k]
    });
    let mates = surface.mates(w, h, SMOOTH_RADIUS as usize);
    // Each raw estimate as its demodulated variance and its degrees of freedom (at most
    // `MAX_PAIRS`), kept apart: a byte for the count instead of a padded word.
    let mut sums = par_vec([0.0f64; 3], w * h);
    let mut dof = par_vec(0u8, w * h);
    // Raw estimates on every other row: adjacent rows' 5×5 windows share 4 of their 5 rows, and
    // the 7×7 smoothing still reads every pair of the 9×9 around a pixel, so half the work reads
    // nearly the same noise.
    sums.par_chunks_mut(w.max(1))
        .zip(dof.par_chunks_mut(w.max(1)))
        .enumerate()
        .filter(|(y, _)| y % 2 == 0)
        .for_each_init(Vec::new, |row, (y, (sums, dof))| {
            row.resize(sums.len(), ([0.0; 3], 0));
            let (flat, mates, out) = (&flat, &mates, row.as_mut_slice());
            row_kernel!(kernel, raw_row(flat: &Padded, mates: &Mates, y: usize, out: &mut [([f64; 3], usize)]));
            for ((s, d), &(v, n)) in sums.iter_mut().zip(dof.iter_mut()).zip(row.iter()) {
                (*s, *d) = (v, degrees(n));
            }
        });
    // A pixel of an odd row with no raw estimate among its surface-mates (a line one pixel high)
    // takes its own.
    let alone: Vec<usize> = (1..h)
        .into_par_iter()
        .step_by(2)
        .flat_map_iter(|y| (y * w..(y + 1) * w).filter(|&i| mates.of(i).all(|j| dof[j] == 0)))
        .collect();
    let window = raw_window(&mates);
    let own: Vec<([f64; 3], usize)> = alone
        .par_iter()
        .map(|&i| pair_spread::<1>(&flat, &mates, window, i % w, i / w, w)[0])
        .collect();
    for (&i, (v, n)) in alone.iter().zip(own) {
        (sums[i], dof[i]) = (v, degrees(n));
    }
    // The padded colour is not read again: its memory is free before the smoothed image's.
    drop(flat);
    smooth(color, &surface, &mates, |j| (sums[j], dof[j] as usize))
}

/// A raw estimate's degrees of freedom as stored: its pairs, at most `MAX_PAIRS`.
fn degrees(n: usize) -> u8 {
    const _: () = assert!(MAX_PAIRS <= u8::MAX as usize, "a window's pairs fit a byte");
    u8::try_from(n).expect("at most MAX_PAIRS pairs")
}

/// The raw window's cells among the mates' bits.
fn raw_window(mates: &Mates) -> u64 {
    let (side, c) = (mates.side as isize, (mates.side / 2) as isize);
    (-RAW_RADIUS..=RAW_RADIUS)
        .flat_map(|dy| (-RAW_RADIUS..=RAW_RADIUS).map(move |dx| (dx, dy)))
        .fold(0, |m, (dx, dy)| m | 1 << ((dy + c) * side + dx + c))
}

/// The raw estimates of row `y`, `LANES` pixels at a time.
#[inline(always)]
fn raw_row(flat: &Padded, mates: &Mates, y: usize, out: &mut [([f64; 3], usize)]) {
    let w = out.len();
    let window = raw_window(mates);
    trim::by_lanes!(
        out,
        |x| pair_spread::<LANES>(flat, mates, window, x, y, w),
        |x| pair_spread::<1>(flat, mates, window, x, y, w)[0],
    );
}

/// The adjacent pairs of one direction in the raw window, and the most of them trimmed.
const DIRECTION_PAIRS: usize = MAX_PAIRS / 2;
const DIRECTION_TRIMMED: usize = (DIRECTION_PAIRS as f64 * TRIM) as usize;
/// The share of the largest squared differences left out: pairs across an edge the features do
/// not show (a light's rim, a shadow's) and fireflies, which are not the noise a filter should
/// follow.
const TRIM: f64 = 0.2;
/// E[χ²₁ | below its 80th percentile], the large-n limit of [`trimmed_chi2`]: the estimate's unit.
/// Its adjacent pairs share pixels, so the iid finite-n value is not exact for them either, and the
/// noise laws were measured on this one: the finite-n value (4 % lower variance at 40 pairs) cost
/// `cycles-studio` 0.006 SSIM at 1 spp (README "Noise-aware strengths").
const TRIMMED_CHI2_MEAN: f64 = 0.437_724_594_903_639;
/// How much more one direction's pairs must read than the other's for only the lower to count.
/// On white noise the two trimmed means of a full window differ by more than 3× at 2.5 % of the
/// pixels, which then read 1 % low on average; across a light's rim they differ by 10× and more.
const DIRECTIONAL_RATIO: f64 = 3.0;
/// Fewest pairs kept in each direction for that test.
const MIN_DIRECTION_PAIRS: usize = 6;
/// Most values the blend's trimmed mean takes (its 5×5 window).
const MAX_TRIMMED: usize = BLEND_TAPS;

/// E[mean of the `n − ⌊n·TRIM⌋` smallest of n iid χ²₁], for n = 0..=MAX_TRIMMED: the blend's
/// trimmed mean of n values (f − c)² is this times v + b². Exact for every n, unlike the large-n
/// limit [`TRIMMED_CHI2_MEAN`]: with fewer than 5 values nothing is trimmed and the mean is
/// unbiased as it is (1, not 0.44).
fn trimmed_chi2(n: usize) -> f64 {
    static TABLE: std::sync::OnceLock<[f64; MAX_TRIMMED + 1]> = std::sync::OnceLock::new();
    TABLE
        .get_or_init(|| std::array::from_fn(|n| trimmed_chi2_of(n, n - (n as f64 * TRIM) as usize)))
        [n.min(MAX_TRIMMED)]
}

/// E[mean of the `kept` smallest of n iid χ²₁] by its order-statistics integral: with X = Z²,
/// E[Σ of the kept smallest] = n ∫ z² · 2φ(z) · P(Binomial(n − 1, P(|Z| < z)) < kept) dz, by
/// Simpson's rule on [0, 12] (the integrand is below 1e-29 beyond).
fn trimmed_chi2_of(n: usize, kept: usize) -> f64 {
    if n == 0 || kept == 0 {
        return 1.0;
    }
    // ln of the pmf's ratio from term j to j + 1, apart from p: the same for every z.
    let ratio: Vec<f64> = (0..kept.min(n))
        .map(|j| ((n - 1 - j) as f64 / (j + 1) as f64).ln())
        .collect();
    let mut sum = 0.0;
    for node in simpson_nodes() {
        // P(Binomial(n − 1, p) ≤ kept − 1), its terms by the pmf's recurrence in the log domain
        // (the first term, (1 − p)^(n−1), underflows for large n).
        let cdf = if node.p >= 1.0 {
            if kept >= n {
                1.0
            } else {
                0.0
            }
        } else {
            let mut log_term = (n - 1) as f64 * node.lq;
            let mut cdf = 0.0;
            for r in &ratio {
                cdf += log_term.exp();
                log_term += r + node.lp - node.lq;
            }
            cdf
        };
        sum += node.weight * cdf.min(1.0);
    }
    n as f64 * sum * SIMPSON_H / 3.0 / kept as f64
}

/// Simpson steps of [`trimmed_chi2_of`]'s integral over [0, 12].
const SIMPSON_STEPS: usize = 4096;
const SIMPSON_H: f64 = 12.0 / SIMPSON_STEPS as f64;

/// One node of that integral: what depends on z alone, computed once for every n.
struct SimpsonNode {
    /// Simpson weight · z² · 2φ(z).
    weight: f64,
    /// P(|Z| < z), and its ln and ln(1 − p).
    p: f64,
    lp: f64,
    lq: f64,
}

fn simpson_nodes() -> &'static [SimpsonNode] {
    static NODES: std::sync::OnceLock<Vec<SimpsonNode>> = std::sync::OnceLock::new();
    NODES.get_or_init(|| {
        (0..=SIMPSON_STEPS)
            .map(|s| {
                let z = s as f64 * SIMPSON_H;
                let p = erf(z / std::f64::consts::SQRT_2);
                let density = 2.0 * (-0.5 * z * z).exp() / (2.0 * std::f64::consts::PI).sqrt();
                let weight = if s == 0 || s == SIMPSON_STEPS {
                    1.0
                } else if s % 2 == 1 {
                    4.0
                } else {
                    2.0
                };
                SimpsonNode {
                    weight: weight * z * z * density,
                    p,
                    lp: p.ln(),
                    lq: (-p).ln_1p(),
                }
            })
            .collect()
    })
}

/// Raw estimates at pixels (x..x + L, y): per lane, trimmed means of the squared differences of
/// adjacent surface-mates in its window (brought to albedo 1), which a smooth change of light
/// barely enters, over its horizontal and over its vertical pairs; with its number of pairs kept
/// (0: too few mates in `window`, its cells' bits). Where one direction reads more than
/// [`DIRECTIONAL_RATIO`] times the other, only the lower counts: an edge the features do not show
/// (a light's rim, a shadow's) raises the pairs across it, not those along it. Elsewhere both
/// count, each by its pairs kept.
#[inline(always)]
fn pair_spread<const L: usize>(
    flat: &Padded,
    mates: &Mates,
    window: u64,
    x: usize,
    y: usize,
    w: usize,
) -> [([f64; 3], usize); L] {
    let mut bits = [0u64; L];
    bits.copy_from_slice(&mates.bits[y * w + x..y * w + x + L]);
    let (side, c) = (mates.side as isize, (mates.side / 2) as isize);
    let bit = |(dx, dy): (isize, isize)| ((dy + c) * side + dx + c) as u32;
    // Per direction (0 horizontal, 1 vertical), its pairs in `PAIRS` order; a pair that is not
    // of surface-mates reads NaN, which the trimmed means leave out.
    let mut d2 = [[[[0.0f64; L]; DIRECTION_PAIRS]; 2]; 3];
    let mut n = [[0usize; L]; 2];
    let mut next = [0usize; 2];
    for &[a, b] in PAIRS.iter() {
        let dir = usize::from(a.1 != b.1);
        let p = next[dir];
        next[dir] += 1;
        let mut mask = [0.0f64; L];
        for l in 0..L {
            let valid = bits[l] >> bit(a) & bits[l] >> bit(b) & 1 == 1;
            n[dir][l] += usize::from(valid);
            mask[l] = trim::valid_or_nan(valid);
        }
        let (ia, ib) = (flat.at(x, y, a), flat.at(x, y, b));
        for (k, plane) in flat.planes.iter().enumerate() {
            let (pa, pb) = (&plane[ia..ia + L], &plane[ib..ib + L]);
            for l in 0..L {
                let d = pa[l] - pb[l];
                d2[k][dir][p][l] = d * d + mask[l];
            }
        }
    }
    let mut dropped = [[0usize; L]; 2];
    let mut kept = [[0usize; L]; 2];
    for dir in 0..2 {
        for l in 0..L {
            dropped[dir][l] = (n[dir][l] as f64 * TRIM) as usize;
            kept[dir][l] = n[dir][l] - dropped[dir][l];
        }
    }
    let mut out = [([0.0; 3], 0); L];
    for (k, d2) in d2.iter().enumerate() {
        // Two calls, not a closure over the directions: a closure is not inlined into the AVX2
        // copy of the row function.
        let h = trim::lanes::<L, DIRECTION_PAIRS, DIRECTION_TRIMMED>(&d2[0], dropped[0]);
        let v = trim::lanes::<L, DIRECTION_PAIRS, DIRECTION_TRIMMED>(&d2[1], dropped[1]);
        for l in 0..L {
            let (lo, hi) = (h[l].min(v[l]), h[l].max(v[l]));
            let both = kept[0][l] >= MIN_DIRECTION_PAIRS && kept[1][l] >= MIN_DIRECTION_PAIRS;
            let (kh, kv) = (kept[0][l] as f64, kept[1][l] as f64);
            let mean = if both && hi > DIRECTIONAL_RATIO * lo {
                lo
            } else {
                (h[l] * kh + v[l] * kv) / (kh + kv).max(1.0)
            };
            out[l].0[k] = mean / (2.0 * TRIMMED_CHI2_MEAN);
        }
    }
    for (l, (var, pairs)) in out.iter_mut().enumerate() {
        let total = n[0][l] + n[1][l];
        if (bits[l] & window).count_ones() as usize >= MIN_MATES && total >= 2 {
            *pairs = kept[0][l] + kept[1][l];
        } else {
            *var = [0.0; 3];
        }
    }
    out
}

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
fn erf(z: f64) -> f64 {
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
    )
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
fn smooth(
    color: &Image,
    surface: &Surface,
    mates: &Mates,
    raw: impl Fn(usize) -> ([f64; 3], usize) + Sync,
) -> Image {
    let (w, h) = color.dims();
    let c = color.data();
    let mut out = Image::new(w, h, 3);
    out.data_mut()
        .par_chunks_mut(3)
        .enumerate()
        .for_each(|(i, px)| {
            let mut acc = [0.0f64; 3];
            let mut dof = 0usize;
            for j in mates.of(i) {
                let (v, d) = raw(j);
                if d == 0 {
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
                let (x, y) = (i % w, i / w);
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
    let var = v.iter().map(|&x| clean(x)).sum::<f64>() / 3.0;
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

/// Radius of the window the blend's error estimate averages over (5×5).
const BLEND_RADIUS: isize = trim::RADIUS;
const BLEND_SIDE: usize = 2 * BLEND_RADIUS as usize + 1;
const BLEND_TAPS: usize = BLEND_SIDE * BLEND_SIDE;

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
    let (w, h) = color.dims();
    let surface = Surface::new(features, (w, h));
    let (c, f, v) = (color.data(), filtered.data(), variance.data());
    let mates = surface.mates(w, h, BLEND_RADIUS as usize);
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
    keep.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each_init(Vec::new, |row, (y, keep)| {
            row.resize(keep.len(), (0.0, 0));
            let (diff2, mates, out) = (&diff2, &mates, row.as_mut_slice());
            row_kernel!(kernel, blend_error_row(diff2: &Padded, mates: &Mates, y: usize, out: &mut [(f64, usize)]));
            for (x, (keep, &(err, n))) in keep.iter_mut().zip(row.iter()).enumerate() {
                let i = y * w + x;
                *keep = keep_weight(&c[3 * i..3 * i + 3], &f[3 * i..3 * i + 3], &v[3 * i..3 * i + 3], err, n, tolerance, leak);
            }
        });
    keep
}

/// One pixel's weight of [`keep_weights`]: its colour `c`, filtered value `f`, noise variance
/// `v`, and the trimmed mean `err` of (f − c)² over its `n` surface-mates.
fn keep_weight(
    c: &[f32],
    f: &[f32],
    v: &[f32],
    err: f64,
    n: usize,
    tolerance: f64,
    leak: f64,
) -> f32 {
    let var = v.iter().map(|&x| clean(x)).sum::<f64>() / 3.0;
    if var <= 0.0 || n == 0 {
        return 0.0;
    }
    // Divided by the constant of its own n: with few mates, as at a geometric edge, little is
    // trimmed.
    let err = err / trimmed_chi2(n);
    let keep = (tolerance * var / err.max(f64::MIN_POSITIVE)).min(1.0);
    // A pixel the filter made far brighter than its own noise allows took light from a neighbour
    // the features could not tell apart (an emitter beside the ceiling it lies in): trimmed away
    // above, so checked alone. Darker is left alone: that is a firefly removed.
    let gain = (0..3)
        .map(|k| (f[k] as f64 - c[k] as f64).max(0.0).powi(2))
        .sum::<f64>()
        / 3.0;
    let leak = leak * var / gain.max(f64::MIN_POSITIVE);
    keep.min(leak).min(1.0) as f32
}

/// Most of the blend's values trimmed: `TRIM` of its window.
const BLEND_TRIMMED: usize = (BLEND_TAPS as f64 * TRIM) as usize;

/// The blend's error estimates along row `y`: per pixel, the trimmed mean of `diff2` over its
/// surface-mates (trimmed as the estimate is, so edges the features miss and fireflies stay out)
/// and how many finite values it had.
#[inline(always)]
fn blend_error_row(diff2: &Padded, mates: &Mates, y: usize, out: &mut [(f64, usize)]) {
    let w = out.len();
    trim::by_lanes!(out, |x| blend_errors::<LANES>(diff2, mates, x, y, w), |x| {
        blend_errors::<1>(diff2, mates, x, y, w)[0]
    },);
}

/// [`blend_error_row`] at pixels (x..x + L, y).
#[inline(always)]
fn blend_errors<const L: usize>(
    diff2: &Padded,
    mates: &Mates,
    x: usize,
    y: usize,
    w: usize,
) -> [(f64, usize); L] {
    let r = BLEND_RADIUS;
    debug_assert_eq!(
        mates.side, BLEND_SIDE,
        "the blend's mates are of its own window"
    );
    let mut bits = [0u64; L];
    bits.copy_from_slice(&mates.bits[y * w + x..y * w + x + L]);
    let plane = &diff2.planes[0];
    // A cell that is not a surface-mate reads NaN, which the trimmed mean leaves out.
    let mut values = [[0.0f64; L]; BLEND_TAPS];
    let mut n = [0usize; L];
    for (cell, value) in values.iter_mut().enumerate() {
        // A constant side: the cell's offset costs no division.
        let (dx, dy) = (
            (cell % BLEND_SIDE) as isize - r,
            (cell / BLEND_SIDE) as isize - r,
        );
        let at = diff2.at(x, y, (dx, dy));
        for l in 0..L {
            let v = plane[at + l] + trim::valid_or_nan(bits[l] >> cell & 1 == 1);
            n[l] += usize::from(v <= f64::MAX);
            value[l] = v;
        }
    }
    let mut dropped = [0usize; L];
    for l in 0..L {
        dropped[l] = (n[l] as f64 * TRIM) as usize;
    }
    let mean = trim::lanes::<L, BLEND_TAPS, BLEND_TRIMMED>(&values, dropped);
    let mut out = [(0.0, 0); L];
    for l in 0..L {
        out[l] = (mean[l], n[l]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::trim::tests::xorshift;

    #[test]
    fn trimmed_chi2_means_match_the_tabulated_ones() {
        assert!((trimmed_chi2_mean(0.5) - 0.142_651_835_488_518_54).abs() < 1e-9);
        assert!((trimmed_chi2_mean(0.8) - 0.437_724_594_903_639).abs() < 1e-9);
        assert!((trimmed_chi2_mean(1.0 - 1e-12) - 1.0).abs() < 1e-6);
        // The estimate's constant is the same quantity at its own trim.
        assert!((trimmed_chi2_mean(1.0 - TRIM) - TRIMMED_CHI2_MEAN).abs() < 1e-12);
    }

    #[test]
    fn a_line_one_pixel_high_reads_its_own_noise_on_any_row() {
        // A noise-free wall of albedo 0.5 crossed by a line one pixel high of albedo 0.9 and
        // noise σ 0.05. Raw estimates are taken on even rows; a line on an odd row has no
        // surface-mate there and must take its own, not the 3×3 spread across the wall.
        let (w, h) = (40, 9);
        let mut next = crate::kernels::trim::tests::xorshift(7);
        for line in [3, 4] {
            let mut set = FeatureSet::default();
            let albedo = Image::from_fn(w, h, 3, |_, y, _| if y == line { 0.9 } else { 0.5 });
            set.set(Feature::Albedo, albedo).unwrap();
            let color = Image::from_fn(w, h, 3, |_, y, _| {
                // A sum of uniforms: near-normal, variance 0.05².
                let u: f32 = (0..12)
                    .map(|_| (next() >> 40) as f32 / (1u64 << 24) as f32)
                    .sum();
                if y == line {
                    0.9 + 0.05 * (u - 6.0)
                } else {
                    0.5
                }
            });
            let est = estimate(&color, &set);
            let mut ratios: Vec<f32> = (2..w - 2)
                .map(|x| est.pixel(line * w + x)[0] / 0.05f32.powi(2))
                .collect();
            ratios.sort_by(f32::total_cmp);
            let median = ratios[ratios.len() / 2];
            assert!(
                (0.5..2.0).contains(&median),
                "line on row {line}: estimate / truth {median}"
            );
        }
    }

    /// A 9×9 flat image of colour 1 and noise variance 0.01 (σ 0.1), with a 2×2 patch of its own
    /// albedo at (4..6, 4..6): the patch's pixels have 4 surface-mates each, the rest many.
    fn blend_case() -> (Image, Image, FeatureSet) {
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
    fn blend_case_keep(filtered: &Image, leak: f64) -> Vec<f32> {
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
    fn a_rise_beyond_two_sigma_is_taken_back() {
        let (color, _, _) = blend_case();
        let leak = crate::filters::blend::BlendParams::default().leak;
        // One pixel 3σ brighter than its input, one 3σ darker (a firefly removed).
        let mut filtered = color.clone();
        let (up, down) = (2 * 9 + 2, 6 * 9 + 7);
        filtered.pixel_mut(up).fill(1.3);
        filtered.pixel_mut(down).fill(0.7);
        let keep = blend_case_keep(&filtered, leak);
        // κ = λ·v / gain²: a rise of exactly 2σ would be kept whole, a larger one shrinks as 1/gain.
        let rise = keep[up] * 0.3;
        assert!(rise <= 0.2, "kept a rise of {rise}, above 2σ = 0.2");
        assert!(
            (keep[up] - 4.0 * 0.01 / 0.09).abs() < 1e-4,
            "keep {}",
            keep[up]
        );
        assert_eq!(keep[down], 1.0, "a darker pixel is a firefly removed");
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
    fn finite_trimmed_chi2_means_are_exact() {
        // Nothing trimmed: the plain mean of χ²₁, whatever n.
        for n in 1..5 {
            assert!(
                (trimmed_chi2(n) - 1.0).abs() < 1e-9,
                "n = {n}: {}",
                trimmed_chi2(n)
            );
        }
        // n = 2, the smaller of two: E[min(Z₁², Z₂²)] = 1 − 2/π.
        assert!((trimmed_chi2_of(2, 1) - (1.0 - 2.0 / std::f64::consts::PI)).abs() < 1e-9);
        // Large n tends to the quantile formula.
        let big = trimmed_chi2_of(2000, 1600);
        assert!((big - trimmed_chi2_mean(0.8)).abs() < 2e-3, "{big}");
        // Against simulation: 4 smallest of 5, and the 25-tap blend window (20 kept).
        let mut next = xorshift(2);
        let mut normal = move || {
            let mut u = || ((next() >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
            let (a, b) = (u(), u());
            (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
        };
        for n in [5usize, 25] {
            let kept = n - (n as f64 * TRIM) as usize;
            let trials = 200_000 / n * 5;
            let mut total = 0.0;
            for _ in 0..trials {
                let mut x: Vec<f64> = (0..n).map(|_| normal().powi(2)).collect();
                x.sort_by(f64::total_cmp);
                total += x[..kept].iter().sum::<f64>() / kept as f64;
            }
            let simulated = total / trials as f64;
            assert!(
                (simulated - trimmed_chi2(n)).abs() < 0.01,
                "n = {n}: simulated {simulated}, exact {}",
                trimmed_chi2(n)
            );
        }
    }

    fn noisy_flat(w: usize, h: usize, level: f32, std: f32, seed: u64) -> Image {
        let mut next = xorshift(seed);
        let mut uniform = move || (next() >> 40) as f32 / (1u64 << 24) as f32;
        Image::from_fn(w, h, 3, |_, _, _| {
            // Sum of 12 uniforms: near Gaussian, variance std².
            let u: f32 = (0..12).map(|_| uniform()).sum::<f32>() - 6.0;
            level + std * u
        })
    }

    #[test]
    fn mates_are_the_pairwise_test_in_window_order() {
        // Taller than `window_bits`' bands of rows, so windows cross from one band to the next.
        let (w, h) = (13, 37);
        let mut set = FeatureSet::default();
        let albedo = Image::from_fn(
            w,
            h,
            3,
            |x, y, k| {
                if (x + 2 * y + k) % 5 < 2 {
                    0.8
                } else {
                    0.3
                }
            },
        );
        // Some unknown normals, and some too short to match themselves.
        let normal = Image::from_fn(w, h, 3, |x, y, k| match ((x * y) % 7, k) {
            (0, _) => 0.0,
            (3, 2) => 0.5,
            (_, 2) => 1.0,
            _ => 0.0,
        });
        let depth = Image::from_fn(w, h, 1, |x, _, _| 1.0 + (x / 4) as f32 * 0.2);
        set.set(Feature::Albedo, albedo).unwrap();
        set.set(Feature::Normal, normal).unwrap();
        set.set(Feature::Depth, depth).unwrap();
        let surface = Surface::new(&set, (w, h));
        let planes = surface.planes(0..h, w);
        let key = |i: usize| std::array::from_fn(|k| planes[k][i]);
        for radius in [1, 2, 3] {
            let mates = surface.mates(w, h, radius);
            for i in 0..w * h {
                let expected: Vec<usize> = window(i % w, i / w, w, h, radius as isize)
                    .filter(|&j| same_key(&key(i), &key(j)))
                    .collect();
                assert_eq!(
                    mates.of(i).collect::<Vec<_>>(),
                    expected,
                    "pixel {i}, radius {radius}"
                );
            }
        }
    }

    #[test]
    fn flat_noise_is_measured() {
        let img = noisy_flat(64, 64, 1.0, 0.1, 3);
        let v = estimate(&img, &FeatureSet::default());
        let mean = v.data().iter().map(|&x| x as f64).sum::<f64>() / v.data().len() as f64;
        assert!((mean.sqrt() - 0.1).abs() < 0.01, "std {}", mean.sqrt());
    }

    /// A bright line one pixel wide that no feature shows (a light's rim seen edge-on): its two
    /// boundaries put half of the vertical pairs of every window near it across an edge, more than
    /// the trim takes out, so a trimmed mean of all pairs reads the step as noise. The horizontal
    /// pairs run along it and read the noise.
    #[test]
    fn a_line_the_features_miss_is_not_noise() {
        let (w, h, std) = (32, 32, 0.1);
        let noise = noisy_flat(w, h, 0.0, std, 6);
        let img = Image::from_fn(w, h, 3, |x, y, k| {
            let line = if y == 16 { 3.0 } else { 1.0 };
            line + noise.at(x, y)[k]
        });
        let v = estimate(&img, &FeatureSet::default());
        for y in 13..=19 {
            for x in 4..w - 4 {
                let sd = (v.at(x, y)[0] as f64).sqrt();
                assert!(
                    sd < 1.5 * std as f64,
                    "({x}, {y}): σ {sd:.3} read for noise of σ {std}"
                );
            }
        }
        // A flat field still reads its noise in full.
        let flat = estimate(&noisy_flat(w, h, 1.0, std, 6), &FeatureSet::default());
        let mean = flat.data().iter().map(|&x| x as f64).sum::<f64>() / flat.data().len() as f64;
        assert!(
            (mean.sqrt() - std as f64).abs() < 0.01,
            "std {}",
            mean.sqrt()
        );
    }

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
