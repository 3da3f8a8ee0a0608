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

/// The index step to each of the 8 neighbours (in [`OFFSETS`] order) in a row-major grid `stride`
/// wide.
#[inline]
fn lane_offsets(stride: usize) -> [isize; 8] {
    OFFSETS.map(|(dx, dy)| dy * stride as isize + dx)
}

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
    /// Index in the whole image of this input's first pixel (0 for a whole image): a strip of
    /// rows draws the random numbers the whole image would.
    pub origin: usize,
}

impl WalkInput<'_> {
    /// The key of start pixel `pixel` (an index into this input).
    #[inline]
    fn key(&self, pixel: usize) -> u64 {
        pixel_key(self.seed, self.level, self.origin + pixel)
    }
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

/// The first lane of weight > 0 whose cumulative weight exceeds `target`; if rounding put
/// `target` above every such lane, the most likely lane (ALGORITHM.md §3).
///
/// The weight test is what keeps walks inside their window and the image: [`prefix8`]'s sums are
/// not monotone to the last ulp (c[3] = (e3 + e2) + (e1 + e0) may exceed c[2] = (e2 + e1) + e0 with
/// e3 = 0), so "a cumulative sum exceeds the target" alone can pick a lane of weight 0, and such
/// lanes are the neighbours outside the window, the image or the mask. Callers guarantee some
/// lane has weight > 0 (Σ ≥ [`LINEAR_MIN`], or the max-subtracted lane's exp(0) = 1).
#[inline]
pub fn pick(c: &[f32; 8], e: &[f32; 8], target: f32) -> usize {
    (0..8)
        .find(|&k| e[k] > 0.0 && target < c[k])
        .unwrap_or_else(|| most_likely(e))
}

/// The first lane of the largest weight > 0 (lane 0 if none is: callers rule that out).
#[inline]
fn most_likely(e: &[f32; 8]) -> usize {
    let mut best = 0;
    let mut top = 0.0f32;
    for k in 0..8 {
        if e[k] > top {
            (best, top) = (k, e[k]);
        }
    }
    best
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
            let pkey = input.key(i0);
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

/// Pixels per strip of [`denoise_in_strips`]: their features take 8 MB, and two or three strips
/// are alive at a time. A budget in pixels, not rows, so that the memory is the same at every
/// width. (At 4 MP, strips of 16 MB made `full`'s peak 664–700 MB, of 8 MB 662–665 MB.)
pub const STRIP_PIXELS: usize = 1 << 17;

/// Rows per strip of [`denoise_in_strips`] for an image `width` pixels wide.
pub fn strip_rows(width: usize) -> usize {
    (STRIP_PIXELS / width.max(1)).max(1)
}

/// The strips of [`denoise_in_strips`] for an image `h` rows high: (rows kept, rows computed).
pub fn strips(
    h: usize,
    params: &WalkParams,
    strip_rows: usize,
) -> Vec<(Range<usize>, Range<usize>)> {
    let Some(reach) = params.window.map(|r| r.min(params.max_steps) as usize) else {
        return vec![(0..h, 0..h)];
    };
    (0..h)
        .step_by(strip_rows.max(1))
        .map(|y0| {
            let y1 = (y0 + strip_rows.max(1)).min(h);
            (y0..y1, y0.saturating_sub(reach)..(y1 + reach).min(h))
        })
        .collect()
}

/// [`denoise`] a strip of `strip_rows` rows at a time, with features built per strip by
/// `features_for(rows)` (a [`Features`] whose row 0 is image row `rows.start`).
///
/// Why: features take 64 bytes a pixel, the largest per-pixel table of a run (268 MB at 4 MP).
/// Windowed walks reach at most the window radius from their start row, so each strip needs only
/// its rows' features plus that halo; walks start from the strip's own rows only. Keys use
/// whole-image pixel indices and nothing a walk can reach differs, so the result and the step
/// count are those of one whole-image run, bit for bit. Unbounded walks may reach any row: one
/// strip.
///
/// Strips do not end in a barrier: every thread takes the next task of one queue (build strip
/// s + 1's features, placed [`LOOKAHEAD`] bands into strip s, or denoise a band), so while one
/// thread builds the next strip the others finish this one. A strip's features are dropped when
/// its last band is done: two strips' features are alive at a time (more only if a band of an
/// older strip is still running when a build starts).
#[allow(clippy::too_many_arguments)]
pub fn denoise_in_strips(
    color: &Image,
    features_for: &(dyn Fn(Range<usize>) -> crate::error::Result<Features> + Sync),
    mask: Option<&[bool]>,
    seed: u64,
    level: u32,
    params: &WalkParams,
    strip_rows: usize,
    on_row: &(dyn Fn() + Sync),
) -> crate::error::Result<(Image, WalkStats)> {
    let (w, h) = color.dims();
    let mut out = Image::new(w, h, 3);
    let strips = strips(h, params, strip_rows);
    let kernel = Kernel::detect();
    let radius = params.window.map(|r| r.min(params.max_steps) as usize);
    let band = Band {
        kernel,
        inv: inv_two_sigma2(params.sigma),
        radius,
        global: None,
    };
    if radius.is_none() || strips.len() <= 1 {
        // One strip (unbounded walks share one whole-image table): the plain parallel run.
        let features = features_for(0..h)?;
        let input = WalkInput {
            color,
            features: &features,
            mask,
            seed,
            level,
            origin: 0,
        };
        return Ok(denoise_with(kernel, &input, params, on_row));
    }

    // The queue: build strip 0, then each strip's bands with the next strip's build among them.
    let mut tasks = vec![Task::Build(0)];
    for (s, (kept, _)) in strips.iter().enumerate() {
        let ys: Vec<_> = kept.clone().step_by(BAND_ROWS).collect();
        for (b, &y) in ys.iter().enumerate() {
            if s + 1 < strips.len() && b == LOOKAHEAD.min(ys.len() - 1) {
                tasks.push(Task::Build(s + 1));
            }
            tasks.push(Task::Band(s, y..(y + BAND_ROWS).min(kept.end)));
        }
    }
    // Each band's output rows, by task index, handed to whichever thread takes the band.
    let mut rest = out.data_mut();
    let outputs: Vec<_> = tasks
        .iter()
        .map(|task| {
            let rows = match task {
                Task::Band(_, ys) => {
                    let (head, tail) = std::mem::take(&mut rest).split_at_mut(3 * w * ys.len());
                    rest = tail;
                    Some(head)
                }
                Task::Build(_) => None,
            };
            std::sync::Mutex::new(rows)
        })
        .collect();
    let slots: Vec<Slot> = strips
        .iter()
        .map(|(kept, _)| Slot {
            state: std::sync::Mutex::new(StripState::Pending),
            ready: std::sync::Condvar::new(),
            bands_left: std::sync::atomic::AtomicUsize::new(kept.len().div_ceil(BAND_ROWS)),
        })
        .collect();
    let next = std::sync::atomic::AtomicUsize::new(0);
    let steps = AtomicU64::new(0);
    let error = std::sync::Mutex::new(None);
    // One worker per pool thread. Broadcast jobs cannot be stolen, so a thread waiting inside a
    // build's parallel loop never starts a second worker that would wait on that same build.
    rayon::broadcast(|_| loop {
        let t = next.fetch_add(1, Ordering::Relaxed);
        let Some(task) = tasks.get(t) else { break };
        match task {
            Task::Build(s) => {
                let rows = strips[*s].1.clone();
                let state = match features_for(rows.clone()) {
                    Ok(features) => {
                        let color = Image::from_vec(
                            w,
                            rows.len(),
                            3,
                            color.data()[3 * w * rows.start..3 * w * rows.end].to_vec(),
                        )
                        .expect("a strip of a 3-channel image");
                        StripState::Ready(std::sync::Arc::new(StripData { features, color }))
                    }
                    Err(e) => {
                        error.lock().expect("no panic holding it").get_or_insert(e);
                        StripState::Gone
                    }
                };
                *slots[*s].state.lock().expect("no panic holding it") = state;
                slots[*s].ready.notify_all();
            }
            Task::Band(s, ys) => {
                let slot = &slots[*s];
                let data = {
                    let mut state = slot.state.lock().expect("no panic holding it");
                    loop {
                        match &*state {
                            StripState::Pending => {
                                state = slot.ready.wait(state).expect("no panic holding it")
                            }
                            StripState::Ready(data) => break Some(data.clone()),
                            StripState::Gone => break None,
                        }
                    }
                };
                let Some(data) = data else { continue };
                let rows = strips[*s].1.clone();
                let input = WalkInput {
                    color: &data.color,
                    features: &data.features,
                    mask: mask.map(|m| &m[w * rows.start..w * rows.end]),
                    seed,
                    level,
                    origin: w * rows.start,
                };
                let dest = outputs[t]
                    .lock()
                    .expect("no panic holding it")
                    .take()
                    .expect("each band is taken once");
                let local = ys.start - rows.start..ys.end - rows.start;
                let n = band.run(&input, params, local, dest, on_row);
                steps.fetch_add(n, Ordering::Relaxed);
                drop(data);
                if slot.bands_left.fetch_sub(1, Ordering::AcqRel) == 1 {
                    *slot.state.lock().expect("no panic holding it") = StripState::Gone;
                }
            }
        }
    });
    if let Some(e) = error.into_inner().expect("no panic holding it") {
        return Err(e);
    }
    let stats = WalkStats {
        walks: (w * h) as u64 * params.walks as u64,
        steps: steps.into_inner(),
    };
    Ok((out, stats))
}

/// Bands of a strip denoised before the next strip's features start building: time for older
/// strips' last bands to finish, so their features are gone before new ones are made.
const LOOKAHEAD: usize = 2;

/// A step of [`denoise_in_strips`]'s queue.
enum Task {
    /// Build strip s's features.
    Build(usize),
    /// Denoise the start pixels of these image rows of strip s.
    Band(usize, Range<usize>),
}

/// What the bands of one strip read.
struct StripData {
    features: Features,
    color: Image,
}

/// Where a strip's features stand; bands of the strip wait on [`Slot::ready`] while `Pending`.
enum StripState {
    Pending,
    Ready(std::sync::Arc<StripData>),
    /// The build failed, or every band is done (the features are dropped).
    Gone,
}

/// One strip's shared state in [`denoise_in_strips`]'s queue.
struct Slot {
    state: std::sync::Mutex<StripState>,
    ready: std::sync::Condvar,
    bands_left: std::sync::atomic::AtomicUsize,
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
    /// Per pixel results of a batch.
    accs: Vec<Accum>,
    /// The AVX2 kernel's per-walk tables.
    #[cfg(target_arch = "x86_64")]
    walks: avx2::Walks,
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
    denoise_rows(kernel, input, params, 0..input.color.height(), on_row)
}

/// [`denoise_with`] for the start pixels of rows `starts` only: the result has `starts.len()`
/// rows. Walks still reach every row of `input` (a strip's halo holds features, not work).
pub fn denoise_rows(
    kernel: Kernel,
    input: &WalkInput,
    params: &WalkParams,
    starts: Range<usize>,
    on_row: &(dyn Fn() + Sync),
) -> (Image, WalkStats) {
    let kernel = if kernel.is_available() {
        kernel
    } else {
        Kernel::Scalar
    };
    let (w, h) = input.color.dims();
    assert!(starts.end <= h, "start rows inside the image");
    let inv = inv_two_sigma2(params.sigma);
    let steps = AtomicU64::new(0);
    let mut out = Image::new(w, starts.len(), 3);
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
            let y_begin = starts.start + band * BAND_ROWS;
            let y_end = (y_begin + BAND_ROWS).min(starts.end);
            let band = Band {
                kernel,
                inv,
                radius,
                global: global.as_ref(),
            };
            let n = band.run(input, params, y_begin..y_end, rows, on_row);
            steps.fetch_add(n, Ordering::Relaxed);
        });
    let stats = WalkStats {
        walks: (w * starts.len()) as u64 * params.walks as u64,
        steps: steps.into_inner(),
    };
    (out, stats)
}

/// What every band of one kernel run shares.
struct Band<'a> {
    kernel: Kernel,
    inv: f32,
    /// Window radius clipped to the step cap; `None` for unbounded walks.
    radius: Option<usize>,
    /// The whole-image neighbour table of unbounded walks.
    global: Option<&'a Near>,
}

impl Band<'_> {
    /// Denoises the start pixels of image rows `ys` into `rows` (3 floats a pixel, row `ys.start`
    /// first), with this thread's scratch tables; returns the steps taken.
    fn run(
        &self,
        input: &WalkInput,
        params: &WalkParams,
        ys: Range<usize>,
        rows: &mut [f32],
        on_row: &(dyn Fn() + Sync),
    ) -> u64 {
        let Band {
            kernel,
            inv,
            radius,
            global,
        } = *self;
        let (w, h) = input.color.dims();
        let (y_begin, y_end) = (ys.start, ys.end);
        SCRATCH.with_borrow_mut(|scratch| {
            // The rows a walk from this band can reach.
            let halo = radius.map(|r| y_begin.saturating_sub(r)..(y_end + r).min(h));
            let near = match &halo {
                Some(rows) => {
                    scratch.near.compute(kernel, input, inv, rows.clone());
                    &scratch.near
                }
                None => global.expect("built above when there is no window"),
            };
            let pairs = match radius {
                Some(r) if scratch.pairs.compute(kernel, input, inv, r, y_begin..y_end) => {
                    Some(&scratch.pairs)
                }
                _ => None,
            };
            let mut band_steps = 0u64;
            // The AVX2 kernel runs windowed walks on bands its 32-bit indices cover.
            #[cfg(target_arch = "x86_64")]
            let vector = kernel == Kernel::Avx2 && radius.is_some() && avx2::fits(near);
            #[cfg(not(target_arch = "x86_64"))]
            let vector = false;
            // Start pixels whose walks share the AVX2 kernel's lanes.
            let batch = match vector {
                #[cfg(target_arch = "x86_64")]
                true => avx2::batch(params.walks),
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
                            match vector {
                                #[cfg(target_arch = "x86_64")]
                                // SAFETY: `vector` holds only if the CPU reported AVX2 above
                                // and `fits` holds for `near`.
                                true => unsafe {
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
                                        &mut scratch.walks,
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
                            let (acc, n) = walk_unbounded(input, params, near, inv, xs.start, y0);
                            scratch.accs[0] = acc;
                            n
                        }
                    };
                    band_steps += n;
                    for (b, x0) in xs.enumerate() {
                        let i0 = y0 * w + x0;
                        scratch.accs[b].write(input.color.pixel(i0), &mut row[3 * x0..3 * x0 + 3]);
                    }
                }
                on_row();
            }
            band_steps
        })
    }
}

/// The x0 terms of a band's start pixels, each pixel pair computed once: for every offset o of
/// the half window (dy > 0, or dy = 0 and dx > 0) and every pixel p from `first_row` to the band's
/// end, −d(p, p + o)²/(2σ²) and its exp (−∞ and 0 where p + o leaves the image). x0's term for
/// x0 + o is entry (o, x0), and for x0 − o entry (o, x0 − o), as d is symmetric bit for bit. A row
/// of one offset is 8 pairs per vector, against 9-wide window rows filled per start pixel before.
#[derive(Default)]
struct Pairs {
    offsets: Vec<(isize, isize)>,
    /// Per offset (dx, dy): where its plane starts in `log` and `lin`, and its step dy·w + dx in
    /// pixels, and dy·side + dx in window grid cells (side = 2r + 3).
    steps: Vec<(usize, usize, usize)>,
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
        let side = 2 * ri + 3;
        self.steps.clear();
        self.steps
            .extend(offsets.iter().enumerate().map(|(o, &(dx, dy))| {
                (
                    o * rows * w,
                    (dy * w as isize + dx) as usize,
                    (dy * side + dx) as usize,
                )
            }));
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
        let center = (r + 1) * side + r + 1;
        let interior = x0 >= r && x0 + r < w && y0 >= r && y0 + r < h;
        if let (Some(pairs), true) = (pairs, interior) {
            // Every cell of the window is in the image: write the outer ring and then each inner
            // cell once, with no bounds to test.
            for (g, v) in [(&mut *grid, f32::NEG_INFINITY), (&mut *egrid, 0.0)] {
                g[..side].fill(v);
                g[side * (side - 1)..].fill(v);
                for row in 1..side - 1 {
                    g[row * side] = v;
                    g[row * side + side - 1] = v;
                }
            }
            let d = input.features.distance(i0, i0);
            let t = -(d * d) * inv;
            (grid[center], egrid[center]) = (t, exp_neg(t));
            let at = (y0 - pairs.first_row) * w + x0;
            for &(plane, dpix, dcell) in &pairs.steps {
                // x0 + o is entry (o, x0); x0 − o is entry (o, x0 − o), as d is symmetric.
                let (up, down) = (plane + at, plane + at - dpix);
                (grid[center + dcell], egrid[center + dcell]) = (pairs.log[up], pairs.lin[up]);
                (grid[center - dcell], egrid[center - dcell]) = (pairs.log[down], pairs.lin[down]);
            }
            if let Some(mask) = input.mask {
                let cells = pairs.steps.iter().flat_map(|&(_, dpix, dcell)| {
                    [(i0 + dpix, center + dcell), (i0 - dpix, center - dcell)]
                });
                for (j, g) in std::iter::once((i0, center)).chain(cells) {
                    if mask[j] {
                        (grid[g], egrid[g]) = (f32::NEG_INFINITY, 0.0);
                    }
                }
            }
            return Window {
                grid,
                egrid,
                side,
                i0,
            };
        }
        grid.fill(f32::NEG_INFINITY);
        egrid.fill(0.0);
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
    let goff = lane_offsets(win.side);
    let ioff = lane_offsets(w);
    let ln_pmin = params.p_min.ln();
    let pkey = input.key(win.i0);
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
    //! Eight walks advance in lockstep, one per lane, and a step is vertical: each walk's 8
    //! neighbour weights (its pixel's precomputed factors times its window's) are built as one
    //! register, the 8 registers are transposed so that register k holds neighbour k of every walk,
    //! and then the prefix sum, the pick, ln of the normaliser, the f64 log-probability, the weight
    //! and the colour sums are each a handful of instructions for all eight walks. When a walk ends
    //! its lane takes the next walk of the batch, which may belong to the next start pixel, so
    //! lanes seldom idle.
    //!
    //! A step is one chain of dependent operations (where a walk stands decides what it loads
    //! next), so the walk loop does only what the next step needs; the weights and colour sums run
    //! after it, in [`weigh`], from a record of every step, where nothing waits on the walks.
    //!
    //! Every operation mirrors the scalar spec (the same IEEE operations in the same order, the
    //! random numbers from the same integer arithmetic), so the results are bit-identical.

    use std::arch::x86_64::*;

    use super::{choose_log, lane_offsets, walk_key, Accum, Near, GAMMA, LINEAR_MIN};
    use crate::fastmath::avx2::exp_neg8;
    use crate::fastmath::{LN2_HI, LN2_LO, LN_POLY};
    use crate::walk::{WalkInput, WalkParams};

    /// Walks in lockstep: one per f32 lane.
    const SLOTS: usize = 8;

    /// Walks per batch to aim for. Lanes idle only while a batch's last walks finish, so more
    /// walks per batch idle less; the batch's window grids must still fit in L1.
    const BATCH_WALKS: usize = 48;

    /// `fastmath::ln_normal` on 8 lanes.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn ln_normal8(x: __m256) -> __m256 {
        let set = _mm256_set1_ps;
        let (add, mul, sub) = (_mm256_add_ps, _mm256_mul_ps, _mm256_sub_ps);
        let bits = _mm256_castps_si256(x);
        let e = _mm256_sub_epi32(
            _mm256_and_si256(_mm256_srli_epi32::<23>(bits), _mm256_set1_epi32(0xff)),
            _mm256_set1_epi32(127),
        );
        let m = _mm256_castsi256_ps(_mm256_or_si256(
            _mm256_and_si256(bits, _mm256_set1_epi32(0x007f_ffff)),
            _mm256_set1_epi32(0x3f80_0000),
        ));
        let big = _mm256_cmp_ps::<_CMP_GT_OQ>(m, set(std::f32::consts::SQRT_2));
        let m = _mm256_blendv_ps(m, mul(m, set(0.5)), big);
        // `big` lanes are all ones, i.e. −1: subtracting adds 1 to the exponent.
        let e = _mm256_sub_epi32(e, _mm256_castps_si256(big));
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
        let ef = _mm256_cvtepi32_ps(e);
        let y = sub(
            add(mul(mul(y, f), z), mul(ef, set(LN2_LO))),
            mul(set(0.5), z),
        );
        add(add(f, y), mul(ef, set(LN2_HI)))
    }

    /// The low 64 bits of z · c per u64 lane (AVX2 has no 64-bit multiply).
    #[inline]
    #[target_feature(enable = "avx2")]
    fn mul64(z: __m256i, c: u64) -> __m256i {
        let (c_lo, c_hi) = (
            _mm256_set1_epi64x((c & 0xffff_ffff) as i64),
            _mm256_set1_epi64x((c >> 32) as i64),
        );
        let cross = _mm256_add_epi64(
            _mm256_mul_epu32(_mm256_srli_epi64::<32>(z), c_lo),
            _mm256_mul_epu32(z, c_hi),
        );
        _mm256_add_epi64(_mm256_mul_epu32(z, c_lo), _mm256_slli_epi64::<32>(cross))
    }

    /// `super::splitmix` after its increment, cut to the top 24 bits, per u64 lane.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn mix24(z: __m256i) -> __m256i {
        let z = mul64(
            _mm256_xor_si256(z, _mm256_srli_epi64::<30>(z)),
            0xbf58_476d_1ce4_e5b9,
        );
        let z = mul64(
            _mm256_xor_si256(z, _mm256_srli_epi64::<27>(z)),
            0x94d0_49bb_1331_11eb,
        );
        _mm256_srli_epi64::<40>(_mm256_xor_si256(z, _mm256_srli_epi64::<31>(z)))
    }

    /// `super::uniform` for 8 walks whose streams stand at `ctr` (key + (step + 2)·GAMMA: the
    /// draw's counter with splitmix's own increment already added), lanes 0–3 then 4–7.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn uniform8(ctr: [__m256i; 2]) -> __m256 {
        let even = _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6);
        let lo = _mm256_permutevar8x32_epi32(mix24(ctr[0]), even);
        let hi = _mm256_permutevar8x32_epi32(mix24(ctr[1]), even);
        let bits = _mm256_permute2x128_si256::<0x20>(lo, hi);
        // Values below 2^24 convert exactly, as the scalar u64 → f32 cast does.
        _mm256_mul_ps(_mm256_cvtepi32_ps(bits), _mm256_set1_ps(1.0 / 16_777_216.0))
    }

    /// The window factors of cell g's 8 neighbours, in lane order: three above, left, right,
    /// three below.
    ///
    /// # Safety
    /// Cells g ± (side + 1) must lie inside the grid at `grid`.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn window_block(grid: *const f32, g: usize, side: usize) -> __m256 {
        let above = _mm_loadu_ps(grid.add(g - side - 1));
        let below = _mm_loadu_ps(grid.add(g + side - 2));
        let lo = _mm_blend_ps::<0b1000>(above, _mm_broadcast_ss(&*grid.add(g - 1)));
        let hi = _mm_blend_ps::<0b0001>(below, _mm_broadcast_ss(&*grid.add(g + 1)));
        _mm256_set_m128(hi, lo)
    }

    /// Transposes 8 registers of 8 lanes: lane s of the result's register k is lane k of r[s].
    #[inline]
    #[target_feature(enable = "avx2")]
    fn transpose8(r: [__m256; 8]) -> [__m256; 8] {
        let t0 = _mm256_unpacklo_ps(r[0], r[1]);
        let t1 = _mm256_unpackhi_ps(r[0], r[1]);
        let t2 = _mm256_unpacklo_ps(r[2], r[3]);
        let t3 = _mm256_unpackhi_ps(r[2], r[3]);
        let t4 = _mm256_unpacklo_ps(r[4], r[5]);
        let t5 = _mm256_unpackhi_ps(r[4], r[5]);
        let t6 = _mm256_unpacklo_ps(r[6], r[7]);
        let t7 = _mm256_unpackhi_ps(r[6], r[7]);
        let u0 = _mm256_shuffle_ps::<0x44>(t0, t2);
        let u1 = _mm256_shuffle_ps::<0xee>(t0, t2);
        let u2 = _mm256_shuffle_ps::<0x44>(t1, t3);
        let u3 = _mm256_shuffle_ps::<0xee>(t1, t3);
        let u4 = _mm256_shuffle_ps::<0x44>(t4, t6);
        let u5 = _mm256_shuffle_ps::<0xee>(t4, t6);
        let u6 = _mm256_shuffle_ps::<0x44>(t5, t7);
        let u7 = _mm256_shuffle_ps::<0xee>(t5, t7);
        [
            _mm256_permute2f128_ps::<0x20>(u0, u4),
            _mm256_permute2f128_ps::<0x20>(u1, u5),
            _mm256_permute2f128_ps::<0x20>(u2, u6),
            _mm256_permute2f128_ps::<0x20>(u3, u7),
            _mm256_permute2f128_ps::<0x31>(u0, u4),
            _mm256_permute2f128_ps::<0x31>(u1, u5),
            _mm256_permute2f128_ps::<0x31>(u2, u6),
            _mm256_permute2f128_ps::<0x31>(u3, u7),
        ]
    }

    /// Lane s of the result is lane k[s] of rows[s].
    #[inline]
    #[target_feature(enable = "avx2")]
    fn pick8(rows: &[__m256; SLOTS], k: __m256i) -> __m256 {
        let [p0, p1, p2, p3, p4, p5, p6, p7] = [
            _mm256_permutevar8x32_ps(rows[0], k),
            _mm256_permutevar8x32_ps(rows[1], k),
            _mm256_permutevar8x32_ps(rows[2], k),
            _mm256_permutevar8x32_ps(rows[3], k),
            _mm256_permutevar8x32_ps(rows[4], k),
            _mm256_permutevar8x32_ps(rows[5], k),
            _mm256_permutevar8x32_ps(rows[6], k),
            _mm256_permutevar8x32_ps(rows[7], k),
        ];
        let lo = _mm256_blend_ps::<0b1100>(
            _mm256_blend_ps::<0b10>(p0, p1),
            _mm256_blend_ps::<0b1000>(p2, p3),
        );
        let hi = _mm256_blend_ps::<0b1100_0000>(
            _mm256_blend_ps::<0b10_0000>(p4, p5),
            _mm256_blend_ps::<0b1000_0000>(p6, p7),
        );
        _mm256_blend_ps::<0b1111_0000>(lo, hi)
    }

    /// The 8-lane mask vector of the low 8 bits of `bits`.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn lanes(bits: i32) -> __m256i {
        let sel = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
        _mm256_cmpeq_epi32(_mm256_and_si256(_mm256_set1_epi32(bits), sel), sel)
    }

    /// 8 lanes of i32 from memory.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn load_lanes(a: &[i32; SLOTS]) -> __m256i {
        // SAFETY: `a` holds 8 i32; unaligned load.
        unsafe { _mm256_loadu_si256(a.as_ptr().cast()) }
    }

    /// Neighbour index steps as one register (they fit in i32: [`fits`] bounds the tables).
    #[inline]
    #[target_feature(enable = "avx2")]
    fn offsets8(o: [isize; 8]) -> __m256i {
        let o = o.map(|v| v as i32);
        // SAFETY: `o` holds 8 i32; unaligned load.
        unsafe { _mm256_loadu_si256(o.as_ptr().cast()) }
    }

    /// A 32-bit lane mask widened to two f64 masks (lanes 0–3, lanes 4–7).
    #[inline]
    #[target_feature(enable = "avx2")]
    fn widen(m: __m256i) -> [__m256d; 2] {
        [
            _mm256_castsi256_pd(_mm256_cvtepi32_epi64(_mm256_castsi256_si128(m))),
            _mm256_castsi256_pd(_mm256_cvtepi32_epi64(_mm256_extracti128_si256::<1>(m))),
        ]
    }

    /// f32 lanes 0–3 and 4–7 as f64.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn to_f64(x: __m256) -> [__m256d; 2] {
        [
            _mm256_cvtps_pd(_mm256_castps256_ps128(x)),
            _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(x)),
        ]
    }

    /// acc + x where `m` is set, acc elsewhere.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn add_where(acc: __m256d, x: __m256d, m: __m256d) -> __m256d {
        _mm256_blendv_pd(acc, _mm256_add_pd(acc, x), m)
    }

    /// `super::pick` on 8 walks: per lane, the first neighbour of weight > 0 whose cumulative
    /// weight `c` exceeds `target` (8 where none does), from the neighbour weights `l`.
    ///
    /// The weight test keeps a walk from picking a neighbour outside its window or the image,
    /// which the sums alone do not (they are not monotone to the last ulp); such a walk would
    /// then load from outside the band's tables.
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(super) fn pick_lane(c: &[__m256; 8], l: &[__m256; 8], target: __m256) -> __m256i {
        let mut k = _mm256_setzero_si256();
        let mut run = _mm256_set1_epi32(-1);
        for (ck, lk) in c.iter().zip(l) {
            let hit = _mm256_and_ps(
                _mm256_cmp_ps::<_CMP_LT_OQ>(target, *ck),
                _mm256_cmp_ps::<_CMP_GT_OQ>(*lk, _mm256_setzero_ps()),
            );
            run = _mm256_andnot_si256(_mm256_castps_si256(hit), run);
            k = _mm256_sub_epi32(k, run);
        }
        k
    }

    /// `super::most_likely` on 8 walks: the first neighbour of the largest weight > 0.
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(super) fn most_likely8(l: &[__m256; 8]) -> __m256i {
        let mut best = _mm256_setzero_si256();
        let mut top = _mm256_setzero_ps();
        for (lane, lk) in l.iter().enumerate() {
            let gt = _mm256_cmp_ps::<_CMP_GT_OQ>(*lk, top);
            top = _mm256_blendv_ps(top, *lk, gt);
            best = _mm256_blendv_epi8(
                best,
                _mm256_set1_epi32(lane as i32),
                _mm256_castps_si256(gt),
            );
        }
        best
    }

    /// Start pixels per call of [`walk_batch`] for `walks` walks each.
    pub(super) fn batch(walks: u32) -> usize {
        BATCH_WALKS.div_ceil(walks.max(1) as usize).max(1)
    }

    /// Whether [`walk_batch`]'s 32-bit indices reach every entry of the band's tables.
    pub(super) fn fits(near: &Near) -> bool {
        near.lin.len() * 8 <= i32::MAX as usize
    }

    /// The window grids of a batch of start pixels, in one buffer.
    pub(super) struct Batch<'a> {
        pub grid: &'a [f32],
        pub egrid: &'a [f32],
        pub side: usize,
        /// Per start pixel: the grid cell of its centre, and its pixel index.
        pub starts: &'a [(usize, usize)],
    }

    /// Per-lane state of the walks in flight, in memory between the vector parts of a step.
    struct Lanes {
        job: [usize; SLOTS],
        cell: [i32; SLOTS],
        pixel: [i32; SLOTS],
        step: [i32; SLOTS],
        ctr: [u64; SLOTS],
    }

    /// What one step of the walk loop leaves for [`weigh`]: per lane the pixel a walk stands on,
    /// its log-probability and step count, and which walks moved and which ended.
    #[derive(Clone, Copy)]
    struct Record {
        pixel: [i32; SLOTS],
        log_p: [f64; SLOTS],
        step: [i32; SLOTS],
        going: i32,
        ended: i32,
    }

    /// Per-batch scratch of [`walk_batch`], reused from batch to batch.
    #[derive(Default)]
    pub(super) struct Walks {
        /// Each walk's sums, merged per start pixel in walk order at the end.
        parts: Vec<Accum>,
        records: Vec<Record>,
        /// The jobs of the walks that ended, in the order they ended.
        ends: Vec<usize>,
    }

    /// The second loop of [`walk_batch`]: each step's weight exp(L_k / k) (in f32 as the spec
    /// rounds it) and the colour sums, lane by lane in the order the walk loop took the steps,
    /// so every sum is the spec's, bit for bit. Nothing here feeds back into the walks, so the
    /// steps overlap each other.
    #[target_feature(enable = "avx2")]
    unsafe fn weigh(records: &[Record], ends: &[usize], color: *const f32, parts: &mut [Accum]) {
        let mut sum = [[_mm256_setzero_pd(); 2]; 3];
        let mut weight = [_mm256_setzero_pd(); 2];
        let mut ends = ends.iter();
        for rec in records {
            let going_v = lanes(rec.going);
            let moved = widen(going_v);
            let step = _mm256_loadu_si256(rec.step.as_ptr().cast());
            let log_p = [
                _mm256_loadu_pd(rec.log_p.as_ptr()),
                _mm256_loadu_pd(rec.log_p[4..].as_ptr()),
            ];
            let step_pd = [
                _mm256_cvtepi32_pd(_mm256_castsi256_si128(step)),
                _mm256_cvtepi32_pd(_mm256_extracti128_si256::<1>(step)),
            ];
            let ratio = _mm256_set_m128(
                _mm256_cvtpd_ps(_mm256_div_pd(log_p[1], step_pd[1])),
                _mm256_cvtpd_ps(_mm256_div_pd(log_p[0], step_pd[0])),
            );
            // Lanes that did not move may hold 0/0: they get exp(0), masked below.
            let ratio = _mm256_and_ps(ratio, _mm256_castsi256_ps(going_v));
            let wgt = to_f64(exp_neg8(ratio));
            let wgt = [
                _mm256_and_pd(wgt[0], moved[0]),
                _mm256_and_pd(wgt[1], moved[1]),
            ];
            let pixel = _mm256_loadu_si256(rec.pixel.as_ptr().cast());
            let at3 = _mm256_mullo_epi32(pixel, _mm256_set1_epi32(3));
            for (ch, acc) in sum.iter_mut().enumerate() {
                let col = to_f64(_mm256_i32gather_ps::<4>(
                    color.add(ch),
                    _mm256_blendv_epi8(_mm256_setzero_si256(), at3, going_v),
                ));
                for h in 0..2 {
                    acc[h] = add_where(acc[h], _mm256_mul_pd(wgt[h], col[h]), moved[h]);
                }
            }
            for h in 0..2 {
                weight[h] = add_where(weight[h], wgt[h], moved[h]);
            }
            if rec.ended != 0 {
                let mut sums = [[0.0f64; SLOTS]; 4];
                for h in 0..2 {
                    _mm256_storeu_pd(sums[3][4 * h..].as_mut_ptr(), weight[h]);
                    for ch in 0..3 {
                        _mm256_storeu_pd(sums[ch][4 * h..].as_mut_ptr(), sum[ch][h]);
                    }
                }
                let mut bits = rec.ended;
                while bits != 0 {
                    let s = bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    let job = *ends.next().expect("one job per ended walk");
                    parts[job] = Accum {
                        sum: [sums[0][s], sums[1][s], sums[2][s]],
                        weight: sums[3][s],
                    };
                }
                let reset = widen(lanes(rec.ended));
                for h in 0..2 {
                    weight[h] = _mm256_andnot_pd(reset[h], weight[h]);
                    for ch in 0..3 {
                        sum[ch][h] = _mm256_andnot_pd(reset[h], sum[ch][h]);
                    }
                }
            }
        }
    }

    /// `super::walk_windowed` for every start pixel of `win`, bit for bit, their walks sharing the
    /// lanes. `parts` is scratch space for the walks' sums; `accs[b]` receives start pixel b's
    /// result. Returns the steps taken.
    ///
    /// # Safety
    /// The CPU must support AVX2, and [`fits`] must hold for `near`.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn walk_batch(
        input: &WalkInput,
        params: &WalkParams,
        near: &Near,
        win: Batch,
        scratch: &mut Walks,
        accs: &mut [Accum],
    ) -> u64 {
        let w = input.color.width();
        let side = win.side;
        let goff_arr = lane_offsets(side);
        let goff = offsets8(goff_arr);
        let ioff = offsets8(lane_offsets(w));
        let ln_pmin = _mm256_set1_pd(params.p_min.ln());
        let walks = params.walks as usize;
        let total = walks * win.starts.len();
        assert!(
            win.starts.len() <= BATCH_WALKS,
            "batch larger than `batch` gives"
        );
        let Walks {
            parts,
            records,
            ends,
        } = scratch;
        parts.clear();
        parts.resize(total, Accum::default());
        records.clear();
        ends.clear();
        if total == 0 {
            return 0;
        }
        // Pixel indices are relative to the band's first row, so they fit in 32 bits.
        let base = near.base;
        let lin = near.lin.as_ptr().cast::<f32>();
        let log = near.log.as_ptr().cast::<f32>();
        let color = input.color.data()[3 * base..].as_ptr();
        let (grid, egrid) = (win.grid.as_ptr(), win.egrid.as_ptr());

        let two_gamma = GAMMA.wrapping_mul(2);
        // One key per start pixel ([`batch`] never gives more than BATCH_WALKS start pixels).
        let mut pkeys = [0u64; BATCH_WALKS];
        for (key, &(_, i0)) in pkeys.iter_mut().zip(win.starts) {
            *key = input.key(i0);
        }
        let start = |j: usize| {
            let (cell, i0) = win.starts[j / walks];
            let key = walk_key(pkeys[j / walks], (j % walks) as u32);
            (cell as i32, (i0 - base) as i32, key.wrapping_add(two_gamma))
        };
        let mut st = Lanes {
            job: [0; SLOTS],
            cell: [0; SLOTS],
            pixel: [0; SLOTS],
            step: [0; SLOTS],
            ctr: [0; SLOTS],
        };
        // Lanes without a walk sit on the first walk's start cell, so their loads stay in bounds.
        let mut live = 0i32;
        let mut next = 0usize;
        for s in 0..SLOTS {
            let j = next.min(total - 1);
            (st.cell[s], st.pixel[s], st.ctr[s]) = start(j);
            if next < total {
                st.job[s] = next;
                live |= 1 << s;
                next += 1;
            }
        }
        let mut steps = 0u64;
        let max_steps = _mm256_set1_epi32(params.max_steps.min(i32::MAX as u32) as i32);
        let mut cell = load_lanes(&st.cell);
        let mut pixel = load_lanes(&st.pixel);
        let mut step = load_lanes(&st.step);
        let mut ctr = [
            _mm256_loadu_si256(st.ctr.as_ptr().cast()),
            _mm256_loadu_si256(st.ctr[4..].as_ptr().cast()),
        ];
        let mut log_p = [_mm256_setzero_pd(); 2];
        while live != 0 {
            let u = uniform8(ctr);
            // Each walk's 8 neighbour weights, one register per walk, then one per neighbour.
            _mm256_storeu_si256(st.cell.as_mut_ptr().cast(), cell);
            _mm256_storeu_si256(st.pixel.as_mut_ptr().cast(), pixel);
            // Their log-domain twins are loaded too, so that the picked one's is a permute away
            // once the pick is known (a gather would wait on memory). A plain loop, not a
            // closure, which a build may leave out of line: a call per walk.
            let mut rows = [_mm256_setzero_ps(); SLOTS];
            let mut logs = [_mm256_setzero_ps(); SLOTS];
            for s in 0..SLOTS {
                // The loads below are in bounds because every lane stands inside its window and
                // the band: walks move only to a neighbour of weight > 0 (`pick_lane`), and the
                // grid's ring and the band's halo hold the cells around a window's edge.
                debug_assert!(
                    (st.pixel[s] as usize) < near.lin.len()
                        && (st.cell[s] as usize) > side
                        && (st.cell[s] as usize) + side + 1 < win.grid.len(),
                    "walk left its window: pixel {} cell {}",
                    st.pixel[s],
                    st.cell[s]
                );
                let (i, g) = (8 * st.pixel[s] as usize, st.cell[s] as usize);
                let e = _mm256_loadu_ps(lin.add(i));
                rows[s] = _mm256_mul_ps(window_block(egrid, g, side), e);
                logs[s] = _mm256_add_ps(window_block(grid, g, side), _mm256_loadu_ps(log.add(i)));
            }
            let l = transpose8(rows);
            // `super::prefix8`, vertically.
            let c3 = _mm256_add_ps(_mm256_add_ps(l[3], l[2]), _mm256_add_ps(l[1], l[0]));
            let h7 = _mm256_add_ps(_mm256_add_ps(l[7], l[6]), _mm256_add_ps(l[5], l[4]));
            let c = [
                l[0],
                _mm256_add_ps(l[1], l[0]),
                _mm256_add_ps(_mm256_add_ps(l[2], l[1]), l[0]),
                c3,
                _mm256_add_ps(l[4], c3),
                _mm256_add_ps(_mm256_add_ps(l[5], l[4]), c3),
                _mm256_add_ps(_mm256_add_ps(_mm256_add_ps(l[6], l[5]), l[4]), c3),
                _mm256_add_ps(h7, c3),
            ];
            let mut total_w = c[7];
            let target = _mm256_mul_ps(u, total_w);
            let mut k = pick_lane(&c, &l, target);
            let cand =
                _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(max_steps, step))) & live;
            let linear = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_GE_OQ>(
                total_w,
                _mm256_set1_ps(LINEAR_MIN),
            )) & cand;
            let missed = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(
                k,
                _mm256_set1_epi32(8),
            ))) & linear;
            if missed != 0 {
                k = _mm256_blendv_epi8(k, most_likely8(&l), lanes(missed));
            }
            let k_safe = _mm256_min_epi32(k, _mm256_set1_epi32(7));
            let mut x = pick8(&logs, k_safe);
            let mut picked = linear;
            let fallback = cand & !linear;
            if fallback != 0 {
                // Weights near underflow: these walks pick in the log domain, one at a time.
                let mut ks = [0i32; SLOTS];
                let (mut xs, mut sums, mut us) = ([0f32; SLOTS], [0f32; SLOTS], [0f32; SLOTS]);
                _mm256_storeu_si256(ks.as_mut_ptr().cast(), k_safe);
                _mm256_storeu_ps(xs.as_mut_ptr(), x);
                _mm256_storeu_ps(sums.as_mut_ptr(), total_w);
                _mm256_storeu_ps(us.as_mut_ptr(), u);
                for s in 0..SLOTS {
                    if fallback & (1 << s) == 0 {
                        continue;
                    }
                    let (g, i) = (st.cell[s] as isize, st.pixel[s] as usize);
                    let t = near.log[i];
                    let a: [f32; 8] =
                        std::array::from_fn(|n| win.grid[(g + goff_arr[n]) as usize] + t[n]);
                    if let Some((kk, xx, ss)) = choose_log(&a, us[s]) {
                        (ks[s], xs[s], sums[s]) = (kk as i32, xx, ss);
                        picked |= 1 << s;
                    }
                }
                k = _mm256_loadu_si256(ks.as_ptr().cast());
                x = _mm256_loadu_ps(xs.as_ptr());
                total_w = _mm256_loadu_ps(sums.as_ptr());
            } else {
                k = k_safe;
            }
            // Walks that cannot step get (x, sum) = (0, 1): finite, and masked below.
            let picked_v = lanes(picked);
            let picked_f = _mm256_castsi256_ps(picked_v);
            x = _mm256_and_ps(x, picked_f);
            total_w = _mm256_blendv_ps(_mm256_set1_ps(1.0), total_w, picked_f);
            let lp = to_f64(_mm256_sub_ps(x, ln_normal8(total_w)));
            let new_log_p = [
                _mm256_add_pd(log_p[0], lp[0]),
                _mm256_add_pd(log_p[1], lp[1]),
            ];
            let above = _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_NLT_UQ>(new_log_p[0], ln_pmin))
                | _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_NLT_UQ>(new_log_p[1], ln_pmin)) << 4;
            let going = picked & above;
            let going_v = lanes(going);
            let moved = widen(going_v);
            // Only walks that go on move: a walk that stops stays where it stood (inside its
            // window and the image), so a lane left without a new walk still loads in bounds.
            cell = _mm256_blendv_epi8(
                cell,
                _mm256_add_epi32(cell, _mm256_permutevar8x32_epi32(goff, k)),
                going_v,
            );
            pixel = _mm256_blendv_epi8(
                pixel,
                _mm256_add_epi32(pixel, _mm256_permutevar8x32_epi32(ioff, k)),
                going_v,
            );
            step = _mm256_sub_epi32(step, going_v);
            let gamma = _mm256_set1_epi64x(GAMMA as i64);
            for h in 0..2 {
                ctr[h] = _mm256_add_epi64(
                    ctr[h],
                    _mm256_and_si256(gamma, _mm256_castpd_si256(moved[h])),
                );
            }
            // The weights and colour sums wait for the second loop: off this loop's chain of
            // dependent steps, they run at the vector units' full rate there.
            let mut rec = Record {
                pixel: [0; SLOTS],
                log_p: [0.0; SLOTS],
                step: [0; SLOTS],
                going,
                ended: live & !going,
            };
            _mm256_storeu_si256(rec.pixel.as_mut_ptr().cast(), pixel);
            _mm256_storeu_si256(rec.step.as_mut_ptr().cast(), step);
            for h in 0..2 {
                _mm256_storeu_pd(rec.log_p[4 * h..].as_mut_ptr(), new_log_p[h]);
                log_p[h] = _mm256_blendv_pd(log_p[h], new_log_p[h], moved[h]);
            }
            records.push(rec);
            // Ended walks hand in their steps; their lane takes the next walk. The resets are
            // blends, and the new walks' starts one blend per field.
            let ended = rec.ended;
            if ended != 0 {
                _mm256_storeu_si256(st.step.as_mut_ptr().cast(), step);
                let mut refilled = 0i32;
                let mut bits = ended;
                while bits != 0 {
                    let s = bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    steps += st.step[s] as u64;
                    ends.push(st.job[s]);
                    if next < total {
                        (st.cell[s], st.pixel[s], st.ctr[s]) = start(next);
                        st.job[s] = next;
                        next += 1;
                        refilled |= 1 << s;
                    } else {
                        live &= !(1 << s);
                    }
                }
                let ended_v = lanes(ended);
                let reset = widen(ended_v);
                step = _mm256_andnot_si256(ended_v, step);
                for h in 0..2 {
                    log_p[h] = _mm256_andnot_pd(reset[h], log_p[h]);
                }
                if refilled != 0 {
                    let fresh = lanes(refilled);
                    cell = _mm256_blendv_epi8(cell, load_lanes(&st.cell), fresh);
                    pixel = _mm256_blendv_epi8(pixel, load_lanes(&st.pixel), fresh);
                    let fresh = widen(fresh);
                    for h in 0..2 {
                        let new = _mm256_loadu_si256(st.ctr[4 * h..].as_ptr().cast());
                        ctr[h] = _mm256_castpd_si256(_mm256_blendv_pd(
                            _mm256_castsi256_pd(ctr[h]),
                            _mm256_castsi256_pd(new),
                            fresh[h],
                        ));
                    }
                }
            }
        }
        weigh(records, ends, color, parts);
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
    let ioff = lane_offsets(w);
    let ln_pmin = params.p_min.ln();
    let pkey = input.key(i0);
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

#[cfg(test)]
mod tests {
    //! The pick against adversarial weights: lanes 3 and 7 (the ends of the prefix sum's two
    //! halves) of weight 0, and targets on every cumulative sum, one ulp either side of it, and
    //! at the top of the distribution (u = 1 − 2⁻²⁴).
    use super::*;

    /// Weight vectors whose lanes 3 or 7 are 0, with cases where [`prefix8`] is not monotone.
    fn adversarial() -> Vec<[f32; 8]> {
        let mut key = 7u64;
        let mut next = || {
            key = splitmix(key);
            (key >> 40) as f32 / 16_777_216.0
        };
        (0..20_000)
            .map(|n| {
                let mut e: [f32; 8] = std::array::from_fn(|_| next());
                e[3] = 0.0;
                if n % 2 == 0 {
                    e[7] = 0.0;
                }
                if n % 5 == 0 {
                    e[0] = 0.0;
                }
                e
            })
            .collect()
    }

    /// Targets at every cumulative sum and one ulp either side, and at the top.
    fn targets(c: &[f32; 8]) -> Vec<f32> {
        let mut t = vec![c[7] * (1.0 - 1.0 / 16_777_216.0), c[7], 0.0];
        for &ck in c {
            t.extend([
                ck,
                f32::from_bits(ck.to_bits().saturating_sub(1)),
                f32::from_bits(ck.to_bits() + 1),
            ]);
        }
        t
    }

    #[test]
    fn a_lane_of_weight_zero_is_never_picked() {
        let mut gaps = 0;
        for e in adversarial() {
            let c = prefix8(&e);
            gaps += usize::from(c[3] > c[2]) + usize::from(c[7] > c[6] && e[7] == 0.0);
            for t in targets(&c) {
                let k = pick(&c, &e, t);
                assert!(
                    e[k] > 0.0,
                    "picked lane {k} of weight 0: e {e:?} target {t}"
                );
            }
        }
        // The vectors do reach the case the weight test is for.
        assert!(gaps > 100, "only {gaps} non-monotone sums");
    }

    #[test]
    fn a_miss_falls_back_to_the_most_likely_lane() {
        let e = [0.1, 0.4, 0.0, 0.2, 0.4, 0.0, 0.3, 0.0];
        let c = prefix8(&e);
        assert_eq!(pick(&c, &e, c[7]), 1);
        assert_eq!(pick(&c, &e, f32::INFINITY), 1);
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_avx2_pick_is_the_scalar_pick() {
        use std::arch::x86_64::*;
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        let vectors = adversarial();
        for chunk in vectors.chunks_exact(8) {
            let cs: Vec<[f32; 8]> = chunk.iter().map(prefix8).collect();
            for probe in 0..targets(&cs[0]).len() {
                let t: [f32; 8] = std::array::from_fn(|s| targets(&cs[s])[probe]);
                // Register k holds lane k of every walk, as in the kernel.
                // SAFETY: AVX2 is present (checked above); loads read 8 floats of local arrays.
                let got = unsafe {
                    let col = |m: &[[f32; 8]], k: usize| -> __m256 {
                        let v: [f32; 8] = std::array::from_fn(|s| m[s][k]);
                        _mm256_loadu_ps(v.as_ptr())
                    };
                    let l: [__m256; 8] = std::array::from_fn(|k| col(chunk, k));
                    let c: [__m256; 8] = std::array::from_fn(|k| col(&cs, k));
                    let k = avx2::pick_lane(&c, &l, _mm256_loadu_ps(t.as_ptr()));
                    let missed = _mm256_cmpeq_epi32(k, _mm256_set1_epi32(8));
                    let k = _mm256_blendv_epi8(k, avx2::most_likely8(&l), missed);
                    let mut out = [0i32; 8];
                    _mm256_storeu_si256(out.as_mut_ptr().cast(), k);
                    out
                };
                for s in 0..8 {
                    let k = got[s] as usize;
                    assert!(
                        chunk[s][k] > 0.0,
                        "AVX2 picked lane {k} of weight 0: {:?}",
                        chunk[s]
                    );
                    let want = pick(&cs[s], &chunk[s], t[s]);
                    assert_eq!(
                        got[s] as usize, want,
                        "lane {s}: e {:?} target {}",
                        chunk[s], t[s]
                    );
                }
            }
        }
    }
}
