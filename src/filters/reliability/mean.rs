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
use crate::kernels::simd::{row_kernel, Kernel};
use crate::meter::Meter;

/// Squared distances over this many times a pixel's scale weigh nothing (e^−40).
const FAR: f64 = 40.0;

/// What the surface mean reads besides the buffers: per pixel, the reliability `rho` and the
/// window's direction `along` (an index into `DIRECTIONS`, or `NO_DIRECTION`).
#[derive(Clone, Copy)]
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
    let taken = box_mean(&residual(raw, gated), (w, h), radius);
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
    let mut flat = par_vec(0.0f64, w * h * c);
    meter.step()?;
    let planes = Planes {
        raw,
        gated,
        raw_p: &raw_p,
        gated_p: &gated_p,
        sample: &sample,
        reading: &reading,
        taken: &taken,
        w,
        radius,
        pair_noise,
    };
    let kernel = Kernel::detect();
    flat.par_chunks_mut(w * c)
        .enumerate()
        .for_each_init(Row::default, |scratch, (y, row)| {
            let planes = &planes;
            row_kernel!(kernel, mean_row(planes: &Planes, y: usize, scratch: &mut Row, row: &mut [f64]));
        });
    // Back to one plane a channel, in parallel.
    Ok((0..c)
        .map(|k| flat.par_chunks(c).map(|px| px[k]).collect())
        .collect())
}

/// What [`mean_row`] reads: unpadded raw and gated values, their padded copies, the padded mask
/// of finite raw samples, the reading, the noise the gate took out (window means), the width, the
/// window's radius and the pair noise.
struct Planes<'a> {
    raw: &'a [Vec<f64>],
    gated: &'a [Vec<f64>],
    raw_p: &'a Padded,
    gated_p: &'a Padded,
    sample: &'a Padded,
    reading: &'a Reading<'a>,
    taken: &'a [f64],
    w: usize,
    radius: usize,
    pair_noise: f64,
}

/// A worker's row buffers: per pixel of the row, its weights'
/// scale and cut-off, the pixels that average their whole window, and its running sums (`line`: one
/// pixel's, along its direction).
#[derive(Default)]
struct Row {
    scale: Vec<f64>,
    far: Vec<f64>,
    square: Vec<usize>,
    total: Vec<f64>,
    sums: Vec<Vec<f64>>,
    d2: Vec<f64>,
    line: Vec<f64>,
}

/// Row y of the pulled values (`row`: w pixels of c channels). A pixel whose window has a direction
/// averages its line, one pixel at a time; the others their whole window, one tap at a time across
/// the row, so each tap's distances are one vectorised pass while every pixel still adds its taps in
/// the window's order (dy, then dx): the same bits as a pixel at a time.
#[inline(always)]
fn mean_row(planes: &Planes, y: usize, s: &mut Row, row: &mut [f64]) {
    let (c, w, r, reading) = (planes.raw.len(), planes.w, planes.radius, planes.reading);
    let (taken, pair_noise) = (planes.taken, planes.pair_noise);
    let ri = r as isize;
    s.sums.resize_with(c, Vec::new);
    for v in s.sums.iter_mut() {
        v.clear();
        v.resize(w, 0.0);
    }
    for v in [&mut s.scale, &mut s.far, &mut s.total, &mut s.d2] {
        v.clear();
        v.resize(w, 0.0);
    }
    s.square.clear();
    for x in 0..w {
        let i = y * w + x;
        let px = &mut row[x * c..(x + 1) * c];
        for (k, v) in px.iter_mut().enumerate() {
            *v = planes.gated[k][i];
        }
        let scale = 2.0 * pair_noise * taken[i];
        let pull = 1.0 - reading.rho[i];
        let finite = px.iter().all(|v| v.is_finite());
        if !(scale > 0.0 && scale.is_finite() && pull > 0.0 && finite) {
            continue;
        }
        // Beyond this squared distance a weight is below e^−40 (under 1e-17 of the pixel's
        // own, 1): skipped without its exponential.
        s.scale[x] = scale;
        s.far[x] = FAR * scale;
        match reading.along[i] {
            NO_DIRECTION => s.square.push(x),
            d => {
                let (dx, dy) = DIRECTIONS[d as usize];
                let mut total = 0.0;
                s.line.clear();
                s.line.resize(c, 0.0);
                for t in -ri..=ri {
                    let at = planes.gated_p.at(x, y, (t * dx, t * dy));
                    let d2 = distance(planes, at, |k| planes.gated[k][i]);
                    if let Some(weight) = weigh(planes, at, d2, s.far[x], scale) {
                        total += weight;
                        for (sum, raw) in s.line.iter_mut().zip(&planes.raw_p.planes) {
                            *sum += weight * raw[at];
                        }
                    }
                }
                if total > 0.0 {
                    for (k, v) in px.iter_mut().enumerate() {
                        *v += pull * (s.line[k] / total - *v);
                    }
                }
            }
        }
    }
    if s.square.is_empty() {
        return;
    }
    for dy in -ri..=ri {
        for dx in -ri..=ri {
            let at0 = planes.gated_p.at(0, y, (dx, dy));
            // Every pixel's distance at this tap, a contiguous run of each padded plane.
            s.d2.fill(0.0);
            for (plane, own) in planes.gated_p.planes.iter().zip(planes.gated) {
                let own = &own[y * w..(y + 1) * w];
                for ((d2, &p), &o) in s.d2.iter_mut().zip(&plane[at0..at0 + w]).zip(own) {
                    let d = p - o;
                    *d2 += d * d;
                }
            }
            for &x in &s.square {
                let at = at0 + x;
                if let Some(weight) = weigh(planes, at, s.d2[x], s.far[x], s.scale[x]) {
                    s.total[x] += weight;
                    for (sum, raw) in s.sums.iter_mut().zip(&planes.raw_p.planes) {
                        sum[x] += weight * raw[at];
                    }
                }
            }
        }
    }
    for &x in &s.square {
        if s.total[x] <= 0.0 {
            continue;
        }
        let pull = 1.0 - reading.rho[y * w + x];
        for (k, v) in row[x * c..(x + 1) * c].iter_mut().enumerate() {
            *v += pull * (s.sums[k][x] / s.total[x] - *v);
        }
    }
}

/// The squared distance of the gated planes at padded index `at` from a pixel's own values.
#[inline(always)]
fn distance(planes: &Planes, at: usize, own: impl Fn(usize) -> f64) -> f64 {
    let mut d2 = 0.0;
    for (k, plane) in planes.gated_p.planes.iter().enumerate() {
        let d = plane[at] - own(k);
        d2 += d * d;
    }
    d2
}

/// A tap's weight `exp(−d2 / scale)`, or none: a distance of infinity (nothing hit) is no sample
/// of a surface, and a distance not below `far` (NaN included) weighs nothing.
#[inline(always)]
fn weigh(planes: &Planes, at: usize, d2: f64, far: f64, scale: f64) -> Option<f64> {
    if planes.sample.planes[0][at] == 0.0 {
        return None;
    }
    if d2.partial_cmp(&far) != Some(std::cmp::Ordering::Less) {
        return None;
    }
    let weight = (-d2 / scale).exp();
    (!weight.is_nan() && weight > 0.0).then_some(weight)
}

/// Per pixel, what the gate took: the squared differences of the raw and gated planes, summed
/// over the channels that are finite.
fn residual(raw: &[Vec<f64>], gated: &[Vec<f64>]) -> Vec<f64> {
    let n = raw.first().map_or(0, Vec::len);
    (0..n)
        .into_par_iter()
        .map(|i| {
            raw.iter()
                .zip(gated)
                .map(|(r, g)| (r[i] - g[i]).powi(2))
                .filter(|d| d.is_finite())
                .sum()
        })
        .collect()
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

    /// The surface mean a pixel at a time, as the definition reads: every pixel's taps in its
    /// window's order (dy, then dx) or along its line, each weighed as [`weigh`] does.
    fn per_pixel(
        raw: &[Vec<f64>],
        gated: &[Vec<f64>],
        reading: &Reading,
        (w, h): (usize, usize),
        r: usize,
    ) -> Vec<Vec<f64>> {
        let c = raw.len();
        let taken = box_mean(&residual(raw, gated), (w, h), r);
        let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
        let mut out = gated.to_vec();
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let scale = 2.0 * 2.0 * taken[i];
                let pull = 1.0 - reading.rho[i];
                let finite = (0..c).all(|k| gated[k][i].is_finite());
                if !(scale > 0.0 && scale.is_finite() && pull > 0.0 && finite) {
                    continue;
                }
                let taps: Vec<(isize, isize)> = match reading.along[i] {
                    NO_DIRECTION => (-(r as isize)..=r as isize)
                        .flat_map(|dy| (-(r as isize)..=r as isize).map(move |dx| (dx, dy)))
                        .collect(),
                    d => {
                        let (dx, dy) = DIRECTIONS[d as usize];
                        (-(r as isize)..=r as isize)
                            .map(|t| (t * dx, t * dy))
                            .collect()
                    }
                };
                let (mut total, mut sums) = (0.0, vec![0.0; c]);
                for (dx, dy) in taps {
                    let j = clamp(y as isize + dy, h) * w + clamp(x as isize + dx, w);
                    if !(0..c).all(|k| raw[k][j].is_finite()) {
                        continue;
                    }
                    let mut d2 = 0.0;
                    for g in gated {
                        let d = g[j] - g[i];
                        d2 += d * d;
                    }
                    if d2.partial_cmp(&(FAR * scale)) != Some(std::cmp::Ordering::Less) {
                        continue;
                    }
                    let weight = (-d2 / scale).exp();
                    if weight.is_nan() || weight <= 0.0 {
                        continue;
                    }
                    total += weight;
                    for k in 0..c {
                        sums[k] += weight * raw[k][j];
                    }
                }
                if total > 0.0 {
                    for k in 0..c {
                        out[k][i] += pull * (sums[k] / total - out[k][i]);
                    }
                }
            }
        }
        out
    }

    #[test]
    fn the_row_at_a_time_sums_give_the_per_pixel_definitions_bits() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::Xoshiro256PlusPlus::seed_from_u64(7);
        for (w, h, c) in [(1, 1, 1), (9, 5, 3), (17, 12, 3), (6, 9, 1)] {
            let n = w * h;
            let gated: Vec<Vec<f64>> = (0..c)
                .map(|_| {
                    (0..n)
                        .map(|_| (rng.random_range(0..4) as f64) * 0.1)
                        .collect()
                })
                .collect();
            let mut raw: Vec<Vec<f64>> = gated
                .iter()
                .map(|g| {
                    g.iter()
                        .map(|&v| v + rng.random_range(-0.05..0.05))
                        .collect()
                })
                .collect();
            // A sample that hit nothing.
            raw[0][n / 2] = f64::INFINITY;
            let rho: Vec<f64> = (0..n)
                .map(|_| rng.random_range(0.0..1.2f64).min(1.0))
                .collect();
            let along: Vec<u8> = (0..n).map(|_| rng.random_range(0..=NO_DIRECTION)).collect();
            let reading = Reading {
                rho: &rho,
                along: &along,
            };
            let got =
                pull_to_surface_mean(&raw, &gated, reading, (w, h), (2, 2.0), &Meter::default())
                    .unwrap();
            let want = per_pixel(&raw, &gated, &reading, (w, h), 2);
            for k in 0..c {
                for i in 0..n {
                    assert_eq!(
                        got[k][i].to_bits(),
                        want[k][i].to_bits(),
                        "{w}x{h} channel {k} pixel {i}"
                    );
                }
            }
        }
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
