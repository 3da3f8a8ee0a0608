//! The windowed variances of the gate: the noise, read from directional second differences, and
//! the signal, read from the medians.

use rayon::prelude::*;

use crate::error::Result;
use crate::image::par_vec;
use crate::kernels::padded::{edge_padded_line, Padded};
use crate::kernels::simd::{row_kernel, Kernel};
use crate::meter::Meter;

/// The four directions a pixel's noise is read along: horizontal, vertical, the two diagonals.
pub(super) const DIRECTIONS: [(isize, isize); 4] = [(1, 0), (0, 1), (1, 1), (1, -1)];

/// `along` of a pixel whose window has no direction of its own.
pub(super) const NO_DIRECTION: u8 = 4;
/// A window has a direction when its least varying direction varies less than this share of its
/// most varying one: over independent Gaussian noise, 5 % of 7×7 windows fall below a half (and 1 %
/// below 0.42), so noise is read as having no direction 19 times in 20.
const ISOTROPIC: f64 = 0.5;

/// Rows a task of the fused passes computes at once: its row sums (with `radius` rows either side)
/// stay in cache between the row and the column pass, instead of a whole image of them going
/// through memory for every direction.
const BAND: usize = 16;

/// The noise variance of every pixel, summed over the channels: the window's mean squared second
/// difference along the direction in which it is smallest, over 6; and that direction (an index
/// into [`DIRECTIONS`], one for all channels: a surface's structure runs one way in all of them).
/// Computed in bands of [`BAND`] rows, each pixel's sums in the same order of additions whatever
/// the band: the same bits as the per-pixel definition (tested), on any thread count.
pub(super) fn noise_variance(
    src: &Padded,
    (w, h): (usize, usize),
    radius: usize,
    meter: &Meter,
) -> Result<(Vec<f64>, Vec<u8>)> {
    meter.step()?;
    let mut best = par_vec(f64::INFINITY, w * h);
    let mut along = par_vec(0u8, w * h);
    let r = radius;
    best.par_chunks_mut(BAND * w.max(1))
        .zip(along.par_chunks_mut(BAND * w.max(1)))
        .enumerate()
        .for_each(|(band, (best, along))| {
            if meter.cancelled() {
                return;
            }
            let (kernel, y0) = (Kernel::detect(), band * BAND);
            row_kernel!(kernel, noise_band(src: &Padded, w: usize, h: usize, r: usize, y0: usize, best: &mut [f64], along: &mut [u8]));
        });
    meter.check()?;
    Ok((best, along))
}

/// [`noise_variance`] of the rows from `y0` on that `best` and `along` hold.
#[inline(always)]
fn noise_band(
    src: &Padded,
    w: usize,
    h: usize,
    r: usize,
    y0: usize,
    best: &mut [f64],
    along: &mut [u8],
) {
    let rows = best.len() / w;
    let m = r.max(1);
    // Row sums of the rows y0 − m … y0 + rows + m − 1, each the clamped row's.
    let span = rows + 2 * m;
    let mut wide = vec![0.0f64; span * w];
    let mut near = vec![0.0f64; span * w];
    let mut worst = vec![0.0f64; rows * w];
    let mut near_best = vec![f64::INFINITY; rows * w];
    let (mut sq, mut line) = (vec![0.0f64; w], Vec::new());
    let (mut col_wide, mut col_near) = (Vec::new(), Vec::new());
    let clamp = |y: isize| y.clamp(0, h as isize - 1) as usize;
    for (d, (dx, dy)) in DIRECTIONS.into_iter().enumerate() {
        for j in 0..span {
            let y = clamp(y0 as isize - m as isize + j as isize);
            sq.fill(0.0);
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
                    sq[x] += d * d;
                }
            }
            edge_padded_line(&mut line, &sq, m);
            row_sum(&mut wide[j * w..(j + 1) * w], &line[m - r..], r);
            row_sum(&mut near[j * w..(j + 1) * w], &line[m - 1..], 1);
        }
        for t in 0..rows {
            // Local row of image row y0 + t + dy is t + m + dy.
            column_mean(&mut col_wide, &wide, (w, span), t + m, r);
            column_mean(&mut col_near, &near, (w, span), t + m, 1);
            let o = t * w;
            for x in 0..w {
                let mean = col_wide[x];
                best[o + x] = best[o + x].min(mean / 6.0);
                worst[o + x] = worst[o + x].max(mean / 6.0);
                // Strictly smaller: a tie keeps the earlier direction, the same on every run.
                if col_near[x] < near_best[o + x] {
                    near_best[o + x] = col_near[x];
                    along[o + x] = d as u8;
                }
            }
        }
    }
    // No direction where the window varies alike in all four (noise, or a texture with no grain).
    for ((a, &b), &wst) in along.iter_mut().zip(best.iter()).zip(&worst) {
        if b >= ISOTROPIC * wst {
            *a = NO_DIRECTION;
        }
    }
}

/// The variance over every pixel's window of the channels' medians, summed over the channels: the
/// window mean of the squares (summed over the channels) less each channel's squared window mean,
/// each window mean as [`box_mean`] adds it, computed in bands of [`BAND`] rows (the same bits).
pub(super) fn signal_variance(
    medians: &[Vec<f64>],
    (w, h): (usize, usize),
    radius: usize,
    meter: &Meter,
) -> Result<Vec<f64>> {
    meter.step()?;
    let mut var = par_vec(0.0, w * h);
    let r = radius;
    var.par_chunks_mut(BAND * w.max(1))
        .enumerate()
        .for_each(|(band, var)| {
            if meter.cancelled() {
                return;
            }
            let (kernel, y0) = (Kernel::detect(), band * BAND);
            row_kernel!(kernel, signal_band(medians: &[Vec<f64>], w: usize, h: usize, r: usize, y0: usize, var: &mut [f64]));
        });
    meter.check()?;
    Ok(var)
}

/// [`signal_variance`] of the rows from `y0` on that `var` holds.
#[inline(always)]
fn signal_band(medians: &[Vec<f64>], w: usize, h: usize, r: usize, y0: usize, var: &mut [f64]) {
    let rows = var.len() / w;
    let span = rows + 2 * r;
    let clamp =
        |j: usize| (y0 as isize - r as isize + j as isize).clamp(0, h as isize - 1) as usize;
    // Row sums of the band's rows and r either side: the squares' first, then each channel's.
    let mut sums = vec![vec![0.0f64; span * w]; 1 + medians.len()];
    let (mut line, mut squares) = (Vec::new(), vec![0.0f64; w]);
    for j in 0..span {
        let y = clamp(j);
        squares.fill(0.0);
        for m in medians {
            for (s, &v) in squares.iter_mut().zip(&m[y * w..(y + 1) * w]) {
                *s += v * v;
            }
        }
        let planes =
            std::iter::once(&squares[..]).chain(medians.iter().map(|m| &m[y * w..(y + 1) * w]));
        for (plane, out) in planes.zip(sums.iter_mut()) {
            edge_padded_line(&mut line, plane, r);
            row_sum(&mut out[j * w..(j + 1) * w], &line, r);
        }
    }
    let (mut sum, mut mean) = (Vec::new(), Vec::new());
    for t in 0..rows {
        column_mean(&mut sum, &sums[0], (w, span), t + r, r);
        for plane in &sums[1..] {
            column_mean(&mut mean, plane, (w, span), t + r, r);
            for (s, &m) in sum.iter_mut().zip(mean.iter()) {
                *s -= m * m;
            }
        }
        for (v, &s) in var[t * w..(t + 1) * w].iter_mut().zip(sum.iter()) {
            *v = s.max(0.0);
        }
    }
}

/// The mean of every pixel's (2r+1)² window, edges replicated: along the rows (a row copied with
/// r edge cells each side), then down the columns (whole rows added, clamped at the edges).
pub(super) fn box_mean(v: &[f64], (w, h): (usize, usize), radius: usize) -> Vec<f64> {
    let rows = row_sums(v, w, radius);
    let mut out = par_vec(0.0, w * h);
    out.par_chunks_mut(w)
        .enumerate()
        .for_each_init(Vec::new, |sum, (y, out)| {
            column_mean(sum, &rows, (w, h), y, radius);
            out.copy_from_slice(sum);
        });
    out
}

/// Every pixel's sum over its row's 2r + 1 pixels, edges replicated ([`row_sum`] a row).
fn row_sums(v: &[f64], w: usize, radius: usize) -> Vec<f64> {
    let mut rows = par_vec(0.0, v.len());
    // One padded line per worker, not one allocation per row.
    rows.par_chunks_mut(w)
        .enumerate()
        .for_each_init(Vec::new, |line, (y, out)| {
            edge_padded_line(line, &v[y * w..(y + 1) * w], radius);
            row_sum(out, line, radius);
        });
    rows
}

/// `out[x]`: the sum of `line[x..=x + 2r]`, added in that order from 0.
#[inline(always)]
fn row_sum(out: &mut [f64], line: &[f64], radius: usize) {
    let w = out.len();
    out.fill(0.0);
    for t in 0..=2 * radius {
        for (o, &s) in out.iter_mut().zip(&line[t..t + w]) {
            *o += s;
        }
    }
}

/// Into `out` (resized to a row), row y's mean over rows y − r … y + r of `rows` (row sums over
/// 2r + 1 pixels), rows clamped at the edges, added in that order from 0.
#[inline(always)]
fn column_mean(out: &mut Vec<f64>, rows: &[f64], (w, h): (usize, usize), y: usize, radius: usize) {
    let n = (2 * radius + 1) as f64;
    let r = radius as isize;
    out.clear();
    out.resize(w, 0.0);
    for dy in -r..=r {
        let yy = (y as isize + dy).clamp(0, h as isize - 1) as usize;
        for (o, &s) in out.iter_mut().zip(&rows[yy * w..(yy + 1) * w]) {
            *o += s;
        }
    }
    for o in out.iter_mut() {
        *o /= n * n;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::padded::Margin;

    /// The window mean of `f` at (x, y) pixel by pixel, coordinates clamped, in the fused passes'
    /// order of additions (each row's sum, then the rows down the window).
    fn window_mean(
        f: impl Fn(usize, usize) -> f64,
        (w, h): (usize, usize),
        (x, y): (usize, usize),
        r: usize,
    ) -> f64 {
        let (r, n) = (r as isize, (2 * r + 1) as f64);
        let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
        let mut sum = 0.0;
        for dy in -r..=r {
            let mut row = 0.0;
            for dx in -r..=r {
                row += f(clamp(x as isize + dx, w), clamp(y as isize + dy, h));
            }
            sum += row;
        }
        sum / (n * n)
    }

    #[test]
    fn the_fused_passes_give_the_per_pixel_variances_bit_for_bit() {
        for (w, h) in [(1, 1), (2, 5), (7, 3), (13, 11), (5, 37), (1, 17)] {
            let value = |i: usize, k: usize| ((i * 37 + k * 11) % 17) as f64 / 8.0 - 0.9;
            let src = Padded::new((w, h), 2, 2, Margin::Edge, value);
            let meter = Meter::default();
            for radius in [1, 3] {
                let (noise, along) = noise_variance(&src, (w, h), radius, &meter).unwrap();
                let medians: Vec<Vec<f64>> = (0..2)
                    .map(|k| (0..w * h).map(|i| value(i, k) * 0.5).collect())
                    .collect();
                let signal = signal_variance(&medians, (w, h), radius, &meter).unwrap();
                for (i, ((&n, &a), &s)) in noise.iter().zip(&along).zip(&signal).enumerate() {
                    let (x, y) = (i % w, i / w);
                    let (mut best, mut worst, mut near, mut dir) =
                        (f64::INFINITY, 0.0f64, f64::INFINITY, 0);
                    for (d, (dx, dy)) in DIRECTIONS.into_iter().enumerate() {
                        let sq = |x: usize, y: usize| -> f64 {
                            src.planes
                                .iter()
                                .map(|p| {
                                    let e = p[src.at(x, y, (dx, dy))] + p[src.at(x, y, (-dx, -dy))]
                                        - 2.0 * p[src.at(x, y, (0, 0))];
                                    e * e
                                })
                                .fold(0.0, |a, b| a + b)
                        };
                        let m = window_mean(sq, (w, h), (x, y), radius) / 6.0;
                        best = best.min(m);
                        worst = worst.max(m);
                        let m1 = window_mean(sq, (w, h), (x, y), 1);
                        if m1 < near {
                            near = m1;
                            dir = d as u8;
                        }
                    }
                    if best >= ISOTROPIC * worst {
                        dir = NO_DIRECTION;
                    }
                    assert_eq!(
                        (n.to_bits(), a),
                        (best.to_bits(), dir),
                        "{w}x{h} r{radius} ({x}, {y})"
                    );
                    let squares = |x: usize, y: usize| {
                        medians
                            .iter()
                            .fold(0.0, |a, m| a + m[y * w + x] * m[y * w + x])
                    };
                    let mut var = window_mean(squares, (w, h), (x, y), radius);
                    for m in &medians {
                        let mean = window_mean(|x, y| m[y * w + x], (w, h), (x, y), radius);
                        var -= mean * mean;
                    }
                    assert_eq!(
                        s.to_bits(),
                        var.max(0.0).to_bits(),
                        "{w}x{h} r{radius} ({x}, {y})"
                    );
                }
            }
        }
    }
}
