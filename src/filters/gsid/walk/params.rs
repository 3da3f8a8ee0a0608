//! What a kernel run is given and gives back: its parameters ([`WalkParams`]), the image it reads
//! ([`WalkInput`]), the neighbourhood's lane order ([`OFFSETS`]), its work ([`WalkStats`]).

use super::rng;
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

/// The index step to each of the 8 neighbours (in [`OFFSETS`] order) in a row-major grid `stride`
/// wide.
#[inline]
pub(super) fn lane_offsets(stride: usize) -> [isize; 8] {
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
    pub(super) fn radius(&self) -> Option<usize> {
        self.window.map(|r| r.min(self.max_steps) as usize)
    }
}

/// Work done by a kernel run: the unit of the kernel benchmarks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WalkStats {
    pub walks: u64,
    pub steps: u64,
}

/// What the kernels read: the colour and features of the whole image or of one strip of rows.
#[derive(Clone, Copy)]
pub(super) struct WalkInput<'a> {
    /// Linear colour that is averaged (3 channels).
    pub(super) color: &'a Image,
    pub(super) features: &'a Features,
    pub(super) mask: Option<&'a [bool]>,
    pub(super) seed: u64,
    pub(super) level: u32,
    /// Index in the whole image of this input's first pixel (0 for a whole image): a strip of
    /// rows draws the random numbers the whole image would.
    pub(super) origin: usize,
}

impl WalkInput<'_> {
    /// The key of start pixel `pixel` (an index into this input).
    #[inline]
    pub(super) fn key(&self, pixel: usize) -> u64 {
        rng::pixel_key(self.seed, self.level, self.origin + pixel)
    }
}

pub(super) fn inv_two_sigma2(sigma: f32) -> f32 {
    1.0 / (2.0 * sigma * sigma)
}
