//! The surface mean: a noisy feature pixel is pulled towards the mean of its own surface's samples,
//! not only towards their median.
//!
//! A feature buffer's reference is the mean of every sample the pixel would take. Where those
//! samples see two things in proportion (fog's medium and the surface behind it), the median of a
//! window picks whichever is the majority there: the gate turns the salt and pepper into blotches of
//! one or the other, and the blotches guide every later stage as if they were texture. The mean of
//! the raw samples is the proportion itself. So after the gate, each pixel moves from its gated
//! value `g` towards its surface mean `μ` by `1 − ρ` (its unreliability): `g + (1 − ρ)(μ − g)`.
//!
//! `μ` averages the raw values of the pixel's window (along its direction when the window has one,
//! as the median does, so a line or an edge running that way is not averaged across), each weighed
//! `exp(−‖g_i − g_j‖² / (2·k·t_i))`: `g` already differs between two pixels only where the surface
//! does, `t_i` is the window mean of `‖x − g‖²`, the noise the gate took out around the pixel, and
//! `k` the pair noise (a difference of two pixels carries the noise of both). Where the gate took
//! nothing out (a clean buffer, or a line the directional median kept) `t` is 0 and the pixel keeps
//! its gated value. Sums in f64 in a fixed order per pixel: the same bits on any thread count.

use rayon::prelude::*;

use super::variance::{box_mean, DIRECTIONS, NO_DIRECTION};
use crate::error::Result;
use crate::image::par_vec;
use crate::kernels::padded::{Margin, Padded};
use crate::meter::Meter;

/// Squared distances over this many times a pixel's scale weigh nothing (e^−40).
const FAR: f64 = 40.0;

/// What the surface mean reads besides the buffers: per pixel, the reliability `rho` and the
/// window's direction `along` (an index into `DIRECTIONS`, or `NO_DIRECTION`).
pub(super) struct Reading<'a> {
    pub rho: &'a [f64],
    pub along: &'a [u8],
}

/// `gated` (planes, one a channel, unpadded) moved towards the surface mean of `raw` by each
/// pixel's unreliability, over a (2r+1)² window or its line (edges replicated).
pub(super) fn pull_to_surface_mean(
    raw: &[Vec<f64>],
    gated: &[Vec<f64>],
    reading: Reading,
    (w, h): (usize, usize),
    (radius, pair_noise): (usize, f64),
    meter: &Meter,
) -> Result<Vec<Vec<f64>>> {
    meter.step()?;
    let c = raw.len();
    let residual: Vec<f64> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            (0..c)
                .map(|k| (raw[k][i] - gated[k][i]).powi(2))
                .filter(|d| d.is_finite())
                .sum()
        })
        .collect();
    let taken = box_mean(&residual, (w, h), radius);
    let pad = |planes: &[Vec<f64>]| {
        Padded::new((w, h), planes.len(), radius, Margin::Edge, |i, k| {
            planes[k][i]
        })
    };
    let (raw_p, gated_p) = (pad(raw), pad(gated));
    // 1 where every channel of the raw sample is finite: a sample of a surface.
    let sample = Padded::new((w, h), 1, radius, Margin::Edge, |i, _| {
        f64::from(u8::from((0..c).all(|k| raw[k][i].is_finite())))
    });
    let r = radius as isize;
    let mut flat = par_vec(0.0f64, w * h * c);
    meter.step()?;
    flat.par_chunks_mut(w * c).enumerate().for_each(|(y, row)| {
        let mut sums = vec![0.0f64; c];
        for x in 0..w {
            let i = y * w + x;
            let px = &mut row[x * c..(x + 1) * c];
            for (k, v) in px.iter_mut().enumerate() {
                *v = gated[k][i];
            }
            let scale = 2.0 * pair_noise * taken[i];
            let pull = 1.0 - reading.rho[i];
            let finite = px.iter().all(|v| v.is_finite());
            if !(scale > 0.0 && scale.is_finite() && pull > 0.0 && finite) {
                continue;
            }
            sums.fill(0.0);
            let mut total = 0.0;
            // Beyond this squared distance a weight is below e^−40 (under 1e-17 of the pixel's
            // own, 1): skipped without its exponential.
            let far = FAR * scale;
            let mut tap = |at: usize| {
                // A distance of infinity (nothing hit) is no sample of a surface.
                if sample.planes[0][at] == 0.0 {
                    return;
                }
                let mut d2 = 0.0;
                for (plane, own) in gated_p.planes.iter().zip(gated) {
                    let d = plane[at] - own[i];
                    d2 += d * d;
                }
                // NaN included: a distance not below `far` weighs nothing.
                if d2.partial_cmp(&far) != Some(std::cmp::Ordering::Less) {
                    return;
                }
                let weight = (-d2 / scale).exp();
                if weight.is_nan() || weight <= 0.0 {
                    return;
                }
                total += weight;
                for (k, s) in sums.iter_mut().enumerate() {
                    *s += weight * raw_p.planes[k][at];
                }
            };
            match reading.along[i] {
                NO_DIRECTION => {
                    for dy in -r..=r {
                        for dx in -r..=r {
                            tap(gated_p.at(x, y, (dx, dy)));
                        }
                    }
                }
                d => {
                    let (dx, dy) = DIRECTIONS[d as usize];
                    for t in -r..=r {
                        tap(gated_p.at(x, y, (t * dx, t * dy)));
                    }
                }
            }
            if total > 0.0 {
                for (v, s) in px.iter_mut().zip(&sums) {
                    *v += pull * (s / total - *v);
                }
            }
        }
    });
    // Back to one plane a channel, in parallel.
    Ok((0..c)
        .map(|k| flat.par_chunks(c).map(|px| px[k]).collect())
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One channel, no direction anywhere, radius 2.
    fn run(raw: &[f64], gated: &[f64], rho: f64, w: usize) -> Vec<f64> {
        let h = raw.len() / w;
        let out = pull_to_surface_mean(
            &[raw.to_vec()],
            &[gated.to_vec()],
            Reading {
                rho: &vec![rho; raw.len()],
                along: &vec![NO_DIRECTION; raw.len()],
            },
            (w, h),
            (2, 2.0),
            &Meter::default(),
        )
        .unwrap();
        out.into_iter().next().unwrap()
    }

    #[test]
    fn a_two_valued_mix_becomes_its_proportion_not_its_majority() {
        // One sample in three sees the medium (0.9), the rest the surface (0.2); the gate pulled
        // every pixel to the majority. Unreliable pixels take the mix, 0.2 + (0.9 − 0.2)/3.
        let raw: Vec<f64> = (0..156)
            .map(|i| if i % 3 == 0 { 0.9 } else { 0.2 })
            .collect();
        let out = run(&raw, &[0.2; 156], 0.0, 13);
        let want = 0.2 + 0.7 / 3.0;
        for y in 3..9 {
            for x in 3..10 {
                let v = out[y * 13 + x];
                assert!((v - want).abs() < 0.03, "({x}, {y}) = {v}, want {want}");
            }
        }
        // A reliable pixel keeps its gated value.
        assert_eq!(run(&raw, &[0.2; 156], 1.0, 13), vec![0.2; 156]);
    }

    #[test]
    fn an_edge_of_the_gated_buffer_keeps_its_sides_apart() {
        // Two surfaces, 0.1 and 0.8, their samples scattered by ±0.02 that the gate took out.
        let raw: Vec<f64> = (0..100)
            .map(|i| if i % 10 < 5 { 0.1 } else { 0.8 } + if i % 2 == 0 { 0.02 } else { -0.02 })
            .collect();
        let gated: Vec<f64> = (0..100)
            .map(|i| if i % 10 < 5 { 0.1 } else { 0.8 })
            .collect();
        let out = run(&raw, &gated, 0.0, 10);
        for (a, b) in out.iter().zip(&gated) {
            assert!((a - b).abs() < 0.021, "{a} against {b}");
        }
    }

    #[test]
    fn where_the_gate_took_nothing_the_gated_value_stays() {
        let raw: Vec<f64> = (0..25).map(|i| i as f64).collect();
        assert_eq!(run(&raw, &raw, 0.0, 5), raw);
    }

    #[test]
    fn a_line_the_window_runs_along_is_not_averaged_across() {
        // A 1-pixel vertical line (0.8) on 0.3, its samples scattered; the window runs along it.
        let (w, h) = (9, 9);
        let raw: Vec<f64> = (0..w * h)
            .map(|i| if i % w == 4 { 0.8 } else { 0.3 } + if i % 3 == 0 { 0.05 } else { 0.0 })
            .collect();
        let gated: Vec<f64> = (0..w * h)
            .map(|i| if i % w == 4 { 0.8 } else { 0.3 })
            .collect();
        let out = pull_to_surface_mean(
            &[raw],
            &[gated],
            Reading {
                rho: &vec![0.0; w * h],
                along: &vec![1; w * h],
            },
            (w, h),
            (2, 2.0),
            &Meter::default(),
        )
        .unwrap();
        for y in 0..h {
            assert!(out[0][y * w + 4] > 0.79, "row {y}: {}", out[0][y * w + 4]);
            assert!(out[0][y * w + 3] < 0.37, "row {y}: {}", out[0][y * w + 3]);
        }
    }
}
