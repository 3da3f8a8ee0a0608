//! What every stage is: the [`Stage`] trait (its checks run once, in `execute`, before the work),
//! the [`Context`] a run carries through its stages, and the helpers stage constructors share.
//!
//! A stage reads named buffers and writes named buffers (see `buffers`). The common keys of every
//! stage table are `kind`, `id`, `input` and `output`; everything else is the kind's parameters,
//! parsed with `deny_unknown_fields` so a misspelled key is an error that names it.

use std::time::Instant;

use crate::buffers::Buffers;
use crate::error::{Error, Result};
use crate::image::Image;
use crate::meter::Meter;
pub use crate::spec::StageIo;

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
    /// The run's cancellation and progress: checked before and after every stage, and between
    /// rows by the heavy kernels.
    pub meter: Meter,
}

impl Context {
    pub fn new(seed: u64, progress: bool) -> Self {
        Context {
            seed,
            level: 0,
            progress,
            notes: Vec::new(),
            reports: Vec::new(),
            meter: Meter::default(),
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

/// Most walk steps a pipeline may take per pixel, over all its `gsid` stages and pyramid levels,
/// on any image (checked when it is built). A walk that never falls below `p_min` takes every step.
pub const MAX_STEPS_PER_PIXEL: f64 = 65_536.0;

/// Steps per pixel every image may take, whatever its size: far above the presets' few thousand.
pub const STEPS_PER_PIXEL_ALWAYS: f64 = 10_000.0;

/// Most steps one image may take in all when that is above [`STEPS_PER_PIXEL_ALWAYS`] a pixel: the
/// slowest steps measured (σ 1e-6 over noise, where every step takes the log-domain path) run at
/// about 24 M a second on two cores, so the worst accepted settings on 256² end within a minute,
/// while a small crop may still take many more walks a pixel.
pub const STEPS_PER_IMAGE: f64 = 1.2e9;

/// The most walk steps a pixel of a `pixels`-pixel image may take (see [`STEPS_PER_IMAGE`]).
pub fn steps_per_pixel_allowed(pixels: usize) -> f64 {
    (STEPS_PER_IMAGE / pixels.max(1) as f64).clamp(STEPS_PER_PIXEL_ALWAYS, MAX_STEPS_PER_PIXEL)
}

/// Builds a stage from its spec: what a composite stage is handed to build its sub-stages.
pub type StageBuilder = fn(&crate::spec::StageSpec) -> Result<Box<dyn Stage>>;

/// A configured stage, ready to run.
pub trait Stage: Send + Sync {
    /// The stage's id in its pipeline (its kind unless the file gives an `id`).
    fn id(&self) -> &str;
    /// Buffers that must exist before it runs.
    fn requires(&self) -> Vec<String>;
    /// Buffers it creates or replaces.
    fn writes(&self) -> Vec<String>;
    /// The most walk steps this stage takes per pixel of its input (walks × max_steps for a
    /// `gsid` stage, its levels' sum weighted by their size for a pyramid): what the pipeline's
    /// time budget, [`MAX_STEPS_PER_PIXEL`], counts.
    fn steps_per_pixel(&self) -> f64 {
        0.0
    }
    /// How a buffer this stage writes scales with the colour's exposure: 1 for light (a filtered
    /// image), 2 for a variance, 0 for what light does not scale (masks, features, weights). The
    /// stages run at one internal exposure; what a user saves is brought back to the input's by it.
    fn exposure_power(&self, _buffer: &str) -> i32 {
        1
    }
    /// How deep pyramids nest in this stage (0: none; 1: a pyramid of plain stages).
    fn nesting(&self) -> usize {
        0
    }
    /// The work itself; `execute` has checked `requires`.
    fn execute_impl(&self, buffers: &mut Buffers, ctx: &mut Context) -> Result<u64>;

    /// Checks preconditions and cancellation, runs, and records the timing.
    fn execute(&self, buffers: &mut Buffers, ctx: &mut Context) -> Result<()> {
        ctx.meter.check()?;
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
        // A cancel seen inside the work left it unfinished: nothing of it is kept.
        ctx.meter.check()?;
        ctx.reports.push(StageReport {
            id: self.id().to_string(),
            level: ctx.level,
            seconds: start.elapsed().as_secs_f64(),
            walk_steps,
        });
        Ok(())
    }
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

/// The feature buffers a stage's `features` key names, each checked to be one and listed once; the
/// error names the key.
pub fn feature_list(names: &[String]) -> Result<Vec<crate::render_set::Feature>> {
    use crate::render_set::Feature;
    let mut features = Vec::with_capacity(names.len());
    for (i, name) in names.iter().enumerate() {
        let Some(feature) = Feature::from_name(name) else {
            let known = Feature::ALL.map(Feature::name).join(", ");
            return Err(Error::config(
                "features",
                format!("`{name}` is not a feature buffer (known: {known})"),
            ));
        };
        if names[..i].contains(name) {
            return Err(Error::config(
                "features",
                format!("`{name}` is listed twice"),
            ));
        }
        features.push(feature);
    }
    Ok(features)
}
