//! The `noise` stage: writes the variance of every pixel's colour mean (RGB) for the stages that
//! set their strength from it (docs/ALGORITHM.md §8): estimated from the image alone
//! (`from_image`) or taken from what the renderer measured (`measured`), both averaged over the
//! surface-mates of `surface` by `smooth`; the tone-mapped level and per-pixel colour scales the
//! other stages follow are in `level` and `scaling`. Every pixel's sums run in f64 in a fixed
//! order, so the result is the same bits on any thread count. Variance is per RGB channel; it
//! scales with the square of the exposure, so everything derived from it is exposure-invariant.
//!
//! ```toml
//! [[stage]]
//! kind = "noise"
//! input = "color"        # the image whose noise is wanted
//! output = "noise"       # the variance buffer the later stages name
//! source = "auto"        # auto | image | measured
//! ```
//! `reuse = "noise"` (optional) takes that buffer at full size instead of measuring again.
//! `auto` uses what the renderer measured when the render set has it and `input` is the render's
//! colour (`variance`, else the halves `color_a`/`color_b`), and estimates from the image otherwise
//! (at coarse pyramid levels, or after another stage). `image` always estimates; `measured`
//! requires the renderer's buffers.

pub(crate) mod chi2;
pub(crate) mod from_image;
mod level;
pub(crate) mod measured;
pub mod scaling;
mod smooth;
pub(crate) mod surface;

use serde::{Deserialize, Serialize};

use crate::buffers::{Buffers, COLOR};
use crate::error::{Error, Result};
use crate::filters::stage::{parse_params, Context, Stage, StageIo};
use crate::image::Image;
use crate::render_set::NoiseInputs;

pub(crate) use chi2::trimmed_chi2_mean;
pub use from_image::{estimate, estimate_metered, estimate_with};
pub use level::{color_scales, tone_level};
pub use measured::{from_halves, smooth_measured};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Source {
    Auto,
    Image,
    Measured,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NoiseParams {
    pub source: Source,
    /// At full size (pyramid level 0), take this buffer when it exists instead of measuring again:
    /// a pyramid's per-level noise stage names the top-level one's output.
    pub reuse: Option<String>,
}

impl Default for NoiseParams {
    fn default() -> Self {
        NoiseParams {
            source: Source::Auto,
            reuse: None,
        }
    }
}

pub struct NoiseStage {
    id: String,
    io: StageIo,
    pub params: NoiseParams,
}

impl NoiseStage {
    pub fn from_table(id: &str, io: StageIo, table: toml::Table) -> Result<Self> {
        let params: NoiseParams = parse_params(id, table)?;
        Ok(NoiseStage {
            id: id.to_string(),
            io,
            params,
        })
    }

    /// The renderer's own measurement of `color`'s noise, if the buffers hold one.
    fn measured(&self, buffers: &Buffers, color: &Image) -> Result<Option<Image>> {
        let features = buffers.features();
        let sized = |name: &str| buffers.get_sized(name, 3, color.dims());
        if let Some(v) = sized(NoiseInputs::VARIANCE)? {
            return Ok(Some(smooth_measured(color, features, v)));
        }
        let [a, b] = NoiseInputs::HALVES;
        if let (Some(a), Some(b)) = (sized(a)?, sized(b)?) {
            return Ok(Some(from_halves(color, features, a, b)));
        }
        Ok(None)
    }
}

impl Stage for NoiseStage {
    fn id(&self) -> &str {
        &self.id
    }

    fn requires(&self) -> Vec<String> {
        vec![self.io.input.clone()]
    }

    fn writes(&self) -> Vec<String> {
        vec![self.io.output.clone()]
    }

    fn exposure_power(&self, _buffer: &str) -> i32 {
        2
    }

    fn execute_impl(&self, buffers: &mut Buffers, ctx: &mut Context) -> Result<u64> {
        let color = buffers.require_channels(&self.io.input, 3)?;
        if let Some(done) = self.params.reuse.as_deref().filter(|_| ctx.level == 0) {
            match buffers.get_channels(done, 3)? {
                Some(v) if v.dims() == color.dims() => {
                    buffers.insert_same(self.io.output.clone(), done)?;
                    return Ok(0);
                }
                Some(_) => {}
                // A misspelt name, or an ablation that removed the stage writing it: say so.
                None => ctx.note(format!(
                    "{}: `reuse` names buffer `{done}`, which no earlier stage wrote; measuring instead",
                    self.id
                )),
            }
        }
        let own_colour = self.io.input == COLOR && ctx.level == 0;
        let measured = match self.params.source {
            Source::Image => None,
            Source::Auto if !own_colour => None,
            Source::Auto | Source::Measured => self.measured(buffers, color)?,
        };
        let variance = match (measured, self.params.source) {
            (Some(v), _) => {
                ctx.note(format!("{}: noise from the renderer's measurement", self.id));
                v
            }
            (None, Source::Measured) => {
                return Err(Error::buffer(
                    NoiseInputs::VARIANCE,
                    format!(
                        "is required by stage `{}` (source = \"measured\"), as are the halves color_a/color_b otherwise",
                        self.id
                    ),
                ))
            }
            (None, _) => estimate_metered(color, buffers.features(), &ctx.meter),
        };
        buffers.insert(self.io.output.clone(), variance)?;
        Ok(0)
    }
}
