//! The `atrous` stage: edge-avoiding à-trous passes with GSID's difference (see `crate::filters::atrous::pass`),
//! to take the residual speckle out of a GSID result.

pub mod pass;
mod range;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::buffers::Buffers;
use crate::error::{Error, Result};
use crate::features::{Recipe, Tone, Weights};
use crate::filters::stage::{parse_params, read_mask, Context, Stage, StageIo};
use crate::render_set::Feature;

/// Parameters of the `atrous` stage (keys of its table in a pipeline file).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AtrousParams {
    /// Passes; pass k spaces its 5×5 taps 2^k pixels apart (2 passes reach 13×13). More passes
    /// smooth wider; each costs the same time.
    pub iterations: u32,
    /// Scale of the difference function: larger averages across bigger differences. Smaller than
    /// GSID's because the colour it compares has already been denoised.
    pub sigma: f32,
    /// The eight feature weights W1..W8.
    pub weights: Weights,
    /// Tone curve for the colour feature F1.
    pub tone: Tone,
    /// Multiplier applied to colour before the tone curve.
    pub exposure: f32,
    /// Optional one-channel buffer of pixels that get no weight (> 0.5 = masked).
    pub mask: Option<String>,
    /// Filter colour / (albedo + 0.01) (the lighting) and multiply the albedo back after, so texture
    /// detail the albedo buffer carries is never averaged. Needs the `albedo` buffer (else ignored).
    pub demodulate: bool,
    /// A variance buffer (a `noise` stage's output): `sigma` then follows the image's noise level.
    pub noise: Option<String>,
    /// The noise level at which `sigma` applies as given.
    pub noise_ref: f32,
    /// σ = sigma · (level / noise_ref)^noise_power.
    pub noise_power: f32,
    /// How far each pixel's colour difference follows its own noise (as `gsid`'s; 0: one σ).
    pub local_noise: f32,
}

impl Default for AtrousParams {
    fn default() -> Self {
        AtrousParams {
            iterations: 2,
            sigma: 0.2,
            weights: Weights::default(),
            tone: Tone::Reinhard,
            exposure: 1.0,
            mask: None,
            demodulate: false,
            noise: None,
            noise_ref: 0.028,
            noise_power: 1.0,
            local_noise: 0.0,
        }
    }
}

/// Added to the albedo before dividing by it: black surfaces keep their (small) colour.
const DEMODULATION_EPS: f32 = 0.01;
/// The window whose brightest pixel a demodulated pass's output is held below: the first pass's 5×5 taps.
const HELD_RADIUS: usize = 2;

/// Most passes accepted. Pass k spaces its taps 2^(k−1) pixels apart and each band's feature planes
/// hold the rows within reach, so a cap on passes bounds a band's memory (5: 32 rows either side);
/// the presets use 2.
pub const MAX_ITERATIONS: u32 = 5;

impl AtrousParams {
    /// Checks every key against its allowed range; the error names the key.
    pub fn validate(&self) -> Result<()> {
        if !(1..=MAX_ITERATIONS).contains(&self.iterations) {
            return Err(Error::range(
                "iterations",
                self.iterations,
                &format!("1 to {MAX_ITERATIONS}"),
            ));
        }
        if !(1e-6..=1e6).contains(&self.sigma) {
            return Err(Error::range("sigma", self.sigma, "1e-6 to 1e6"));
        }
        if !(self.exposure > 0.0 && self.exposure <= 1e6) {
            return Err(Error::range(
                "exposure",
                self.exposure,
                "above 0, at most 1e6",
            ));
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
}

pub struct AtrousStage {
    id: String,
    io: StageIo,
    pub params: AtrousParams,
}

impl AtrousStage {
    pub fn from_table(id: &str, io: StageIo, table: toml::Table) -> Result<Self> {
        let params: AtrousParams = parse_params(id, table)?;
        params.validate().map_err(|e| e.in_context(id))?;
        Ok(AtrousStage {
            id: id.to_string(),
            io,
            params,
        })
    }
}

impl Stage for AtrousStage {
    fn id(&self) -> &str {
        &self.id
    }

    fn requires(&self) -> Vec<String> {
        vec![self.io.input.clone()]
    }

    fn writes(&self) -> Vec<String> {
        vec![self.io.output.clone()]
    }

    fn execute_impl(&self, buffers: &mut Buffers, ctx: &mut Context) -> Result<u64> {
        let p = &self.params;
        let input = &self.io.input;
        // The stage replaces its input when it writes the same buffer (as in `full`): take it
        // instead of copying it.
        let mut color = if *input == self.io.output {
            buffers.require_channels(input, 3)?;
            buffers.remove(input).expect("required above")
        } else {
            buffers.require_channels(input, 3)?.par_clone()
        };
        let mask = read_mask(buffers, p.mask.as_deref(), color.dims(), ctx, &self.id)?;
        let sigma = p
            .scaling()
            .sigma(p.sigma, buffers, &color, p.exposure, ctx, &self.id)?;
        // From the colour as it comes in: a pixel's noise relative to the image's does not depend
        // on the demodulation below.
        let scales = p.scaling().color_scales(buffers, &color, p.exposure)?;
        let albedo = if p.demodulate {
            match buffers.features().get(Feature::Albedo) {
                Some(a) if a.dims() == color.dims() => Some(a),
                Some(_) => {
                    return Err(Error::buffer(
                        Feature::Albedo.name(),
                        "does not match the colour buffer's size",
                    ))
                }
                None => {
                    ctx.note(format!("{}: no albedo buffer; not demodulating", self.id));
                    None
                }
            }
        } else {
            None
        };
        // What the pass's output is held below when it demodulates (`range`).
        let peak = albedo.map(|_| range::peaks(&color, HELD_RADIUS));
        if let Some(a) = albedo {
            color
                .data_mut()
                .par_iter_mut()
                .zip(a.data())
                .for_each(|(c, &a)| *c /= a.max(0.0) + DEMODULATION_EPS);
        }
        // Zero rows: checks every feature buffer's size and reports the missing ones, before any work.
        for k in 0..p.iterations {
            // The colour feature is read from each pass's input, which gets cleaner every pass.
            ctx.meter.check()?;
            let current = &color;
            let recipe = Recipe::new(
                current,
                buffers.features(),
                &p.weights,
                p.tone,
                p.exposure,
                scales.as_deref(),
            )?;
            let bands = |rows, pad| recipe.planes(rows, pad);
            color =
                pass::pass_metered(&color, &bands, mask.as_deref(), (1 << k, sigma), &ctx.meter);
        }
        ctx.meter.check()?;
        if let Some(a) = albedo {
            color
                .data_mut()
                .par_iter_mut()
                .zip(a.data())
                .for_each(|(c, &a)| *c *= a.max(0.0) + DEMODULATION_EPS);
        }
        if let Some(peak) = peak {
            range::hold_below(&mut color, &peak);
        }
        buffers.insert(self.io.output.clone(), color)?;
        Ok(0)
    }
}
