//! Across each edge: how far the renderer's pixel filter spreads an edge beyond the pixel it
//! crosses, read from the features, and the colour spread across its edges by that much.
//!
//! A box pixel filter mixes an edge's two sides only in the pixel the edge crosses; a wider filter
//! (Cycles' Blackman-Harris, which importance-samples positions up to a pixel and a half away)
//! also mixes them into the pixels either side. Averaged along a straight edge, the features show
//! that mix whatever the sample count, since every sample's features land where its colour does.
//! At a few samples a pixel, each pixel shows its samples' sides instead, and the filters above
//! keep an edge as sharp as a box would draw it; this stage gives the pixels beside an edge their
//! share of the other side, as far as their noise covers the change (docs/ALGORITHM.md §8).

use rayon::prelude::*;

use super::orient::{bilinear, colour_planes, gated_move, mix, Guide};
use crate::filters::noise::measured::pixel_variance;
use crate::image::{par_vec, Image};
use crate::meter::Meter;

/// Pixels each way across an edge (to its two sides) and along it (the average) the estimate reads.
const REACH: usize = 3;
/// Least squared guide contrast between an edge's two sides for the estimate to read it.
const CONTRAST: f64 = 0.2;
/// The most a profile point may leave the line between the two sides (squared, against the
/// contrast): more, and a third surface is in the window.
const OFF_LINE: f64 = 0.05;
/// The most the share of the first side may rise from one profile point to the next: more, and
/// the profile is not one edge.
const RISE: f64 = 0.05;
/// How close to an image axis an edge's direction must be for the estimate to read it (|cos|): the
/// profile is then read at pixel centres, with no interpolation to soften it.
const AXIS: f32 = 0.97;
/// Fewest edges the estimate needs; with fewer it reads no spread (the box's).
pub const MIN_EDGES: usize = 32;
/// Feature differences between 4-neighbours that mark an edge pixel: albedo (largest channel) and
/// normal (1 − cos).
const ALBEDO_STEP: f32 = 0.05;
const NORMAL_STEP: f32 = 0.1;

/// What the features say of the renderer's pixel filter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Spread {
    /// The mix of an edge's two sides in the pixels either side of the pixel it crosses, summed
    /// over both, averaged over the edges read: 0 for a box filter, 1 at most.
    pub tail: f64,
    /// How many edges were read.
    pub edges: usize,
}

impl Spread {
    /// The share of each across-neighbour a pixel beside an edge takes: half the tail on each side,
    /// as a three-tap kernel across the edge, halved again because the filters' edges are already
    /// partly soft; none when too few edges were read.
    pub fn share(&self) -> f64 {
        if self.edges < MIN_EDGES {
            0.0
        } else {
            (self.tail / 4.0).clamp(0.0, 0.25)
        }
    }
}

/// The renderer's spread read from `guide`'s straight, lone, two-sided edges near an image axis
/// (directions from `normals`): the guide averaged over `2·REACH + 1` pixels along each such edge,
/// then, across it, each profile point's share of one side; the edge's tail is the mix of the
/// points either side of the most mixed one, which must be the centre.
pub fn spread(guide: &Guide, normals: &[(f32, f32)]) -> Spread {
    let (w, h) = (guide.w, guide.h);
    let rows: Vec<(f64, usize)> = (0..h)
        .into_par_iter()
        .map_init(
            || vec![0.0f64; (2 * REACH + 2) * guide.planes.len()],
            |profile, y| {
                let mut sum = (0.0f64, 0usize);
                for x in 0..w {
                    if let Some(t) = edge_tail(guide, (x, y), normals[y * w + x], profile) {
                        sum.0 += t;
                        sum.1 += 1;
                    }
                }
                sum
            },
        )
        .collect();
    // Summed in row order: the same bits on any thread count.
    let (total, edges) = rows.iter().fold((0.0, 0), |(s, n), &(t, k)| (s + t, n + k));
    Spread {
        tail: if edges > 0 { total / edges as f64 } else { 0.0 },
        edges,
    }
}

/// The tail of the edge through pixel `(x, y)`, if it is one the estimate reads. `scratch` holds
/// `2·REACH + 2` guide pixels.
fn edge_tail(
    guide: &Guide,
    (x, y): (usize, usize),
    (nx, ny): (f32, f32),
    scratch: &mut [f64],
) -> Option<f64> {
    let (w, h) = (guide.w, guide.h);
    let g = guide.planes.len();
    // `across` steps over the edge, `along` along it.
    let (across, along, len, pos) = if nx.abs() >= AXIS {
        (1isize, w as isize, w, x)
    } else if ny.abs() >= AXIS {
        (w as isize, 1isize, h, y)
    } else {
        return None;
    };
    let (along_len, along_pos) = if across == 1 { (h, y) } else { (w, x) };
    if pos < REACH || pos + REACH >= len {
        return None;
    }
    let centre = (y * w + x) as isize;
    // The guide at offset k across, averaged along (clamped to the image), into `out`.
    let read = |k: usize, out: &mut [f64]| {
        out.fill(0.0);
        for o in -(REACH as isize)..=REACH as isize {
            let a = (along_pos as isize + o).clamp(0, along_len as isize - 1) - along_pos as isize;
            let i = (centre + (k as isize - REACH as isize) * across + a * along) as usize;
            for (v, p) in out.iter_mut().zip(&guide.planes) {
                *v += p[i] as f64;
            }
        }
        for v in out.iter_mut() {
            *v /= (2 * REACH + 1) as f64;
        }
    };
    let n = 2 * REACH + 1;
    // The profile's n points, then the first point minus the last (one edge's sides).
    let (profile, ab) = scratch.split_at_mut(n * g);
    for k in [0, n - 1] {
        read(k, &mut profile[k * g..(k + 1) * g]);
    }
    let (first, rest) = profile.split_at(g);
    for ((d, a), b) in ab.iter_mut().zip(first).zip(&rest[(n - 2) * g..]) {
        *d = a - b;
    }
    let ab = &*ab;
    let contrast: f64 = ab.iter().map(|d| d * d).sum();
    if contrast.is_nan() || contrast < CONTRAST {
        return None;
    }
    for k in 1..n - 1 {
        read(k, &mut profile[k * g..(k + 1) * g]);
    }
    let b = &profile[(n - 1) * g..n * g];
    let mut shares = [0.0f64; 2 * REACH + 1];
    for (k, share) in shares.iter_mut().enumerate() {
        let p = &profile[k * g..(k + 1) * g];
        let q = p
            .iter()
            .zip(b)
            .zip(ab)
            .map(|((p, b), d)| (p - b) * d)
            .sum::<f64>()
            / contrast;
        let off: f64 = p
            .iter()
            .zip(b)
            .zip(ab)
            .map(|((p, b), d)| (p - b - q * d).powi(2))
            .sum();
        if off > OFF_LINE * contrast {
            return None;
        }
        *share = q;
    }
    if shares.windows(2).any(|s| s[1] - s[0] > RISE) {
        return None;
    }
    let mixed = shares.map(|q| q.min(1.0 - q).clamp(0.0, 1.0));
    let most = (0..n).fold(0, |m, k| if mixed[k] > mixed[m] { k } else { m });
    (most == REACH).then(|| mixed[REACH - 1] + mixed[REACH + 1])
}

/// Whether each pixel's features differ from a 4-neighbour's by an edge's step.
fn edge_pixels(guide: &Guide) -> Vec<bool> {
    let (w, h) = (guide.w, guide.h);
    let (albedo, normal) = guide.planes.split_at(guide.albedo);
    let step = |i: usize, j: usize| {
        let da = albedo
            .iter()
            .map(|p| (p[i] - p[j]).abs())
            .fold(0.0f32, f32::max);
        // Half normals: the cosine is four times their dot product.
        let dn = normal.len() == 3 && {
            let dot: f32 = normal.iter().map(|p| p[i] * p[j]).sum();
            1.0 - 4.0 * dot > NORMAL_STEP
        };
        da > ALBEDO_STEP || dn
    };
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (x, y) = (i % w, i / w);
            (x + 1 < w && step(i, i + 1))
                || (x > 0 && step(i, i - 1))
                || (y + 1 < h && step(i, i + w))
                || (y > 0 && step(i, i - w))
        })
        .collect()
}

/// `color` with each edge pixel moved towards a three-tap mean across its edge (the directions of
/// `normals`), each across-neighbour weighing `share`, as far as the least noise `variance` of its
/// 3×3 window covers the change with `tolerance` as the slack of `blend`. Rows skipped once
/// `meter` is cancelled.
pub fn across_edges(
    color: &Image,
    variance: &Image,
    guide: &Guide,
    normals: &[(f32, f32)],
    (share, tolerance): (f64, f64),
    meter: &Meter,
) -> Image {
    let (w, h) = color.dims();
    if share <= 0.0 {
        return color.par_clone();
    }
    let planes = colour_planes(color);
    let noise: Vec<f64> = variance
        .data()
        .par_chunks_exact(3)
        .map(pixel_variance)
        .collect();
    let edges = edge_pixels(guide);
    let c = color.data();
    let mut out = par_vec(0.0f32, 3 * w * h);
    meter.pass(h);
    out.par_chunks_mut(3 * w.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            if meter.cancelled() {
                return;
            }
            meter.rows(1);
            for x in 0..w {
                let i = y * w + x;
                let px = &mut row[3 * x..3 * x + 3];
                px.copy_from_slice(&c[3 * i..3 * i + 3]);
                if !edges[i] {
                    continue;
                }
                let var = least_around(&noise, (w, h), (x, y));
                if var.is_nan() || var <= 0.0 {
                    continue;
                }
                let (nx, ny) = normals[i];
                let (fx, fy) = (x as f32, y as f32);
                let (ip, fp) = bilinear(fx + nx, fy + ny, w, h);
                let (im, fm) = bilinear(fx - nx, fy - ny, w, h);
                let change: [f64; 3] = std::array::from_fn(|k| {
                    let (p, m) = (mix(&planes[k], ip, fp), mix(&planes[k], im, fm));
                    share * (p as f64 + m as f64 - 2.0 * px[k] as f64)
                });
                gated_move(px, change, var, tolerance);
            }
        });
    Image::from_vec(w, h, 3, out).expect("3 channels a pixel")
}

/// The least of `plane` over the 3×3 window around `(x, y)` (clamped): a pixel beside a highlight
/// reads its own surface's noise, not the highlight's.
fn least_around(plane: &[f64], (w, h): (usize, usize), (x, y): (usize, usize)) -> f64 {
    let mut least = f64::INFINITY;
    for yy in y.saturating_sub(1)..(y + 2).min(h) {
        for xx in x.saturating_sub(1)..(x + 2).min(w) {
            least = least.min(plane[yy * w + xx]);
        }
    }
    least
}
