//! The noise estimate from the image alone: per pixel, trimmed means of the squared differences of
//! adjacent surface-mates in its window, one direction's where an edge the features miss raises
//! the other's, then smoothed over the surface.

use rayon::prelude::*;

use super::chi2::{TRIM, TRIMMED_CHI2_MEAN};
use super::smooth::{plain_spread, smooth, SMOOTH_RADIUS};
use super::surface::{Mates, Surface};
use crate::image::{par_vec, Image};
use crate::kernels::padded::{Margin, Padded};
use crate::kernels::simd::{row_kernel, Kernel};
use crate::kernels::trim::{self, LANES, MAX_PAIRS, PAIRS};
use crate::meter::Meter;
use crate::render_set::FeatureSet;

/// Radius of the window of the raw estimate (5×5): the adjacent pairs are `trim::PAIRS`.
const RAW_RADIUS: isize = trim::RADIUS;
/// Fewest surface-mates (the pixel included) a raw estimate needs.
pub(crate) const MIN_MATES: usize = 4;

/// Estimates the variance of every pixel's colour mean (RGB) from the colour and the features.
///
/// Why from the image: most users have colour, albedo, normal and depth only. Pixels of one
/// surface (same albedo, normal and depth) see nearly the same radiance, so their spread around
/// the local mean is noise; bringing each neighbour to the pixel's own albedo first keeps texture
/// out of it. Raw estimates from one 5×5 window are themselves noisy, so they are averaged over a
/// 7×7 window of the same surface, weighted by their degrees of freedom. A pixel that finds no
/// surface-mates reads the adjacent pairs of its whole 5×5 window; one whose samples hit nothing
/// (no normal) and whose renderer wrote nothing it saw (`FeatureSet::seen`), or without pairs (a 1×1
/// image), takes the plain 3×3 spread, or 0 when it has none.
pub fn estimate(color: &Image, features: &FeatureSet) -> Image {
    estimate_with(Kernel::detect(), color, features)
}

/// [`estimate`] with a chosen kernel for the raw estimates (all give the same bits).
pub fn estimate_with(kernel: Kernel, color: &Image, features: &FeatureSet) -> Image {
    estimate_in(kernel, color, features, &Meter::default())
}

/// [`estimate`] in a run: its rows tell `meter` as they finish and are skipped once it is
/// cancelled (the result is then unfinished, for the caller to throw away).
pub fn estimate_metered(color: &Image, features: &FeatureSet, meter: &Meter) -> Image {
    estimate_in(Kernel::detect(), color, features, meter)
}

fn estimate_in(kernel: Kernel, color: &Image, features: &FeatureSet, meter: &Meter) -> Image {
    let (w, h) = color.dims();
    let surface = Surface::new(features, (w, h));
    // Brought to albedo 1: bringing a neighbour to a pixel's albedo is then one factor per
    // pixel, applied in `smooth`.
    let c = color.data();
    let flat = Padded::new((w, h), 3, trim::RADIUS as usize, Margin::Zeros, |i, k| {
        c[3 * i + k] as f64 / surface.scale(i)[k]
    });
    let mates = surface.mates_metered(w, h, SMOOTH_RADIUS as usize, meter);
    if meter.cancelled() {
        return Image::new(w, h, 3);
    }
    // Each raw estimate as its demodulated variance and its degrees of freedom (at most
    // `MAX_PAIRS`), kept apart: a byte for the count instead of a padded word.
    let mut sums = par_vec([0.0f64; 3], w * h);
    let mut dof = par_vec(0u8, w * h);
    meter.pass(h);
    // Raw estimates on every other row: adjacent rows' 5×5 windows share 4 of their 5 rows, and
    // the 7×7 smoothing still reads every pair of the 9×9 around a pixel, so half the work reads
    // nearly the same noise.
    sums.par_chunks_mut(w.max(1))
        .zip(dof.par_chunks_mut(w.max(1)))
        .enumerate()
        .filter(|(y, _)| y % 2 == 0)
        .for_each_init(Vec::new, |row, (y, (sums, dof))| {
            if meter.cancelled() {
                return;
            }
            meter.rows(2);
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
        .flat_map_iter(|y| {
            // A cancelled run's rows are skipped: none is alone, nothing more is computed.
            let rows = if meter.cancelled() {
                0..0
            } else {
                y * w..(y + 1) * w
            };
            rows.filter(|&i| mates.of(i).all(|j| dof[j] == 0))
        })
        .collect();
    let window = raw_window(&mates);
    let own: Vec<([f64; 3], usize)> = alone
        .par_iter()
        .map(|&i| pair_spread::<1>(&flat, &mates, window, i % w, i / w, w)[0])
        .collect();
    for (&i, (v, n)) in alone.iter().zip(own) {
        (sums[i], dof[i]) = (v, degrees(n));
    }
    if meter.cancelled() {
        return Image::new(w, h, 3);
    }
    // A pixel with no surface-mate (a chrome pixel showing the scene, a lone texel) reads the
    // adjacent pairs of its whole 5×5 window, demodulated, one direction's where the other's
    // cross an edge: structure the features do not show enters less than in the colours' spread.
    // Untrimmed: with no surface to pool over, its tails are its noise too.
    let side = mates.side;
    let lone = |i: usize| {
        let (x, y) = (i % w, i / w);
        let c = (side / 2) as isize;
        let mut bits = 0u64;
        for dy in -c..=c {
            for dx in -c..=c {
                let (px, py) = (x as isize + dx, y as isize + dy);
                if (0..w as isize).contains(&px) && (0..h as isize).contains(&py) {
                    bits |= 1 << ((dy + c) * side as isize + dx + c);
                }
            }
        }
        let [(v, n)] = pair_spread_of::<1, false>(&flat, side, [bits], window, x, y);
        // A pixel whose samples hit nothing (beside a floor's edge at one sample) has no albedo
        // to bring the demodulated variance to: its colour is what few samples hit. Unless the
        // renderer wrote what it saw (a light in a mirror, with every sample of the pixel missing
        // the surfaces): demodulated by that, its pairs read the noise, not the light's shape.
        if n == 0 || !(surface.hit(i) || surface.seen(i)) {
            return plain_spread(color, i);
        }
        let s = surface.scale(i);
        std::array::from_fn(|k| v[k] * s[k] * s[k])
    };
    // Read here, for the pixels `smooth` will find with no raw estimate among their mates, so the
    // padded colour's memory is free before the smoothed image's.
    let lone: Vec<(usize, [f64; 3])> = (0..w * h)
        .into_par_iter()
        .filter(|&i| !meter.cancelled() && mates.of(i).all(|j| dof[j] == 0))
        .map(|i| (i, lone(i)))
        .collect();
    drop(flat);
    if meter.cancelled() {
        return Image::new(w, h, 3);
    }
    smooth(
        color,
        &surface,
        &mates,
        |j| (sums[j], dof[j] as usize),
        |i| match lone.binary_search_by_key(&i, |&(j, _)| j) {
            Ok(at) => lone[at].1,
            Err(_) => plain_spread(color, i),
        },
        meter,
    )
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
/// How much more one direction's pairs must read than the other's for only the lower to count.
/// On white noise the two trimmed means of a full window differ by more than 3× at 2.5 % of the
/// pixels, which then read 1 % low on average; across a light's rim they differ by 10× and more.
const DIRECTIONAL_RATIO: f64 = 3.0;
/// Fewest pairs kept in each direction for that test.
const MIN_DIRECTION_PAIRS: usize = 6;

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
    pair_spread_of::<L, true>(flat, mates.side, bits, window, x, y)
}

/// [`pair_spread`] with the mates given as bits of a window of `side`; `TRIMMED` false: each
/// direction's untrimmed mean (a pixel without surface-mates), the direction still chosen by the
/// trimmed ones.
#[inline(always)]
fn pair_spread_of<const L: usize, const TRIMMED: bool>(
    flat: &Padded,
    side: usize,
    bits: [u64; L],
    window: u64,
    x: usize,
    y: usize,
) -> [([f64; 3], usize); L] {
    let (side, c) = (side as isize, (side / 2) as isize);
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
        // Untrimmed, each direction's mean of all its pairs: the variance with its tails.
        let all = (!TRIMMED).then(|| {
            let none = [0usize; L];
            (
                trim::lanes::<L, DIRECTION_PAIRS, DIRECTION_TRIMMED>(&d2[0], none),
                trim::lanes::<L, DIRECTION_PAIRS, DIRECTION_TRIMMED>(&d2[1], none),
            )
        });
        for l in 0..L {
            let (lo, hi) = (h[l].min(v[l]), h[l].max(v[l]));
            let both = kept[0][l] >= MIN_DIRECTION_PAIRS && kept[1][l] >= MIN_DIRECTION_PAIRS;
            let one = both && hi > DIRECTIONAL_RATIO * lo;
            out[l].0[k] = match all {
                None => {
                    let (kh, kv) = (kept[0][l] as f64, kept[1][l] as f64);
                    let mean = if one {
                        lo
                    } else {
                        (h[l] * kh + v[l] * kv) / (kh + kv).max(1.0)
                    };
                    mean / (2.0 * TRIMMED_CHI2_MEAN)
                }
                Some((ha, va)) => {
                    let (nh, nv) = (n[0][l] as f64, n[1][l] as f64);
                    let mean = if one {
                        if h[l] <= v[l] {
                            ha[l]
                        } else {
                            va[l]
                        }
                    } else {
                        (ha[l] * nh + va[l] * nv) / (nh + nv).max(1.0)
                    };
                    mean / 2.0
                }
            };
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

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::kernels::trim::tests::xorshift;
    use crate::render_set::Feature;

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

    /// A pixel of its own albedo (no surface-mate) beside an edge the features do not show (a
    /// shadow's): the plain spread of its 3×3 colours reads the edge as noise, many times its
    /// own; its window's adjacent pairs along the edge read the noise.
    #[test]
    fn a_lone_pixel_beside_an_edge_reads_its_noise() {
        let (w, h, std) = (32, 32, 0.1f32);
        let (lx, ly) = (15, 16);
        let lone = |x: usize, y: usize| (x, y) == (lx, ly);
        let noise = noisy_flat(w, h, 0.0, std, 11);
        let albedo = Image::from_fn(w, h, 3, |x, y, _| if lone(x, y) { 0.9 } else { 0.5 });
        // Light 0.4 left of the edge, 2.0 right of it; the noise in proportion to the albedo.
        let color = Image::from_fn(w, h, 3, |x, y, k| {
            let light = if x < 16 { 0.4 } else { 2.0 };
            albedo.at(x, y)[k] * (light + noise.at(x, y)[k])
        });
        let mut set = FeatureSet::default();
        set.set(Feature::Albedo, albedo).unwrap();
        let est = estimate(&color, &set);
        let truth = (0.9 * std).powi(2);
        let ratio = est.at(lx, ly)[0] / truth;
        assert!(
            (0.25..4.0).contains(&ratio),
            "the lone pixel reads {ratio:.2}× its noise"
        );
    }

    /// A pixel whose one sample missed, inside a lit floor: it has no albedo to bring a
    /// demodulated variance to (bringing it to black reads nothing), and keeps the plain spread
    /// of its colours, which its coverage noise is.
    #[test]
    fn a_pixel_that_hit_nothing_reads_its_colours() {
        let (w, h, std) = (16, 16, 0.03f32);
        let (hx, hy) = (7, 8);
        let hole = |x: usize, y: usize| (x, y) == (hx, hy);
        let noise = noisy_flat(w, h, 0.0, std, 12);
        let on_floor = |x, y, v: f32| if hole(x, y) { 0.0 } else { v };
        let mut set = FeatureSet::default();
        let albedo = Image::from_fn(w, h, 3, |x, y, _| on_floor(x, y, 0.6));
        let normal = Image::from_fn(w, h, 3, |x, y, k| on_floor(x, y, (k == 1) as u8 as f32));
        set.set(Feature::Albedo, albedo).unwrap();
        set.set(Feature::Normal, normal).unwrap();
        let color = Image::from_fn(w, h, 3, |x, y, k| on_floor(x, y, 0.3 + noise.at(x, y)[k]));
        let est = estimate(&color, &set);
        let floor = est.at(3, 3)[0];
        assert!(
            est.at(hx, hy)[0] > floor,
            "the hole reads {:.2e}, the floor {floor:.2e}",
            est.at(hx, hy)[0]
        );
    }

    /// A light seen in a mirror: its pixels hit no surface (no normal) and Blender writes the light
    /// as their albedo, the colour being that albedo times about one. The light's shape (0.1 to 10
    /// across a few pixels) is no noise: demodulated by what the pixel saw, its pairs read the
    /// colour's own 1 % noise; the plain spread of its colours, which it took before, reads the
    /// shape, hundreds of times the noise. Normals averaged over samples (short at the wall's edge)
    /// say a zero normal is every sample missing.
    #[test]
    fn a_light_seen_in_a_mirror_reads_its_noise_not_its_shape() {
        let (w, h, rel) = (24, 24, 0.01f32);
        let noise = noisy_flat(w, h, 0.0, 1.0, 13);
        let mirror = |x: usize| x >= 8;
        let light = |x: usize, y: usize| {
            let (dx, dy) = (x as f32 - 16.0, y as f32 - 12.0);
            0.02 + 10.0 * (-(dx * dx + dy * dy) / 4.0).exp()
        };
        let albedo = Image::from_fn(w, h, 3, |x, y, _| if mirror(x) { light(x, y) } else { 0.5 });
        let normal = Image::from_fn(w, h, 3, |x, _, k| match (mirror(x), x == 7) {
            (true, _) => 0.0,
            (false, edge) => (k == 2) as u8 as f32 * if edge { 0.5 } else { 1.0 },
        });
        let mut color = Image::from_fn(w, h, 3, |x, y, k| {
            let n = noise.at(x, y)[k];
            if mirror(x) {
                1.03 * light(x, y) * (1.0 + rel * n)
            } else {
                0.3 + 0.03 * n
            }
        });
        let mut set = FeatureSet::default();
        set.set(Feature::Albedo, albedo).unwrap();
        set.set(Feature::Normal, normal).unwrap();
        crate::condition::sanitize(Some(&mut color), &mut set);
        assert!(set
            .get(Feature::Albedo)
            .unwrap()
            .data()
            .iter()
            .all(|&a| a <= 1.0));
        let median_ratio = |set: &FeatureSet| {
            let est = estimate(&color, set);
            // The light and its rim, where its few pixels step from 0.1 to 10 and have no mates.
            let mut r: Vec<f32> = (10..22)
                .flat_map(|x| (6..18).map(move |y| (x, y)))
                .filter(|&(x, y)| light(x, y) > 0.1)
                .map(|(x, y)| est.at(x, y)[0] / (1.03 * light(x, y) * rel).powi(2))
                .collect();
            r.sort_by(f32::total_cmp);
            r[r.len() / 2]
        };
        let seen = median_ratio(&set);
        assert!(
            (0.25..4.0).contains(&seen),
            "the light reads {seen:.2}× its noise"
        );
        set.set_seen(None);
        let blind = median_ratio(&set);
        assert!(
            blind > 50.0 * seen,
            "without what it saw: {blind:.1}× against {seen:.2}×"
        );
    }

    pub(crate) fn noisy_flat(w: usize, h: usize, level: f32, std: f32, seed: u64) -> Image {
        let mut next = xorshift(seed);
        let mut uniform = move || (next() >> 40) as f32 / (1u64 << 24) as f32;
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
}
