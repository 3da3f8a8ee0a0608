//! Pipeline stages: each kind parses its parameters, checks them, and dispatches to a kernel.
//!
//! A stage reads named buffers and writes named buffers (see `buffers`). The common keys of every
//! stage table are `kind`, `id`, `input` and `output`; everything else is the kind's parameters,
//! parsed with `deny_unknown_fields` so a misspelled key is an error that names it.

pub mod atrous;
pub mod blend;
pub mod gsid;
pub mod noise;
pub mod outlier;
pub mod prefilter;
pub mod pyramid;
pub mod regress;

use std::time::Instant;

use crate::buffers::Buffers;
use crate::error::{Error, Result};
use crate::image::Image;
pub use crate::spec::StageIo;
use crate::spec::StageSpec;

/// What every stage run can use and report into.
pub struct Context {
    pub seed: u64,
    /// Pyramid level (0 = full size), so levels draw independent random numbers.
    pub level: u32,
    /// Show progress bars.
    pub progress: bool,
    /// One-line notices for the user, in order.
    pub notes: Vec<String>,
    /// Per-stage timings and work, in order of execution.
    pub reports: Vec<StageReport>,
}

impl Context {
    pub fn new(seed: u64, progress: bool) -> Self {
        Context {
            seed,
            level: 0,
            progress,
            notes: Vec::new(),
            reports: Vec::new(),
        }
    }

    /// Adds a notice once (the same line is not repeated, e.g. from every pyramid level).
    pub fn note(&mut self, line: String) {
        if !self.notes.contains(&line) {
            self.notes.push(line);
        }
    }
}

/// Timing and work of one stage run.
#[derive(Clone, Debug, serde::Serialize)]
pub struct StageReport {
    pub id: String,
    pub level: u32,
    pub seconds: f64,
    pub walk_steps: u64,
}

/// A configured stage, ready to run.
pub trait Stage: Send + Sync {
    /// The stage's id in its pipeline (its kind unless the file gives an `id`).
    fn id(&self) -> &str;
    /// Buffers that must exist before it runs.
    fn requires(&self) -> Vec<String>;
    /// Buffers it creates or replaces.
    fn writes(&self) -> Vec<String>;
    /// The work itself; `execute` has checked `requires`.
    fn execute_impl(&self, buffers: &mut Buffers, ctx: &mut Context) -> Result<u64>;

    /// Checks preconditions, runs, and records the timing.
    fn execute(&self, buffers: &mut Buffers, ctx: &mut Context) -> Result<()> {
        for name in self.requires() {
            buffers.require(&name).map_err(|_| {
                Error::buffer(
                    &name,
                    format!(
                        "is required by stage `{}` but no earlier stage or input provides it",
                        self.id()
                    ),
                )
            })?;
        }
        let start = Instant::now();
        let walk_steps = self.execute_impl(buffers, ctx)?;
        ctx.reports.push(StageReport {
            id: self.id().to_string(),
            level: ctx.level,
            seconds: start.elapsed().as_secs_f64(),
            walk_steps,
        });
        Ok(())
    }
}

/// The stage kinds gsid knows, for error messages.
pub const KINDS: &[&str] = &[
    "atrous",
    "blend",
    "gsid",
    "noise",
    "outlier",
    "prefilter",
    "pyramid",
    "regress",
];

/// Builds a stage from its spec: a composite kind from its children and overrides, any other kind
/// from its parameter table alone.
pub fn build(spec: &StageSpec) -> Result<Box<dyn Stage>> {
    let (id, io) = (spec.id.as_str(), spec.io.clone());
    if spec.kind != "pyramid" && KINDS.contains(&spec.kind.as_str()) {
        leaf_only(spec)?;
    }
    let params = || spec.params.clone();
    match spec.kind.as_str() {
        "atrous" => Ok(Box::new(atrous::AtrousStage::from_table(id, io, params())?)),
        "blend" => Ok(Box::new(blend::BlendStage::from_table(id, io, params())?)),
        "gsid" => Ok(Box::new(gsid::GsidStage::from_table(id, io, params())?)),
        "noise" => Ok(Box::new(noise::NoiseStage::from_table(id, io, params())?)),
        "outlier" => Ok(Box::new(outlier::OutlierStage::from_table(
            id,
            io,
            params(),
        )?)),
        "prefilter" => Ok(Box::new(prefilter::PrefilterStage::from_table(
            id,
            io,
            params(),
        )?)),
        "pyramid" => Ok(Box::new(pyramid::PyramidStage::from_spec(spec)?)),
        "regress" => Ok(Box::new(regress::RegressStage::from_table(
            id,
            io,
            params(),
        )?)),
        other => Err(Error::config(
            format!("{id}.kind"),
            format!("unknown stage kind `{other}` (known: {})", KINDS.join(", ")),
        )),
    }
}

/// Rejects a sub-list or per-level overrides on a stage kind that runs no sub-stages.
fn leaf_only(spec: &StageSpec) -> Result<()> {
    let composite = |key: &str, what: &str| {
        Err(Error::config(
            format!("{}.{key}", spec.id),
            format!(
                "a {} stage takes no {what}; only pyramid stages do",
                spec.kind
            ),
        ))
    };
    if !spec.children.is_empty() {
        return composite("stages", "sub-list");
    }
    if let Some(key) = spec.overrides.levels.keys().next() {
        return composite(key, "per-level overrides");
    }
    if let Some(key) = spec.overrides.every_level.keys().next() {
        return composite(key, "sub-stage overrides");
    }
    Ok(())
}

/// The pixels a stage must avoid: buffer `name` read as one channel, > 0.5 = masked, checked to
/// be `dims` in size. A named buffer that does not exist masks nothing, with a note under `label`.
pub fn read_mask(
    buffers: &Buffers,
    name: Option<&str>,
    dims: (usize, usize),
    ctx: &mut Context,
    label: &str,
) -> Result<Option<Vec<bool>>> {
    let Some(name) = name else {
        return Ok(None);
    };
    match buffers.get_sized(name, 1, dims)? {
        Some(m) => Ok(Some(m.data().iter().map(|&v| v > 0.5).collect())),
        None => {
            ctx.note(format!(
                "{label}: mask buffer `{name}` not present; no pixels masked"
            ));
            Ok(None)
        }
    }
}

/// The most a stage's σ grows over `sigma` with the noise.
const MAX_GAIN: f64 = 2.0;

/// How a stage's `sigma` follows the noise: σ = sigma · (level / noise_ref)^noise_power, with
/// level the image's typical noise after the tone curve (`crate::filters::noise::kernel::tone_level`).
#[derive(Clone, Debug, PartialEq)]
pub struct NoiseScaling {
    /// A variance buffer (a `noise` stage's output); none: `sigma` is used as given.
    pub noise: Option<String>,
    /// The noise level at which `sigma` applies as given.
    pub noise_ref: f32,
    /// How fast σ follows the level (2: with the variance).
    pub noise_power: f32,
    /// How far each pixel's colour difference follows its own noise (`crate::filters::noise::kernel::color_scales`;
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

    /// Per-pixel factors of the colour feature of `color` (`crate::filters::noise::kernel::color_scales`), or none
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
        Ok(Some(crate::filters::noise::kernel::color_scales(
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
        let level = crate::filters::noise::kernel::tone_level(color, variance, exposure);
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

/// A filtered image (`input`), the colour it was filtered from (`original`) and that colour's
/// variance (`noise`): three channels each, all the filtered image's size. What the stages that
/// weigh a filter's change against the noise read (`blend`, `regress`).
pub fn filtered_original_noise<'a>(
    buffers: &'a Buffers,
    input: &str,
    original: &str,
    noise: &str,
) -> Result<(&'a Image, &'a Image, &'a Image)> {
    let three = |name: &str| buffers.require_channels(name, 3);
    let (filtered, original_img, variance) = (three(input)?, three(original)?, three(noise)?);
    for (name, img) in [(original, original_img), (noise, variance)] {
        if img.dims() != filtered.dims() {
            return Err(Error::buffer(
                name,
                "does not match the filtered image's size",
            ));
        }
    }
    Ok((filtered, original_img, variance))
}

/// Deserialises a parameter table into `T`, naming the stage in errors.
pub fn parse_params<T: serde::de::DeserializeOwned>(id: &str, params: toml::Table) -> Result<T> {
    T::deserialize(toml::Value::Table(params)).map_err(|e| {
        let msg = e.to_string();
        let msg = msg.trim().replace('\n', " ");
        Error::config(id.to_string(), msg)
    })
}

#[cfg(test)]
mod tests {
    use crate::pipeline::PipelineSpec;

    /// `local_noise` is checked like the other noise keys, in both stages that take it.
    #[test]
    fn out_of_range_local_noise_is_named() {
        for (stage, value) in [
            ("pyramid.gsid", "-0.5"),
            ("pyramid.gsid", "nan"),
            ("atrous", "5"),
        ] {
            let mut spec = PipelineSpec::builtin("full").unwrap();
            spec.apply_set(&format!("{stage}.local_noise={value}"))
                .unwrap();
            let err = spec.build().err().expect("rejected").to_string();
            assert!(
                err.contains("local_noise") && err.contains("0 to 4"),
                "{stage} = {value}: {err}"
            );
        }
        let mut spec = PipelineSpec::builtin("full").unwrap();
        spec.apply_set("atrous.local_noise=0.5").unwrap();
        assert!(spec.build().is_ok());
    }
}
