//! The random-walk kernel of SID/GSID (ALGORITHM.md §3).
//!
//! From every start pixel x0, `walks` random walks step to one of the 8 neighbours with
//! p ∝ exp(a), a = −(d(x0, y)² + d(x_j, y)²) / (2σ²), computed in the log domain (subtract the largest
//! a before exp, so the normaliser is ≥ 1 for every σ). A walk stops once its log-probability
//! L_k = Σ log p drops below ln(p_min), or at `max_steps`. The pixel reached at step k adds
//! w = exp(L_k / k) (the geometric mean of its step probabilities) to x0's weighted average of
//! linear colour, accumulated in f64.
//!
//! Two versions: [`denoise_reference`] recomputes every distance (the readable spec, used by tests),
//! [`denoise`] precomputes the x0-independent term d(x_j, y) once per pixel and neighbour and, with a
//! window, the x0 term once per window cell. Both consume the same random numbers and form the same
//! sums in the same order, so they agree bit for bit.

// Lane loops index several 8-wide arrays at once; indices read better than zipped iterators.
#![allow(clippy::needless_range_loop)]

use std::sync::atomic::{AtomicU64, Ordering};

use rand::rngs::Xoshiro256PlusPlus;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

use crate::features::Features;
use crate::image::Image;

/// The 8-neighbourhood, in the lane order used everywhere (row above, same row, row below).
pub const OFFSETS: [(isize, isize); 8] = [
    (-1, -1),
    (0, -1),
    (1, -1),
    (-1, 0),
    (1, 0),
    (-1, 1),
    (0, 1),
    (1, 1),
];

/// Parameters of one walk kernel run, already validated by the stage.
#[derive(Clone, Debug, PartialEq)]
pub struct WalkParams {
    /// Scale of the difference function: larger averages more.
    pub sigma: f32,
    /// Walks per start pixel: more is smoother and slower (linear cost).
    pub walks: u32,
    /// A walk stops once its probability falls below this.
    pub p_min: f64,
    /// Hard cap on steps per walk.
    pub max_steps: u32,
    /// Optional window radius around x0 that walks may not leave (4 gives 9×9).
    pub window: Option<u32>,
    /// Weight of the start pixel's own colour per walk (0: it counts only when a walk returns).
    pub self_weight: f32,
}

impl Default for WalkParams {
    fn default() -> Self {
        WalkParams {
            sigma: 1.0,
            walks: 20,
            p_min: 1e-6,
            max_steps: 64,
            window: Some(4),
            self_weight: 0.0,
        }
    }
}

/// Work done by a kernel run: the unit of the kernel benchmarks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WalkStats {
    pub walks: u64,
    pub steps: u64,
}

/// Inputs shared by both kernel versions.
#[derive(Clone, Copy)]
pub struct WalkInput<'a> {
    /// Linear colour that is averaged (3 channels).
    pub color: &'a Image,
    pub features: &'a Features,
    /// Pixels walks must avoid and that get no weight (e.g. detected outliers).
    pub mask: Option<&'a [bool]>,
    pub seed: u64,
    /// Pyramid level, so every level draws its own random numbers.
    pub level: u32,
}

fn splitmix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The random stream of one start pixel: depends only on (seed, level, pixel), never on scheduling.
pub fn pixel_rng(seed: u64, level: u32, pixel: usize) -> Xoshiro256PlusPlus {
    Xoshiro256PlusPlus::seed_from_u64(splitmix(
        splitmix(splitmix(seed) ^ level as u64) ^ pixel as u64,
    ))
}

/// Uniform in [0, 1) with 24 bits, the precision of the f32 sums it is compared with.
#[inline]
fn uniform(rng: &mut Xoshiro256PlusPlus) -> f32 {
    (rng.next_u32() >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// Picks a neighbour from logits `a` (−∞ = not allowed) with the uniform draw `u`.
///
/// Returns the lane and its log-probability, or `None` when no neighbour is allowed. A rounding miss
/// at the top of the cumulative sum falls back to the most likely lane.
#[inline]
pub fn choose(a: &[f32; 8], u: f32) -> Option<(usize, f32)> {
    let mut m = f32::NEG_INFINITY;
    let mut best = 0;
    for (k, &v) in a.iter().enumerate() {
        if v > m {
            m = v;
            best = k;
        }
    }
    if m == f32::NEG_INFINITY {
        return None;
    }
    let mut e = [0.0f32; 8];
    let mut sum = 0.0f32;
    for k in 0..8 {
        e[k] = (a[k] - m).exp();
        sum += e[k];
    }
    let target = u * sum;
    let mut cum = 0.0f32;
    let mut pick = best;
    for k in 0..8 {
        cum += e[k];
        if target < cum && e[k] > 0.0 {
            pick = k;
            break;
        }
    }
    Some((pick, (a[pick] - m) - sum.ln()))
}

/// Accumulates one start pixel's weighted colour in f64.
struct Accum {
    sum: [f64; 3],
    weight: f64,
}

impl Accum {
    fn new(input: &WalkInput, x0: usize, params: &WalkParams) -> Self {
        let mut acc = Accum {
            sum: [0.0; 3],
            weight: 0.0,
        };
        if params.self_weight > 0.0 {
            acc.add(
                input.color.pixel(x0),
                params.self_weight as f64 * params.walks as f64,
            );
        }
        acc
    }

    #[inline]
    fn add(&mut self, c: &[f32], w: f64) {
        self.sum[0] += w * c[0] as f64;
        self.sum[1] += w * c[1] as f64;
        self.sum[2] += w * c[2] as f64;
        self.weight += w;
    }

    fn write(&self, fallback: &[f32], out: &mut [f32]) {
        if self.weight > 0.0 && self.weight.is_finite() {
            for k in 0..3 {
                out[k] = (self.sum[k] / self.weight) as f32;
            }
        } else {
            out.copy_from_slice(&fallback[..3]);
        }
    }
}

#[inline]
fn neighbour(x: usize, y: usize, k: usize, w: usize, h: usize) -> Option<(usize, usize)> {
    let (dx, dy) = OFFSETS[k];
    let nx = x as isize + dx;
    let ny = y as isize + dy;
    (nx >= 0 && ny >= 0 && (nx as usize) < w && (ny as usize) < h)
        .then_some((nx as usize, ny as usize))
}

fn inv_two_sigma2(sigma: f32) -> f32 {
    1.0 / (2.0 * sigma * sigma)
}

/// The plain version: every logit recomputed from the features. Single-threaded; for tests.
pub fn denoise_reference(input: &WalkInput, params: &WalkParams) -> (Image, WalkStats) {
    let (w, h) = input.color.dims();
    let inv = inv_two_sigma2(params.sigma);
    let ln_pmin = params.p_min.ln();
    let blocked = |j: usize| input.mask.is_some_and(|m| m[j]);
    let mut out = Image::new(w, h, 3);
    let mut stats = WalkStats::default();
    for y0 in 0..h {
        for x0 in 0..w {
            let i0 = y0 * w + x0;
            let mut rng = pixel_rng(input.seed, input.level, i0);
            let mut acc = Accum::new(input, i0, params);
            for _ in 0..params.walks {
                stats.walks += 1;
                let (mut x, mut y) = (x0, y0);
                let mut log_p = 0.0f64;
                for step in 1..=params.max_steps {
                    let i = y * w + x;
                    let mut a = [f32::NEG_INFINITY; 8];
                    for (k, ak) in a.iter_mut().enumerate() {
                        let Some((nx, ny)) = neighbour(x, y, k, w, h) else {
                            continue;
                        };
                        let in_window = params.window.is_none_or(|r| {
                            nx.abs_diff(x0) <= r as usize && ny.abs_diff(y0) <= r as usize
                        });
                        let j = ny * w + nx;
                        if !in_window || blocked(j) {
                            continue;
                        }
                        let d0 = input.features.distance(i0, j);
                        let dj = input.features.distance(i, j);
                        *ak = (-(d0 * d0) * inv) + (-(dj * dj) * inv);
                    }
                    let u = uniform(&mut rng);
                    let Some((k, lp)) = choose(&a, u) else { break };
                    log_p += lp as f64;
                    if log_p < ln_pmin {
                        break;
                    }
                    (x, y) = neighbour(x, y, k, w, h).expect("chosen neighbour is inside");
                    stats.steps += 1;
                    acc.add(input.color.pixel(y * w + x), (log_p / step as f64).exp());
                }
            }
            acc.write(input.color.pixel(i0), out.pixel_mut(i0));
        }
    }
    (out, stats)
}

/// −d(i, neighbour k)²/(2σ²) for every pixel and lane; −∞ outside the image or on masked pixels.
fn neighbour_terms(input: &WalkInput, inv: f32) -> Vec<[f32; 8]> {
    let (w, h) = input.color.dims();
    let blocked = |j: usize| input.mask.is_some_and(|m| m[j]);
    let mut terms = vec![[f32::NEG_INFINITY; 8]; w * h];
    terms
        .par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            for (x, t) in row.iter_mut().enumerate() {
                let i = y * w + x;
                for (k, tk) in t.iter_mut().enumerate() {
                    if let Some((nx, ny)) = neighbour(x, y, k, w, h) {
                        let j = ny * w + nx;
                        if !blocked(j) {
                            let d = input.features.distance(i, j);
                            *tk = -(d * d) * inv;
                        }
                    }
                }
            }
        });
    terms
}

/// The fast version: parallel over rows, x0-independent terms precomputed, window terms cached.
///
/// `on_row` is called once per finished row (for progress bars).
pub fn denoise(
    input: &WalkInput,
    params: &WalkParams,
    on_row: &(dyn Fn() + Sync),
) -> (Image, WalkStats) {
    let (w, h) = input.color.dims();
    let inv = inv_two_sigma2(params.sigma);
    let near = neighbour_terms(input, inv);
    let steps = AtomicU64::new(0);
    let mut out = Image::new(w, h, 3);
    // The window is clipped to what a walk can reach: a larger one only costs time.
    let radius = params.window.map(|r| r.min(params.max_steps) as usize);
    let side = radius.map_or(0, |r| 2 * r + 3);
    out.data_mut()
        .par_chunks_mut(3 * w.max(1))
        .enumerate()
        .for_each_init(
            || vec![f32::NEG_INFINITY; side * side],
            |grid, (y0, row)| {
                let mut row_steps = 0u64;
                for x0 in 0..w {
                    let i0 = y0 * w + x0;
                    let (acc, n) = match radius {
                        Some(r) => walk_windowed(input, params, &near, inv, grid, r, x0, y0),
                        None => walk_unbounded(input, params, &near, inv, x0, y0),
                    };
                    row_steps += n;
                    acc.write(input.color.pixel(i0), &mut row[3 * x0..3 * x0 + 3]);
                }
                steps.fetch_add(row_steps, Ordering::Relaxed);
                on_row();
            },
        );
    let stats = WalkStats {
        walks: (w * h) as u64 * params.walks as u64,
        steps: steps.into_inner(),
    };
    (out, stats)
}

/// Walks from (x0, y0) with the x0 terms cached in a (2r+3)² grid whose outer ring is −∞.
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn walk_windowed(
    input: &WalkInput,
    params: &WalkParams,
    near: &[[f32; 8]],
    inv: f32,
    grid: &mut [f32],
    r: usize,
    x0: usize,
    y0: usize,
) -> (Accum, u64) {
    let (w, h) = input.color.dims();
    let side = 2 * r + 3;
    let i0 = y0 * w + x0;
    let blocked = |j: usize| input.mask.is_some_and(|m| m[j]);
    grid.fill(f32::NEG_INFINITY);
    let (ylo, yhi) = (y0.saturating_sub(r), (y0 + r).min(h - 1));
    let (xlo, xhi) = (x0.saturating_sub(r), (x0 + r).min(w - 1));
    for y in ylo..=yhi {
        let gy = y + r + 1 - y0;
        for x in xlo..=xhi {
            let j = y * w + x;
            if !blocked(j) {
                let d = input.features.distance(i0, j);
                grid[gy * side + (x + r + 1 - x0)] = -(d * d) * inv;
            }
        }
    }
    let goff: [isize; 8] = OFFSETS.map(|(dx, dy)| dy * side as isize + dx);
    let ioff: [isize; 8] = OFFSETS.map(|(dx, dy)| dy * w as isize + dx);
    let center = (r + 1) * side + (r + 1);
    let ln_pmin = params.p_min.ln();
    let mut rng = pixel_rng(input.seed, input.level, i0);
    let mut acc = Accum::new(input, i0, params);
    let mut steps = 0u64;
    for _ in 0..params.walks {
        let (mut g, mut i) = (center, i0);
        let mut log_p = 0.0f64;
        for step in 1..=params.max_steps {
            let t = &near[i];
            let mut a = [0.0f32; 8];
            for k in 0..8 {
                a[k] = grid[(g as isize + goff[k]) as usize] + t[k];
            }
            let u = uniform(&mut rng);
            let Some((k, lp)) = choose(&a, u) else { break };
            log_p += lp as f64;
            if log_p < ln_pmin {
                break;
            }
            g = (g as isize + goff[k]) as usize;
            i = (i as isize + ioff[k]) as usize;
            steps += 1;
            acc.add(input.color.pixel(i), (log_p / step as f64).exp());
        }
    }
    (acc, steps)
}

/// Walks from (x0, y0) with no window: the x0 term is computed on the fly.
fn walk_unbounded(
    input: &WalkInput,
    params: &WalkParams,
    near: &[[f32; 8]],
    inv: f32,
    x0: usize,
    y0: usize,
) -> (Accum, u64) {
    let w = input.color.width();
    let i0 = y0 * w + x0;
    let ioff: [isize; 8] = OFFSETS.map(|(dx, dy)| dy * w as isize + dx);
    let ln_pmin = params.p_min.ln();
    let mut rng = pixel_rng(input.seed, input.level, i0);
    let mut acc = Accum::new(input, i0, params);
    let mut steps = 0u64;
    for _ in 0..params.walks {
        let mut i = i0;
        let mut log_p = 0.0f64;
        for step in 1..=params.max_steps {
            let t = &near[i];
            let mut a = [f32::NEG_INFINITY; 8];
            for k in 0..8 {
                if t[k] != f32::NEG_INFINITY {
                    let d0 = input.features.distance(i0, (i as isize + ioff[k]) as usize);
                    a[k] = (-(d0 * d0) * inv) + t[k];
                }
            }
            let u = uniform(&mut rng);
            let Some((k, lp)) = choose(&a, u) else { break };
            log_p += lp as f64;
            if log_p < ln_pmin {
                break;
            }
            i = (i as isize + ioff[k]) as usize;
            steps += 1;
            acc.add(input.color.pixel(i), (log_p / step as f64).exp());
        }
    }
    (acc, steps)
}
