//! Pipelines: named TOML files of ordered stages over named buffers.
//!
//! Raw text → [`PipelineSpec`] (still TOML tables, so `--set` overrides edit it like the file would)
//! → [`Pipeline`] of built, validated stages. A pipeline file:
//!
//! ```toml
//! name = "gsid"
//! description = "one line"
//! [[stage]]
//! kind = "gsid"          # the stage kind
//! id = "gsid"            # optional; defaults to the kind; `--set ID.key=value` addresses it
//! input = "color"        # optional; buffer read
//! output = "out"         # optional; buffer written
//! sigma = 1.0            # the kind's parameters
//! ```

use std::path::Path;
use std::time::Instant;

use serde::Serialize;

use crate::buffers::{Buffers, COLOR};
use crate::condition::{Conditioning, SanitizeReport};
use crate::error::{Error, Result};
use crate::image::Image;
use crate::stages::{self, Context, Stage, StageIo, StageReport};

/// The buffer a pipeline's result is read from.
pub const OUTPUT_BUFFER: &str = "out";
/// The pipeline `gsid denoise` runs without `--pipeline`.
pub const DEFAULT_PIPELINE: &str = "full";

/// Pipelines built into the binary, so they work from any folder.
pub const BUILTIN: &[(&str, &str)] = &[
    ("sid", include_str!("../pipelines/sid.toml")),
    ("gsid", include_str!("../pipelines/gsid.toml")),
    (
        "gsid-outlier",
        include_str!("../pipelines/gsid-outlier.toml"),
    ),
    ("pyramid", include_str!("../pipelines/pyramid.toml")),
    ("full", include_str!("../pipelines/full.toml")),
    ("fast", include_str!("../pipelines/fast.toml")),
    ("balanced", include_str!("../pipelines/balanced.toml")),
    ("quality", include_str!("../pipelines/quality.toml")),
];

/// One stage as written in the file.
#[derive(Clone, Debug, PartialEq)]
pub struct StageSpec {
    pub kind: String,
    pub id: String,
    pub io: StageIo,
    pub params: toml::Table,
}

/// A pipeline as written, before its stages are built.
#[derive(Clone, Debug, PartialEq)]
pub struct PipelineSpec {
    pub name: String,
    pub description: String,
    pub stages: Vec<StageSpec>,
    /// Where it came from (a path or `built-in`), for error messages.
    pub origin: String,
}

fn take_string(table: &mut toml::Table, key: &str, ctx: &str) -> Result<Option<String>> {
    match table.remove(key) {
        None => Ok(None),
        Some(toml::Value::String(s)) => Ok(Some(s)),
        Some(other) => Err(Error::config(
            format!("{ctx}{key}"),
            format!("must be a string, not {}", other.type_str()),
        )),
    }
}

impl PipelineSpec {
    /// Parses pipeline TOML; `origin` names the file in errors.
    pub fn parse(text: &str, origin: &str) -> Result<Self> {
        let mut root: toml::Table = text.parse().map_err(|e: toml::de::Error| {
            Error::config(origin, format!("invalid TOML: {}", e.message()))
        })?;
        let ctx = |e: Error| match e {
            Error::Config { key, msg } => Error::Config {
                key: format!("{origin}: {key}"),
                msg,
            },
            other => other,
        };
        let name = take_string(&mut root, "name", "")
            .map_err(ctx)?
            .ok_or_else(|| Error::config(format!("{origin}: name"), "is required"))?;
        let description = take_string(&mut root, "description", "")
            .map_err(ctx)?
            .unwrap_or_default();
        let raw_stages = root.remove("stage");
        if let Some(key) = root.keys().next() {
            return Err(Error::config(
                format!("{origin}: {key}"),
                "unknown top-level key (expected name, description, stage)",
            ));
        }
        let raw_stages = match raw_stages {
            Some(toml::Value::Array(a)) => a,
            Some(_) => {
                return Err(Error::config(
                    format!("{origin}: stage"),
                    "must be an array of tables ([[stage]])",
                ))
            }
            None => {
                return Err(Error::config(
                    format!("{origin}: stage"),
                    "a pipeline needs at least one [[stage]]",
                ))
            }
        };
        let stages = parse_stage_list(raw_stages, "stage").map_err(ctx)?;
        Ok(PipelineSpec {
            name,
            description,
            stages,
            origin: origin.to_string(),
        })
    }

    /// Finds a pipeline by name (`pipelines/NAME.toml` in the current folder, else built in) or by file path.
    pub fn resolve(name_or_path: &str) -> Result<Self> {
        let as_path = Path::new(name_or_path);
        let looks_like_file =
            name_or_path.ends_with(".toml") || name_or_path.contains(std::path::MAIN_SEPARATOR);
        if looks_like_file {
            let text = std::fs::read_to_string(as_path).map_err(|e| Error::file(as_path, e))?;
            return Self::parse(&text, name_or_path);
        }
        let local = Path::new("pipelines").join(format!("{name_or_path}.toml"));
        if local.is_file() {
            let text = std::fs::read_to_string(&local).map_err(|e| Error::file(&local, e))?;
            return Self::parse(&text, &local.display().to_string());
        }
        match BUILTIN.iter().find(|(n, _)| *n == name_or_path) {
            Some((n, text)) => Self::parse(text, &format!("built-in pipeline {n}")),
            None => Err(Error::config(
                "--pipeline",
                format!(
                    "unknown pipeline `{name_or_path}` (known: {}; or give a .toml file)",
                    BUILTIN
                        .iter()
                        .map(|(n, _)| *n)
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            )),
        }
    }

    /// Applies one `STAGE_ID.key[.sub]=VALUE` override; VALUE is read as TOML (bare words as strings).
    pub fn apply_set(&mut self, assignment: &str) -> Result<()> {
        let (key, value) = assignment.split_once('=').ok_or_else(|| {
            Error::config(assignment, "--set needs KEY=VALUE, e.g. gsid.walks=40")
        })?;
        let key = key.trim();
        let mut path = key.split('.');
        let stage_id = path.next().unwrap_or_default();
        let rest: Vec<&str> = path.collect();
        if rest.is_empty() || rest.iter().any(|p| p.is_empty()) {
            return Err(Error::config(
                key,
                "--set key must be STAGE_ID.PARAM, e.g. gsid.walks",
            ));
        }
        let ids: Vec<String> = self.stages.iter().map(|s| s.id.clone()).collect();
        let stage = self
            .stages
            .iter_mut()
            .find(|s| s.id == stage_id)
            .ok_or_else(|| {
                Error::config(
                    key,
                    format!(
                        "no stage `{stage_id}` in pipeline {} (stages: {})",
                        self.name,
                        ids.join(", ")
                    ),
                )
            })?;
        let value = parse_value(value.trim());
        let mut table = &mut stage.params;
        for part in &rest[..rest.len() - 1] {
            let entry = table
                .entry(part.to_string())
                .or_insert_with(|| toml::Value::Table(toml::Table::new()));
            table = entry
                .as_table_mut()
                .ok_or_else(|| Error::config(key, format!("`{part}` is not a table")))?;
        }
        table.insert(rest[rest.len() - 1].to_string(), value);
        Ok(())
    }

    /// Builds and validates every stage.
    pub fn build(&self) -> Result<Pipeline> {
        let stages = self
            .stages
            .iter()
            .map(|s| {
                stages::build(&s.kind, &s.id, s.io.clone(), s.params.clone()).map_err(|e| match e {
                    Error::Config { key, msg } => Error::Config {
                        key: format!("{}: {key}", self.origin),
                        msg,
                    },
                    other => other,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Pipeline {
            name: self.name.clone(),
            description: self.description.clone(),
            stages,
        })
    }
}

/// Parses an array of stage tables (`[[stage]]`, or a composite stage's sub-list); `prefix` names
/// the array in errors (e.g. `stage`, `pyramid.stages`).
pub fn parse_stage_list(values: Vec<toml::Value>, prefix: &str) -> Result<Vec<StageSpec>> {
    let mut stages: Vec<StageSpec> = Vec::new();
    for (n, value) in values.into_iter().enumerate() {
        let here = format!("{prefix}[{n}].");
        let toml::Value::Table(mut table) = value else {
            return Err(Error::config(format!("{prefix}[{n}]"), "must be a table"));
        };
        let kind = take_string(&mut table, "kind", &here)?
            .ok_or_else(|| Error::config(format!("{here}kind"), "is required"))?;
        let id = take_string(&mut table, "id", &here)?.unwrap_or_else(|| kind.clone());
        if stages.iter().any(|s| s.id == id) {
            return Err(Error::config(
                format!("{here}id"),
                format!("`{id}` is used twice; give each stage of the same kind its own id"),
            ));
        }
        let input = take_string(&mut table, "input", &here)?.unwrap_or_else(|| "color".into());
        let output =
            take_string(&mut table, "output", &here)?.unwrap_or_else(|| OUTPUT_BUFFER.into());
        stages.push(StageSpec {
            kind,
            id,
            io: StageIo { input, output },
            params: table,
        });
    }
    Ok(stages)
}

/// Reads an override value as TOML, falling back to a plain string (so `tone=log1p` works unquoted).
fn parse_value(text: &str) -> toml::Value {
    format!("v = {text}")
        .parse::<toml::Table>()
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(text.to_string()))
}

/// A built pipeline: stages in order.
pub struct Pipeline {
    pub name: String,
    pub description: String,
    pub stages: Vec<Box<dyn Stage>>,
}

/// What a run did: sanitisation, notices, per-stage timings.
#[derive(Clone, Debug, Serialize)]
pub struct RunReport {
    pub pipeline: String,
    pub sanitized: SanitizeReport,
    pub notes: Vec<String>,
    pub stages: Vec<StageReport>,
    pub seconds: f64,
}

impl RunReport {
    pub fn walk_steps(&self) -> u64 {
        self.stages.iter().map(|s| s.walk_steps).sum()
    }
}

impl Pipeline {
    /// Conditions the inputs (sanitising, brightness: [`Conditioning`]), runs every stage, and
    /// takes the `out` buffer out of `buffers` (back at the input's scale, as is `color`) with a
    /// report.
    pub fn run(
        &self,
        buffers: &mut Buffers,
        seed: u64,
        progress: bool,
    ) -> Result<(Image, RunReport)> {
        let start = Instant::now();
        let conditioning = Conditioning::apply(buffers);
        let mut ctx = Context::new(seed, progress);
        for line in conditioning.notes() {
            ctx.note(line);
        }
        self.check_buffers(buffers)?;
        for stage in &self.stages {
            stage.execute(buffers, &mut ctx)?;
        }
        if let Some(color) = buffers.get_mut(COLOR) {
            conditioning.undo(color);
        }
        let mut out = buffers.remove(OUTPUT_BUFFER).ok_or_else(|| {
            Error::buffer(
                OUTPUT_BUFFER,
                format!("pipeline {} never writes it", self.name),
            )
        })?;
        conditioning.undo(&mut out);
        let report = RunReport {
            pipeline: self.name.clone(),
            sanitized: conditioning.sanitized,
            notes: ctx.notes,
            stages: ctx.reports,
            seconds: start.elapsed().as_secs_f64(),
        };
        Ok((out, report))
    }

    /// Checks, before any work, that every stage's inputs exist or are written by an earlier stage.
    fn check_buffers(&self, buffers: &Buffers) -> Result<()> {
        let mut available: Vec<String> = buffers.names().map(String::from).collect();
        for stage in &self.stages {
            for need in stage.requires() {
                if !available.contains(&need) {
                    return Err(Error::buffer(
                        &need,
                        format!("is required by stage `{}` but neither the input nor an earlier stage provides it", stage.id()),
                    ));
                }
            }
            available.extend(stage.writes());
        }
        if !available.iter().any(|b| b == OUTPUT_BUFFER) {
            return Err(Error::buffer(
                OUTPUT_BUFFER,
                format!("pipeline {} never writes it", self.name),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_builtin_pipeline_parses_builds_and_matches_its_file_name() {
        for (name, text) in BUILTIN {
            let spec = PipelineSpec::parse(text, name).unwrap();
            assert_eq!(&spec.name, name);
            assert!(!spec.description.is_empty());
            spec.build().unwrap();
        }
    }

    #[test]
    fn misspelled_keys_are_named() {
        let err = PipelineSpec::parse(
            "name = \"x\"\n[[stage]]\nkind = \"gsid\"\nwalsk = 3\n",
            "x.toml",
        )
        .unwrap()
        .build()
        .err()
        .unwrap()
        .to_string();
        assert!(err.contains("x.toml") && err.contains("walsk"), "{err}");
        let err = PipelineSpec::parse("name = \"x\"\nstages = 1\n", "x.toml")
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("stages"), "{err}");
        let err = PipelineSpec::parse("name = \"x\"\n[[stage]]\nkind = \"blur\"\n", "x.toml")
            .unwrap()
            .build()
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("blur") && err.contains("kind"), "{err}");
    }

    #[test]
    fn out_of_range_values_name_key_and_range() {
        let mut spec = PipelineSpec::resolve("gsid").unwrap();
        spec.apply_set("gsid.p_min=2").unwrap();
        let err = spec.build().err().unwrap().to_string();
        assert!(
            err.contains("gsid.p_min") && err.contains("between 0 and 1"),
            "{err}"
        );
        let mut spec = PipelineSpec::resolve("gsid").unwrap();
        spec.apply_set("gsid.weights.normal=-1").unwrap();
        let err = spec.build().err().unwrap().to_string();
        assert!(err.contains("gsid.weights.normal"), "{err}");
    }

    #[test]
    fn overrides_parse_toml_values_and_bare_words() {
        let mut spec = PipelineSpec::resolve("gsid").unwrap();
        spec.apply_set("gsid.walks=40").unwrap();
        spec.apply_set("gsid.tone=log1p").unwrap();
        spec.apply_set("gsid.weights.depth=0.5").unwrap();
        let p = &spec.stages[0].params;
        assert_eq!(p["walks"].as_integer(), Some(40));
        assert_eq!(p["tone"].as_str(), Some("log1p"));
        assert_eq!(p["weights"]["depth"].as_float(), Some(0.5));
        spec.build().unwrap();
        assert!(spec.apply_set("walks=4").is_err());
        assert!(spec.apply_set("gsid.walks").is_err());
    }

    #[test]
    fn duplicate_stage_ids_are_rejected() {
        let text = "name = \"x\"\n[[stage]]\nkind = \"gsid\"\n[[stage]]\nkind = \"gsid\"\n";
        let err = PipelineSpec::parse(text, "x.toml")
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("used twice"), "{err}");
    }
}
