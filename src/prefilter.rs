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
use crate::noise::{total_key, trimmed_chi2_mean, trimmed_mean};

/// Radius of the window the variance is read from (5×5, as the colour's raw estimate).
const VAR_RADIUS: isize = 2;
const VAR_SIDE: usize = 2 * VAR_RADIUS as usize + 1;
/// Adjacent pairs in that window: every horizontal and vertical pair.
const MAX_PAIRS: usize = 2 * VAR_SIDE * (VAR_SIDE - 1);
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
            let mut d2 = [0i64; MAX_PAIRS];
            let mut total = 0.0;
            for k in 0..c {
                let mut zeros = 0;
                for (slot, &(j, q)) in d2.iter_mut().zip(&pairs[..n]) {
                    let d = img.pixel(j)[k] as f64 - img.pixel(q)[k] as f64;
                    *slot = total_key(d * d);
                    zeros += usize::from(d == 0.0);
                }
                // Squares are ≥ 0, so when the kept share is all zeros its mean is 0: the common
                // case of a uniform albedo, without the selection.
                if zeros < kept {
                    total += trimmed_mean(&mut d2[..n], kept) / unit;
                }
            }
            (total / c as f64) as f32
        })
        .collect()
}

/// Rows one parallel task filters: every pixel's sums still run over the offsets in one fixed
/// order, so the band size changes no bit.
const BAND: usize = 16;

/// NL-means over `img` with its per-pixel `variance` ([`variance`]). The distance of the patches
/// around i and j, per channel and patch pixel p (q its partner in j's patch), is
/// ((u_p − u_q)² − (v_p + min(v_p, v_q))) / (ε_p + k²(v_p + v_q)), averaged; j weighs
/// exp(−max(0, that)). Subtracting the expected noise makes two noisy samples of one value
/// distance 0; dividing by it makes a difference the noise cannot explain (an edge, a texture)
/// weigh nothing. A pixel whose variance reads 0 is kept as it is.
///
/// Computed offset by offset (the classic fast NL-means): for one offset, the per-pixel terms over
/// a band of rows, box-summed over the patch, give every pixel's distance to its partner at once.
pub fn filter(img: &Image, variance: &[f32], kind: Kind, p: &Params) -> Image {
    let (w, h) = img.dims();
    let c = img.channels();
    let data = img.data();
    let known: Vec<bool> = (0..w * h).map(|i| known(img, kind, i)).collect();
    let active = |i: usize| variance[i] > 0.0 && known[i];
    let eps: Vec<f64> = (0..w * h)
        .map(|i| match kind {
            Kind::Depth => (EPS * (data[i] as f64).powi(2)).max(f64::MIN_POSITIVE),
            Kind::Plain | Kind::Normal => EPS,
        })
        .collect();
    let (r, f) = (p.radius as isize, p.patch as isize);
    let k2 = p.strength * p.strength;
    let terms = ((2 * f + 1) * (2 * f + 1)) as f64 * c as f64;
    let clamp = |x: isize, y: isize| {
        let (x, y) = (x.clamp(0, w as isize - 1), y.clamp(0, h as isize - 1));
        y as usize * w + x as usize
    };
    let mut out = img.par_clone();
    out.data_mut()
        .par_chunks_mut(BAND * w * c)
        .enumerate()
        .for_each(|(band, rows)| {
            let y0 = band * BAND;
            let y1 = (y0 + BAND).min(h);
            // Only the columns an active pixel (and its patch) reaches are computed.
            let Some(x_lo) = (0..w).find(|&x| (y0..y1).any(|y| active(y * w + x))) else {
                return;
            };
            let x_hi = (0..w)
                .rev()
                .find(|&x| (y0..y1).any(|y| active(y * w + x)))
                .expect("an active column exists");
            // Terms over the band's rows and columns widened by the patch radius.
            let (tw, th) = (w + 2 * f as usize, y1 - y0 + 2 * f as usize);
            let mut term = vec![0.0f64; tw * th];
            let mut across = vec![0.0f64; w * th];
            let mut sum = vec![[0.0f64; 3]; (y1 - y0) * w];
            let mut total = vec![0.0f64; (y1 - y0) * w];
            for oy in -r..=r {
                for ox in -r..=r {
                    for ty in 0..th {
                        let py = y0 as isize + ty as isize - f;
                        for tx in x_lo..=x_hi + 2 * f as usize {
                            let px = tx as isize - f;
                            let (a, b) = (clamp(px, py), clamp(px + ox, py + oy));
                            let (va, vb) = (variance[a] as f64, variance[b] as f64);
                            let expected = va + va.min(vb);
                            let scale = eps[a] + k2 * (va + vb);
                            let mut d2 = 0.0;
                            for ch in 0..c {
                                let d = data[a * c + ch] as f64 - data[b * c + ch] as f64;
                                d2 += d * d;
                            }
                            term[ty * tw + tx] = (d2 - c as f64 * expected) / scale;
                        }
                    }
                    for ty in 0..th {
                        let row = &term[ty * tw..(ty + 1) * tw];
                        for x in x_lo..=x_hi {
                            across[ty * w + x] = row[x..x + 2 * f as usize + 1].iter().sum();
                        }
                    }
                    for y in y0..y1 {
                        let (ny, ly) = (y as isize + oy, y - y0);
                        if ny < 0 || ny >= h as isize {
                            continue;
                        }
                        for x in x_lo..=x_hi {
                            let (i, nx) = (y * w + x, x as isize + ox);
                            if nx < 0 || nx >= w as isize || !active(i) {
                                continue;
                            }
                            let j = ny as usize * w + nx as usize;
                            if !known[j] {
                                continue;
                            }
                            let dist: f64 = (0..=2 * f as usize)
                                .map(|dy| across[(ly + dy) * w + x])
                                .sum();
                            let weight = (-(dist / terms).max(0.0)).exp();
                            let acc = &mut sum[ly * w + x];
                            for ch in 0..c {
                                acc[ch] += weight * data[j * c + ch] as f64;
                            }
                            total[ly * w + x] += weight;
                        }
                    }
                }
            }
            for (l, px) in rows.chunks_exact_mut(c).enumerate() {
                if !active(y0 * w + l) {
                    continue;
                }
                // The pixel itself is its own partner at offset 0, weight 1, so total ≥ 1.
                let mut v: [f64; 3] = std::array::from_fn(|ch| sum[l][ch] / total[l]);
                if kind == Kind::Normal {
                    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                    if len <= 1e-6 {
                        continue;
                    }
                    v.iter_mut().for_each(|x| *x /= len);
                }
                for (o, x) in px.iter_mut().zip(v) {
                    *o = x as f32;
                }
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
}
