//! The `reliability` stage: a feature buffer guides only as far as it is more than its own noise.
//!
//! At a few samples per pixel a feature buffer is a few-sample average too. Where its samples see
//! different things (fog's medium and the surface behind it, depth of field, motion blur, hair) it is
//! salt and pepper, and a filter that trusts it keeps that pattern in the output as if it were
//! texture. This stage reads, per pixel, how much of the buffer's local variation its noise explains
//! (`gate`: noise from directional second differences, signal from the variance of a directional
//! median)
//! and pulls the pixel towards its window's median in that proportion; then (`centre = "mean"`,
//! `mean`) replaces it by the mean of the raw samples of its own surface around it, which is what
//! the feature's reference is where the samples see two things in proportion. Every later stage (prefilter,
//! walks, à-trous, fit) then sees a buffer that differs between two pixels only where the surface
//! does: a feature's say in the pixel difference follows its reliability, with no kernel changed.
//! The reliability of each gated feature is kept as `<feature>_reliability` (for `--save-buffer`).
//! With `albedo_by_geometry` the albedo's reliability is at least the geometry's: texture coverage
//! on clean geometry (mortar) keeps guiding, while fog mixes the normal too and stays gated.
//!
//! ```toml
//! [[stage]]
//! kind = "reliability"
//! features = ["albedo", "normal", "depth"]   # gated, each in place
//! radius = 3                                 # window of the variances, (2·3+1)²
//! centre = "mean"                            # or "median"
//! albedo_by_geometry = true                  # the albedo's reliability at least the geometry's
//! ```
//! A listed feature the render set does not have is skipped with a note.

mod gate;
mod mean;
mod median;
mod variance;

pub use gate::{gate, gate_metered, Centre, Domain, Params};
pub use median::MEDIAN_RADIUS;

use serde::{Deserialize, Serialize};

use crate::buffers::Buffers;
use crate::error::{Error, Result};
use crate::filters::stage::{feature_list, parse_params, Context, Stage, StageIo};
use crate::image::Image;
use crate::render_set::Feature;

/// Largest window radius.
pub const MAX_RADIUS: usize = 8;

/// Parameters of the `reliability` stage (keys of its table in a pipeline file).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReliabilityParams {
    /// Feature buffers gated: any of albedo, normal, material, shadow, depth.
    pub features: Vec<String>,
    /// Radius of the window the noise and the signal are read over. Larger reads both more surely
    /// and blurs the reliability across edges (time grows with it, linearly).
    pub radius: usize,
    /// What a noisy pixel is pulled towards: `mean`, the mean of its own surface's raw samples (a
    /// mix of medium and surface becomes its proportion, as the reference does), or `median`, the
    /// window's median (the mix becomes its majority, in blotches).
    pub centre: Centre,
    /// The albedo is trusted at least as far as the geometry is, pixel by pixel: ρ_albedo at least
    /// the smaller of ρ_normal and ρ_depth (those of them gated here). Where the geometry is clean
    /// the pixel sees one surface, and its albedo's few-sample noise is the coverage of that
    /// surface's texture (a brick wall's mortar), which the colour shares; a per-sample mix of
    /// medium and surface (fog) or of two depths (defocus, motion) makes the geometry as noisy as
    /// the albedo, and the gate stays.
    pub albedo_by_geometry: bool,
}

impl Default for ReliabilityParams {
    fn default() -> Self {
        ReliabilityParams {
            features: vec!["albedo".into(), "normal".into(), "depth".into()],
            radius: 3,
            centre: Centre::Mean,
            albedo_by_geometry: false,
        }
    }
}

impl ReliabilityParams {
    /// Checks every key against its allowed range; the error names the key.
    pub fn validate(&self) -> Result<()> {
        feature_list(&self.features)?;
        if !(1..=MAX_RADIUS).contains(&self.radius) {
            return Err(Error::range("radius", self.radius, "1 to 8"));
        }
        Ok(())
    }

    /// The kernel's settings. The noise counts twice: a difference between two pixels carries
    /// the noise of both.
    pub fn kernel_params(&self) -> Params {
        Params {
            radius: self.radius,
            pair_noise: 2.0,
            centre: self.centre,
        }
    }
}

/// The buffer name a feature's reliability is kept under.
pub fn reliability_name(feature: Feature) -> String {
    format!("{}_reliability", feature.name())
}

pub struct ReliabilityStage {
    id: String,
    features: Vec<Feature>,
    pub params: ReliabilityParams,
}

impl ReliabilityStage {
    pub fn from_table(id: &str, _io: StageIo, table: toml::Table) -> Result<Self> {
        let params: ReliabilityParams = parse_params(id, table)?;
        params.validate().map_err(|e| e.in_context(id))?;
        let features = feature_list(&params.features)?;
        Ok(ReliabilityStage {
            id: id.to_string(),
            features,
            params,
        })
    }
}

impl Stage for ReliabilityStage {
    fn id(&self) -> &str {
        &self.id
    }

    fn requires(&self) -> Vec<String> {
        Vec::new()
    }

    fn writes(&self) -> Vec<String> {
        self.features
            .iter()
            .flat_map(|&f| [f.name().to_string(), reliability_name(f)])
            .collect()
    }

    fn exposure_power(&self, _buffer: &str) -> i32 {
        0
    }

    fn execute_impl(&self, buffers: &mut Buffers, ctx: &mut Context) -> Result<u64> {
        let p = self.params.kernel_params();
        // The geometry first when the albedo's floor is its reliability (each feature reads only its
        // own raw buffer, so the order changes nothing else).
        let mut order = self.features.clone();
        if self.params.albedo_by_geometry {
            order.sort_by_key(|&f| f == Feature::Albedo);
        }
        let mut geometry: Option<Image> = None;
        for feature in order {
            ctx.meter.check()?;
            let Some(img) = buffers.features().get(feature) else {
                ctx.note(format!(
                    "{}: no {} buffer; not gated",
                    self.id,
                    feature.name()
                ));
                continue;
            };
            let domain = match feature {
                Feature::Normal => Domain::Normal,
                Feature::Depth => Domain::Log,
                Feature::Albedo | Feature::Material | Feature::Shadow => Domain::Linear,
            };
            let floor = match feature {
                Feature::Albedo if self.params.albedo_by_geometry => geometry.as_ref(),
                _ => None,
            };
            let (gated, rho) = gate_metered(img, domain, p, floor, &ctx.meter)?;
            if matches!(feature, Feature::Normal | Feature::Depth) && self.params.albedo_by_geometry
            {
                // The geometry is as reliable as its least reliable buffer.
                geometry = Some(match geometry.take() {
                    None => rho.clone(),
                    Some(g) => Image::from_fn(g.width(), g.height(), 1, |x, y, _| {
                        g.at(x, y)[0].min(rho.at(x, y)[0])
                    }),
                });
            }
            buffers.insert(feature.name(), gated)?;
            buffers.insert(reliability_name(feature), rho)?;
        }
        Ok(0)
    }
}
