//! The `regress` stage: a first-order fit of the noisy colour around every pixel, guided by a
//! filtered image, mixed into that image where it is biased (docs/ALGORITHM.md §9).
//!
//! Why: every other filter in gsid averages (a zero-order fit). Where a pixel's neighbours on its
//! own surface lie on one side only — along every geometric edge and into every corner — and the
//! light changes across them (a corner darkens, a wall brightens towards the light), the average
//! is biased towards the inside of the surface, in a band a few pixels wide. A weighted
//! least-squares fit of colour = β₀ + β₁·dx + β₂·dy over the pixel's window extrapolates instead,
//! and its intercept β₀ has no first-order bias. Its weights choose the neighbours: the filtered
//! image's colour difference measured in units of the noise, the albedo and the normal.
//!
//! The fit is less smooth than the filter it refines, and its variance is known exactly from its
//! weights. So the output is the filtered value f moved towards the fit g by the Wiener weight
//! κ = b²/(b² + s²): s² the fit's variance, b² the filter's squared bias, read as |g − f|² less
//! s² (see [`keep`]). Where f is right, κ ≈ 0 and nothing changes.
//!
//! Deterministic: each pixel's sums run in one fixed order (f32 along a window row, f64 across
//! rows), so the result is the same bits on any thread count and with either kernel.
//!
//! Beside this stage: `params` (what the fit reads and gives), `planes` (a band's inputs as padded
//! planes), `window_sums` (the tap loop), `solve` (the normal equations), `fit` (the bands of rows)
//! and `shrink` (the mix).
//!
//! ```toml
//! [[stage]]
//! kind = "regress"
//! input = "out"          # the filtered image it refines
//! original = "color"     # the noisy colour it fits
//! noise = "noise"        # the original's variance (a `noise` stage's output)
//! output = "out"
//! radius = 6             # window (2·6 + 1)²
//! sigma = 1.0            # filtered colour difference, in noise standard deviations
//! clip = 3.0             # a sample's departure from the filtered image, capped in noise σ
//! albedo_sigma = 0.4
//! normal_cos = 0.9
//! demodulate = true
//! ```

mod fit;
mod params;
mod planes;
mod shrink;
mod solve;
mod window_sums;

pub use fit::regress_with;
pub use params::{Fit, Inputs, Params, DEMODULATION_EPS, MAX_RADIUS};
pub use shrink::{keep, mix, refine, refine_metered, refine_with};
pub use window_sums::falloff;

use serde::{Deserialize, Serialize};

use crate::buffers::{Buffers, COLOR};
use crate::error::{Error, Result};
use crate::filters::stage::{parse_params, Context, Stage, StageIo};
use crate::render_set::Feature;

/// Parameters of the `regress` stage (keys of its table in a pipeline file).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RegressParams {
    /// The noisy colour the fit reads.
    pub original: String,
    /// Its variance (a `noise` stage's output).
    pub noise: String,
    /// Window radius: time grows with (2·radius + 1)².
    pub radius: usize,
    /// Scale of the filtered image's colour difference, in noise standard deviations: larger
    /// lets the fit read across smaller changes of colour.
    pub sigma: f32,
    /// A noisy sample's departure from the filtered image is capped at this many noise standard
    /// deviations, so fireflies the filter removed stay out of the fit.
    pub clip: f32,
    /// Scale of the albedo difference (albedo is in 0..1).
    pub albedo_sigma: f32,
    /// Neighbours whose normals meet the pixel's at a cosine below this get no weight.
    pub normal_cos: f32,
    /// Fit the lighting, colour / (albedo + 0.02), and multiply the albedo back after. Needs the
    /// `albedo` buffer (else ignored, with a note).
    pub demodulate: bool,
}

impl Default for RegressParams {
    fn default() -> Self {
        let p = Params::default();
        RegressParams {
            original: COLOR.to_string(),
            noise: "noise".to_string(),
            radius: p.radius,
            sigma: p.sigma,
            clip: p.clip,
            albedo_sigma: p.albedo_sigma,
            normal_cos: p.normal_cos,
            demodulate: p.demodulate,
        }
    }
}

impl RegressParams {
    /// Checks every key against its allowed range; the error names the key.
    pub fn validate(&self) -> Result<()> {
        if !(1..=MAX_RADIUS).contains(&self.radius) {
            return Err(Error::range(
                "radius",
                self.radius,
                &format!("1 to {MAX_RADIUS}"),
            ));
        }
        for (key, value) in [
            ("sigma", self.sigma),
            ("clip", self.clip),
            ("albedo_sigma", self.albedo_sigma),
        ] {
            if !(1e-3..=1e3).contains(&value) {
                return Err(Error::range(key, value, "1e-3 to 1e3"));
            }
        }
        if !(-1.0..=1.0).contains(&self.normal_cos) {
            return Err(Error::range("normal_cos", self.normal_cos, "-1 to 1"));
        }
        Ok(())
    }

    /// The kernel's settings.
    pub fn kernel_params(&self) -> Params {
        Params {
            radius: self.radius,
            sigma: self.sigma,
            clip: self.clip,
            albedo_sigma: self.albedo_sigma,
            normal_cos: self.normal_cos,
            demodulate: self.demodulate,
            ..Params::default()
        }
    }
}

pub struct RegressStage {
    id: String,
    io: StageIo,
    pub params: RegressParams,
}

impl RegressStage {
    pub fn from_table(id: &str, io: StageIo, table: toml::Table) -> Result<Self> {
        let params: RegressParams = parse_params(id, table)?;
        params.validate().map_err(|e| e.in_context(id))?;
        Ok(RegressStage {
            id: id.to_string(),
            io,
            params,
        })
    }
}

impl Stage for RegressStage {
    fn id(&self) -> &str {
        &self.id
    }

    fn requires(&self) -> Vec<String> {
        vec![
            self.io.input.clone(),
            self.params.original.clone(),
            self.params.noise.clone(),
        ]
    }

    fn writes(&self) -> Vec<String> {
        vec![self.io.output.clone()]
    }

    fn execute_impl(&self, buffers: &mut Buffers, ctx: &mut Context) -> Result<u64> {
        let (filtered, noisy, variance) = crate::filters::stage::filtered_original_noise(
            buffers,
            &self.io.input,
            &self.params.original,
            &self.params.noise,
        )?;
        let feature = |f: Feature| -> Result<_> {
            match buffers.features().get(f) {
                Some(img) if img.dims() != filtered.dims() => Err(Error::buffer(
                    f.name(),
                    "does not match the colour buffer's size",
                )),
                other => Ok(other),
            }
        };
        let (albedo, normal) = (feature(Feature::Albedo)?, feature(Feature::Normal)?);
        if self.params.demodulate && albedo.is_none() {
            ctx.note(format!("{}: no albedo buffer; not demodulating", self.id));
        }
        let out = refine_metered(
            Inputs {
                noisy,
                filtered,
                variance,
                albedo,
                normal,
            },
            &self.params.kernel_params(),
            &ctx.meter,
        );
        buffers.insert(self.io.output.clone(), out)?;
        Ok(0)
    }
}
