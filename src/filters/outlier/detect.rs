//! Detection: per pixel, the luminance above which its rule flags it, from its neighbourhood
//! without itself, and the flags.

use rayon::prelude::*;

use super::neighbourhood::{luminance_image, median, quantile, window};
use super::params::{DetectParams, Detection, Guides, Rule};
use super::surface::{surface_bits, BITS_RADIUS};
use crate::image::Image;

/// log luminance is taken of max(L, this): black pixels would otherwise be −∞.
const LOG_EPS: f32 = 1e-4;
/// 0.6745 = Φ⁻¹(0.75): scales the MAD to a standard deviation for Gaussian data.
const MAD_SCALE: f32 = 0.6745;

/// Flags outliers of a 3-channel linear colour image.
pub fn detect(color: &Image, guides: &Guides, params: &DetectParams) -> Detection {
    let (w, h) = color.dims();
    let n = w * h;
    let lum = luminance_image(color);
    let mut limits = vec![(f32::INFINITY, f32::NEG_INFINITY); n];
    if n == 0 {
        return Detection {
            mask: Vec::new(),
            limit: Vec::new(),
            low: Vec::new(),
        };
    }
    let key: Vec<f32> = match params.rule {
        Rule::Zscore => lum.par_iter().map(|&l| l.max(LOG_EPS).ln()).collect(),
        Rule::Feature => lum.par_iter().map(|&l| l / (1.0 + l)).collect(),
        Rule::Percentile => lum.clone(),
    };
    let p = *params;
    // With each window bit's pixel offset, so a neighbour's index costs no division.
    let surface = (p.rule == Rule::Feature && guides.any() && p.radius <= BITS_RADIUS).then(|| {
        (
            surface_bits(guides, &p, w, h),
            crate::kernels::window_bits::offsets(w, p.radius),
        )
    });
    let surface = surface
        .as_ref()
        .map(|(bits, offsets)| (bits.as_slice(), offsets.as_slice()));
    limits.par_chunks_mut(w).enumerate().for_each_init(
        Vec::new,
        |scratch: &mut Vec<f32>, (y, row)| {
            for (x, lim) in row.iter_mut().enumerate() {
                *lim = pixel_limits(&key, guides, surface, &p, x, y, w, h, scratch);
            }
        },
    );
    let (limit, low): (Vec<f32>, Vec<f32>) = limits.into_par_iter().unzip();
    let mask = lum
        .par_iter()
        .zip(&limit)
        .zip(&low)
        .map(|((&l, &t), &b)| l > t || l < b)
        .collect();
    Detection { mask, limit, low }
}

/// The luminances above and below which pixel (x, y) is an outlier under `p.rule`: +∞ and −∞
/// where it cannot be one (below: always, unless the feature rule is two-sided).
#[allow(clippy::too_many_arguments)]
fn pixel_limits(
    key: &[f32],
    guides: &Guides,
    surface: Option<(&[u64], &[isize])>,
    p: &DetectParams,
    x: usize,
    y: usize,
    w: usize,
    h: usize,
    scratch: &mut Vec<f32>,
) -> (f32, f32) {
    let i = y * w + x;
    scratch.clear();
    let none = (f32::INFINITY, f32::NEG_INFINITY);
    match p.rule {
        Rule::Zscore => {
            scratch.extend(window(x, y, p.radius, w, h).map(|j| key[j]));
            if scratch.is_empty() {
                return none;
            }
            let med = median(scratch);
            for v in scratch.iter_mut() {
                *v = (*v - med).abs();
            }
            let mad = median(scratch).max(p.mad_floor);
            let log_limit = med + p.threshold * mad / MAD_SCALE;
            let l = log_limit.exp();
            (if l.is_finite() { l } else { f32::INFINITY }, none.1)
        }
        Rule::Percentile => {
            scratch.extend(window(x, y, p.radius, w, h).map(|j| key[j]));
            if scratch.is_empty() {
                return none;
            }
            let q75 = quantile(scratch, 0.75).max(LOG_EPS);
            let l = p.threshold * q75;
            (if l.is_finite() { l } else { f32::INFINITY }, none.1)
        }
        Rule::Feature => {
            if let Some((bits, offsets)) = surface {
                // The same neighbours in the same (raster) order as the test below.
                let mut m = bits[i];
                while m != 0 {
                    let b = m.trailing_zeros() as usize;
                    m &= m - 1;
                    scratch.push(key[(i as isize + offsets[b]) as usize]);
                }
            } else if guides.any() {
                scratch.extend(window(x, y, p.radius, w, h).filter_map(|j| {
                    let (da, dn) = guides.distances(i, j);
                    (da <= p.albedo_tol && dn <= p.normal_tol).then_some(key[j])
                }));
            }
            // Too few neighbours on the same surface to estimate a spread: test against all.
            let alone = scratch.len() < 2;
            if alone {
                scratch.clear();
                scratch.extend(window(x, y, p.radius, w, h).map(|j| key[j]));
            }
            if scratch.is_empty() {
                return none;
            }
            // A dot is darker than all its neighbours but one (a second dot beside it), and is
            // raised no higher than the second-darkest: most pixels are not, and cost nothing more.
            let floor = if p.two_sided {
                second_darkest(window(x, y, p.radius, w, h).map(|j| key[j]))
            } else {
                f32::NEG_INFINITY
            };
            let low = match guides.albedo {
                _ if key[i].is_nan() || key[i] >= floor => none.1,
                // Alone on its surface in a clean albedo (its neighbours' within the same-surface
                // tolerance of each other): a texel of its own. Each neighbour is first brought to
                // the pixel's albedo, as the noise stage does, so a dark texel the albedo shows is
                // no darker than its neighbours. In a noisy
                // albedo (fog's per-sample mix of medium and surface) being alone says nothing,
                // and the colours are compared as they are.
                Some(albedo)
                    if alone
                        && clean_around(albedo, window(x, y, p.radius, w, h), p.albedo_tol) =>
                {
                    let own = albedo_level(albedo.pixel(i));
                    let keys: Vec<f32> = window(x, y, p.radius, w, h)
                        .map(|j| {
                            let l = key[j] / (1.0 - key[j]);
                            let l = l * own / albedo_level(albedo.pixel(j));
                            if l.is_finite() {
                                l / (1.0 + l)
                            } else {
                                1.0
                            }
                        })
                        .collect();
                    let bound = floor.min(second_darkest(keys.iter().copied()));
                    dark_limit(&keys, bound, p)
                }
                _ => dark_limit(scratch, floor, p),
            };
            // Leave the brightest neighbour out when enough remain: two adjacent fireflies
            // would otherwise inflate each other's std and both pass.
            if scratch.len() >= 4 {
                let (k, _) = scratch
                    .iter()
                    .enumerate()
                    .max_by(|a, b| a.1.total_cmp(b.1))
                    .expect("not empty");
                scratch.swap_remove(k);
            }
            let (mean, sd) = mean_sd(scratch.iter().map(|&v| v as f64));
            let t = mean + p.threshold as f64 * sd.max(p.std_floor as f64);
            (untone(t).unwrap_or(f32::INFINITY), low)
        }
    }
}

/// Mean and standard deviation of surface-mates' keys `v` (not empty) without the darkest when
/// at least 4 remain with it.
fn spread_without_darkest(v: &[f32]) -> (f64, f64) {
    let skip = (v.len() >= 4)
        .then(|| v.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1)))
        .flatten()
        .map(|(k, _)| k);
    mean_sd(
        v.iter()
            .enumerate()
            .filter(|&(k, _)| Some(k) != skip)
            .map(|(_, &x)| x as f64),
    )
}

/// Mean and (population) standard deviation of `values`, in their order; not empty.
fn mean_sd(values: impl Iterator<Item = f64> + Clone) -> (f64, f64) {
    let m = values.clone().count() as f64;
    let mean = values.clone().sum::<f64>() / m;
    let var = values.map(|x| (x - mean).powi(2)).sum::<f64>() / m;
    (mean, var.sqrt())
}

/// The luminance of a tone-mapped key t = L / (1 + L) in (0, 1); None at or above 1.
fn untone(t: f64) -> Option<f32> {
    (t < 1.0).then(|| (t / (1.0 - t)) as f32)
}

/// Whether the albedo luminances of the pixels `around` lie within `tol` of each other.
fn clean_around(albedo: &Image, around: impl Iterator<Item = usize>, tol: f32) -> bool {
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for j in around {
        let l = albedo_level(albedo.pixel(j));
        (lo, hi) = (lo.min(l), hi.max(l));
    }
    hi - lo <= tol
}

/// Albedo luminance plus the noise stage's 0.02, so a black albedo divides nothing by zero.
fn albedo_level(a: &[f32]) -> f32 {
    let l = 0.2126 * a[0] + 0.7152 * a[1] + 0.0722 * a[2];
    if l.is_finite() {
        l.max(0.0) + 0.02
    } else {
        0.02
    }
}

/// The second-smallest of `keys` (+∞ with fewer than two).
fn second_darkest(keys: impl Iterator<Item = f32>) -> f32 {
    let (mut d0, mut d1) = (f32::INFINITY, f32::INFINITY);
    for k in keys {
        if k < d0 {
            (d0, d1) = (k, d0);
        } else if k < d1 {
            d1 = k;
        }
    }
    d1
}

/// The luminance below which a pixel is a dark dot, from its surface-mates' keys `mates` and the
/// key `bound` it may not be raised above (its second-darkest neighbour's): the mates' mean less
/// `threshold` std with the darkest mate left out (a second dot beside it would inflate the std). A
/// dot is a sample that returned almost nothing on a surface whose other pixels did; a shadow's edge
/// or a dark crease the features do not show has dark neighbours along it, so it is not flagged,
/// and a flagged pixel is raised no further than its own window shows. −∞ if none.
fn dark_limit(mates: &[f32], bound: f32, p: &DetectParams) -> f32 {
    if mates.is_empty() {
        return f32::NEG_INFINITY;
    }
    let (mean, sd) = spread_without_darkest(mates);
    let t = mean - p.threshold as f64 * sd.max(p.std_floor as f64);
    let t = t.min(bound as f64);
    if t > 0.0 && t.is_finite() {
        untone(t).unwrap_or(f32::NEG_INFINITY)
    } else {
        f32::NEG_INFINITY
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filters::outlier::params::fixtures::{params, RULES};

    #[test]
    fn a_lone_firefly_is_flagged_by_every_rule_and_nothing_else() {
        let mut img = Image::filled(9, 7, 3, 0.3);
        img.pixel_mut(4 * 9 + 4)
            .copy_from_slice(&[50.0, 40.0, 30.0]);
        for rule in RULES {
            let d = detect(&img, &Guides::default(), &params(rule));
            assert_eq!(d.count(), 1, "{rule:?}");
            assert!(d.mask[4 * 9 + 4], "{rule:?}");
        }
    }

    #[test]
    fn feature_rule_gates_on_albedo() {
        // A bright surface strip next to a dark one is not an outlier; a firefly on the dark one is.
        let (w, h) = (7, 7);
        let img = Image::from_fn(w, h, 3, |x, y, _| match (x, y) {
            (5, 5) => 20.0,
            (3, _) => 20.0,
            _ => 0.1,
        });
        let albedo = Image::from_fn(w, h, 3, |x, _, _| if x == 3 { 0.9 } else { 0.1 });
        let guides = Guides {
            albedo: Some(&albedo),
            normal: None,
        };
        let p = params(Rule::Feature);
        let d = detect(&img, &guides, &p);
        assert!(d.mask[5 * w + 5]);
        // Strip ends at the border have one same-surface neighbour, too few: they fall back to all.
        assert!((1..h - 1).all(|y| !d.mask[y * w + 3]));
        assert_eq!(d.count(), 3);
    }
}
