//! The filters, one folder per stage `kind` of a pipeline file: its stage (parameters, checks,
//! dispatch) in the folder's `mod.rs`, its kernels beside it. This file is the registry that
//! builds a stage from its spec; what every stage is lives in `stage`.

pub mod atrous;
pub mod blend;
pub mod coverage;
pub mod gsid;
pub mod noise;
pub mod outlier;
pub mod prefilter;
pub mod pyramid;
pub mod regress;
pub mod reliability;
pub mod stage;

use crate::error::{Error, Result};
use crate::spec::StageSpec;
pub use stage::{Context, Stage, StageIo, StageReport};

/// The stage kinds gsid knows, for error messages.
pub const KINDS: &[&str] = &[
    "atrous",
    "blend",
    "coverage",
    "gsid",
    "noise",
    "outlier",
    "prefilter",
    "pyramid",
    "regress",
    "reliability",
    "spread",
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
        "coverage" => Ok(Box::new(coverage::CoverageStage::from_table(
            id,
            io,
            params(),
        )?)),
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
        "pyramid" => Ok(Box::new(pyramid::PyramidStage::from_spec(spec, build)?)),
        "spread" => Ok(Box::new(outlier::SpreadStage::from_table(
            id,
            io,
            params(),
        )?)),
        "regress" => Ok(Box::new(regress::RegressStage::from_table(
            id,
            io,
            params(),
        )?)),
        "reliability" => Ok(Box::new(reliability::ReliabilityStage::from_table(
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
