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
    // Each pixel's squared second differences summed along its row over the window's width and
    // over 3 pixels, reused by every direction: the box means of `box_mean`, in its order of
    // additions, without a full-image pass and an allocation for each.
    let mut rows_wide = par_vec(0.0, w * h);
    let mut rows_near = par_vec(0.0, w * h);
    let (r, m) = (radius, radius.max(1));
    for (d, (dx, dy)) in DIRECTIONS.into_iter().enumerate() {
        meter.step()?;
        rows_wide
            .par_chunks_mut(w)
            .zip(rows_near.par_chunks_mut(w))
            .enumerate()
            .for_each_init(
                || (Vec::new(), Vec::new()),
                |(sq, line), (y, (wide, near))| {
                    sq.clear();
                    sq.resize(w, 0.0);
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
                    edge_padded_line(line, sq, m);
                    row_sum(wide, &line[m - r..], r);
                    row_sum(near, &line[m - 1..], 1);
                },
            );
        meter.step()?;
        let (rows_wide, rows_near) = (&rows_wide, &rows_near);
        best.par_chunks_mut(w)
            .zip(worst.par_chunks_mut(w))
            .zip(near_best.par_chunks_mut(w))
            .zip(along.par_chunks_mut(w))
            .enumerate()
            .for_each_init(
                || (Vec::new(), Vec::new()),
                |(wide, near), (y, (((b, wst), nb), a))| {
                    column_mean(wide, rows_wide, (w, h), y, r);
                    column_mean(near, rows_near, (w, h), y, 1);
                    for x in 0..w {
                        let m = wide[x];
                        b[x] = b[x].min(m / 6.0);
                        wst[x] = wst[x].max(m / 6.0);
                        // Strictly smaller: a tie keeps the earlier direction, the same on every run.
                        if near[x] < nb[x] {
                            nb[x] = near[x];
                            a[x] = d as u8;
                        }
                    }
                },
            );
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

/// The variance over every pixel's window of the channels' medians, summed over the channels: the
/// window mean of the squares (summed over the channels) less each channel's squared window mean,
/// each window mean as [`box_mean`] adds it, in one column pass over all the row sums.
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
    // Row sums: the squares' first, then each channel's.
    let rows: Vec<Vec<f64>> = std::iter::once(&squares)
        .chain(medians)
        .map(|plane| row_sums(plane, w, radius))
        .collect();
    meter.step()?;
    let mut var = par_vec(0.0, w * h);
    var.par_chunks_mut(w).enumerate().for_each_init(
        || (Vec::new(), Vec::new()),
        |(sum, mean), (y, var)| {
            column_mean(sum, &rows[0], (w, h), y, radius);
            for plane in &rows[1..] {
                column_mean(mean, plane, (w, h), y, radius);
                for (s, &m) in sum.iter_mut().zip(mean.iter()) {
                    *s -= m * m;
                }
            }
            for (v, &s) in var.iter_mut().zip(sum.iter()) {
                *v = s.max(0.0);
            }
        },
    );
    Ok(var)
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
        for (w, h) in [(1, 1), (2, 5), (7, 3), (13, 11)] {
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
