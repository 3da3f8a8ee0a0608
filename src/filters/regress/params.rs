//! What the fit reads and gives, and its settings: shared by the planes, the solve, the fit's
//! bands and the mix.

use crate::image::Image;

/// Added to the albedo before dividing by it: a black surface keeps its (small) colour.
pub const DEMODULATION_EPS: f32 = 0.02;

/// Largest window radius accepted (a 33×33 window).
pub const MAX_RADIUS: usize = 16;

/// Settings of the regression and the mix.
#[derive(Clone, Debug, PartialEq)]
pub struct Params {
    /// Window radius: the fit reads (2r + 1)² pixels.
    pub radius: usize,
    /// Scale of the filtered image's colour difference, in units of the pixel's noise standard
    /// deviation: a neighbour weighs [`falloff`](super::falloff) of
    /// |Δf|² / (2σ²v) + |Δa|² / (2 albedo_sigma²).
    pub sigma: f32,
    /// Each noisy sample's departure from the filtered image is capped at `clip` standard
    /// deviations of its noise, so a firefly the filter removed does not come back.
    pub clip: f32,
    /// Scale of the albedo difference (see `sigma`).
    pub albedo_sigma: f32,
    /// Neighbours whose normal is at a cosine below this from the pixel's get no weight.
    pub normal_cos: f32,
    /// Ridge on the two slopes, relative to the sum of weights: a window whose weights lie along
    /// a line fits no slope across it.
    pub ridge: f64,
    /// Fit colour / (albedo + ε) (the lighting), so texture the albedo carries is not a slope.
    pub demodulate: bool,
}

impl Default for Params {
    fn default() -> Self {
        Params {
            radius: 6,
            sigma: 1.0,
            clip: 3.0,
            albedo_sigma: 0.4,
            normal_cos: 0.9,
            ridge: 1e-3,
            demodulate: true,
        }
    }
}

/// What the regression reads; every image is `noisy`'s size, colour buffers have 3 channels.
#[derive(Clone, Copy)]
pub struct Inputs<'a> {
    /// The colour as sampled (after any firefly clamp): what the fit regresses.
    pub noisy: &'a Image,
    /// A filtered image of it: its colour differences choose the neighbours, and it is what the
    /// mix refines.
    pub filtered: &'a Image,
    /// Variance of each pixel's mean in `noisy`, per channel.
    pub variance: &'a Image,
    pub albedo: Option<&'a Image>,
    pub normal: Option<&'a Image>,
}

/// The fit at every pixel and its variance (mean over the channels).
pub struct Fit {
    pub color: Image,
    pub variance: Vec<f32>,
}
