//! The average along each pixel's edge, and how much of it a pixel takes.
//!
//! At a few samples a pixel, a pixel on an edge is not the mix of the two sides its area covers but
//! the sides its few samples happened to land on: its features and colour both jump from side to
//! side along the edge, and a filter that follows the features keeps that staircase. Along a
//! straight edge every pixel covers the same share, so the mean of the pixels along it is the
//! expected mix. A pixel moves towards that mean by the share of the variation along its edge
//! that is not explained by a smooth edge (the features' jumps against the edge's contrast: 0 on a
//! clean anti-aliased edge), and only as far as its colour noise covers the change (a Wiener
//! weight, `tolerance` · noise / change², as `blend` weighs its change). An edge with another edge
//! within three pixels (stripes, fine texture) is left alone: its direction is not one line's.
//! On an edge only the colour shows ([`Gate::Scatter`]), the noise that gates the move is at least
//! the colour's own scatter along the edge.

use rayon::prelude::*;

use super::orient::{bilinear, colour_planes, gated_move, mix, Guide};
use crate::filters::noise::measured::pixel_variance;
use crate::image::{par_vec, Image};
use crate::meter::Meter;

/// How far across the edge its two sides are read, in pixels.
const SIDE: f32 = 1.5;
/// How far beyond a side the next edge must be for this one to count as alone.
const BEYOND: f32 = 3.0;
/// Least contrast (squared guide distance) across an edge that counts as one.
const MIN_CONTRAST: f32 = 1e-4;

/// What the move's noise gate weighs the change against.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Gate {
    /// The pixel's noise variance.
    Noise,
    /// The larger of the pixel's noise variance and the colour's scatter along the edge. Where
    /// the guide is the colour itself, the pixels along an edge of few samples scatter between
    /// its two sides' levels by how many of their samples fell on each side; the image's noise
    /// estimate trims such pairs as an edge's and leaves that noise out, while the scatter along
    /// the edge measures it.
    Scatter,
}

/// `color` moved towards its mean along each pixel's edge (`reach` pixels each way, the
/// directions of `normals`), as far as the noise of `gate` covers, with `tolerance` as the
/// slack of `blend`. Rows skipped once `meter` is cancelled.
pub fn along_edges(
    color: &Image,
    variance: &Image,
    guide: &Guide,
    normals: &[(f32, f32)],
    (reach, tolerance, gate): (usize, f64, Gate),
    meter: &Meter,
) -> Image {
    let (w, h) = color.dims();
    let planes = colour_planes(color);
    let (c, v) = (color.data(), variance.data());
    let mut out = par_vec(0.0f32, 3 * w * h);
    let g = guide.planes.len();
    meter.pass(h);
    out.par_chunks_mut(3 * w.max(1)).enumerate().for_each_init(
        || vec![0.0f32; (2 * reach + 6) * g],
        |scratch, (y, row)| {
            if meter.cancelled() {
                return;
            }
            meter.rows(1);
            for x in 0..w {
                let i = y * w + x;
                let px = &mut row[3 * x..3 * x + 3];
                px.copy_from_slice(&c[3 * i..3 * i + 3]);
                let pos = (x as f32, y as f32);
                // The colour's guide noise only where the scatter gate asks for it.
                let noise = || guide_noise(&c[3 * i..3 * i + 3], &v[3 * i..3 * i + 3]);
                let share = jump_share(guide, pos, normals[i], reach, (gate, noise), scratch);
                if share <= 0.0 {
                    continue;
                }
                let var = pixel_variance(&v[3 * i..3 * i + 3]);
                if var <= 0.0 {
                    continue;
                }
                let (mean, scatter) = mean_along(&planes, (w, h), pos, normals[i], reach);
                let var = match gate {
                    Gate::Noise => var,
                    Gate::Scatter => var.max(scatter),
                };
                let change: [f64; 3] = std::array::from_fn(|k| share * (mean[k] - px[k] as f64));
                gated_move(px, change, var, tolerance);
            }
        },
    );
    Image::from_vec(w, h, 3, out).expect("3 channels a pixel")
}

/// The squared distance in the tone-mapped colour guide (c / (1 + c) per channel) that two
/// independent reads of a pixel of colour `c` and noise variance `v` differ by: Σ 2 v / (1 + c)⁴.
fn guide_noise(c: &[f32], v: &[f32]) -> f64 {
    c.iter()
        .zip(v)
        .map(|(&c, &v)| {
            let slope = 1.0 / (1.0 + (c as f64).max(0.0)).powi(2);
            let v = v as f64;
            if v.is_finite() && v > 0.0 && slope.is_finite() {
                2.0 * v * slope * slope
            } else {
                0.0
            }
        })
        .sum()
}

/// The points along the edge through `(x, y)`: `reach` pixel steps each way along the tangent.
fn along(
    (x, y): (f32, f32),
    (nx, ny): (f32, f32),
    reach: usize,
) -> impl Iterator<Item = (f32, f32)> {
    let r = reach as isize;
    (-r..=r).map(move |o| (x - o as f32 * ny, y + o as f32 * nx))
}

/// The colour's mean along the edge, per channel, and its scatter there: the sample variance of
/// the points along the edge, averaged over the channels.
fn mean_along(
    planes: &[Vec<f32>; 3],
    (w, h): (usize, usize),
    pos: (f32, f32),
    n: (f32, f32),
    reach: usize,
) -> ([f64; 3], f64) {
    let count = 2 * reach + 1;
    let (mut sum, mut squares) = ([0.0f64; 3], [0.0f64; 3]);
    for (x, y) in along(pos, n, reach) {
        let (i, f) = bilinear(x, y, w, h);
        for k in 0..3 {
            let v = mix(&planes[k], i, f) as f64;
            sum[k] += v;
            squares[k] += v * v;
        }
    }
    let mean = sum.map(|s| s / count as f64);
    let scatter = (0..3)
        .map(|k| (squares[k] - sum[k] * mean[k]).max(0.0))
        .sum::<f64>()
        / (3 * (count - 1)) as f64;
    (mean, scatter)
}

/// How much of the guide's variation along the edge through `pos` is jumps, against the edge's
/// contrast (a side's value against the other's): 0 off an edge, on an edge with another near it,
/// and on a smooth edge; 1 when the pixels along it are each one side or the other at random.
/// Under [`Gate::Scatter`] also 0 where the guide's mean along the edge is not a mix of its two
/// sides (beyond either side, or off the line between them by more than a quarter of their
/// distance): the pixels along a colour edge that are each some share of its sides average to
/// such a mix, structure along it (a reflection, a pattern) need not; and 0 where either side is not
/// one level along the edge ([`sides_even`]). `scratch` holds
/// `2·reach + 6` guide pixels.
fn jump_share(
    guide: &Guide,
    (x, y): (f32, f32),
    (nx, ny): (f32, f32),
    reach: usize,
    (gate, noise): (Gate, impl Fn() -> f64),
    scratch: &mut [f32],
) -> f64 {
    let g = guide.planes.len();
    let (a, rest) = scratch.split_at_mut(g);
    let (b, rest) = rest.split_at_mut(g);
    let (a3, rest) = rest.split_at_mut(g);
    let (b3, rest) = rest.split_at_mut(g);
    let (mean, samples) = rest.split_at_mut(g);
    guide.sample(x + SIDE * nx, y + SIDE * ny, a);
    guide.sample(x - SIDE * nx, y - SIDE * ny, b);
    let contrast = dist(a, b);
    if contrast.is_nan() || contrast <= MIN_CONTRAST as f64 {
        return 0.0;
    }
    guide.sample(x + BEYOND * nx, y + BEYOND * ny, a3);
    guide.sample(x - BEYOND * nx, y - BEYOND * ny, b3);
    if dist(a3, a).max(dist(b3, b)) >= contrast / 4.0 {
        return 0.0;
    }
    // Each point along the edge read once: its mean first, then the spread around it.
    mean.fill(0.0);
    let count = (2 * reach + 1) as f32;
    for ((px, py), sample) in along((x, y), (nx, ny), reach).zip(samples.chunks_exact_mut(g)) {
        guide.sample(px, py, sample);
        for (m, &s) in mean.iter_mut().zip(sample.iter()) {
            *m += s / count;
        }
    }
    if gate == Gate::Scatter
        && (!a_mix_of(mean, a, b, contrast)
            || !sides_even(
                (a, a3),
                (b, b3),
                guide,
                (x, y),
                (nx, ny),
                reach,
                (contrast, noise()),
            ))
    {
        return 0.0;
    }
    let spread: f64 = samples.chunks_exact(g).map(|s| dist(s, mean)).sum();
    let spread = spread / count as f64;
    (spread / (contrast / 4.0)).clamp(0.0, 1.0)
}

/// Whether each side of the edge through `pos` is one level along it: the guide `SIDE` pixels
/// across, at every point along the edge, within a quarter of the edge's distance (|a − b|² =
/// `contrast`) of that side's value `a` or `b` at the pixel itself, in mean square, beyond what the
/// colour's `noise` (the squared guide distance two samples of it differ by) explains. A straight edge
/// whose pixels show one side or the other at random has even sides; a reflection's highlight or a
/// pattern the line crosses does not, and the mean along such a line is no pixel's expected mix.
/// `sa` and `sb` hold one guide pixel each.
fn sides_even(
    (a, sa): (&[f32], &mut [f32]),
    (b, sb): (&[f32], &mut [f32]),
    guide: &Guide,
    pos: (f32, f32),
    (nx, ny): (f32, f32),
    reach: usize,
    (contrast, noise): (f64, f64),
) -> bool {
    let (mut da, mut db) = (0.0, 0.0);
    for (px, py) in along(pos, (nx, ny), reach) {
        guide.sample(px + SIDE * nx, py + SIDE * ny, sa);
        guide.sample(px - SIDE * nx, py - SIDE * ny, sb);
        da += dist(sa, a);
        db += dist(sb, b);
    }
    let count = (2 * reach + 1) as f64;
    da.max(db) / count <= contrast / 16.0 + noise
}

/// The squared distance of two guide pixels.
fn dist(p: &[f32], q: &[f32]) -> f64 {
    p.iter()
        .zip(q)
        .map(|(&s, &t)| ((s - t) as f64).powi(2))
        .sum()
}

/// Whether `m` lies between `a` and `b` (its projection on the line from `b` to `a` within the
/// two) and off that line by at most a quarter of their distance; `contrast` is |a − b|².
fn a_mix_of(m: &[f32], a: &[f32], b: &[f32], contrast: f64) -> bool {
    let dot: f64 = m
        .iter()
        .zip(a.iter().zip(b))
        .map(|(&m, (&a, &b))| (m - b) as f64 * (a - b) as f64)
        .sum();
    let t = dot / contrast;
    let off: f64 = m
        .iter()
        .zip(a.iter().zip(b))
        .map(|(&m, (&a, &b))| (m as f64 - (b as f64 + t * (a - b) as f64)).powi(2))
        .sum();
    (0.0..=1.0).contains(&t) && off <= contrast / 16.0
}
