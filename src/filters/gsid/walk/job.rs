//! What [`run`](super::run) is asked to do: a [`WalkJob`], with where its features come from
//! ([`FeatureSource`]) and which implementation walks ([`Engine`]).

use std::ops::Range;

use super::params::WalkParams;
use crate::error::Result;
use crate::features::Features;
use crate::image::Image;
use crate::kernels::simd::Kernel;

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

/// One run of the walk kernel: what [`run`](super::run) denoises, and how.
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
    /// Told of finished rows (`on_row(1)`, for progress) and asked before a band of rows starts
    /// (`on_row(0)`); false skips the remaining rows (a cancelled run, whose result is thrown away).
    pub on_row: &'a (dyn Fn(usize) -> bool + Sync),
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
            on_row: &|_| true,
        }
    }
}
