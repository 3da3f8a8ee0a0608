//! The `outlier` stage: flags fireflies, repairs or only marks them, and always writes the mask.
//!
//! Firefly (outlier) detection and repair (docs/ALGORITHM.md §4), as plain kernels over `Image`s.
//! Low-spp renders carry salt-and-pepper outliers: a few pixels whose one lucky path hit a light.
//! They are found by comparing a pixel's luminance with its neighbourhood (the centre itself is
//! never part of its own reference, so a firefly cannot hide by inflating the statistics), then
//! repaired (neighbour median or energy-aware clamp) or only marked so the walks avoid them.
//!
//! Every rule is one-sided (only too-bright pixels are outliers) and yields, per pixel, the
//! luminance above which it would be flagged: the `clamp` action scales a flagged pixel down to it.
//! A pixel without neighbours (a 1×1 image) is never flagged. Deterministic: no randomness, and
//! rows are independent, so any thread count gives the same bits.
//!
//! Beside this stage: `params` (rules, actions, settings, guides, the detection), `neighbourhood`
//! (the window and its statistics), `surface` (the feature rule's same-surface bits), `detect` and
//! `repair`; `spread` gives the clamp's light back, `highlight` tells it which pixels were highlights.

mod detect;
mod highlight;
mod neighbourhood;
mod params;
mod repair;
mod spread;
mod surface;

pub use detect::detect;
pub use neighbourhood::{luminance, luminance_image};
pub use params::{Action, DetectParams, Detection, Guides, Rule};
pub use repair::repair;
pub use spread::{spread_light, Given, SpreadParams, SpreadStage};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::buffers::Buffers;
use crate::error::{Error, Result};
use crate::filters::stage::{parse_params, Context, Stage, StageIo};
use crate::image::Image;
use crate::render_set::Feature;

/// What a repair took from each pixel, channel by channel (never below 0: a median's colour may
/// be brighter in one channel, and that is not light to give back).
fn removed_light(color: &Image, repaired: &Image) -> Image {
    let mut removed = color.par_clone();
    removed
        .data_mut()
        .par_iter_mut()
        .zip(repaired.data())
        .for_each(|(r, &after)| {
            let d = *r - after;
            *r = if d.is_finite() && d > 0.0 { d } else { 0.0 };
        });
    removed
}

/// Parameters of the `outlier` stage (keys of its table in a pipeline file).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutlierParams {
    /// Detection rule: zscore, feature or percentile (all cost about the same, a few ms per MP).
    pub rule: Rule,
    /// Rule threshold; default 3.5 (zscore, robust σ), 3 (feature, σ), 2 (percentile, × 75th pct).
    /// Lower flags more pixels.
    pub threshold: Option<f32>,
    /// Neighbourhood radius ((2r+1)² window); default 2 (zscore, percentile), 1 (feature).
    /// Time grows with the window's area.
    pub radius: Option<u32>,
    /// What to do with flagged pixels: median, clamp or mask.
    pub action: Action,
    /// Name of the 1-channel mask buffer written (1.0 = outlier), e.g. for `gsid`'s `mask` key.
    pub mask: String,
    /// Name of a 3-channel buffer to write the light the repair removed into (input − repaired,
    /// 0 elsewhere), for a `spread` stage to give back; none by default.
    pub light: Option<String>,
    /// zscore: smallest MAD of log luminance (log units ≈ relative spread): flat areas stay unflagged.
    pub mad_floor: f32,
    /// feature: smallest std of tone-mapped luminance, for the same reason.
    pub std_floor: f32,
    /// feature and median: largest albedo difference (RGB distance) of "the same surface".
    pub albedo_tol: f32,
    /// feature and median: largest normal difference (1 − n·n′)/2 of "the same surface".
    pub normal_tol: f32,
    /// feature: also flag dark dots (a sample that returned almost nothing on a bright surface)
    /// and raise them to their lower limit, so the walks and the blend average them.
    pub two_sided: bool,
}

impl Default for OutlierParams {
    fn default() -> Self {
        OutlierParams {
            rule: Rule::Zscore,
            threshold: None,
            radius: None,
            action: Action::Median,
            mask: "outlier_mask".into(),
            light: None,
            mad_floor: 0.25,
            std_floor: 0.02,
            albedo_tol: 0.1,
            normal_tol: 0.05,
            two_sided: false,
        }
    }
}

impl OutlierParams {
    /// Checks every key against its allowed range; the error names the key.
    pub fn validate(&self) -> Result<()> {
        if let Some(t) = self.threshold {
            let (lo, hi, range) = match self.rule {
                Rule::Zscore | Rule::Feature => {
                    (0.5, 100.0, "0.5 to 100 (for rule zscore/feature)")
                }
                Rule::Percentile => (1.0, 1000.0, "1 to 1000 (for rule percentile)"),
            };
            if !(lo..=hi).contains(&t) {
                return Err(Error::range("threshold", t, range));
            }
        }
        if let Some(r) = self.radius {
            if !(1..=16).contains(&r) {
                return Err(Error::range("radius", r, "1 to 16"));
            }
        }
        if self.mask.is_empty() {
            return Err(Error::config("mask", "must name a buffer"));
        }
        if self.light.as_deref() == Some("") {
            return Err(Error::config("light", "must name a buffer"));
        }
        if self.two_sided && self.rule != Rule::Feature {
            return Err(Error::config(
                "two_sided",
                "needs rule = \"feature\" (the other rules are one-sided)",
            ));
        }
        if !(0.0..=10.0).contains(&self.mad_floor) {
            return Err(Error::range("mad_floor", self.mad_floor, "0 to 10"));
        }
        if !(0.0..=1.0).contains(&self.std_floor) {
            return Err(Error::range("std_floor", self.std_floor, "0 to 1"));
        }
        if !(self.albedo_tol > 0.0 && self.albedo_tol <= 2.0) {
            return Err(Error::range(
                "albedo_tol",
                self.albedo_tol,
                "above 0, at most 2",
            ));
        }
        if !(self.normal_tol > 0.0 && self.normal_tol <= 1.0) {
            return Err(Error::range(
                "normal_tol",
                self.normal_tol,
                "above 0, at most 1",
            ));
        }
        Ok(())
    }

    /// The kernel's settings, with the rule's defaults filled in.
    pub fn detect_params(&self) -> DetectParams {
        DetectParams {
            rule: self.rule,
            threshold: self.threshold.unwrap_or(self.rule.default_threshold()),
            radius: self
                .radius
                .map_or(self.rule.default_radius(), |r| r as usize),
            mad_floor: self.mad_floor,
            std_floor: self.std_floor,
            albedo_tol: self.albedo_tol,
            normal_tol: self.normal_tol,
            two_sided: self.two_sided,
        }
    }
}

pub struct OutlierStage {
    id: String,
    io: StageIo,
    pub params: OutlierParams,
}

impl OutlierStage {
    pub fn from_table(id: &str, io: StageIo, table: toml::Table) -> Result<Self> {
        Self::new(id, io, parse_params(id, table)?)
    }

    pub fn new(id: &str, io: StageIo, params: OutlierParams) -> Result<Self> {
        params.validate().map_err(|e| e.in_context(id))?;
        Ok(OutlierStage {
            id: id.to_string(),
            io,
            params,
        })
    }
}

impl Stage for OutlierStage {
    fn id(&self) -> &str {
        &self.id
    }

    fn requires(&self) -> Vec<String> {
        vec![self.io.input.clone()]
    }

    fn writes(&self) -> Vec<String> {
        let mut writes = vec![self.io.output.clone(), self.params.mask.clone()];
        writes.extend(self.params.light.clone());
        writes
    }

    fn exposure_power(&self, buffer: &str) -> i32 {
        i32::from(buffer != self.params.mask)
    }

    fn execute_impl(&self, buffers: &mut Buffers, ctx: &mut Context) -> Result<u64> {
        let color = buffers.require_channels(&self.io.input, 3)?;
        let guides = Guides {
            albedo: buffers.features().get(Feature::Albedo),
            normal: buffers.features().get(Feature::Normal),
        };
        let p = self.params.detect_params();
        let uses_guides = p.rule == Rule::Feature || self.params.action == Action::Median;
        if uses_guides && guides.albedo.is_none() && guides.normal.is_none() {
            ctx.note(format!(
                "{}: albedo and normal missing; outliers are judged against all neighbours",
                self.id
            ));
        }
        let detection = detect(color, &guides, &p);
        ctx.meter.check()?;
        let repaired = repair(color, &detection, &guides, &p, self.params.action);
        let (w, h) = color.dims();
        let mask = detection.mask_image(w, h);
        ctx.note(format!(
            "outlier: {} pixels flagged ({}, {})",
            detection.count(),
            p.rule.name(),
            self.params.action.name()
        ));
        if let Some(name) = &self.params.light {
            let removed = removed_light(color, &repaired);
            buffers.insert(name.clone(), removed)?;
        }
        buffers.insert(self.io.output.clone(), repaired)?;
        buffers.insert(self.params.mask.clone(), mask)?;
        Ok(0)
    }
}
