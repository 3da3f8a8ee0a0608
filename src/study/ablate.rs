//! `gsid ablate`: what does each stage and each feature buy?
//!
//! Runs a pipeline, then variants of it: each top-level stage removed in turn (a pyramid is
//! "removed" by running its sub-stages at full size only), a `reliability` stage's surface mean
//! replaced by its median centre, each of the eight feature weights zeroed in
//! every stage that uses them (gsid, atrous), and plain SID; scores each against the reference.

use std::time::Instant;

use serde::Serialize;

use super::table;
use crate::buffers::Buffers;
use crate::error::Result;
use crate::features::Weights;
use crate::image::Image;
use crate::metrics;
use crate::options::DenoiseOptions;
use crate::spec::{PipelineSpec, StageSpec};

/// One row of the ablation table.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub variant: String,
    pub ssim: f64,
    pub psnr: f64,
    pub relmse: f64,
    pub seconds: f64,
    /// SSIM minus the full pipeline's SSIM.
    pub delta_ssim: f64,
}

/// A named variant of the pipeline under study.
pub struct Variant {
    pub name: String,
    pub spec: PipelineSpec,
}

/// `--set` paths that reach every stage with feature weights (gsid and atrous) of `spec` (top
/// level, or a composite stage's child).
fn feature_paths(spec: &PipelineSpec) -> Vec<String> {
    let weighted = |s: &StageSpec| matches!(s.kind.as_str(), "gsid" | "atrous");
    let mut paths = Vec::new();
    for s in &spec.stages {
        if weighted(s) {
            paths.push(s.id.clone());
        }
        let children = s.children.iter().filter(|c| weighted(c));
        paths.extend(children.map(|c| format!("{}.{}", s.id, c.id)));
    }
    paths
}

/// The variants `ablate` runs, the full pipeline first.
pub fn variants(spec: &PipelineSpec) -> Result<Vec<Variant>> {
    let mut out = vec![Variant {
        name: format!("full ({})", spec.name),
        spec: spec.clone(),
    }];
    if spec.stages.len() > 1 || spec.stages.iter().any(|s| s.kind == "pyramid") {
        for (i, stage) in spec.stages.iter().enumerate() {
            let mut v = spec.clone();
            let name = if stage.kind == "noise" {
                // Later stages read its buffer: the noise rows below take it out whole.
                continue;
            } else if stage.kind == "pyramid" {
                // One level: the sub-stages at full size, with only the overrides that apply there.
                v.stages[i].overrides.levels.retain(|_, o| o.level == 0);
                v.stages[i].set(&["levels"], toml::Value::Integer(1))?;
                format!("without {} (single scale)", stage.id)
            } else if spec.stages.len() > 1 {
                v.stages.remove(i);
                // A `spread` gives back the light of the clamp it follows: it goes with it.
                let light = stage.params.get("light").and_then(toml::Value::as_str);
                let before = v.stages.len();
                v.stages.retain(|s| {
                    s.kind != "spread"
                        || light.is_none()
                        || s.params.get("light").and_then(toml::Value::as_str) != light
                });
                if v.stages.len() < before {
                    format!("without {} (and its spread)", stage.id)
                } else {
                    format!("without {}", stage.id)
                }
            } else {
                continue;
            };
            out.push(Variant { name, spec: v });
        }
    }
    // A `reliability` stage's surface mean against its median centre and its albedo floor (the
    // geometry's reliability), where a pipeline turns it on, against off; a `coverage` stage's
    // across-edge spread (the renderer's estimated pixel-filter width) and its step along the
    // edges only the colour shows, each against none; an `outlier` stage's dark dots, a `blend`
    // stage's noise-level cap and its leak test's level, and a `spread` stage's highlights, where a
    // pipeline turns them on, against off.
    type On<'a> = &'a dyn Fn(Option<&toml::Value>) -> bool;
    let unset_or = |want: toml::Value| move |v: Option<&toml::Value>| v.is_none_or(|v| *v == want);
    let (mean_centre, unset_or_true) = (unset_or("mean".into()), unset_or(true.into()));
    let set_true = |v: Option<&toml::Value>| v == Some(&true.into());
    let positive =
        |v: Option<&toml::Value>| v.and_then(toml::Value::as_float).is_some_and(|q| q > 0.0);
    let off = toml::Value::Float(0.0);
    #[rustfmt::skip]
    let switches: [(&str, &str, On, toml::Value, &str); 8] = [
        ("reliability", "centre", &mean_centre, "median".into(), "with median centres"),
        ("reliability", "albedo_by_geometry", &set_true, false.into(), "albedo without the geometry's floor"),
        ("coverage", "across", &unset_or_true, false.into(), "without the across-edge spread"),
        ("coverage", "colour", &unset_or_true, false.into(), "without the colour's own edges"),
        ("outlier", "two_sided", &set_true, false.into(), "one-sided (dark dots kept)"),
        ("blend", "noise_level", &positive, off.clone(), "without the noise-level cap"),
        ("blend", "leak_level", &positive, off.clone(), "without the leak test's level"),
        ("spread", "highlights", &positive, off, "without highlights kept"),
    ];
    for (kind, key, on, other, label) in switches {
        out.extend(switched_variants(spec, (kind, key), (on, other), label)?);
    }
    out.extend(noise_variants(spec)?);
    let paths = feature_paths(spec);
    if !paths.is_empty() {
        for name in Weights::NAMES {
            let mut v = spec.clone();
            for p in &paths {
                v.set(&format!("{p}.weights.{name}"), toml::Value::Float(0.0))?;
            }
            out.push(Variant {
                name: format!("weight {name} = 0"),
                spec: v,
            });
        }
    }
    out.push(Variant {
        name: "plain SID".into(),
        spec: PipelineSpec::resolve("sid")?,
    });
    Ok(out)
}

/// For every stage of `kind` whose `key` (its value, or none when unset) passes `on`, the row with
/// `other` instead, named "<stage> <label>": what that setting buys.
fn switched_variants(
    spec: &PipelineSpec,
    (kind, key): (&str, &str),
    (on, other): (impl Fn(Option<&toml::Value>) -> bool, toml::Value),
    label: &str,
) -> Result<Vec<Variant>> {
    let mut out = Vec::new();
    for (i, stage) in spec.stages.iter().enumerate() {
        if stage.kind != kind || !on(stage.params.get(key)) {
            continue;
        }
        let mut v = spec.clone();
        v.stages[i].set(&[key], other.clone())?;
        out.push(Variant {
            name: format!("{} {label}", stage.id),
            spec: v,
        });
    }
    Ok(out)
}

/// The rows that show what measuring the noise buys, for a pipeline with `noise` stages: every
/// noise stage, noise key, blend, regression, spread and coverage taken out ("fixed σ", the
/// behaviour before the stages followed the noise; those four are weighed by the noise); one σ per
/// image (every `local_noise` set to 0, where a stage follows each pixel's own noise too); the
/// noise always estimated from the image (a `variance` buffer, if any, ignored); and the walks
/// taken out (the pyramid removed, à-trous on the colour, σ still from the noise).
fn noise_variants(spec: &PipelineSpec) -> Result<Vec<Variant>> {
    let is_noise = |s: &StageSpec| s.kind == "noise";
    if !spec
        .stages
        .iter()
        .any(|s| is_noise(s) || s.children.iter().any(is_noise))
    {
        return Ok(Vec::new());
    }
    let mut fixed = spec.clone();
    fixed.stages.retain(|s| {
        !is_noise(s) && !matches!(s.kind.as_str(), "blend" | "regress" | "spread" | "coverage")
    });
    // The colour guides count in the noise, so they go with it.
    let unlink = |p: &mut toml::Table| {
        for key in ["noise", "color_guide", "stack_color_guide"] {
            p.remove(key);
        }
    };
    for s in &mut fixed.stages {
        unlink(&mut s.params);
        s.children.retain(|c| !is_noise(c));
        for c in &mut s.children {
            unlink(&mut c.params);
        }
    }
    let mut from_image = spec.clone();
    for s in &mut from_image.stages {
        let image = toml::Value::String("image".into());
        if is_noise(s) {
            s.params.insert("source".into(), image.clone());
        }
        for c in s.children.iter_mut().filter(|c| is_noise(c)) {
            c.params.insert("source".into(), image.clone());
        }
    }
    let mut per_image = spec.clone();
    let mut local = false;
    for s in &mut per_image.stages {
        for p in std::iter::once(&mut s.params).chain(s.children.iter_mut().map(|c| &mut c.params))
        {
            if p.get("local_noise")
                .and_then(toml::Value::as_float)
                .is_some_and(|g| g > 0.0)
            {
                p.insert("local_noise".into(), toml::Value::Float(0.0));
                local = true;
            }
        }
    }
    let mut out = vec![Variant {
        name: "fixed σ (no noise measured)".into(),
        spec: fixed,
    }];
    if local {
        out.push(Variant {
            name: "one σ per image (no per-pixel noise)".into(),
            spec: per_image,
        });
    }
    out.push(Variant {
        name: "noise from the image only".into(),
        spec: from_image,
    });
    if let Some(p) = spec.stages.iter().position(|s| s.kind == "pyramid") {
        let mut v = spec.clone();
        v.stages.remove(p);
        for s in v.stages.iter_mut().filter(|s| s.kind == "atrous") {
            s.io.input = crate::buffers::COLOR.into();
        }
        out.push(Variant {
            name: "without walks (à-trous alone)".into(),
            spec: v,
        });
    }
    Ok(out)
}

/// Runs every variant on a copy of `buffers` and scores it against `reference`.
pub fn run(
    variants: &[Variant],
    buffers: &Buffers,
    reference: &Image,
    seed: u64,
    on_variant: &dyn Fn(&str),
) -> Result<Vec<Row>> {
    let mut rows: Vec<Row> = Vec::new();
    for v in variants {
        on_variant(&v.name);
        let pipeline = v.spec.build()?;
        let mut b = buffers.clone();
        let start = Instant::now();
        let (out, _) = pipeline.run(&mut b, &DenoiseOptions::seeded(seed))?;
        let seconds = start.elapsed().as_secs_f64();
        let s = metrics::score(&out, reference)?;
        let base = rows.first().map_or(s.ssim, |r| r.ssim);
        rows.push(Row {
            variant: v.name.clone(),
            ssim: s.ssim,
            psnr: s.psnr,
            relmse: s.relmse,
            seconds,
            delta_ssim: s.ssim - base,
        });
    }
    Ok(rows)
}

/// The table as text, one row per variant.
pub fn table(rows: &[Row]) -> String {
    let mut t = format!(
        "{:<34} {:>7} {:>8} {:>9} {:>8} {:>8}\n",
        "variant", "SSIM", "PSNR", "relMSE", "seconds", "ΔSSIM"
    );
    for r in rows {
        t += &format!(
            "{:<34} {:>7.4} {:>8.2} {:>9.5} {:>8.3} {:>+8.4}\n",
            r.variant, r.ssim, r.psnr, r.relmse, r.seconds, r.delta_ssim
        );
    }
    t
}

/// The rows as CSV.
pub fn csv(rows: &[Row]) -> Result<String> {
    let header = ["variant", "ssim", "psnr", "relmse", "seconds", "delta_ssim"].map(String::from);
    let fields: Vec<[String; 6]> = rows
        .iter()
        .map(|r| {
            [
                r.variant.clone(),
                r.ssim.to_string(),
                r.psnr.to_string(),
                r.relmse.to_string(),
                r.seconds.to_string(),
                r.delta_ssim.to_string(),
            ]
        })
        .collect();
    table::csv(&header, &fields)
}
