//! Firefly (outlier) detection and repair (docs/ALGORITHM.md §4), as plain kernels over `Image`s.
//!
//! Low-spp renders carry salt-and-pepper outliers: a few pixels whose one lucky path hit a light.
//! They are found by comparing a pixel's luminance with its neighbourhood (the centre itself is
//! never part of its own reference, so a firefly cannot hide by inflating the statistics), then
//! repaired (neighbour median or energy-aware clamp) or only marked so the walks avoid them.
//!
//! Every rule is one-sided (only too-bright pixels are outliers) and yields, per pixel, the
//! luminance above which it would be flagged: the `clamp` action scales a flagged pixel down to it.
//! A pixel without neighbours (a 1×1 image) is never flagged. Deterministic: no randomness, and
//! rows are independent, so any thread count gives the same bits.

use std::ops::Range;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::image::Image;
use crate::kernels::simd::{row_kernel, Kernel};
use crate::kernels::window_bits::window_bits;

/// log luminance is taken of max(L, this): black pixels would otherwise be −∞.
const LOG_EPS: f32 = 1e-4;
/// 0.6745 = Φ⁻¹(0.75): scales the MAD to a standard deviation for Gaussian data.
const MAD_SCALE: f32 = 0.6745;

/// Which test decides that a pixel is an outlier.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Rule {
    /// One-sided robust z-score of log luminance against the neighbourhood's median and MAD.
    Zscore,
    /// Tone-mapped luminance against the mean and std of neighbours sharing albedo and normal.
    Feature,
    /// Cycles-style: luminance above `threshold` × the 75th percentile of the neighbourhood.
    Percentile,
}

impl Rule {
    pub fn name(self) -> &'static str {
        match self {
            Rule::Zscore => "zscore",
            Rule::Feature => "feature",
            Rule::Percentile => "percentile",
        }
    }

    /// The rule's customary threshold: 3.5 robust σ, 3 σ, twice the 75th percentile.
    pub fn default_threshold(self) -> f32 {
        match self {
            Rule::Zscore => 3.5,
            Rule::Feature => 3.0,
            Rule::Percentile => 2.0,
        }
    }

    /// Neighbourhood radius: 5×5 for the order statistics (a 3×3 median of 8 values is too noisy
    /// at low spp), 3×3 for the feature test as the report describes it.
    pub fn default_radius(self) -> usize {
        match self {
            Rule::Zscore | Rule::Percentile => 2,
            Rule::Feature => 1,
        }
    }
}

/// What happens to a flagged pixel's colour.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Action {
    /// Replace with the colour of the feature-weighted median (by luminance) of non-outlier neighbours.
    Median,
    /// Scale the colour down so its luminance equals the detection limit: keeps hue, bounds energy.
    Clamp,
    /// Leave the colour unchanged; only the mask marks the pixel (the walks then avoid it).
    Mask,
}

impl Action {
    pub fn name(self) -> &'static str {
        match self {
            Action::Median => "median",
            Action::Clamp => "clamp",
            Action::Mask => "mask",
        }
    }
}

/// Settings of the detection kernel (already validated by the stage).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DetectParams {
    pub rule: Rule,
    pub threshold: f32,
    /// Neighbourhood radius r: the (2r+1)² window around the pixel, the pixel itself excluded.
    pub radius: usize,
    /// Smallest MAD of log luminance used by `zscore` (log units, i.e. relative to the median):
    /// a flat neighbourhood has MAD 0, which would flag any pixel slightly above it.
    pub mad_floor: f32,
    /// Smallest std of tone-mapped luminance used by `feature`, for the same reason.
    pub std_floor: f32,
    /// Neighbours whose albedo differs by at most this (Euclidean, RGB) count as the same surface.
    pub albedo_tol: f32,
    /// Neighbours whose normal difference (1 − n·n′)/2 is at most this count as the same surface.
    pub normal_tol: f32,
}

/// Optional feature buffers that gate the `feature` rule and weight the `median` repair.
#[derive(Clone, Copy, Default)]
pub struct Guides<'a> {
    /// 3-channel albedo.
    pub albedo: Option<&'a Image>,
    /// 3-channel unit normals; zero-length normals are "unknown" and match anything.
    pub normal: Option<&'a Image>,
}

impl Guides<'_> {
    /// Feature distances (albedo, normal) of pixels i and j, each 0 when its buffer is missing.
    #[inline]
    fn distances(&self, i: usize, j: usize) -> (f32, f32) {
        let da = self.albedo.map_or(0.0, |a| {
            let (p, q) = (a.pixel(i), a.pixel(j));
            ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
        });
        let dn = self.normal.map_or(0.0, |n| {
            let (p, q) = (n.pixel(i), n.pixel(j));
            let dot = p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
            let known = p.iter().any(|&v| v != 0.0) && q.iter().any(|&v| v != 0.0);
            if known {
                ((1.0 - dot) * 0.5).clamp(0.0, 1.0)
            } else {
                0.0
            }
        });
        (da, dn)
    }

    fn any(&self) -> bool {
        self.albedo.is_some() || self.normal.is_some()
    }
}

/// The result of detection.
#[derive(Clone, Debug, PartialEq)]
pub struct Detection {
    /// One flag per pixel (row-major): true = outlier.
    pub mask: Vec<bool>,
    /// Per pixel, the luminance above which it is flagged (+∞ where it cannot be flagged).
    pub limit: Vec<f32>,
}

impl Detection {
    pub fn count(&self) -> usize {
        self.mask.iter().filter(|&&m| m).count()
    }

    /// The mask as a 1-channel image (1.0 = outlier), the form the walk stage reads.
    pub fn mask_image(&self, width: usize, height: usize) -> Image {
        let data = self
            .mask
            .par_iter()
            .map(|&m| if m { 1.0 } else { 0.0 })
            .collect();
        Image::from_vec(width, height, 1, data).expect("mask has one value per pixel")
    }
}

/// Rec. 709 luminance of linear RGB, summed in f64 so that f32::MAX input cannot overflow to ∞.
#[inline]
pub fn luminance(c: &[f32]) -> f32 {
    let l = 0.2126 * c[0] as f64 + 0.7152 * c[1] as f64 + 0.0722 * c[2] as f64;
    (l as f32).min(f32::MAX)
}

/// Luminance of every pixel of a 3-channel image.
pub fn luminance_image(color: &Image) -> Vec<f32> {
    color.data().par_chunks_exact(3).map(luminance).collect()
}

/// Median of `v` (reorders it); `v` must not be empty.
fn median(v: &mut [f32]) -> f32 {
    let n = v.len();
    let (_, &mut hi, _) = v.select_nth_unstable_by(n / 2, f32::total_cmp);
    if n % 2 == 1 {
        hi
    } else {
        let lo = v[..n / 2].iter().copied().fold(f32::NEG_INFINITY, f32::max);
        0.5 * lo + 0.5 * hi
    }
}

/// The q-quantile of `v` with linear interpolation (numpy's default); sorts `v`; `v` not empty.
fn quantile(v: &mut [f32], q: f32) -> f32 {
    v.sort_unstable_by(f32::total_cmp);
    let pos = q * (v.len() - 1) as f32;
    let lo = pos.floor() as usize;
    let hi = (lo + 1).min(v.len() - 1);
    let t = pos - lo as f32;
    v[lo] + t * (v[hi] - v[lo])
}

/// Indices of the pixels in the (2r+1)² window around (x, y), the centre excluded, clipped to the image.
#[inline]
fn window(x: usize, y: usize, r: usize, w: usize, h: usize) -> impl Iterator<Item = usize> {
    let (x0, x1) = (x.saturating_sub(r), (x + r).min(w - 1));
    let (y0, y1) = (y.saturating_sub(r), (y + r).min(h - 1));
    (y0..=y1).flat_map(move |ny| {
        (x0..=x1)
            .filter(move |&nx| nx != x || ny != y)
            .map(move |nx| ny * w + nx)
    })
}

/// Largest radius up to which the `feature` rule tests its pairs once, side by side
/// ([`surface_bits`]).
const BITS_RADIUS: usize = crate::kernels::window_bits::MOST_RADIUS;

/// Per pixel, a bit per cell of its (2r+1)² window in raster order: set when that neighbour is
/// inside the image and on the pixel's surface (`Guides::distances` within both tolerances, the
/// same f32 operations, so the same neighbours).
fn surface_bits(guides: &Guides, p: &DetectParams, w: usize, h: usize) -> Vec<u64> {
    let kernel = Kernel::detect();
    window_bits(
        w,
        h,
        p.radius,
        false,
        |rows| SurfacePlanes::of_rows(guides, p, rows, w),
        |planes, i0, j0, bit, out| row_kernel!(kernel, same_surface_run(planes: &SurfacePlanes, i0: usize, j0: usize, bit: u32, out: &mut [u64])),
    )
}

/// What [`surface_bits`] compares, one plane per channel.
struct SurfacePlanes {
    albedo: [Vec<f32>; 3],
    normal: [Vec<f32>; 3],
    known: Vec<bool>,
    /// Albedo and normal tolerances.
    tol: (f32, f32),
}

impl SurfacePlanes {
    /// The planes of the `w`-pixel rows `rows`. Albedo (3), normal (3), normal known: zeros stand
    /// for a missing buffer, whose distance is then 0, as `distances` has it.
    fn of_rows<'a>(guides: &Guides<'a>, p: &DetectParams, rows: Range<usize>, w: usize) -> Self {
        let (first, n) = (rows.start * w, rows.len() * w);
        let pixels = |img: &'a Image| img.data()[3 * first..3 * (first + n)].chunks_exact(3);
        let plane = |img: Option<&'a Image>, k: usize| -> Vec<f32> {
            img.map_or_else(|| vec![0.0; n], |img| pixels(img).map(|px| px[k]).collect())
        };
        SurfacePlanes {
            albedo: std::array::from_fn(|k| plane(guides.albedo, k)),
            normal: std::array::from_fn(|k| plane(guides.normal, k)),
            known: guides.normal.map_or_else(
                || vec![false; n],
                |img| pixels(img).map(|v| v.iter().any(|&c| c != 0.0)).collect(),
            ),
            tol: (p.albedo_tol, p.normal_tol),
        }
    }
}

/// Sets `bit` of `out[t]` where pixels i0 + t and j0 + t lie on one surface: `Guides::distances`,
/// operation for operation, over a run of pixels.
#[inline(always)]
fn same_surface_run(planes: &SurfacePlanes, i0: usize, j0: usize, bit: u32, out: &mut [u64]) {
    let n = out.len();
    let [a0, a1, a2] = &planes.albedo;
    let [n0, n1, n2] = &planes.normal;
    let (pa, qa) = (
        [&a0[i0..i0 + n], &a1[i0..i0 + n], &a2[i0..i0 + n]],
        [&a0[j0..j0 + n], &a1[j0..j0 + n], &a2[j0..j0 + n]],
    );
    let (pn, qn) = (
        [&n0[i0..i0 + n], &n1[i0..i0 + n], &n2[i0..i0 + n]],
        [&n0[j0..j0 + n], &n1[j0..j0 + n], &n2[j0..j0 + n]],
    );
    let (pk, qk) = (&planes.known[i0..i0 + n], &planes.known[j0..j0 + n]);
    let (albedo_tol, normal_tol) = planes.tol;
    for (t, b) in out.iter_mut().enumerate() {
        let da = ((pa[0][t] - qa[0][t]).powi(2)
            + (pa[1][t] - qa[1][t]).powi(2)
            + (pa[2][t] - qa[2][t]).powi(2))
        .sqrt();
        let dot = pn[0][t] * qn[0][t] + pn[1][t] * qn[1][t] + pn[2][t] * qn[2][t];
        let dn = if pk[t] & qk[t] {
            ((1.0 - dot) * 0.5).clamp(0.0, 1.0)
        } else {
            0.0
        };
        *b |= u64::from((da <= albedo_tol) & (dn <= normal_tol)) << bit;
    }
}

/// Flags outliers of a 3-channel linear colour image.
pub fn detect(color: &Image, guides: &Guides, params: &DetectParams) -> Detection {
    let (w, h) = color.dims();
    let n = w * h;
    let lum = luminance_image(color);
    let mut limit = vec![f32::INFINITY; n];
    if n == 0 {
        return Detection {
            mask: Vec::new(),
            limit,
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
    limit.par_chunks_mut(w).enumerate().for_each_init(
        Vec::new,
        |scratch: &mut Vec<f32>, (y, row)| {
            for (x, lim) in row.iter_mut().enumerate() {
                *lim = pixel_limit(&key, guides, surface, &p, x, y, w, h, scratch);
            }
        },
    );
    let mask = lum.par_iter().zip(&limit).map(|(&l, &t)| l > t).collect();
    Detection { mask, limit }
}

/// The luminance above which pixel (x, y) is an outlier under `p.rule`; +∞ if it cannot be one.
#[allow(clippy::too_many_arguments)]
fn pixel_limit(
    key: &[f32],
    guides: &Guides,
    surface: Option<(&[u64], &[isize])>,
    p: &DetectParams,
    x: usize,
    y: usize,
    w: usize,
    h: usize,
    scratch: &mut Vec<f32>,
) -> f32 {
    let i = y * w + x;
    scratch.clear();
    match p.rule {
        Rule::Zscore => {
            scratch.extend(window(x, y, p.radius, w, h).map(|j| key[j]));
            if scratch.is_empty() {
                return f32::INFINITY;
            }
            let med = median(scratch);
            for v in scratch.iter_mut() {
                *v = (*v - med).abs();
            }
            let mad = median(scratch).max(p.mad_floor);
            let log_limit = med + p.threshold * mad / MAD_SCALE;
            let l = log_limit.exp();
            if l.is_finite() {
                l
            } else {
                f32::INFINITY
            }
        }
        Rule::Percentile => {
            scratch.extend(window(x, y, p.radius, w, h).map(|j| key[j]));
            if scratch.is_empty() {
                return f32::INFINITY;
            }
            let q75 = quantile(scratch, 0.75).max(LOG_EPS);
            let l = p.threshold * q75;
            if l.is_finite() {
                l
            } else {
                f32::INFINITY
            }
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
            if scratch.len() < 2 {
                scratch.clear();
                scratch.extend(window(x, y, p.radius, w, h).map(|j| key[j]));
            }
            if scratch.is_empty() {
                return f32::INFINITY;
            }
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
            let m = scratch.len() as f64;
            let mean = scratch.iter().map(|&v| v as f64).sum::<f64>() / m;
            let var = scratch
                .iter()
                .map(|&v| (v as f64 - mean).powi(2))
                .sum::<f64>()
                / m;
            let t = mean + p.threshold as f64 * var.sqrt().max(p.std_floor as f64);
            if t < 1.0 {
                (t / (1.0 - t)) as f32
            } else {
                f32::INFINITY
            }
        }
    }
}

/// Repairs the flagged pixels of `color` by `action`; returns the new colour image.
///
/// `median` takes the colour of the neighbour (radius `radius`, at least 1) whose luminance is the
/// weighted median of the non-outlier neighbours, each weighted by feature similarity
/// exp(−½(Δalbedo/albedo_tol)² − ½(Δnormal/normal_tol)²): a real pixel's colour, from the same
/// surface when there is one. Without non-outlier neighbours it falls back to `clamp`.
pub fn repair(
    color: &Image,
    detection: &Detection,
    guides: &Guides,
    params: &DetectParams,
    action: Action,
) -> Image {
    let mut out = color.par_clone();
    if action == Action::Mask {
        return out;
    }
    let (w, h) = color.dims();
    let r = params.radius.max(1);
    let lum = luminance_image(color);
    let src = color.data();
    out.data_mut()
        .par_chunks_mut(3 * w.max(1))
        .enumerate()
        .for_each_init(Vec::new, |cand: &mut Vec<(f32, f32, usize)>, (y, row)| {
            for (x, px) in row.chunks_exact_mut(3).enumerate() {
                let i = y * w + x;
                if !detection.mask[i] {
                    continue;
                }
                if action == Action::Median {
                    cand.clear();
                    cand.extend(
                        window(x, y, r, w, h)
                            .filter(|&j| !detection.mask[j])
                            .map(|j| {
                                let (da, dn) = guides.distances(i, j);
                                let za = da / params.albedo_tol.max(1e-6);
                                let zn = dn / params.normal_tol.max(1e-6);
                                // Floor so a pixel on its own surface still gets its neighbours' median.
                                let wt = (-0.5 * (za * za + zn * zn)).exp().max(1e-6);
                                (lum[j], wt, j)
                            }),
                    );
                    if !cand.is_empty() {
                        cand.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.2.cmp(&b.2)));
                        let half = 0.5 * cand.iter().map(|c| c.1).sum::<f32>();
                        let mut acc = 0.0;
                        let mut pick = cand[cand.len() - 1].2;
                        for c in cand.iter() {
                            acc += c.1;
                            if acc >= half {
                                pick = c.2;
                                break;
                            }
                        }
                        px.copy_from_slice(&src[3 * pick..3 * pick + 3]);
                        continue;
                    }
                }
                let l = lum[i];
                let scale = if l > 0.0 {
                    (detection.limit[i] / l).clamp(0.0, 1.0)
                } else {
                    1.0
                };
                for v in px.iter_mut() {
                    *v *= scale;
                }
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(rule: Rule) -> DetectParams {
        DetectParams {
            rule,
            threshold: rule.default_threshold(),
            radius: rule.default_radius(),
            mad_floor: 0.25,
            std_floor: 0.02,
            albedo_tol: 0.1,
            normal_tol: 0.05,
        }
    }

    const RULES: [Rule; 3] = [Rule::Zscore, Rule::Feature, Rule::Percentile];

    #[test]
    fn median_and_quantile_agree_with_hand_values() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
        assert_eq!(quantile(&mut [1.0, 2.0, 3.0, 4.0, 5.0], 0.75), 4.0);
        assert_eq!(quantile(&mut [0.0, 1.0], 0.75), 0.75);
        assert_eq!(quantile(&mut [7.0], 0.75), 7.0);
    }

    #[test]
    fn surface_bits_are_the_pairwise_test_in_window_order() {
        // Taller than `window_bits`' bands of rows, so windows cross from one band to the next.
        let (w, h) = (13, 37);
        // Few distinct albedos and normals (ties at the tolerances), unknown normals, a NaN.
        let albedo = Image::from_fn(w, h, 3, |x, y, k| {
            if (x, y) == (4, 4) {
                f32::NAN
            } else {
                [0.2, 0.25, 0.3, 0.7][(x * 3 + y * 5 + k) % 4]
            }
        });
        let normal = Image::from_fn(w, h, 3, |x, y, k| match (x + 2 * y) % 5 {
            0 => 0.0,
            1 => [0.0, 0.6, 0.8][k],
            _ => [0.0, 0.0, 1.0][k],
        });
        for guides in [
            Guides {
                albedo: Some(&albedo),
                normal: Some(&normal),
            },
            Guides {
                albedo: Some(&albedo),
                normal: None,
            },
            Guides {
                albedo: None,
                normal: Some(&normal),
            },
        ] {
            for radius in 1..=BITS_RADIUS {
                let p = DetectParams {
                    radius,
                    albedo_tol: 0.05,
                    normal_tol: 0.1,
                    ..params(Rule::Feature)
                };
                let bits = surface_bits(&guides, &p, w, h);
                let side = 2 * radius + 1;
                for (i, &m) in bits.iter().enumerate() {
                    let (x, y) = ((i % w) as isize, (i / w) as isize);
                    let got: Vec<usize> = (0..side * side)
                        .filter(|&b| m >> b & 1 == 1)
                        .map(|b| {
                            let (dx, dy) = ((b % side) as isize, (b / side) as isize);
                            ((y + dy - radius as isize) * w as isize + x + dx - radius as isize)
                                as usize
                        })
                        .collect();
                    let want: Vec<usize> = window(x as usize, y as usize, radius, w, h)
                        .filter(|&j| {
                            let (da, dn) = guides.distances(i, j);
                            da <= p.albedo_tol && dn <= p.normal_tol
                        })
                        .collect();
                    assert_eq!(got, want, "pixel ({x}, {y}), radius {radius}");
                }
            }
        }
    }

    #[test]
    fn window_excludes_centre_and_clips() {
        let v: Vec<usize> = window(0, 0, 1, 3, 3).collect();
        assert_eq!(v, vec![1, 3, 4]);
        assert_eq!(window(1, 1, 1, 3, 3).count(), 8);
        assert_eq!(window(0, 0, 2, 1, 1).count(), 0);
    }

    #[test]
    fn luminance_is_finite_at_f32_max() {
        assert!(luminance(&[f32::MAX; 3]).is_finite());
        assert!((luminance(&[1.0, 1.0, 1.0]) - 1.0).abs() < 1e-6);
    }

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
    fn clamp_keeps_hue_and_hits_the_limit() {
        let mut img = Image::filled(5, 5, 3, 0.2);
        img.pixel_mut(12).copy_from_slice(&[1e5, 2e5, 3e5]);
        for rule in RULES {
            let p = params(rule);
            let d = detect(&img, &Guides::default(), &p);
            let out = repair(&img, &d, &Guides::default(), &p, Action::Clamp);
            let c = out.pixel(12);
            assert!((luminance(c) / d.limit[12] - 1.0).abs() < 1e-4, "{rule:?}");
            assert!((c[1] / c[0] - 2.0).abs() < 1e-4 && (c[2] / c[0] - 3.0).abs() < 1e-4);
        }
    }

    #[test]
    fn median_prefers_neighbours_on_the_same_surface() {
        // Left half dark surface A, right half bright surface B; a firefly on A next to the edge.
        let (w, h) = (6, 5);
        let img = Image::from_fn(w, h, 3, |x, y, _| match (x, y) {
            (2, 2) => 1e4,
            (x, _) if x < 3 => 0.1,
            _ => 0.9,
        });
        let albedo = Image::from_fn(w, h, 3, |x, _, _| if x < 3 { 0.2 } else { 0.8 });
        let guides = Guides {
            albedo: Some(&albedo),
            normal: None,
        };
        let p = params(Rule::Zscore);
        let d = detect(&img, &guides, &p);
        assert!(d.mask[2 * w + 2]);
        let out = repair(&img, &d, &guides, &p, Action::Median);
        assert_eq!(out.pixel(2 * w + 2), &[0.1, 0.1, 0.1]);
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

    #[test]
    fn detection_is_identical_on_one_and_two_threads() {
        let img = Image::from_fn(31, 17, 3, |x, y, c| {
            let v = ((x * 7919 + y * 104729 + c * 31) % 97) as f32 / 97.0;
            if (x * 13 + y * 7) % 41 == 0 {
                1e3 * v
            } else {
                v
            }
        });
        for rule in RULES {
            let p = params(rule);
            let run = |threads| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap()
                    .install(|| {
                        let d = detect(&img, &Guides::default(), &p);
                        let o = repair(&img, &d, &Guides::default(), &p, Action::Median);
                        (d, o)
                    })
            };
            assert_eq!(run(1), run(2), "{rule:?}");
        }
    }
}
