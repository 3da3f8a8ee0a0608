//! The random-walk kernel of SID/GSID (docs/ALGORITHM.md §3).
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
//! [`run`] is the one entry point. Its [`Engine`] is the reference (`reference`: every distance
//! recomputed, the readable spec) or the fast kernels, which precompute the x0-independent terms
//! per band of rows (`tables`, `band`) and, with a window, the x0 terms per window cell, and step
//! lane by lane (`scalar`) or two groups of eight walks in turn (`avx2`; its weighing in AVX-512
//! registers where the CPU has them), over the whole image or strip by strip (`strips`). All
//! consume the same random numbers (`rng`) and run the same step (`step`), so they agree bit for
//! bit.

// Lane loops index several 8-wide arrays at once; indices read better than zipped iterators.
#![allow(clippy::needless_range_loop)]

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx2_weigh;
mod band;
mod reference;
pub mod rng;
mod scalar;
mod step;
mod strips;
mod tables;
#[cfg(test)]
mod transitions;

use std::ops::Range;

use crate::error::Result;
use crate::features::Features;
use crate::image::Image;
pub use crate::kernels::simd::Kernel;

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

/// Parameters of one walk kernel run, already validated by the stage. The defaults are the `gsid`
/// stage's.
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

impl WalkParams {
    /// The window radius clipped to what a walk can reach (a larger one only costs time); `None`
    /// for unbounded walks.
    fn radius(&self) -> Option<usize> {
        self.window.map(|r| r.min(self.max_steps) as usize)
    }
}

/// Work done by a kernel run: the unit of the kernel benchmarks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WalkStats {
    pub walks: u64,
    pub steps: u64,
}

/// Builds the features of image rows `rows`: a [`Features`] whose row 0 is image row `rows.start`.
pub type FeatureBuilder<'a> = dyn Fn(Range<usize>) -> Result<Features> + Sync + 'a;

/// Where a run's features come from.
#[derive(Clone, Copy)]
pub enum FeatureSource<'a> {
    /// The whole image's, built by the caller.
    Whole(&'a Features),
    /// Built a strip of rows at a time (the fast engine; the reference builds the whole image's).
    /// Features take 64 bytes a pixel, the largest per-pixel table of a run: with a window, only
    /// two or three strips' exist at once, and the result is one whole-image run's, bit for bit.
    Strips {
        build: &'a FeatureBuilder<'a>,
        /// Rows per strip; `None`: as many as make 8 MB of features.
        rows: Option<usize>,
    },
}

/// Which implementation walks. All draw the same random numbers and form the same sums in the
/// same order, so they give the same bits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Engine {
    /// The readable specification, for tests: every distance recomputed where a step needs it, on
    /// one thread.
    Reference,
    /// Tables precomputed per band of rows, bands in parallel, stepping with this kernel (the
    /// portable one if the CPU lacks it).
    Fast(Kernel),
}

impl Default for Engine {
    /// The fast engine with the fastest kernel this CPU runs.
    fn default() -> Self {
        Engine::Fast(Kernel::detect())
    }
}

/// One run of the walk kernel: what [`run`] denoises, and how.
#[derive(Clone, Copy)]
pub struct WalkJob<'a> {
    /// Linear colour that is averaged (3 channels).
    pub color: &'a Image,
    pub features: FeatureSource<'a>,
    /// Pixels walks must avoid and that get no weight (e.g. detected outliers).
    pub mask: Option<&'a [bool]>,
    pub seed: u64,
    /// Pyramid level, so every level draws its own random numbers.
    pub level: u32,
    pub params: &'a WalkParams,
    pub engine: Engine,
    /// Called once per finished row (for progress bars).
    pub on_row: &'a (dyn Fn() + Sync),
}

impl<'a> WalkJob<'a> {
    /// A job with no mask, seed 0, level 0, the default engine and no progress calls.
    pub fn new(color: &'a Image, features: FeatureSource<'a>, params: &'a WalkParams) -> Self {
        WalkJob {
            color,
            features,
            mask: None,
            seed: 0,
            level: 0,
            params,
            engine: Engine::default(),
            on_row: &|| {},
        }
    }
}

/// Denoises `job.color`: every pixel becomes the weighted average of the pixels its walks reach.
/// Fails only when features cannot be built.
pub fn run(job: &WalkJob) -> Result<(Image, WalkStats)> {
    // A radius of max(w, h) already holds every pixel of the image from any start pixel, so a
    // larger one gives the same walks; clipped here, no grid or table scales with it beyond the
    // image (strips would otherwise clip to a strip, not the image).
    let (w, h) = job.color.dims();
    let clipped = WalkParams {
        window: job.params.window.map(|r| r.min(w.max(h) as u32)),
        ..job.params.clone()
    };
    let job = &WalkJob {
        params: &clipped,
        ..*job
    };
    let whole;
    let features = match (job.features, job.engine) {
        (FeatureSource::Whole(features), _) => features,
        (FeatureSource::Strips { build, rows }, Engine::Fast(kernel)) => {
            let rows = rows.unwrap_or_else(|| strips::strip_rows(job.color.width()));
            return strips::denoise(job, kernel.or_portable(), build, rows);
        }
        (FeatureSource::Strips { build, .. }, Engine::Reference) => {
            whole = build(0..job.color.height())?;
            &whole
        }
    };
    let input = WalkInput {
        color: job.color,
        features,
        mask: job.mask,
        seed: job.seed,
        level: job.level,
        origin: 0,
    };
    Ok(match job.engine {
        Engine::Reference => reference::denoise(&input, job.params, job.on_row),
        Engine::Fast(kernel) => band::denoise(kernel.or_portable(), &input, job.params, job.on_row),
    })
}

/// What the kernels read: the colour and features of the whole image or of one strip of rows.
#[derive(Clone, Copy)]
struct WalkInput<'a> {
    /// Linear colour that is averaged (3 channels).
    color: &'a Image,
    features: &'a Features,
    mask: Option<&'a [bool]>,
    seed: u64,
    level: u32,
    /// Index in the whole image of this input's first pixel (0 for a whole image): a strip of
    /// rows draws the random numbers the whole image would.
    origin: usize,
}

impl WalkInput<'_> {
    /// The key of start pixel `pixel` (an index into this input).
    #[inline]
    fn key(&self, pixel: usize) -> u64 {
        rng::pixel_key(self.seed, self.level, self.origin + pixel)
    }
}

fn inv_two_sigma2(sigma: f32) -> f32 {
    1.0 / (2.0 * sigma * sigma)
}
