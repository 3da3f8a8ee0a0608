//! Feature prefiltering (docs/ALGORITHM.md §8, "Noisy features"): at a few samples per pixel the
//! albedo and normal buffers are averages of a few samples too, noisy where a pixel's samples see
//! different surfaces (glossy and glass paths, depth of field, sub-pixel texture), and every stage
//! uses them as guides. No renderer we read writes their variance, so it is estimated from the
//! buffer itself, and an NL-means filter whose patch distance counts in units of that variance
//! (Rousselle et al. 2012, as NFOR prefilters its features) smooths the noise away where there is
//! some and leaves a clean pixel, a sharp edge or a texture alone.
//!
//! Every pixel's sums run in f64 in a fixed order, so the result is the same bits on any thread
//! count.

use rayon::prelude::*;

use crate::image::Image;
use crate::noise::trimmed_mean;

/// Radius of the window the variance is read from (5×5, as the colour's raw estimate).
const VAR_RADIUS: isize = 2;
const VAR_SIDE: usize = 2 * VAR_RADIUS as usize + 1;
/// Adjacent pairs in that window: every horizontal and vertical pair.
const MAX_PAIRS: usize = 2 * VAR_SIDE * (VAR_SIDE - 1);
/// The mean of the smallest `keep` share of χ²₁ samples, E[χ²₁ | below its `keep` quantile]: the
/// kept pairs' mean of (x_j − x_k)² is this times 2·variance. With z the quantile of |Z|,
/// E[Z² | |Z| < z] = 1 − 2zφ(z)/keep, and z solves erf(z/√2) = keep (by bisection).
pub fn trimmed_chi2_mean(keep: f64) -> f64 {
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

/// Smallest variance (in the feature's units squared) a patch distance is divided by: a difference
/// of 1 % of an albedo or normal component is one unit where the estimate reads no noise at all.
const EPS: f64 = 1e-4;

/// How the prefilter treats one feature buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// Values in absolute units (albedo, material weights, shadow).
    Plain,
    /// Unit vectors: all-zero ("unknown") pixels are left out and stay so; the result is renormalised.
    Normal,
    /// Distances: the floor of the distance normalisation is relative to the pixel's depth.
    Depth,
}

/// Settings of the NL-means prefilter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Params {
    /// k: patches closer than k noise standard deviations average.
    pub strength: f64,
    /// Search window radius.
    pub radius: usize,
    /// Patch radius.
    pub patch: usize,
    /// The share of a window's adjacent-pixel differences read as noise (the smallest ones); the
    /// rest is taken for structure.
    pub keep: f64,
}

/// Whether pixel `i` takes part (an unknown normal does not).
fn known(img: &Image, kind: Kind, i: usize) -> bool {
    kind != Kind::Normal || img.pixel(i).iter().any(|&v| v != 0.0)
}

/// The variance of every pixel's feature mean (mean over channels), from the squared differences
/// of adjacent pixels in its 5×5 window: per channel the smallest `keep` share, so an edge or a
/// texture the feature shows cleanly (crossing fewer pairs than the rest) reads as no noise. A
/// pixel with fewer than two pairs reads 0.
pub fn variance(img: &Image, kind: Kind, keep: f64) -> Vec<f32> {
    let (w, h) = img.dims();
    let c = img.channels();
    let unit = 2.0 * trimmed_chi2_mean(keep);
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            if !known(img, kind, i) {
                return 0.0;
            }
            let (x, y) = ((i % w) as isize, (i / w) as isize);
            let inside = |nx: isize, ny: isize| {
                (x - VAR_RADIUS..=x + VAR_RADIUS).contains(&nx)
                    && (y - VAR_RADIUS..=y + VAR_RADIUS).contains(&ny)
                    && nx >= 0
                    && ny >= 0
                    && (nx as usize) < w
                    && (ny as usize) < h
            };
            let mut pairs = [(0usize, 0usize); MAX_PAIRS];
            let mut n = 0;
            for ny in y - VAR_RADIUS..=y + VAR_RADIUS {
                for nx in x - VAR_RADIUS..=x + VAR_RADIUS {
                    if !inside(nx, ny) {
                        continue;
                    }
                    let j = ny as usize * w + nx as usize;
                    for (qx, qy) in [(nx + 1, ny), (nx, ny + 1)] {
                        let q = qy as usize * w + qx as usize;
                        if inside(qx, qy) && known(img, kind, j) && known(img, kind, q) {
                            pairs[n] = (j, q);
                            n += 1;
                        }
                    }
                }
            }
            if n < 2 {
                return 0.0;
            }
            let kept = ((n as f64 * keep) as usize).max(1);
            let mut d2 = [0.0f64; MAX_PAIRS];
            let mut total = 0.0;
            for k in 0..c {
                for (slot, &(j, q)) in d2.iter_mut().zip(&pairs[..n]) {
                    let d = img.pixel(j)[k] as f64 - img.pixel(q)[k] as f64;
                    *slot = d * d;
                }
                total += trimmed_mean(&mut d2[..n], kept) / unit;
            }
            (total / c as f64) as f32
        })
        .collect()
}

/// NL-means over `img` with its per-pixel `variance` ([`variance`]). The distance of the patches
/// around i and j, per channel and patch pixel p, is ((u_p − u_q)² − (v_p + min(v_p, v_q))) /
/// (ε + k²(v_p + v_q)), averaged; j weighs exp(−max(0, that)). Subtracting the expected noise makes
/// two noisy samples of one value distance 0; dividing by it makes a difference the noise cannot
/// explain (an edge, a texture) weigh nothing. A pixel whose variance reads 0 is kept as it is.
pub fn filter(img: &Image, variance: &[f32], kind: Kind, p: &Params) -> Image {
    let (w, h) = img.dims();
    let c = img.channels();
    let (r, f) = (p.radius as isize, p.patch as isize);
    let k2 = p.strength * p.strength;
    let at = |x: isize, y: isize| {
        let (x, y) = (x.clamp(0, w as isize - 1), y.clamp(0, h as isize - 1));
        y as usize * w + x as usize
    };
    let mut out = img.par_clone();
    out.data_mut()
        .par_chunks_mut(c)
        .enumerate()
        .for_each(|(i, px)| {
            if variance[i] <= 0.0 || !known(img, kind, i) {
                return;
            }
            let eps = match kind {
                Kind::Depth => EPS * (img.pixel(i)[0] as f64).powi(2),
                Kind::Plain | Kind::Normal => EPS,
            }
            .max(f64::MIN_POSITIVE);
            let (x, y) = ((i % w) as isize, (i / w) as isize);
            let mut sum = [0.0f64; 3];
            let mut total = 0.0f64;
            for ny in (y - r).max(0)..=(y + r).min(h as isize - 1) {
                for nx in (x - r).max(0)..=(x + r).min(w as isize - 1) {
                    let j = ny as usize * w + nx as usize;
                    if !known(img, kind, j) {
                        continue;
                    }
                    let mut dist = 0.0f64;
                    let mut terms = 0usize;
                    for dy in -f..=f {
                        for dx in -f..=f {
                            let (a, b) = (at(x + dx, y + dy), at(nx + dx, ny + dy));
                            let (va, vb) = (variance[a] as f64, variance[b] as f64);
                            let expected = va + va.min(vb);
                            let scale = eps + k2 * (va + vb);
                            for ch in 0..c {
                                let d = img.pixel(a)[ch] as f64 - img.pixel(b)[ch] as f64;
                                dist += (d * d - expected) / scale;
                            }
                            terms += c;
                        }
                    }
                    let weight = (-(dist / terms as f64).max(0.0)).exp();
                    for (acc, &v) in sum.iter_mut().zip(img.pixel(j)) {
                        *acc += weight * v as f64;
                    }
                    total += weight;
                }
            }
            // The pixel itself is in its window with weight 1, so total ≥ 1.
            let mut v: [f64; 3] = std::array::from_fn(|ch| sum[ch] / total);
            if kind == Kind::Normal {
                let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                if len > 1e-6 {
                    v.iter_mut().for_each(|x| *x /= len);
                } else {
                    return;
                }
            }
            for ch in 0..c {
                px[ch] = v[ch] as f32;
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flat_noise_reads_its_variance() {
        let mut state = 7u64;
        let mut uniform = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let img = Image::from_fn(64, 64, 3, |_, _, _| {
            0.5 + 0.05 * ((0..12).map(|_| uniform()).sum::<f32>() - 6.0)
        });
        let v = variance(&img, Kind::Plain, 0.5);
        let mean = v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64;
        assert!((mean.sqrt() - 0.05).abs() < 0.005, "std {}", mean.sqrt());
    }

    #[test]
    fn a_clean_checker_reads_no_noise() {
        let img = Image::from_fn(16, 16, 3, |x, y, _| ((x / 2 + y / 2) % 2) as f32);
        assert!(variance(&img, Kind::Plain, 0.5).iter().all(|&v| v == 0.0));
    }

    #[test]
    fn trimmed_chi2_means_match_the_tabulated_ones() {
        assert!((trimmed_chi2_mean(0.5) - 0.142_651_835_488_518_54).abs() < 1e-9);
        assert!((trimmed_chi2_mean(0.8) - 0.437_724_594_903_639).abs() < 1e-9);
        assert!((trimmed_chi2_mean(1.0 - 1e-12) - 1.0).abs() < 1e-6);
    }
}
