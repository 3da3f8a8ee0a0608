//! How a stage's σ follows the noise the `noise` stage measured: one σ per image from its noise
//! level, and per-pixel colour scales from each pixel's own noise.

use super::level::{color_scales, tone_level};
use crate::buffers::Buffers;
use crate::error::{Error, Result};
use crate::filters::stage::Context;
use crate::image::Image;

/// The most a stage's σ grows over `sigma` with the noise.
const MAX_GAIN: f64 = 2.0;

/// How a stage's `sigma` follows the noise: σ = sigma · (level / noise_ref)^noise_power, with
/// level the image's typical noise after the tone curve (`crate::filters::noise::tone_level`).
#[derive(Clone, Debug, PartialEq)]
pub struct NoiseScaling {
    /// A variance buffer (a `noise` stage's output); none: `sigma` is used as given.
    pub noise: Option<String>,
    /// The noise level at which `sigma` applies as given.
    pub noise_ref: f32,
    /// How fast σ follows the level (2: with the variance).
    pub noise_power: f32,
    /// How far each pixel's colour difference follows its own noise (`crate::filters::noise::color_scales`;
    /// 0: one σ for the whole image).
    pub local_noise: f32,
}

impl NoiseScaling {
    pub fn validate(&self) -> Result<()> {
        if !(1e-6..=1e3).contains(&self.noise_ref) {
            return Err(Error::range("noise_ref", self.noise_ref, "1e-6 to 1e3"));
        }
        if !(0.0..=4.0).contains(&self.noise_power) {
            return Err(Error::range("noise_power", self.noise_power, "0 to 4"));
        }
        if !(0.0..=4.0).contains(&self.local_noise) {
            return Err(Error::range("local_noise", self.local_noise, "0 to 4"));
        }
        Ok(())
    }

    /// Per-pixel factors of the colour feature of `color` (`crate::filters::noise::color_scales`), or none
    /// when `local_noise` is 0 or no `noise` buffer is named.
    pub fn color_scales(
        &self,
        buffers: &Buffers,
        color: &Image,
        exposure: f32,
    ) -> Result<Option<Vec<f32>>> {
        let Some(name) = self.noise.as_deref().filter(|_| self.local_noise > 0.0) else {
            return Ok(None);
        };
        let variance = self.variance(buffers, name, color)?;
        Ok(Some(color_scales(
            color,
            variance,
            exposure,
            self.local_noise as f64,
            self.noise_ref as f64,
        )))
    }

    /// The variance buffer `name`, which the stage requires.
    fn variance<'a>(&self, buffers: &'a Buffers, name: &str, color: &Image) -> Result<&'a Image> {
        buffers.get_sized(name, 3, color.dims())?.ok_or_else(|| {
            Error::buffer(
                name,
                "is required (the stage's `noise`) but missing; a `noise` stage writes it",
            )
        })
    }

    /// The σ to filter `color` with: `sigma` scaled by its noise level, kept inside the range
    /// `sigma` itself is validated in; with a note of the level and the σ under `label`.
    pub fn sigma(
        &self,
        sigma: f32,
        buffers: &Buffers,
        color: &Image,
        exposure: f32,
        ctx: &mut Context,
        label: &str,
    ) -> Result<f32> {
        let Some(name) = self.noise.as_deref() else {
            return Ok(sigma);
        };
        let variance = self.variance(buffers, name, color)?;
        let level = tone_level(color, variance, exposure);
        // Above the reference level σ grows no further than MAX_GAIN×: at very high noise the
        // estimate also holds fine geometry taken for noise, and a larger σ would average it away.
        let factor = (level / self.noise_ref as f64)
            .powf(self.noise_power as f64)
            .min(MAX_GAIN);
        let scaled = (sigma as f64 * factor).clamp(1e-3, 1e3) as f32;
        ctx.note(format!(
            "{label} (level {}): noise level {level:.4} → σ {scaled:.3}",
            ctx.level
        ));
        Ok(scaled)
    }
}
