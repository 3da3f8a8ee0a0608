//! The windowed variances of the gate: the noise, read from directional second differences, and
//! the signal, read from the medians.

use rayon::prelude::*;

use crate::error::Result;
use crate::image::par_vec;
use crate::kernels::padded::{edge_padded_line, Padded};
use crate::meter::Meter;

/// The four directions a pixel's noise is read along: horizontal, vertical, the two diagonals.
pub(super) const DIRECTIONS: [(isize, isize); 4] = [(1, 0), (0, 1), (1, 1), (1, -1)];

/// `along` of a pixel whose window has no direction of its own.
pub(super) const NO_DIRECTION: u8 = 4;
/// A window has a direction when its least varying direction varies less than this share of its
/// most varying one: over independent Gaussian noise, 5 % of 7×7 windows fall below a half (and 1 %
/// below 0.42), so noise is read as having no direction 19 times in 20.
const ISOTROPIC: f64 = 0.5;

/// The noise variance of every pixel, summed over the channels: the window's mean squared second
/// difference along the direction in which it is smallest, over 6; and that direction (an index
/// into [`DIRECTIONS`], one for all channels: a surface's structure runs one way in all of them).
pub(super) fn noise_variance(
    src: &Padded,
    (w, h): (usize, usize),
    radius: usize,
    meter: &Meter,
) -> Result<(Vec<f64>, Vec<u8>)> {
    let mut best = par_vec(f64::INFINITY, w * h);
    let mut worst = par_vec(0.0f64, w * h);
    let mut near_best = par_vec(f64::INFINITY, w * h);
    let mut along = par_vec(0u8, w * h);
    let mut sq = par_vec(0.0, w * h);
    for (d, (dx, dy)) in DIRECTIONS.into_iter().enumerate() {
        meter.step()?;
        sq.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            row.fill(0.0);
            let (at, ahead, behind) = (
                src.at(0, y, (0, 0)),
                src.at(0, y, (dx, dy)),
                src.at(0, y, (-dx, -dy)),
            );
            for plane in &src.planes {
                let (c, a, b) = (
                    &plane[at..at + w],
                    &plane[ahead..ahead + w],
                    &plane[behind..behind + w],
                );
                for x in 0..w {
                    let d = a[x] + b[x] - 2.0 * c[x];
                    row[x] += d * d;
                }
            }
        });
        meter.step()?;
        let mean = box_mean(&sq, (w, h), radius);
        best.par_iter_mut()
            .zip(worst.par_iter_mut())
            .zip(mean.par_iter())
            .for_each(|((b, wst), &m)| {
                *b = b.min(m / 6.0);
                *wst = wst.max(m / 6.0);
            });
        meter.step()?;
        let near = box_mean(&sq, (w, h), 1);
        near_best
            .par_iter_mut()
            .zip(along.par_iter_mut())
            .zip(near.par_iter())
            .for_each(|((b, a), &m)| {
                // Strictly smaller: a tie keeps the earlier direction, the same on every run.
                if m < *b {
                    *b = m;
                    *a = d as u8;
                }
            });
    }
    // No direction where the window varies alike in all four (noise, or a texture with no grain).
    along
        .par_iter_mut()
        .zip(best.par_iter().zip(worst.par_iter()))
        .for_each(|(a, (&b, &wst))| {
            if b >= ISOTROPIC * wst {
                *a = NO_DIRECTION;
            }
        });
    Ok((best, along))
}

/// The variance over every pixel's window of the channels' medians, summed over the channels.
pub(super) fn signal_variance(
    medians: &[Vec<f64>],
    (w, h): (usize, usize),
    radius: usize,
    meter: &Meter,
) -> Result<Vec<f64>> {
    let mut squares = par_vec(0.0, w * h);
    for m in medians {
        squares
            .par_iter_mut()
            .zip(m.par_iter())
            .for_each(|(s, &v)| *s += v * v);
    }
    meter.step()?;
    let mut var = box_mean(&squares, (w, h), radius);
    for m in medians {
        meter.step()?;
        let mean = box_mean(m, (w, h), radius);
        var.par_iter_mut()
            .zip(mean.par_iter())
            .for_each(|(v, &m)| *v -= m * m);
    }
    var.par_iter_mut().for_each(|v| *v = v.max(0.0));
    Ok(var)
}

/// The mean of every pixel's (2r+1)² window, edges replicated: along the rows (a row copied with
/// r edge cells each side), then down the columns (whole rows added, clamped at the edges).
pub(super) fn box_mean(v: &[f64], (w, h): (usize, usize), radius: usize) -> Vec<f64> {
    let n = (2 * radius + 1) as f64;
    let mut rows = par_vec(0.0, w * h);
    // One padded line per worker, not one allocation per row.
    rows.par_chunks_mut(w)
        .enumerate()
        .for_each_init(Vec::new, |line, (y, out)| {
            let src = &v[y * w..(y + 1) * w];
            edge_padded_line(line, src, radius);
            for t in 0..=2 * radius {
                for (o, &s) in out.iter_mut().zip(&line[t..t + w]) {
                    *o += s;
                }
            }
        });
    let mut out = par_vec(0.0, w * h);
    let r = radius as isize;
    out.par_chunks_mut(w).enumerate().for_each(|(y, out)| {
        for dy in -r..=r {
            let yy = (y as isize + dy).clamp(0, h as isize - 1) as usize;
            for (o, &s) in out.iter_mut().zip(&rows[yy * w..(yy + 1) * w]) {
                *o += s;
            }
        }
        for o in out.iter_mut() {
            *o /= n * n;
        }
    });
    out
}
