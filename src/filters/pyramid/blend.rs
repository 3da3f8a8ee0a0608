//! Laplacian blending of the filtered levels back into one image, in the linear or the log
//! domain, each coarse level expanded under the guide of the finer one (docs/ALGORITHM.md §4). It
//! uses the very same REDUCE and EXPAND as the levels for building and collapsing, so an untouched
//! pyramid reconstructs its input up to float rounding whatever the filters are.

use rayon::prelude::*;

use super::levels::{expand, gaussian, reduce};
use crate::error::{Error, Result};
use crate::image::Image;
use crate::kernels::fastmath::exp_neg;
use crate::meter::Meter;

/// Where the bands of Laplacian blending are formed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BlendDomain {
    /// Bands of linear radiance: the textbook form; halos around bright HDR edges.
    Linear,
    /// Bands of ln(x + ε): a coarse-level change acts as a ratio, so a correction next to a light does
    /// not swamp a dark neighbour.
    Log,
}

/// Offset of the log domain: about the noise floor that relMSE also forgives (its 0.01 is ε²).
const LOG_EPS: f32 = 0.1;

impl BlendDomain {
    fn forward(self, img: &mut Image) {
        if self == BlendDomain::Log {
            img.data_mut()
                .par_chunks_mut(1 << 14)
                .for_each(|c| c.iter_mut().for_each(|v| *v = (v.max(0.0) + LOG_EPS).ln()));
        }
    }

    fn inverse(self, img: &mut Image) {
        if self == BlendDomain::Log {
            img.data_mut()
                .par_chunks_mut(1 << 14)
                .for_each(|c| c.iter_mut().for_each(|v| *v = v.exp() - LOG_EPS));
        }
    }
}

/// A tap pattern's column offsets and its 4×4 spatial weights.
type TapWeights = ([f32; 4], [[f32; 4]; 4]);

/// Range scale of the guided EXPAND, in the blend domain (log: 0.5 ≈ a factor 1.6 in brightness).
const GUIDE_SIGMA: f32 = 0.5;

/// EXPAND of a coarse correction `c` to the fine size, guided by the fine image `fine` and its
/// REDUCE `coarse_guide` (all in the blend domain): joint bilateral upsampling (Kopf et al. 2007).
/// A fine pixel takes corrections only from coarse pixels that look like it, so a change made at a
/// mixed light/ceiling pixel does not spill onto the ceiling. Zero correction expands to exactly zero.
fn guided_expand(c: &Image, fine: &Image, coarse_guide: &Image, meter: &Meter) -> Image {
    let (w, h) = fine.dims();
    let (cw, ch) = c.dims();
    let inv_r = 1.0 / (2.0 * GUIDE_SIGMA * GUIDE_SIGMA);
    let mut out = Image::new(w, h, 3);
    // Rows are independent: one parallel task per row.
    meter.pass(h);
    out.data_mut()
        .par_chunks_mut(3 * w.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            // A cancelled run's rows are left unset: its result is thrown away.
            if meter.cancelled() {
                return;
            }
            meter.rows(1);
            let fy = (y as f32 + 0.5) * ch as f32 / h as f32 - 0.5;
            let y0 = fy.floor() as isize;
            // The spatial weights of the 4×4 taps depend only on the taps' offsets, which repeat
            // along a row (two patterns, alternating, at an exact 2× EXPAND): kept for the last two
            // offsets seen.
            let mut cached: [Option<TapWeights>; 2] = [None, None];
            for x in 0..w {
                // Fine pixel centre in coarse pixel coordinates.
                let fx = (x as f32 + 0.5) * cw as f32 / w as f32 - 0.5;
                let x0 = fx.floor() as isize;
                let dxs: [f32; 4] = std::array::from_fn(|a| (x0 - 1 + a as isize) as f32 - fx);
                let seen = cached
                    .iter()
                    .flatten()
                    .find(|(d, _)| d.map(f32::to_bits) == dxs.map(f32::to_bits));
                let spatial = match seen {
                    Some(&(_, s)) => s,
                    None => {
                        let s = std::array::from_fn(|b| {
                            let dy = (y0 - 1 + b as isize) as f32 - fy;
                            std::array::from_fn(|a| {
                                let dx = dxs[a];
                                gaussian((dx * dx + dy * dy).sqrt() as f64) as f32
                            })
                        });
                        cached = [Some((dxs, s)), cached[0]];
                        s
                    }
                };
                let g = fine.at(x, y);
                // The 16 taps' range exponents first (in vector lanes), then the sums in tap order.
                let mut arg = [0.0f32; 16];
                let mut tap = [None; 16];
                for (b, qy) in (y0 - 1..=y0 + 2).enumerate() {
                    for (a, qx) in (x0 - 1..=x0 + 2).enumerate() {
                        if qx < 0 || qy < 0 || qx >= cw as isize || qy >= ch as isize {
                            continue;
                        }
                        let (qx, qy) = (qx as usize, qy as usize);
                        let q = coarse_guide.at(qx, qy);
                        let d2 =
                            ((g[0] - q[0]).powi(2) + (g[1] - q[1]).powi(2) + (g[2] - q[2]).powi(2))
                                / 3.0;
                        arg[4 * b + a] = -d2 * inv_r;
                        tap[4 * b + a] = Some((qx, qy));
                    }
                }
                let range = arg.map(exp_neg);
                let (mut sum, mut plain) = ([0.0f32; 3], [0.0f32; 3]);
                let (mut wsum, mut psum) = (0.0f32, 0.0f32);
                for (t, &at) in tap.iter().enumerate() {
                    let Some((qx, qy)) = at else {
                        continue;
                    };
                    let spatial = spatial[t / 4][t % 4];
                    let wq = spatial * range[t];
                    let cq = c.at(qx, qy);
                    for k in 0..3 {
                        sum[k] += wq * cq[k];
                        plain[k] += spatial * cq[k];
                    }
                    wsum += wq;
                    psum += spatial;
                }
                // No similar coarse pixel: fall back to the plain spatial weights rather than dropping the correction.
                let px = &mut row[3 * x..3 * x + 3];
                for k in 0..3 {
                    px[k] = if wsum > 1e-4 * psum {
                        sum[k] / wsum
                    } else {
                        plain[k] / psum.max(f32::MIN_POSITIVE)
                    };
                }
            }
        });
    out
}

/// Keeps every sample of `img` within the range of `guide`'s (2r+1)² neighbourhood, per channel: coarse
/// corrections may move a pixel towards its neighbours' values but never beyond them (no overshoot
/// or ringing, as the neighbourhood clamp of temporal anti-aliasing). Leaves `img` unchanged where it
/// already is in range, so an untouched pyramid still reconstructs exactly.
fn clamp_to_neighbourhood(img: &mut Image, guide: &Image, r: usize, meter: &Meter) {
    clamp_in_bands(img, guide, r, CLAMP_BAND_ROWS, meter);
}

/// Output rows per task of the neighbourhood clamp: each holds its rows' (and the window's reach)
/// minima and maxima across, not the whole image's.
const CLAMP_BAND_ROWS: usize = 32;

/// [`clamp_to_neighbourhood`] with `band_rows` output rows per task.
fn clamp_in_bands(img: &mut Image, guide: &Image, r: usize, band_rows: usize, meter: &Meter) {
    let ((w, h), c) = (img.dims(), img.channels());
    let stride = c * w;
    if stride == 0 {
        return;
    }
    let band_rows = band_rows.max(1);
    // Min and max are exact and the window a rectangle: over each row's 2r + 1 columns first
    // (whole rows at a time, so the loops run in vector lanes), then over the 2r + 1 rows.
    let across = |rows: std::ops::Range<usize>, pick: fn(f32, f32) -> f32| {
        let mut out = guide.data()[rows.start * stride..rows.end * stride].to_vec();
        for (out, row) in out
            .chunks_mut(stride)
            .zip(guide.data()[rows.start * stride..].chunks(stride))
        {
            for s in (1..=r.min(w - 1)).map(|d| c * d) {
                for (o, &v) in out[..stride - s].iter_mut().zip(&row[s..]) {
                    *o = pick(*o, v);
                }
                for (o, &v) in out[s..].iter_mut().zip(&row[..stride - s]) {
                    *o = pick(*o, v);
                }
            }
        }
        out
    };
    meter.pass(h);
    img.data_mut()
        .par_chunks_mut(stride * band_rows)
        .enumerate()
        .for_each(|(band, rows)| {
            if meter.cancelled() {
                return;
            }
            let y0 = band * band_rows;
            let y1 = (y0 + band_rows).min(h);
            meter.rows(y1 - y0);
            let reach = y0.saturating_sub(r)..(y1 + r).min(h);
            let (lo_rows, hi_rows) = (
                across(reach.clone(), f32::min),
                across(reach.clone(), f32::max),
            );
            let span = |yy: usize| (yy - reach.start) * stride..(yy - reach.start + 1) * stride;
            // One output row's window minima and maxima, rewritten row by row.
            let (mut lo, mut hi) = (vec![0.0f32; stride], vec![0.0f32; stride]);
            for (y, row) in (y0..y1).zip(rows.chunks_mut(stride)) {
                lo.copy_from_slice(&lo_rows[span(y)]);
                hi.copy_from_slice(&hi_rows[span(y)]);
                for yy in (y.saturating_sub(r)..=(y + r).min(h - 1)).filter(|&yy| yy != y) {
                    for ((l, h), (&a, &b)) in lo
                        .iter_mut()
                        .zip(hi.iter_mut())
                        .zip(lo_rows[span(yy)].iter().zip(&hi_rows[span(yy)]))
                    {
                        *l = l.min(a);
                        *h = h.max(b);
                    }
                }
                for ((v, &l), &h) in row.iter_mut().zip(&lo).zip(&hi) {
                    *v = v.clamp(l, h);
                }
            }
        });
}

/// Laplacian blending of denoised levels `d[0]` (finest) … `d[L]` (coarsest), in domain T:
/// T(R_L) = T(D_L); T(R_l) = b_l·(T(D_l) − EXPAND(T(REDUCE(D_l)))) + EXPAND(T(R_{l+1})), clamped at 0.
///
/// Written as a correction, T(R_l) = b_l·T(D_l) + (1 − b_l)·EXPAND(T(REDUCE(D_l))) + EXPAND(C) with
/// C = T(R_{l+1}) − T(REDUCE(D_l)); with `guided`, C is expanded by [`guided_expand`]. REDUCE is the
/// linear one that built the pyramid, so an untouched pyramid (R_{l+1} = REDUCE(D_l), C = 0) gives back
/// D_0 in every mode. `band_weights[l]` (default 1) scales the detail band of level l.
/// The levels are taken, not borrowed: each is brought into the blend domain in its own memory.
pub fn blend(
    d: Vec<Image>,
    band_weights: &[f32],
    domain: BlendDomain,
    guided: bool,
    clamp_radius: Option<usize>,
) -> Result<Image> {
    blend_metered(
        d,
        band_weights,
        domain,
        guided,
        clamp_radius,
        &Meter::default(),
    )
}

/// [`blend`] that ends with `Err(Cancelled)` between its passes (and skips the rows of its
/// row loops) once `meter` is cancelled.
pub fn blend_metered(
    mut d: Vec<Image>,
    band_weights: &[f32],
    domain: BlendDomain,
    guided: bool,
    clamp_radius: Option<usize>,
    meter: &Meter,
) -> Result<Image> {
    let last = d
        .len()
        .checked_sub(1)
        .ok_or_else(|| Error::Runtime("blend of no levels".into()))?;
    let mut r = d.pop().expect("at least one level");
    if last == 0 {
        // One level is its own reconstruction (R_0 = D_0): no round trip through the blend domain.
        r.data_mut().iter_mut().for_each(|v| *v = v.max(0.0));
        return Ok(r);
    }
    domain.forward(&mut r);
    for l in (0..last).rev() {
        meter.check()?;
        let mut fine = d.pop().expect("one image per level");
        let (w, h) = fine.dims();
        let mut reduced = reduce(&fine)?;
        meter.check()?;
        domain.forward(&mut reduced);
        domain.forward(&mut fine);
        meter.check()?;
        let mut correction = r;
        for (v, &lo) in correction.data_mut().iter_mut().zip(reduced.data()) {
            *v -= lo;
        }
        let up = if guided {
            guided_expand(&correction, &fine, &reduced, meter)
        } else {
            expand(&correction, w, h)?
        };
        meter.check()?;
        let b = band_weights.get(l).copied().unwrap_or(1.0);
        // The sum is formed in `up`'s memory, so `fine` stays as the clamp's guide without a copy.
        let mut next = up;
        if b != 1.0 {
            let low = expand(&reduced, w, h)?;
            for ((v, &f), &lo) in next.data_mut().iter_mut().zip(fine.data()).zip(low.data()) {
                *v += b * f + (1.0 - b) * lo;
            }
        } else {
            for (v, &f) in next.data_mut().iter_mut().zip(fine.data()) {
                *v += f;
            }
        }
        meter.check()?;
        if let Some(radius) = clamp_radius {
            clamp_to_neighbourhood(&mut next, &fine, radius, meter);
        }
        meter.check()?;
        r = next;
    }
    domain.inverse(&mut r);
    r.data_mut().iter_mut().for_each(|v| *v = v.max(0.0));
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filters::pyramid::levels::allowed_levels;
    use crate::filters::pyramid::levels::tests::ramp;

    #[test]
    fn the_neighbourhood_clamp_is_the_windows_min_and_max() {
        for (w, h) in [(1, 1), (1, 6), (7, 1), (5, 9), (13, 4)] {
            for r in 1..=3 {
                let guide =
                    Image::from_fn(w, h, 3, |x, y, c| ((x * 31 + y * 17 + c * 7) % 11) as f32);
                let img =
                    Image::from_fn(w, h, 3, |x, y, c| ((x * 5 + y * 3 + c) % 13) as f32 - 1.0);
                for band_rows in [1, 2, 3, CLAMP_BAND_ROWS] {
                    let mut got = img.clone();
                    clamp_in_bands(&mut got, &guide, r, band_rows, &Meter::default());
                    for y in 0..h {
                        for x in 0..w {
                            for c in 0..3 {
                                let cells =
                                    (y.saturating_sub(r)..=(y + r).min(h - 1)).flat_map(|yy| {
                                        (x.saturating_sub(r)..=(x + r).min(w - 1))
                                            .map(move |xx| (xx, yy))
                                    });
                                let values: Vec<f32> =
                                    cells.map(|(xx, yy)| guide.at(xx, yy)[c]).collect();
                                let lo = values.iter().copied().fold(f32::INFINITY, f32::min);
                                let hi = values.iter().copied().fold(f32::NEG_INFINITY, f32::max);
                                let want = img.at(x, y)[c].clamp(lo, hi);
                                assert_eq!(
                                    got.at(x, y)[c],
                                    want,
                                    "{w}x{h} r {r}, {band_rows} rows a band, at ({x}, {y}, {c})"
                                );
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn untouched_pyramid_reconstructs_its_input() {
        for (w, h, levels) in [(37, 23, 4), (1, 1, 3), (64, 64, 5), (5, 9, 3)] {
            let img = ramp(w, h);
            let n = allowed_levels(w, h, levels);
            let mut levels_imgs = vec![img.clone()];
            for _ in 1..n {
                let next = reduce(levels_imgs.last().unwrap()).unwrap();
                levels_imgs.push(next);
            }
            for (domain, guided) in [
                (BlendDomain::Linear, false),
                (BlendDomain::Log, false),
                (BlendDomain::Log, true),
            ] {
                let out = blend(levels_imgs.clone(), &[], domain, guided, Some(1)).unwrap();
                let max_rel = out
                    .data()
                    .iter()
                    .zip(img.data())
                    .map(|(a, b)| ((a - b) / b.abs().max(1e-6)).abs())
                    .fold(0.0f32, f32::max);
                assert!(
                    max_rel < 1e-5,
                    "{w}x{h} {domain:?} guided {guided}: {max_rel}"
                );
            }
        }
    }
}
