//! The `gsid` stage: feature-guided random-walk denoising (SID when only the colour weight is set).

pub mod guide;
#[cfg(test)]
mod stack_tests;
pub mod walk;

use serde::{Deserialize, Serialize};

use crate::buffers::Buffers;
use crate::error::{Error, Result};
use crate::features::{Recipe, Tone, Weights};
use crate::filters::stage::{
    parse_params, read_mask, Context, Stage, StageIo, MAX_STEPS_PER_PIXEL,
};
use crate::progress::Progress;
use walk::{FeatureSource, WalkJob, WalkParams};

/// Parameters of the `gsid` stage (keys of its table in a pipeline file).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GsidParams {
    /// Scale of the difference function: larger averages across bigger differences (no time cost).
    pub sigma: f32,
    /// Walks per pixel: quality saturates around 20–40; time grows linearly.
    pub walks: u32,
    /// A walk stops when its probability falls below this: smaller walks longer (slower, smoother).
    pub p_min: f64,
    /// Step cap per walk.
    pub max_steps: u32,
    /// Window radius walks stay inside (4 = 9×9); 0 = unbounded (slower: no distance cache).
    pub window: u32,
    /// Weight of the start pixel's own colour per walk (0: counted only when a walk returns).
    pub self_weight: f32,
    /// The eight feature weights W1..W8.
    pub weights: Weights,
    /// Tone curve for the colour feature F1.
    pub tone: Tone,
    /// Multiplier applied to colour before the tone curve.
    pub exposure: f32,
    /// Optional one-channel buffer of pixels to avoid (> 0.5 = masked), e.g. `outlier_mask`.
    pub mask: Option<String>,
    /// A variance buffer (a `noise` stage's output): `sigma` then follows the image's noise level.
    pub noise: Option<String>,
    /// The noise level at which `sigma` applies as given.
    pub noise_ref: f32,
    /// σ = sigma · (level / noise_ref)^noise_power.
    pub noise_power: f32,
    /// How far each pixel's colour difference follows its own noise, besides σ following the
    /// image's (`crate::filters::noise::color_scales`; 0: one σ for the whole image).
    pub local_noise: f32,
    /// k of the colour the walks compare (`guide::color_guide`): the colour after an NL-means
    /// pass whose 3×3 patch distance counts in noise σ of `noise`, so a reflected or refracted
    /// edge the features do not show stays while the noise goes; 0: the colour as it is.
    pub color_guide: f32,
    /// `color_guide` on a `--temporal` frame, whose variance is measured from the shot's frames and
    /// does not read a reflection's structure as noise, as an image estimate does: there the guide's
    /// patch distances count in the right units. Replaces `color_guide` on such a frame.
    pub stack_color_guide: f32,
}

impl Default for GsidParams {
    /// The walk parameters are the kernel's defaults ([`WalkParams::default`]).
    fn default() -> Self {
        let walk = WalkParams::default();
        GsidParams {
            sigma: walk.sigma,
            walks: walk.walks,
            p_min: walk.p_min,
            max_steps: walk.max_steps,
            window: walk.window.unwrap_or(0),
            self_weight: walk.self_weight,
            weights: Weights::default(),
            tone: Tone::Reinhard,
            exposure: 1.0,
            mask: None,
            noise: None,
            noise_ref: 0.04,
            noise_power: 1.0,
            local_noise: 0.0,
            color_guide: 0.0,
            stack_color_guide: 0.0,
        }
    }
}

/// Most steps the walks of one start pixel may take together (walks × max_steps): the whole
/// pipeline's budget (`MAX_STEPS_PER_PIXEL`), which all its walks share.
const MAX_WALK_STEPS: u64 = MAX_STEPS_PER_PIXEL as u64;

impl GsidParams {
    /// Checks every key against its allowed range; the error names the key.
    pub fn validate(&self) -> Result<()> {
        if !(1e-6..=1e6).contains(&self.sigma) {
            return Err(Error::range("sigma", self.sigma, "1e-6 to 1e6"));
        }
        if !(1..=100_000).contains(&self.walks) {
            return Err(Error::range("walks", self.walks, "1 to 100000"));
        }
        if !(self.p_min > 0.0 && self.p_min < 1.0) {
            return Err(Error::range(
                "p_min",
                self.p_min,
                "between 0 and 1 (exclusive)",
            ));
        }
        if !(1..=100_000).contains(&self.max_steps) {
            return Err(Error::range("max_steps", self.max_steps, "1 to 100000"));
        }
        let most = MAX_WALK_STEPS / self.walks as u64;
        if self.max_steps as u64 > most {
            return Err(Error::range(
                "max_steps",
                self.max_steps,
                &format!(
                    "1 to {most} with walks = {} (walks × max_steps at most {MAX_WALK_STEPS})",
                    self.walks
                ),
            ));
        }
        if self.window > 1024 {
            return Err(Error::range("window", self.window, "0 (unbounded) to 1024"));
        }
        if !(0.0..=1e6).contains(&self.self_weight) {
            return Err(Error::range("self_weight", self.self_weight, "0 to 1e6"));
        }
        if !(self.exposure > 0.0 && self.exposure <= 1e6) {
            return Err(Error::range(
                "exposure",
                self.exposure,
                "above 0, at most 1e6",
            ));
        }
        for (key, k) in [
            ("color_guide", self.color_guide),
            ("stack_color_guide", self.stack_color_guide),
        ] {
            if !(0.0..=10.0).contains(&k) {
                return Err(Error::range(key, k, "0 (off) to 10"));
            }
            if k > 0.0 && self.noise.is_none() {
                return Err(Error::range(
                    key,
                    k,
                    "0 without `noise` (the guide counts in the noise it names)",
                ));
            }
        }
        self.scaling().validate()?;
        self.weights.validate()
    }

    /// How `sigma` follows the noise.
    pub fn scaling(&self) -> crate::filters::noise::scaling::NoiseScaling {
        crate::filters::noise::scaling::NoiseScaling {
            noise: self.noise.clone(),
            noise_ref: self.noise_ref,
            noise_power: self.noise_power,
            local_noise: self.local_noise,
        }
    }

    pub fn walk_params(&self) -> WalkParams {
        WalkParams {
            sigma: self.sigma,
            walks: self.walks,
            p_min: self.p_min,
            max_steps: self.max_steps,
            window: (self.window > 0).then_some(self.window),
            self_weight: self.self_weight,
        }
    }
}

pub struct GsidStage {
    id: String,
    io: StageIo,
    pub params: GsidParams,
}

impl GsidStage {
    pub fn from_table(id: &str, io: StageIo, table: toml::Table) -> Result<Self> {
        let params: GsidParams = parse_params(id, table)?;
        params.validate().map_err(|e| e.in_context(id))?;
        Ok(GsidStage {
            id: id.to_string(),
            io,
            params,
        })
    }

    pub fn new(id: &str, io: StageIo, params: GsidParams) -> Result<Self> {
        params.validate().map_err(|e| e.in_context(id))?;
        Ok(GsidStage {
            id: id.to_string(),
            io,
            params,
        })
    }
}

/// The `gsid` stage's work: denoises buffer `input` with the walk kernel, with features built
/// strip by strip from `buffers`; returns the result and the walk steps taken.
pub fn run_gsid(
    params: &GsidParams,
    input: &str,
    buffers: &Buffers,
    ctx: &mut Context,
    label: &str,
) -> Result<(crate::image::Image, u64)> {
    let color = buffers.require_channels(input, 3)?;
    // A missing buffer's features are off; the loader says so once, naming only buffers the
    // renderer could have written (a note here would repeat it for every stage and level).
    let mask = read_mask(buffers, params.mask.as_deref(), color.dims(), ctx, label)?;
    let scales = params
        .scaling()
        .color_scales(buffers, color, params.exposure)?;
    ctx.meter.check()?;
    let k = if buffers.variance_from_stack() {
        params.stack_color_guide
    } else {
        params.color_guide
    };
    let guide = match params.noise.as_deref().filter(|_| k > 0.0) {
        Some(name) => {
            let variance = buffers.get_sized(name, 3, color.dims())?.ok_or_else(|| {
                Error::buffer(
                    name,
                    "is required (the stage's `noise`) but missing; a `noise` stage writes it",
                )
            })?;
            guide::color_guide(color, variance, k as f64, &ctx.meter)
        }
        None => None,
    };
    ctx.meter.check()?;
    let recipe = Recipe::new(
        guide.as_ref().unwrap_or(color),
        buffers.features(),
        &params.weights,
        params.tone,
        params.exposure,
        scales.as_deref(),
    )?;
    let features_for = |rows: std::ops::Range<usize>| Ok(recipe.records(rows));
    let mut walk_params = params.walk_params();
    walk_params.sigma =
        params
            .scaling()
            .sigma(params.sigma, buffers, color, params.exposure, ctx, label)?;
    ctx.meter.check()?;
    let progress = Progress::new(ctx.progress, label, color.height() as u64);
    let meter = &ctx.meter;
    meter.pass(color.height());
    let features = FeatureSource::Strips {
        build: &features_for,
        rows: None,
    };
    let (out, stats) = walk::run(&WalkJob {
        mask: mask.as_deref(),
        seed: ctx.seed,
        level: ctx.level,
        on_row: &|rows| {
            progress.inc(rows as u64);
            meter.rows(rows);
            !meter.cancelled()
        },
        ..WalkJob::new(color, features, &walk_params)
    })?;
    progress.finish();
    Ok((out, stats.steps))
}

impl Stage for GsidStage {
    fn id(&self) -> &str {
        &self.id
    }

    fn steps_per_pixel(&self) -> f64 {
        self.params.walks as f64 * self.params.max_steps as f64
    }

    fn requires(&self) -> Vec<String> {
        vec![self.io.input.clone()]
    }

    fn writes(&self) -> Vec<String> {
        vec![self.io.output.clone()]
    }

    fn execute_impl(&self, buffers: &mut Buffers, ctx: &mut Context) -> Result<u64> {
        let (out, steps) = run_gsid(&self.params, &self.io.input, buffers, ctx, &self.id)?;
        buffers.insert(self.io.output.clone(), out)?;
        Ok(steps)
    }
}
