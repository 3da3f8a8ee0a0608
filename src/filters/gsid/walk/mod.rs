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
//!
//! This file only declares the parts and holds [`run`]; what a run is given lives in `params`
//! and `job`, which every part imports (re-exported here).

// Lane loops index several 8-wide arrays at once; indices read better than zipped iterators.
#![allow(clippy::needless_range_loop)]

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx2_group;
#[cfg(target_arch = "x86_64")]
mod avx2_lanes;
#[cfg(target_arch = "x86_64")]
mod avx2_step;
#[cfg(target_arch = "x86_64")]
mod avx2_weigh;
mod band;
mod job;
mod params;
mod reference;
pub mod rng;
mod scalar;
mod step;
mod strips;
mod tables;
#[cfg(test)]
mod transitions;

pub use job::{Engine, FeatureBuilder, FeatureSource, WalkJob};
use params::WalkInput;
pub use params::{WalkParams, WalkStats, OFFSETS};

use crate::error::Result;
use crate::image::Image;
pub use crate::kernels::simd::Kernel;

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
