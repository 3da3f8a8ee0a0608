//! The `prefilter` stage: takes the noise out of feature buffers before they guide anything, and
//! writes them back under their own names, so every later stage sees the filtered ones.
//!
//! Feature prefiltering (docs/ALGORITHM.md §8, "Noisy features"): at a few samples per pixel the
//! albedo and normal buffers are averages of a few samples too, noisy where a pixel's samples see
//! different surfaces (glossy and glass paths, depth of field, sub-pixel texture), and every stage
//! uses them as guides. No renderer we read writes their variance, so it is estimated from the
//! buffer itself (`estimate`), and an NL-means filter whose patch distance counts in units of that
//! variance (Rousselle et al. 2012, as NFOR prefilters its features; `nl_means`) smooths the noise
//! away where there is some and leaves a clean pixel, a sharp edge or a texture alone.
//!
//! Every pixel's sums run in f64 in a fixed order, so the result is the same bits on any thread
//! count.
//!
//! ```toml
//! [[stage]]
//! kind = "prefilter"
//! features = ["albedo", "normal"]   # feature buffers filtered, each in place
//! strength = 0.25                   # k, in noise standard deviations
//! radius = 3                        # search window (2·3+1)²
//! patch = 1                         # patches (2·1+1)²
//! estimate = "directional"          # how the noise is read: "directional" or "trimmed"
//! keep = 0.65                       # trimmed: share of adjacent differences read as noise
//! ```
//! A listed feature the render set does not have is skipped with a note.

mod estimate;
mod nl_means;
mod params;

pub use estimate::{
    directional_variance, directional_with, line_aware_metered, line_aware_variance, variance,
    variance_with,
};
pub use nl_means::{filter, filter_metered, filter_with, MAX_PATCH, MAX_RADIUS};
pub use params::{Kind, Params};

use serde::{Deserialize, Serialize};

use crate::buffers::Buffers;
use crate::error::{Error, Result};
use crate::filters::stage::{feature_list, parse_params, Context, Stage, StageIo};
use crate::render_set::Feature;

/// Parameters of the `prefilter` stage (keys of its table in a pipeline file).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PrefilterParams {
    /// Feature buffers filtered: any of albedo, normal, material, shadow, depth.
    pub features: Vec<String>,
    /// k: two patches average while they differ by less than about k noise standard deviations.
    /// Higher smooths more (no time cost).
    pub strength: f64,
    /// Search window radius: time grows with (2·radius + 1)².
    pub radius: usize,
    /// Patch radius: time grows with (2·patch + 1)².
    pub patch: usize,
    /// How the feature's noise is read: from the smallest `keep` share of its window's adjacent
    /// differences (`trimmed`), or the larger of that and the reading along the direction in which
    /// it varies least (`directional`, which also finds the noise of a thin line's coverage).
    pub estimate: Estimate,
    /// `trimmed`: share of a 5×5 window's adjacent-pixel differences read as noise, the smallest
    /// ones; the rest is taken for structure. Higher finds few-sample noise where a pixel's samples
    /// see one surface or another; lower keeps finer texture (no time cost).
    pub keep: f64,
}

/// How a feature buffer's noise is read.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Estimate {
    /// [`line_aware_variance`]: the larger of the trimmed reading and the one along
    /// the direction the buffer varies least.
    Directional,
    /// [`variance`] with `keep`.
    Trimmed,
}

impl Default for PrefilterParams {
    fn default() -> Self {
        PrefilterParams {
            features: vec!["albedo".into(), "normal".into()],
            strength: 0.25,
            radius: 3,
            patch: 1,
            estimate: Estimate::Directional,
            keep: 0.65,
        }
    }
}

impl PrefilterParams {
    /// Checks every key against its allowed range; the error names the key.
    pub fn validate(&self) -> Result<()> {
        feature_list(&self.features)?;
        if !(self.strength > 0.0 && self.strength <= 10.0) {
            return Err(Error::range(
                "strength",
                self.strength,
                "above 0, at most 10",
            ));
        }
        if !(1..=MAX_RADIUS).contains(&self.radius) {
            return Err(Error::range("radius", self.radius, "1 to 8"));
        }
        if !(0.05..=0.95).contains(&self.keep) {
            return Err(Error::range("keep", self.keep, "0.05 to 0.95"));
        }
        if self.patch > MAX_PATCH {
            return Err(Error::range("patch", self.patch, "0 to 3"));
        }
        Ok(())
    }

    /// The kernel's settings.
    pub fn kernel_params(&self) -> Params {
        Params {
            strength: self.strength,
            radius: self.radius,
            patch: self.patch,
            keep: self.keep,
        }
    }
}

pub struct PrefilterStage {
    id: String,
    features: Vec<Feature>,
    pub params: PrefilterParams,
}

impl PrefilterStage {
    pub fn from_table(id: &str, _io: StageIo, table: toml::Table) -> Result<Self> {
        let params: PrefilterParams = parse_params(id, table)?;
        params.validate().map_err(|e| e.in_context(id))?;
        let features = feature_list(&params.features)?;
        Ok(PrefilterStage {
            id: id.to_string(),
            features,
            params,
        })
    }
}

impl Stage for PrefilterStage {
    fn id(&self) -> &str {
        &self.id
    }

    fn requires(&self) -> Vec<String> {
        Vec::new()
    }

    fn writes(&self) -> Vec<String> {
        self.features.iter().map(|f| f.name().to_string()).collect()
    }

    fn exposure_power(&self, _buffer: &str) -> i32 {
        0
    }

    fn execute_impl(&self, buffers: &mut Buffers, ctx: &mut Context) -> Result<u64> {
        let p = self.params.kernel_params();
        for &feature in &self.features {
            let Some(img) = buffers.features().get(feature) else {
                ctx.note(format!(
                    "{}: no {} buffer; not filtered",
                    self.id,
                    feature.name()
                ));
                continue;
            };
            let kind = match feature {
                Feature::Normal => Kind::Normal,
                Feature::Depth => Kind::Depth,
                Feature::Albedo | Feature::Material | Feature::Shadow => Kind::Plain,
            };
            let variance = match self.params.estimate {
                Estimate::Directional => line_aware_metered(img, kind, p.keep, &ctx.meter),
                Estimate::Trimmed => variance(img, kind, p.keep),
            };
            ctx.meter.check()?;
            let filtered = filter_metered(img, &variance, kind, &p, &ctx.meter);
            ctx.meter.check()?;
            buffers.insert(feature.name(), filtered)?;
        }
        Ok(0)
    }
}
