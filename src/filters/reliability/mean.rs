//! The surface mean: what a noisy feature pixel is pulled to is the mean of its own surface's
//! samples, not their median.
//!
//! A feature buffer's reference is the mean of every sample the pixel would take. Where those
//! samples see two things in proportion (fog's medium and the surface behind it), the median of a
//! window picks whichever is the majority there, so it turns the salt and pepper into blotches of
//! one or the other, and the blotches guide every later stage as if they were texture. The mean
//! of the window's raw samples is the proportion itself. It is taken only over the pixel's own
//! surface: each neighbour weighs `exp(−‖g_i − g_j‖² / (2·k·n_i²))`, `g` the gated buffer (which
//! already differs between two pixels only where the surface does), `n_i²` the pixel's noise
//! reading and `k` the pair noise (a difference of two pixels carries the noise of both). A pixel
//! whose noise reads 0 keeps its gated value, so a clean buffer passes unchanged.

use rayon::prelude::*;

use crate::error::Result;
use crate::image::par_vec;
use crate::kernels::padded::{Margin, Padded};
use crate::meter::Meter;

/// Each pixel's surface mean of `raw` (unpadded planes, one a channel) over a (2r+1)² window
/// (edges replicated), its neighbours weighed by their likeness in `gated` against the pixel's
/// `noise` (summed over channels). Sums in f64 in a fixed order per pixel.
pub(super) fn surface_mean(
    raw: &[Vec<f64>],
    gated: &[Vec<f64>],
    noise: &[f64],
    (w, h): (usize, usize),
    (radius, pair_noise): (usize, f64),
    meter: &Meter,
) -> Result<Vec<Vec<f64>>> {
    meter.step()?;
    let pad = |planes: &[Vec<f64>]| {
        Padded::new((w, h), planes.len(), radius, Margin::Edge, |i, k| {
            planes[k][i]
        })
    };
    let (raw_p, gated_p) = (pad(raw), pad(gated));
    let c = raw.len();
    let r = radius as isize;
    let mut flat = par_vec(0.0f64, w * h * c);
    meter.step()?;
    flat.par_chunks_mut(w * c).enumerate().for_each(|(y, row)| {
        let mut sums = vec![0.0f64; c];
        for x in 0..w {
            let i = y * w + x;
            let px = &mut row[x * c..(x + 1) * c];
            let scale = 2.0 * pair_noise * noise[i];
            if !(scale > 0.0) {
                for (k, v) in px.iter_mut().enumerate() {
                    *v = gated[k][i];
                }
                continue;
            }
            sums.fill(0.0);
            let mut total = 0.0;
            for dy in -r..=r {
                for dx in -r..=r {
                    let at = gated_p.at(x, y, (dx, dy));
                    let d2: f64 = (0..c)
                        .map(|k| {
                            let d = gated_p.planes[k][at] - gated[k][i];
                            d * d
                        })
                        .sum();
                    let weight = (-d2 / scale).exp();
                    total += weight;
                    for (k, s) in sums.iter_mut().enumerate() {
                        *s += weight * raw_p.planes[k][at];
                    }
                }
            }
            for (v, s) in px.iter_mut().zip(&sums) {
                *v = s / total;
            }
        }
    });
    Ok((0..c)
        .map(|k| (0..w * h).map(|i| flat[i * c + k]).collect())
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(raw: &[f64], gated: &[f64], noise: &[f64], w: usize) -> Vec<f64> {
        let h = raw.len() / w;
        let out = surface_mean(
            &[raw.to_vec()],
            &[gated.to_vec()],
            noise,
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
        // every pixel to the majority. The mean is the mix, 0.2 + (0.9 − 0.2)/3.
        let raw: Vec<f64> = (0..144)
            .map(|i| if i % 3 == 0 { 0.9 } else { 0.2 })
            .collect();
        let out = run(&raw, &[0.2; 144], &[0.05; 144], 12);
        let want = 0.2 + 0.7 / 3.0;
        for y in 3..9 {
            for x in 3..9 {
                let v = out[y * 12 + x];
                assert!((v - want).abs() < 0.03, "({x}, {y}) = {v}, want {want}");
            }
        }
    }

    #[test]
    fn an_edge_of_the_gated_buffer_keeps_its_sides_apart() {
        // Two surfaces, 0.1 and 0.8, with noise far below the step: no side borrows the other.
        let raw: Vec<f64> = (0..100)
            .map(|i| if i % 10 < 5 { 0.1 } else { 0.8 })
            .collect();
        let out = run(&raw, &raw, &[1e-4; 100], 10);
        for (a, b) in out.iter().zip(&raw) {
            assert!((a - b).abs() < 1e-6, "{a} against {b}");
        }
    }

    #[test]
    fn a_pixel_without_noise_keeps_its_gated_value() {
        let raw: Vec<f64> = (0..25).map(|i| i as f64).collect();
        let gated: Vec<f64> = (0..25).map(|i| 100.0 + i as f64).collect();
        assert_eq!(run(&raw, &gated, &[0.0; 25], 5), gated);
    }
}
