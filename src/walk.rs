//! The random-walk kernel of SID/GSID (ALGORITHM.md §3).
//!
//! From every start pixel x0, `walks` random walks step to one of the 8 neighbours with
//! p ∝ exp(a), a = −(d(x0, y)² + d(x_j, y)²) / (2σ²). A walk stops once its log-probability
//! L_k = Σ log p drops below ln(p_min), or at `max_steps`. The pixel reached at step k adds
//! w = exp(L_k / k) (the geometric mean of its step probabilities) to x0's weighted average of
//! linear colour, accumulated in f64.
//!
//! Sampling uses exp(a) = exp(x0 term) · exp(neighbour term), both exponentials precomputed, so a
//! step needs no exp; L_k is kept in the log domain (a_pick − ln Σ exp(a)). When Σ exp(a) nears
//! f32 underflow (tiny σ, strong edges) the step falls back to the max-subtracted log domain, which
//! is exact for every σ.
//!
//! Versions: [`denoise_reference`] recomputes every distance (the readable spec, used by tests);
//! [`denoise`] precomputes the x0-independent terms per band of rows and, with a window, the x0
//! terms per window cell, and runs a scalar or an AVX2 step ([`Kernel`]). All consume the same
//! random numbers and form the same sums in the same order, so they agree bit for bit.

// Lane loops index several 8-wide arrays at once; indices read better than zipped iterators.
#![allow(clippy::needless_range_loop)]

use std::ops::Range;
use std::sync::atomic::{AtomicU64, Ordering};

use rayon::prelude::*;

use crate::fastmath::{exp_neg, exp_neg_row, ln_normal};
use crate::features::{distance_row, Features};
use crate::image::Image;
pub use crate::simd::Kernel;

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
    z = z.wrapping_add(GAMMA);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// SplitMix64's increment (the golden ratio in 64 bits).
const GAMMA: u64 = 0x9e37_79b9_7f4a_7c15;

/// The key of one start pixel: depends only on (seed, level, pixel), never on scheduling.
#[inline]
pub fn pixel_key(seed: u64, level: u32, pixel: usize) -> u64 {
    splitmix(splitmix(splitmix(seed) ^ level as u64) ^ pixel as u64)
}

/// The key of walk `walk` from a start pixel. Every walk has its own stream, so walks may be
/// interleaved (or run in any order) without changing which numbers each one draws.
#[inline]
pub fn walk_key(pixel_key: u64, walk: u32) -> u64 {
    splitmix(pixel_key ^ walk as u64)
}

/// The uniform in [0, 1) that step `step` of the walk `key` draws: SplitMix64's output number
/// `step` of the stream seeded with `key`, cut to 24 bits (the precision of the f32 sums it meets).
#[inline]
pub fn uniform(key: u64, step: u32) -> f32 {
    (splitmix(key.wrapping_add((step as u64).wrapping_mul(GAMMA))) >> 40) as f32
        * (1.0 / 16_777_216.0)
}

/// Below this Σ exp(a) a step samples in the max-subtracted log domain instead: the linear
/// weights are then too close to f32 underflow to be trusted.
pub const LINEAR_MIN: f32 = 1e-30;

/// Inclusive prefix sums of 8 lanes, added in the order of the AVX2 kernel's in-register scan
/// (pairs, then quads, then the low half's total carried into the high half), so both versions
/// round identically.
#[inline]
pub fn prefix8(e: &[f32; 8]) -> [f32; 8] {
    let c3 = (e[3] + e[2]) + (e[1] + e[0]);
    let h7 = (e[7] + e[6]) + (e[5] + e[4]);
    [
        e[0],
        e[1] + e[0],
        (e[2] + e[1]) + e[0],
        c3,
        e[4] + c3,
        (e[5] + e[4]) + c3,
        ((e[6] + e[5]) + e[4]) + c3,
        h7 + c3,
    ]
}

/// The lane whose cumulative weight first exceeds `target`. If rounding put `target` at the very
/// top, the last lane with weight (the top of the distribution). Lanes of weight 0 are never
/// picked: their cumulative sum equals the previous lane's.
#[inline]
fn pick(c: &[f32; 8], e: &[f32; 8], target: f32) -> usize {
    (0..8)
        .find(|&k| target < c[k])
        .unwrap_or_else(|| (0..8).rev().find(|&k| e[k] > 0.0).unwrap_or(0))
}

/// Picks a neighbour with the uniform draw `u`, from log-weights `a` (−∞ = not allowed) and their
/// exponentials `l` (each the product of the two precomputed factors).
///
/// Returns the lane and its log-probability, or `None` when no neighbour is allowed. This is the
/// specification the AVX2 kernel reproduces bit for bit.
#[inline]
pub fn choose(a: &[f32; 8], l: &[f32; 8], u: f32) -> Option<(usize, f32)> {
    choose_parts(a, l, u).map(|(k, x, sum)| (k, x - ln_normal(sum)))
}

/// [`choose`] before its last operation: the lane k, and x and sum with log-probability
/// x − ln(sum) (the AVX2 kernel takes that ln for several walks at once).
#[inline]
fn choose_parts(a: &[f32; 8], l: &[f32; 8], u: f32) -> Option<(usize, f32, f32)> {
    let c = prefix8(l);
    let sum = c[7];
    if sum >= LINEAR_MIN {
        let k = pick(&c, l, u * sum);
        return Some((k, a[k], sum));
    }
    choose_log(a, u)
}

/// [`choose_parts`] for weights near underflow: subtract the largest log-weight m before exp, so
/// the normaliser lies in [1, 8] for every σ; x is then a_k − m.
#[inline]
fn choose_log(a: &[f32; 8], u: f32) -> Option<(usize, f32, f32)> {
    let m = a.iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v));
    if m == f32::NEG_INFINITY {
        return None;
    }
    let z = a.map(|v| v - m);
    let e = z.map(exp_neg);
    let c = prefix8(&e);
    let sum = c[7];
    let k = pick(&c, &e, u * sum);
    Some((k, z[k], sum))
}

/// The weight of the pixel reached at step `step` with log-probability `log_p`: the geometric mean
/// of the step probabilities, exp(log_p / step).
#[inline]
fn step_weight(log_p: f64, step: u32) -> f64 {
    exp_neg((log_p / step as f64) as f32) as f64
}

/// Accumulates weighted colour in f64: one per walk, then merged into the start pixel's in walk
/// order, so walks may run interleaved and still give the same bits.
#[derive(Clone, Copy, Default)]
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

    #[inline]
    fn merge(&mut self, walk: &Accum) {
        for k in 0..3 {
            self.sum[k] += walk.sum[k];
        }
        self.weight += walk.weight;
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
            let pkey = pixel_key(input.seed, input.level, i0);
            let mut acc = Accum::new(input, i0, params);
            for walk in 0..params.walks {
                stats.walks += 1;
                let key = walk_key(pkey, walk);
                let (mut x, mut y) = (x0, y0);
                let mut log_p = 0.0f64;
                let mut part = Accum::default();
                for step in 1..=params.max_steps {
                    let i = y * w + x;
                    let mut a = [f32::NEG_INFINITY; 8];
                    let mut l = [0.0f32; 8];
                    for k in 0..8 {
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
                        let (t0, tj) = (-(d0 * d0) * inv, -(dj * dj) * inv);
                        a[k] = t0 + tj;
                        l[k] = exp_neg(t0) * exp_neg(tj);
                    }
                    let Some((k, lp)) = choose(&a, &l, uniform(key, step)) else {
                        break;
                    };
                    log_p += lp as f64;
                    if log_p < ln_pmin {
                        break;
                    }
                    (x, y) = neighbour(x, y, k, w, h).expect("chosen neighbour is inside");
                    stats.steps += 1;
                    part.add(input.color.pixel(y * w + x), step_weight(log_p, step));
                }
                acc.merge(&part);
            }
            acc.write(input.color.pixel(i0), out.pixel_mut(i0));
        }
    }
    (out, stats)
}

/// The x0-independent terms of a band of rows: for each pixel i and lane k, −d(i, j)²/(2σ²) and
/// its exp (−∞ and 0 outside the image or on masked pixels). One pixel's 8 terms are one 32-byte
/// block, so a step loads them with one vector load.
#[derive(Default)]
struct Near {
    /// Index of the first pixel of the band.
    base: usize,
    log: Vec<[f32; 8]>,
    lin: Vec<[f32; 8]>,
}

impl Near {
    /// The terms of rows `rows`, into `self` (its buffers are reused from band to band).
    ///
    /// Each pair of neighbours is computed once, a row at a time with [`distance_row`]: the pair
    /// (p, p + o) for the four offsets o that point forward fills lane o of p and lane −o of p + o.
    fn compute(&mut self, kernel: Kernel, input: &WalkInput, inv: f32, rows: Range<usize>) {
        let (w, h) = input.color.dims();
        let blocked = |j: usize| input.mask.is_some_and(|m| m[j]);
        let n = rows.len() * w;
        self.base = rows.start * w;
        self.log.clear();
        self.log.resize(n, [f32::NEG_INFINITY; 8]);
        self.lin.clear();
        self.lin.resize(n, [0.0f32; 8]);
        // A pixel's backward lanes come from pairs that start one row above.
        let first = rows.start.saturating_sub(1);
        let planes = input.features.planes(first..(rows.end + 1).min(h), RUN_PAD);
        let depth_weight = input.features.depth_weight();
        let (mut t, mut e) = (vec![0.0f32; w + RUN_PAD], vec![0.0f32; w + RUN_PAD]);
        // (forward lane, its reverse lane) of OFFSETS.
        for (fwd, back) in [(4, 3), (5, 2), (6, 1), (7, 0)] {
            let (dx, dy) = OFFSETS[fwd];
            let lo = (-dx).max(0) as usize;
            let hi = (w as isize - dx).clamp(0, w as isize) as usize;
            for y in first..rows.end {
                let ny = y + dy as usize;
                if ny >= h || ny >= rows.end || lo >= hi {
                    continue;
                }
                let center = planes.offset(lo as isize, y);
                let other = planes.offset(lo as isize + dx, ny);
                let run = lo..lo + (hi - lo).next_multiple_of(8);
                distance_row(kernel, &planes, depth_weight, center, other, &mut t[run]);
                let (t, e) = (&mut t[lo..hi], &mut e[lo..hi]);
                for v in t.iter_mut() {
                    *v = -(*v * *v) * inv;
                }
                e.copy_from_slice(t);
                exp_neg_row(kernel, e);
                for (k, x) in (lo..hi).enumerate() {
                    let (p, q) = (y * w + x, ny * w + (x as isize + dx) as usize);
                    if y >= rows.start && !blocked(q) {
                        self.log[p - self.base][fwd] = t[k];
                        self.lin[p - self.base][fwd] = e[k];
                    }
                    if ny >= rows.start && !blocked(p) {
                        self.log[q - self.base][back] = t[k];
                        self.lin[q - self.base][back] = e[k];
                    }
                }
            }
        }
    }

    #[inline]
    fn log(&self, i: usize) -> &[f32; 8] {
        &self.log[i - self.base]
    }

    #[inline]
    fn lin(&self, i: usize) -> &[f32; 8] {
        &self.lin[i - self.base]
    }
}

/// Start-pixel rows per parallel task: the band's neighbour terms (with a window-radius halo) stay
/// in cache and never exist for the whole image at once.
const BAND_ROWS: usize = 16;

/// The fast version with the fastest kernel this CPU has. See [`denoise_with`].
pub fn denoise(
    input: &WalkInput,
    params: &WalkParams,
    on_row: &(dyn Fn() + Sync),
) -> (Image, WalkStats) {
    denoise_with(Kernel::detect(), input, params, on_row)
}

thread_local! {
    /// Each worker thread's scratch space. Thread-local rather than rayon's `for_each_init`, which
    /// makes a fresh one per work split: the band tables would be allocated (and page-faulted in)
    /// again for every band.
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// Per-thread scratch space, reused across start pixels, bands and runs.
#[derive(Default)]
struct Scratch {
    /// Window grids of a batch of start pixels, one after the other.
    grid: Vec<f32>,
    egrid: Vec<f32>,
    /// Per batch pixel: (grid cell of its centre, pixel index).
    starts: Vec<(usize, usize)>,
    /// Per walk sums of a batch, and per pixel results.
    parts: Vec<Accum>,
    accs: Vec<Accum>,
    near: Near,
    pairs: Pairs,
}

/// The fast version: parallel over bands of rows, neighbour terms precomputed per band, window
/// terms per start pixel.
///
/// `on_row` is called once per finished row (for progress bars). An unavailable `kernel` falls
/// back to the scalar one (same result).
pub fn denoise_with(
    kernel: Kernel,
    input: &WalkInput,
    params: &WalkParams,
    on_row: &(dyn Fn() + Sync),
) -> (Image, WalkStats) {
    let kernel = if kernel.is_available() {
        kernel
    } else {
        Kernel::Scalar
    };
    let (w, h) = input.color.dims();
    let inv = inv_two_sigma2(params.sigma);
    let steps = AtomicU64::new(0);
    let mut out = Image::new(w, h, 3);
    // The window is clipped to what a walk can reach: a larger one only costs time.
    let radius = params.window.map(|r| r.min(params.max_steps) as usize);
    // Unbounded walks may reach any row, so they share one whole-image table.
    let global = radius.is_none().then(|| {
        let mut near = Near::default();
        near.compute(kernel, input, inv, 0..h);
        near
    });
    out.data_mut()
        .par_chunks_mut(3 * w.max(1) * BAND_ROWS)
        .enumerate()
        .for_each(|(band, rows)| {
            SCRATCH.with_borrow_mut(|scratch| {
                let y_begin = band * BAND_ROWS;
                let y_end = (y_begin + BAND_ROWS).min(h);
                // The rows a walk from this band can reach.
                let halo = radius.map(|r| y_begin.saturating_sub(r)..(y_end + r).min(h));
                let near = match &halo {
                    Some(rows) => {
                        scratch.near.compute(kernel, input, inv, rows.clone());
                        &scratch.near
                    }
                    None => global
                        .as_ref()
                        .expect("built above when there is no window"),
                };
                let pairs = match radius {
                    Some(r) if scratch.pairs.compute(kernel, input, inv, r, y_begin..y_end) => {
                        Some(&scratch.pairs)
                    }
                    _ => None,
                };
                let mut band_steps = 0u64;
                // Start pixels whose walks run in lockstep: enough to fill the AVX2 kernel's slots.
                let batch = match kernel {
                    #[cfg(target_arch = "x86_64")]
                    Kernel::Avx2 if radius.is_some() => avx2::batch(params.walks),
                    _ => 1,
                };
                let cells = radius.map_or(0, |r| (2 * r + 3) * (2 * r + 3));
                scratch.grid.resize(batch * cells, 0.0);
                scratch.egrid.resize(batch * cells, 0.0);
                scratch.accs.resize(batch, Accum::default());
                for y0 in y_begin..y_end {
                    let row = &mut rows[3 * w * (y0 - y_begin)..3 * w * (y0 - y_begin + 1)];
                    for x_begin in (0..w).step_by(batch) {
                        let xs = x_begin..(x_begin + batch).min(w);
                        let n = match radius {
                            Some(r) => {
                                scratch.starts.clear();
                                for (b, x0) in xs.clone().enumerate() {
                                    let cell = b * cells..(b + 1) * cells;
                                    let win = Window::fill(
                                        input,
                                        inv,
                                        &mut scratch.grid[cell.clone()],
                                        &mut scratch.egrid[cell],
                                        pairs,
                                        r,
                                        x0,
                                        y0,
                                    );
                                    scratch.starts.push((b * cells + win.center(), win.i0));
                                }
                                match kernel {
                                    #[cfg(target_arch = "x86_64")]
                                    // SAFETY: `kernel` is Avx2 only if the CPU reported AVX2 above.
                                    Kernel::Avx2 => unsafe {
                                        avx2::walk_batch(
                                            input,
                                            params,
                                            near,
                                            avx2::Batch {
                                                grid: &scratch.grid,
                                                egrid: &scratch.egrid,
                                                side: 2 * r + 3,
                                                starts: &scratch.starts,
                                            },
                                            &mut scratch.parts,
                                            &mut scratch.accs,
                                        )
                                    },
                                    _ => {
                                        let win = Window {
                                            grid: &scratch.grid[..cells],
                                            egrid: &scratch.egrid[..cells],
                                            side: 2 * r + 3,
                                            i0: y0 * w + xs.start,
                                        };
                                        let (acc, n) = walk_windowed(input, params, near, &win);
                                        scratch.accs[0] = acc;
                                        n
                                    }
                                }
                            }
                            None => {
                                let (acc, n) =
                                    walk_unbounded(input, params, near, inv, xs.start, y0);
                                scratch.accs[0] = acc;
                                n
                            }
                        };
                        band_steps += n;
                        for (b, x0) in xs.enumerate() {
                            let i0 = y0 * w + x0;
                            scratch.accs[b]
                                .write(input.color.pixel(i0), &mut row[3 * x0..3 * x0 + 3]);
                        }
                    }
                    on_row();
                }
                steps.fetch_add(band_steps, Ordering::Relaxed);
            })
        });
    let stats = WalkStats {
        walks: (w * h) as u64 * params.walks as u64,
        steps: steps.into_inner(),
    };
    (out, stats)
}

/// The x0 terms of a band's start pixels, each pixel pair computed once: for every offset o of
/// the half window (dy > 0, or dy = 0 and dx > 0) and every pixel p from `first_row` to the band's
/// end, −d(p, p + o)²/(2σ²) and its exp (−∞ and 0 where p + o leaves the image). x0's term for
/// x0 + o is entry (o, x0), and for x0 − o entry (o, x0 − o), as d is symmetric bit for bit. A row
/// of one offset is 8 pairs per vector, against 9-wide window rows filled per start pixel before.
#[derive(Default)]
struct Pairs {
    offsets: Vec<(isize, isize)>,
    first_row: usize,
    rows: usize,
    width: usize,
    log: Vec<f32>,
    lin: Vec<f32>,
}

/// Padding of feature planes so that a run of pairs can be computed in whole groups of 8 (the
/// extra results are dropped).
const RUN_PAD: usize = 8;

/// Largest pair table (floats per array) a band builds; larger windows fill cell by cell.
const PAIRS_MAX_FLOATS: usize = 1 << 22;

impl Pairs {
    /// The table for start rows `band` and window radius `r`, into `self` (buffers reused);
    /// false if it would be too large.
    fn compute(
        &mut self,
        kernel: Kernel,
        input: &WalkInput,
        inv: f32,
        r: usize,
        band: Range<usize>,
    ) -> bool {
        let (w, h) = input.color.dims();
        let ri = r as isize;
        let offsets: Vec<(isize, isize)> = (1..=ri)
            .map(|dx| (dx, 0))
            .chain((1..=ri).flat_map(|dy| (-ri..=ri).map(move |dx| (dx, dy))))
            .collect();
        let first_row = band.start.saturating_sub(r);
        let rows = band.end - first_row;
        let n = offsets.len() * rows * w;
        if n > PAIRS_MAX_FLOATS {
            return false;
        }
        let planes = input
            .features
            .planes(first_row..(band.end + r).min(h), r + RUN_PAD);
        let mut run = vec![0.0f32; w + RUN_PAD];
        let depth_weight = input.features.depth_weight();
        let (log, lin) = (&mut self.log, &mut self.lin);
        log.clear();
        log.resize(n, f32::NEG_INFINITY);
        lin.clear();
        lin.resize(n, 0.0);
        for (o, &(dx, dy)) in offsets.iter().enumerate() {
            let lo = (-dx).max(0) as usize;
            let hi = (w as isize - dx).clamp(0, w as isize) as usize;
            for y in first_row..band.end {
                let ny = y + dy as usize;
                if ny >= h || lo >= hi {
                    continue;
                }
                let at = (o * rows + y - first_row) * w;
                let center = planes.offset(lo as isize, y);
                let other = planes.offset(lo as isize + dx, ny);
                let n = hi - lo;
                distance_row(
                    kernel,
                    &planes,
                    depth_weight,
                    center,
                    other,
                    &mut run[..n.next_multiple_of(8)],
                );
                let t = &mut log[at + lo..at + hi];
                t.copy_from_slice(&run[..n]);
                for v in t.iter_mut() {
                    *v = -(*v * *v) * inv;
                }
                let e = &mut lin[at + lo..at + hi];
                e.copy_from_slice(t);
                exp_neg_row(kernel, e);
            }
        }
        (self.offsets, self.first_row, self.rows, self.width) = (offsets, first_row, rows, w);
        true
    }

    /// Entry (offset index `o`, pixel (x, y)): the log term and its exp.
    #[inline]
    fn at(&self, o: usize, x: usize, y: usize) -> (f32, f32) {
        let i = (o * self.rows + y - self.first_row) * self.width + x;
        (self.log[i], self.lin[i])
    }
}

/// The x0 terms −d(x0, y)²/(2σ²) of one start pixel and their exps, cached in (2r+3)² grids
/// centred on x0 whose cells outside the window, the image or the mask (and the whole outer ring)
/// are −∞ (exp: 0).
struct Window<'g> {
    grid: &'g [f32],
    egrid: &'g [f32],
    side: usize,
    i0: usize,
}

impl<'g> Window<'g> {
    /// Fills x0's grids from the band's `pairs` table when there is one, else by computing each
    /// cell's distance (windows too large for a table).
    #[allow(clippy::too_many_arguments)]
    fn fill(
        input: &WalkInput,
        inv: f32,
        grid: &'g mut [f32],
        egrid: &'g mut [f32],
        pairs: Option<&Pairs>,
        r: usize,
        x0: usize,
        y0: usize,
    ) -> Self {
        let (w, h) = input.color.dims();
        let side = 2 * r + 3;
        let i0 = y0 * w + x0;
        let blocked = |j: usize| input.mask.is_some_and(|m| m[j]);
        let (grid, egrid) = (&mut grid[..side * side], &mut egrid[..side * side]);
        grid.fill(f32::NEG_INFINITY);
        egrid.fill(0.0);
        let center = (r + 1) * side + r + 1;
        if let Some(pairs) = pairs {
            if !blocked(i0) {
                let d = input.features.distance(i0, i0);
                grid[center] = -(d * d) * inv;
                egrid[center] = exp_neg(grid[center]);
            }
            let inside =
                |x: isize, y: isize| x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h;
            let (sx, sy) = (x0 as isize, y0 as isize);
            for (o, &(dx, dy)) in pairs.offsets.iter().enumerate() {
                let cell = dy * side as isize + dx;
                // x0 + o: the entry of x0 itself.
                let (x, y) = (sx + dx, sy + dy);
                if inside(x, y) && !blocked(y as usize * w + x as usize) {
                    let (g, e) = pairs.at(o, x0, y0);
                    let c = (center as isize + cell) as usize;
                    (grid[c], egrid[c]) = (g, e);
                }
                // x0 − o: the entry of x0 − o, whose partner at +o is x0 (d is symmetric).
                let (x, y) = (sx - dx, sy - dy);
                if inside(x, y) && !blocked(y as usize * w + x as usize) {
                    let (g, e) = pairs.at(o, x as usize, y as usize);
                    let c = (center as isize - cell) as usize;
                    (grid[c], egrid[c]) = (g, e);
                }
            }
        } else {
            let (ylo, yhi) = (y0.saturating_sub(r), (y0 + r).min(h - 1));
            let (xlo, xhi) = (x0.saturating_sub(r), (x0 + r).min(w - 1));
            for y in ylo..=yhi {
                for x in xlo..=xhi {
                    let j = y * w + x;
                    if !blocked(j) {
                        let d = input.features.distance(i0, j);
                        let g = (y + r + 1 - y0) * side + r + 1 + x - x0;
                        grid[g] = -(d * d) * inv;
                        egrid[g] = exp_neg(grid[g]);
                    }
                }
            }
        }
        Window {
            grid,
            egrid,
            side,
            i0,
        }
    }

    /// The grid cell of x0.
    fn center(&self) -> usize {
        (self.side / 2) * self.side + self.side / 2
    }
}

/// Walks from the window's x0, lane by lane (the portable kernel).
#[inline(never)]
fn walk_windowed(
    input: &WalkInput,
    params: &WalkParams,
    near: &Near,
    win: &Window,
) -> (Accum, u64) {
    let w = input.color.width();
    let goff: [isize; 8] = OFFSETS.map(|(dx, dy)| dy * win.side as isize + dx);
    let ioff: [isize; 8] = OFFSETS.map(|(dx, dy)| dy * w as isize + dx);
    let ln_pmin = params.p_min.ln();
    let pkey = pixel_key(input.seed, input.level, win.i0);
    let mut acc = Accum::new(input, win.i0, params);
    let mut steps = 0u64;
    for walk in 0..params.walks {
        let key = walk_key(pkey, walk);
        let (mut g, mut i) = (win.center(), win.i0);
        let mut log_p = 0.0f64;
        let mut part = Accum::default();
        for step in 1..=params.max_steps {
            let (t, e) = (near.log(i), near.lin(i));
            let mut a = [0.0f32; 8];
            let mut l = [0.0f32; 8];
            for k in 0..8 {
                let gk = (g as isize + goff[k]) as usize;
                a[k] = win.grid[gk] + t[k];
                l[k] = win.egrid[gk] * e[k];
            }
            let Some((k, lp)) = choose(&a, &l, uniform(key, step)) else {
                break;
            };
            log_p += lp as f64;
            if log_p < ln_pmin {
                break;
            }
            g = (g as isize + goff[k]) as usize;
            i = (i as isize + ioff[k]) as usize;
            steps += 1;
            part.add(input.color.pixel(i), step_weight(log_p, step));
        }
        acc.merge(&part);
    }
    (acc, steps)
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    //! The windowed walk with AVX2, bit for bit equal to `super::walk_windowed`.
    //!
    //! [`SLOTS`] walks of one start pixel advance in lockstep. For each, the pick is one register
    //! of 8 neighbour weights (one load of the pixel's precomputed factors, two loads and two blends
    //! for the window's, a multiply, an in-register prefix sum, a compare and a bit scan). The
    //! scalar tail of a step (ln of the normaliser, the f64 log-probability, the exp of the weight,
    //! the f64 colour sums) then runs once for all slots, one slot per lane. Every operation mirrors
    //! the scalar spec (same IEEE operations in the same order), so the results are bit-identical.

    use std::arch::x86_64::*;

    use super::{choose_log, pixel_key, uniform, walk_key, Accum, Near, LINEAR_MIN, OFFSETS};
    use crate::fastmath::avx2::exp_neg8;
    use crate::fastmath::{LN2_HI, LN2_LO, LN_POLY};
    use crate::walk::{WalkInput, WalkParams};

    /// Walks in lockstep per start pixel (a multiple of 4, the lanes of the f64 tail).
    const SLOTS: usize = 8;

    /// `super::prefix8` on a register.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn prefix8(e: __m256) -> __m256 {
        let x = _mm256_add_ps(
            e,
            _mm256_castsi256_ps(_mm256_slli_si256::<4>(_mm256_castps_si256(e))),
        );
        let x = _mm256_add_ps(
            x,
            _mm256_castsi256_ps(_mm256_slli_si256::<8>(_mm256_castps_si256(x))),
        );
        let low_total = _mm256_shuffle_ps::<0xff>(x, x);
        _mm256_add_ps(x, _mm256_permute2f128_ps::<0x08>(low_total, low_total))
    }

    /// `fastmath::exp_neg` on 4 lanes (the low half of the 8-lane version).
    #[inline]
    #[target_feature(enable = "avx2")]
    fn exp_neg4(x: __m128) -> __m128 {
        _mm256_castps256_ps128(exp_neg8(_mm256_set_m128(_mm_setzero_ps(), x)))
    }

    /// `fastmath::ln_normal` on 4 lanes.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn ln_normal4(x: __m128) -> __m128 {
        let set = _mm_set1_ps;
        let (add, mul, sub) = (_mm_add_ps, _mm_mul_ps, _mm_sub_ps);
        let bits = _mm_castps_si128(x);
        let e = _mm_sub_epi32(
            _mm_and_si128(_mm_srli_epi32::<23>(bits), _mm_set1_epi32(0xff)),
            _mm_set1_epi32(127),
        );
        let m = _mm_castsi128_ps(_mm_or_si128(
            _mm_and_si128(bits, _mm_set1_epi32(0x007f_ffff)),
            _mm_set1_epi32(0x3f80_0000),
        ));
        let big = _mm_cmp_ps::<_CMP_GT_OQ>(m, set(std::f32::consts::SQRT_2));
        let m = _mm_blendv_ps(m, mul(m, set(0.5)), big);
        // `big` lanes are all ones, i.e. −1: subtracting adds 1 to the exponent.
        let e = _mm_sub_epi32(e, _mm_castps_si128(big));
        let f = sub(m, set(1.0));
        let z = mul(f, f);
        let f4 = mul(z, z);
        let [c8, c7, c6, c5, c4, c3, c2, c1, c0] = LN_POLY;
        let lin = |hi: f32, lo: f32| add(mul(set(hi), f), set(lo));
        let y = add(
            add(lin(c1, c0), mul(lin(c3, c2), z)),
            mul(add(lin(c5, c4), mul(lin(c7, c6), z)), f4),
        );
        let y = add(y, mul(set(c8), mul(f4, f4)));
        let ef = _mm_cvtepi32_ps(e);
        let y = sub(
            add(mul(mul(y, f), z), mul(ef, set(LN2_LO))),
            mul(set(0.5), z),
        );
        add(add(f, y), mul(ef, set(LN2_HI)))
    }

    /// The window values of cell g's 8 neighbours, in lane order: three above, left, right, three below.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn window_block(grid: &[f32], g: usize, side: usize) -> __m256 {
        let above = &grid[g - side - 1..g - side + 3];
        let below = &grid[g + side - 2..g + side + 2];
        // SAFETY: both slices hold 4 floats (bounds-checked above); loads are unaligned.
        let (above, below) =
            unsafe { (_mm_loadu_ps(above.as_ptr()), _mm_loadu_ps(below.as_ptr())) };
        let lo = _mm_blend_ps::<0b1000>(above, _mm_set1_ps(grid[g - 1]));
        let hi = _mm_blend_ps::<0b0001>(below, _mm_set1_ps(grid[g + 1]));
        _mm256_set_m128(hi, lo)
    }

    /// The pick of one step: lane `k`, and `x`, `sum` with log-probability x − ln(sum).
    struct Pick {
        k: usize,
        x: f32,
        sum: f32,
    }

    /// `super::choose` for the walk at grid cell g, pixel i, with draw u; `None` ends the walk.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn pick(
        near: &Near,
        win: &Batch,
        goff: &[isize; 8],
        g: usize,
        i: usize,
        u: f32,
    ) -> Option<Pick> {
        // SAFETY: a Near row is 8 floats; unaligned load.
        let e = unsafe { _mm256_loadu_ps(near.lin(i).as_ptr()) };
        let l = _mm256_mul_ps(window_block(win.egrid, g, win.side), e);
        let c = prefix8(l);
        let sum = _mm256_cvtss_f32(_mm256_permutevar8x32_ps(c, _mm256_set1_epi32(7)));
        if sum >= LINEAR_MIN {
            let target = _mm256_set1_ps(u * sum);
            let bits = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LT_OQ>(target, c));
            let k = if bits != 0 {
                bits.trailing_zeros() as usize
            } else {
                let nonzero =
                    _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_GT_OQ>(l, _mm256_setzero_ps()));
                31 - nonzero.leading_zeros() as usize
            };
            let x = win.grid[(g as isize + goff[k]) as usize] + near.log(i)[k];
            return Some(Pick { k, x, sum });
        }
        let t = near.log(i);
        let mut a = [0.0f32; 8];
        for k in 0..8 {
            a[k] = win.grid[(g as isize + goff[k]) as usize] + t[k];
        }
        choose_log(&a, u).map(|(k, x, sum)| Pick { k, x, sum })
    }

    /// Start pixels per call of [`walk_batch`] for `walks` walks each: enough walks to fill the slots.
    pub(super) fn batch(walks: u32) -> usize {
        SLOTS.div_ceil(walks.max(1) as usize).max(1)
    }

    /// The window grids of a batch of start pixels, in one buffer.
    pub(super) struct Batch<'a> {
        pub grid: &'a [f32],
        pub egrid: &'a [f32],
        pub side: usize,
        /// Per start pixel: the grid cell of its centre, and its pixel index.
        pub starts: &'a [(usize, usize)],
    }

    /// `super::walk_windowed` for every start pixel of `win`, bit for bit, their walks sharing the
    /// slots (so few walks per pixel still fill a register). `parts` is scratch space for the walks'
    /// sums; `accs[b]` receives start pixel b's result. Returns the steps taken.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn walk_batch(
        input: &WalkInput,
        params: &WalkParams,
        near: &Near,
        win: Batch,
        parts: &mut Vec<Accum>,
        accs: &mut [Accum],
    ) -> u64 {
        let w = input.color.width();
        let goff: [isize; 8] = OFFSETS.map(|(dx, dy)| dy * win.side as isize + dx);
        let ioff: [isize; 8] = OFFSETS.map(|(dx, dy)| dy * w as isize + dx);
        let ln_pmin = _mm256_set1_pd(params.p_min.ln());
        let walks = params.walks as usize;
        let total = walks * win.starts.len();
        let pkeys: [u64; SLOTS] = std::array::from_fn(|b| {
            win.starts
                .get(b)
                .map_or(0, |&(_, i0)| pixel_key(input.seed, input.level, i0))
        });
        parts.clear();
        parts.resize(total, Accum::default());

        // Slot state, one lane each; job j is walk j % walks of start pixel j / walks.
        let mut job = [0usize; SLOTS];
        let mut key = [0u64; SLOTS];
        let mut g = [0usize; SLOTS];
        let mut i = [0usize; SLOTS];
        let mut step = [0i32; SLOTS];
        let mut live = [false; SLOTS];
        let mut log_p = [0.0f64; SLOTS];
        let mut sum = [[0.0f64; SLOTS]; 3];
        let mut weight = [0.0f64; SLOTS];

        // Slots beyond the walk count would only add idle lanes to every round.
        let slots = total.min(SLOTS).div_ceil(4) * 4;
        let start = |j: usize| {
            let (cell, i0) = win.starts[j / walks];
            (cell, i0, walk_key(pkeys[j / walks], (j % walks) as u32))
        };
        let mut next = 0usize;
        for s in 0..slots {
            if next < total {
                (g[s], i[s], key[s]) = start(next);
                (job[s], live[s]) = (next, true);
                next += 1;
            }
        }
        let mut steps = 0u64;
        let max_steps = params.max_steps.min(i32::MAX as u32) as i32;
        let color = input.color.data();
        while live.iter().any(|&l| l) {
            // The picks, slot by slot; a slot that cannot step gets (x, sum) = (0, 1) and is ended below.
            let mut going = [false; SLOTS];
            let mut ks = [0usize; SLOTS];
            let mut xs = [0.0f32; SLOTS];
            let mut sums = [1.0f32; SLOTS];
            for s in 0..slots {
                if !live[s] || step[s] >= max_steps {
                    continue;
                }
                let u = uniform(key[s], step[s] as u32 + 1);
                if let Some(p) = pick(near, &win, &goff, g[s], i[s], u) {
                    (going[s], ks[s], xs[s], sums[s]) = (true, p.k, p.x, p.sum);
                }
            }
            // The tail, four slots per register: log-probability, stop test, weight, colour sums.
            for o in (0..slots).step_by(4) {
                let q = o..o + 4;
                let lp = _mm_sub_ps(
                    _mm_loadu_ps(xs[q.clone()].as_ptr()),
                    ln_normal4(_mm_loadu_ps(sums[q.clone()].as_ptr())),
                );
                let old_log_p = _mm256_loadu_pd(log_p[q.clone()].as_ptr());
                let new_log_p = _mm256_add_pd(old_log_p, _mm256_cvtps_pd(lp));
                let above = _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_NLT_UQ>(new_log_p, ln_pmin));
                let mut moved = [0.0f64; 4];
                for (lane, s) in q.clone().enumerate() {
                    going[s] &= above & (1 << lane) != 0;
                    if going[s] {
                        g[s] = (g[s] as isize + goff[ks[s]]) as usize;
                        i[s] = (i[s] as isize + ioff[ks[s]]) as usize;
                        step[s] += 1;
                        moved[lane] = f64::from_bits(u64::MAX);
                    }
                }
                let moved = _mm256_loadu_pd(moved.as_ptr());
                let step_pd = _mm256_cvtepi32_pd(_mm_loadu_si128(step[q.clone()].as_ptr().cast()));
                let wgt =
                    _mm256_cvtps_pd(exp_neg4(_mm256_cvtpd_ps(_mm256_div_pd(new_log_p, step_pd))));
                let wgt = _mm256_and_pd(wgt, moved);
                for c in 0..3 {
                    let px = |lane: usize| color[3 * i[o + lane] + c] as f64;
                    let col = _mm256_set_pd(px(3), px(2), px(1), px(0));
                    let acc = _mm256_loadu_pd(sum[c][q.clone()].as_ptr());
                    let acc =
                        _mm256_blendv_pd(acc, _mm256_add_pd(acc, _mm256_mul_pd(wgt, col)), moved);
                    _mm256_storeu_pd(sum[c][q.clone()].as_mut_ptr(), acc);
                }
                let wsum = _mm256_loadu_pd(weight[q.clone()].as_ptr());
                _mm256_storeu_pd(
                    weight[q.clone()].as_mut_ptr(),
                    _mm256_blendv_pd(wsum, _mm256_add_pd(wsum, wgt), moved),
                );
                _mm256_storeu_pd(
                    log_p[q.clone()].as_mut_ptr(),
                    _mm256_blendv_pd(old_log_p, new_log_p, moved),
                );
            }
            // Ended walks hand in their sums; their slot takes the next walk.
            for s in 0..slots {
                if !live[s] || going[s] {
                    continue;
                }
                steps += step[s] as u64;
                parts[job[s]] = Accum {
                    sum: [sum[0][s], sum[1][s], sum[2][s]],
                    weight: weight[s],
                };
                (step[s], log_p[s], weight[s]) = (0, 0.0, 0.0);
                for c in 0..3 {
                    sum[c][s] = 0.0;
                }
                if next < total {
                    (g[s], i[s], key[s]) = start(next);
                    job[s] = next;
                    next += 1;
                } else {
                    live[s] = false;
                }
            }
        }
        for (b, &(_, i0)) in win.starts.iter().enumerate() {
            let mut acc = Accum::new(input, i0, params);
            for part in &parts[b * walks..(b + 1) * walks] {
                acc.merge(part);
            }
            accs[b] = acc;
        }
        steps
    }
}

/// Walks from (x0, y0) with no window: the x0 term is computed on the fly.
fn walk_unbounded(
    input: &WalkInput,
    params: &WalkParams,
    near: &Near,
    inv: f32,
    x0: usize,
    y0: usize,
) -> (Accum, u64) {
    let w = input.color.width();
    let i0 = y0 * w + x0;
    let ioff: [isize; 8] = OFFSETS.map(|(dx, dy)| dy * w as isize + dx);
    let ln_pmin = params.p_min.ln();
    let pkey = pixel_key(input.seed, input.level, i0);
    let mut acc = Accum::new(input, i0, params);
    let mut steps = 0u64;
    for walk in 0..params.walks {
        let key = walk_key(pkey, walk);
        let mut i = i0;
        let mut log_p = 0.0f64;
        let mut part = Accum::default();
        for step in 1..=params.max_steps {
            let (t, e) = (near.log(i), near.lin(i));
            let mut a = [f32::NEG_INFINITY; 8];
            let mut l = [0.0f32; 8];
            for k in 0..8 {
                if t[k] != f32::NEG_INFINITY {
                    let d0 = input.features.distance(i0, (i as isize + ioff[k]) as usize);
                    let t0 = -(d0 * d0) * inv;
                    a[k] = t0 + t[k];
                    l[k] = exp_neg(t0) * e[k];
                }
            }
            let Some((k, lp)) = choose(&a, &l, uniform(key, step)) else {
                break;
            };
            log_p += lp as f64;
            if log_p < ln_pmin {
                break;
            }
            i = (i as isize + ioff[k]) as usize;
            steps += 1;
            part.add(input.color.pixel(i), step_weight(log_p, step));
        }
        acc.merge(&part);
    }
    (acc, steps)
}
