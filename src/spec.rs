//! The pipeline file as a plain data tree, parsed once.
//!
//! Text → [`PipelineSpec`]: stages with their kind, id, buffers, parameter table, a composite stage's
//! sub-list and its overrides. `--set`, `sweep --vary` and `ablate`'s variants edit this tree, and
//! `Pipeline::from_spec` builds stages from it; no other module reads the file's tables. Parameters
//! stay TOML until a stage kind reads them, so this module knows the grammar but no stage kind.
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
//!
//! A composite stage (the pyramid) also has a sub-list and overrides of its children's parameters:
//!
//! ```toml
//! [[stage]]
//! kind = "pyramid"
//! gsid = { walks = 16 }                 # child `gsid` at every level
//! level1 = { gsid = { sigma = 1.5 } }   # child `gsid` at level 1 only
//! [[stage.stages]]
//! kind = "gsid"
//! ```

use std::collections::{BTreeMap, HashSet};
use std::path::Path;

use crate::error::{Error, Result};

/// The buffer a pipeline's result is read from (and a stage's default output).
pub const OUTPUT_BUFFER: &str = "out";

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

/// Names of a stage's input and output buffers.
#[derive(Clone, Debug, PartialEq)]
pub struct StageIo {
    pub input: String,
    pub output: String,
}

/// A composite stage's changes to its children's parameters, by child id.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Overrides {
    /// `ID = { key = value }`: applied at every level.
    pub every_level: BTreeMap<String, toml::Table>,
    /// `levelN = { ID = { key = value } }`, by the key as written (`level1`).
    pub levels: BTreeMap<String, LevelOverride>,
}

/// The overrides of one `levelN` key.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LevelOverride {
    pub level: usize,
    /// Parameter overrides by child id.
    pub stages: BTreeMap<String, toml::Table>,
}

impl Overrides {
    /// The overrides of the `levelN` key `key`, made empty if missing.
    fn level_mut(&mut self, key: &str, level: usize) -> &mut LevelOverride {
        self.levels
            .entry(key.to_string())
            .or_insert_with(|| LevelOverride {
                level,
                stages: BTreeMap::new(),
            })
    }
}

/// One stage as written in the file.
#[derive(Clone, Debug, PartialEq)]
pub struct StageSpec {
    pub kind: String,
    pub id: String,
    pub io: StageIo,
    /// The kind's own parameters: every key but the common ones, the sub-list and the overrides.
    pub params: toml::Table,
    /// A composite stage's sub-list (`[[stage.stages]]`), run at each of its levels.
    pub children: Vec<StageSpec>,
    pub overrides: Overrides,
}

/// A pipeline as written, before its stages are built.
#[derive(Clone, Debug, PartialEq)]
pub struct PipelineSpec {
    pub name: String,
    pub description: String,
    pub stages: Vec<StageSpec>,
    /// Where it came from (a path or `built-in`), for error messages.
    pub origin: String,
    /// `temporal = R`: frames each side a frame sequence is merged over (`--temporal` overrides).
    pub temporal: Option<usize>,
}

/// The level a `levelN` key names (`levels` is a parameter, not a level).
fn level_key(key: &str) -> Option<usize> {
    key.strip_prefix("level").and_then(|n| n.parse().ok())
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

/// `value` as a table, or an error naming `key`.
fn into_table(value: toml::Value, key: &str, what: &str) -> Result<toml::Table> {
    match value {
        toml::Value::Table(t) => Ok(t),
        _ => Err(Error::config(key, format!("must be a table of {what}"))),
    }
}

/// A `levelN` value: a table of child id → parameter table.
fn level_override(level: usize, value: toml::Value, key: &str) -> Result<LevelOverride> {
    let mut stages = BTreeMap::new();
    for (child, v) in into_table(value, key, "sub-stage overrides")? {
        let t = into_table(v, &format!("{key}.{child}"), "parameter overrides")?;
        stages.insert(child, t);
    }
    Ok(LevelOverride { level, stages })
}

/// Deep-merges `over` into `base` (tables merge key by key, other values replace).
fn merge_tables(base: &mut toml::Table, over: &toml::Table) {
    for (k, v) in over {
        match (base.get_mut(k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge_tables(b, o),
            _ => {
                base.insert(k.clone(), v.clone());
            }
        }
    }
}

/// Sets `path` (at least one key) in `table` to `value`, making tables on the way; `key` names errors.
fn insert_path(
    mut table: &mut toml::Table,
    path: &[&str],
    value: toml::Value,
    key: &str,
) -> Result<()> {
    let (last, parents) = path.split_last().expect("a non-empty path");
    for part in parents {
        let entry = table
            .entry(part.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        table = entry
            .as_table_mut()
            .ok_or_else(|| Error::config(key, format!("`{part}` is not a table")))?;
    }
    table.insert(last.to_string(), value);
    Ok(())
}

/// Where a key of a stage table lives in the tree.
enum Slot {
    Level(usize),
    Child,
    Param,
}

impl StageSpec {
    fn slot(&self, key: &str) -> Slot {
        if let Some(level) = level_key(key) {
            Slot::Level(level)
        } else if self.children.iter().any(|c| c.id == key) {
            Slot::Child
        } else {
            Slot::Param
        }
    }

    /// Stores one key of the stage's table as the file would (replacing what was there).
    fn put(&mut self, key: &str, value: toml::Value) -> Result<()> {
        let here = format!("{}.{key}", self.id);
        match self.slot(key) {
            Slot::Level(level) => {
                let o = level_override(level, value, &here)?;
                self.overrides.levels.insert(key.to_string(), o);
            }
            Slot::Child => {
                let t = into_table(value, &here, "parameter overrides")?;
                self.overrides.every_level.insert(key.to_string(), t);
            }
            Slot::Param => {
                self.params.insert(key.to_string(), value);
            }
        }
        Ok(())
    }

    /// Sets `path` (`["weights", "depth"]`, `["level1", "gsid", "sigma"]`) to `value`, as a
    /// `--set ID.PATH=VALUE` does.
    pub fn set(&mut self, path: &[&str], value: toml::Value) -> Result<()> {
        let key = format!("{}.{}", self.id, path.join("."));
        let Some((first, rest)) = path.split_first() else {
            return Err(Error::config(key, "names no parameter"));
        };
        if *first == "stages" {
            return Err(Error::config(
                key,
                "a sub-list is changed in the pipeline file, not with --set",
            ));
        }
        if rest.is_empty() {
            return self.put(first, value);
        }
        match self.slot(first) {
            Slot::Level(level) => {
                let (child, tail) = rest.split_first().expect("rest is not empty");
                if !self.children.iter().any(|c| c.id == *child) {
                    return Err(Error::config(
                        format!("{}.{first}.{child}", self.id),
                        format!("names no sub-stage of stage `{}`", self.id),
                    ));
                }
                let entry = self.overrides.level_mut(first, level);
                if tail.is_empty() {
                    let t = into_table(value, &key, "parameter overrides")?;
                    entry.stages.insert(child.to_string(), t);
                    Ok(())
                } else {
                    let t = entry.stages.entry(child.to_string()).or_default();
                    insert_path(t, tail, value, &key)
                }
            }
            Slot::Child => {
                let t = self
                    .overrides
                    .every_level
                    .entry(first.to_string())
                    .or_default();
                insert_path(t, rest, value, &key)
            }
            Slot::Param => insert_path(&mut self.params, path, value, &key),
        }
    }

    /// Applies a table of overrides as if it were merged, key by key, into the stage's table in the
    /// file (how a composite stage applies its overrides to a child).
    pub fn merge(&mut self, over: &toml::Table) -> Result<()> {
        for (key, value) in over {
            let here = format!("{}.{key}", self.id);
            match self.slot(key) {
                Slot::Level(level) => {
                    let o = level_override(level, value.clone(), &here)?;
                    let entry = self.overrides.level_mut(key, level);
                    for (child, t) in &o.stages {
                        merge_tables(entry.stages.entry(child.clone()).or_default(), t);
                    }
                }
                Slot::Child => {
                    let t = into_table(value.clone(), &here, "parameter overrides")?;
                    let entry = self.overrides.every_level.entry(key.clone()).or_default();
                    merge_tables(entry, &t);
                }
                Slot::Param => merge_tables(
                    &mut self.params,
                    &toml::Table::from_iter([(key.clone(), value.clone())]),
                ),
            }
        }
        Ok(())
    }
}

/// Parses an array of stage tables (`[[stage]]`, or a composite stage's sub-list); `prefix` names
/// the array in errors (e.g. `stage`, `pyramid.stages`).
/// Largest pipeline file read: the shipped ones are a few KiB, and 256 stages fit in far less.
pub const MAX_PIPELINE_BYTES: u64 = 1 << 20;

/// Most frames each side `temporal = R` (and `--temporal`) may merge: 8 holds 17 frames in memory.
pub const MAX_TEMPORAL_RADIUS: usize = 8;

/// Most stages one pipeline file may hold, sub-stages included: far more than any pipeline runs.
pub const MAX_STAGES: usize = 256;

/// Deepest nesting of sub-lists: a pyramid inside a pyramid, no deeper. Every level of nesting
/// multiplies the planes alive at once.
pub const MAX_NESTING: usize = 2;

/// Parses a `[[stage]]` list (`depth` 0) or a sub-list, counting the stages parsed so far in
/// `count`; ids are checked against a set, so a long list parses in time linear in its length.
fn parse_stage_list(
    values: Vec<toml::Value>,
    prefix: &str,
    depth: usize,
    count: &mut usize,
) -> Result<Vec<StageSpec>> {
    if depth > MAX_NESTING {
        return Err(Error::config(
            prefix,
            format!("sub-lists nest deeper than {MAX_NESTING} levels"),
        ));
    }
    *count += values.len();
    if *count > MAX_STAGES {
        return Err(Error::config(
            prefix,
            format!("the pipeline has more than {MAX_STAGES} stages"),
        ));
    }
    let mut stages: Vec<StageSpec> = Vec::new();
    let mut ids: HashSet<String> = HashSet::new();
    for (n, value) in values.into_iter().enumerate() {
        let here = format!("{prefix}[{n}].");
        let toml::Value::Table(mut table) = value else {
            return Err(Error::config(format!("{prefix}[{n}]"), "must be a table"));
        };
        let kind = take_string(&mut table, "kind", &here)?
            .ok_or_else(|| Error::config(format!("{here}kind"), "is required"))?;
        let id = take_string(&mut table, "id", &here)?.unwrap_or_else(|| kind.clone());
        if !ids.insert(id.clone()) {
            return Err(Error::config(
                format!("{here}id"),
                format!("`{id}` is used twice; give each stage of the same kind its own id"),
            ));
        }
        let input = take_string(&mut table, "input", &here)?.unwrap_or_else(|| "color".into());
        let output =
            take_string(&mut table, "output", &here)?.unwrap_or_else(|| OUTPUT_BUFFER.into());
        let children = match table.remove("stages") {
            Some(toml::Value::Array(a)) => {
                parse_stage_list(a, &format!("{id}.stages"), depth + 1, count)?
            }
            Some(_) => {
                return Err(Error::config(
                    format!("{id}.stages"),
                    "must be an array of tables ([[stage.stages]])",
                ))
            }
            None => Vec::new(),
        };
        let mut stage = StageSpec {
            kind,
            id,
            io: StageIo { input, output },
            params: toml::Table::new(),
            children,
            overrides: Overrides::default(),
        };
        for (key, value) in table {
            stage.put(&key, value)?;
        }
        stages.push(stage);
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

impl PipelineSpec {
    /// Parses pipeline TOML; `origin` names the file in errors.
    pub fn parse(text: &str, origin: &str) -> Result<Self> {
        let mut root: toml::Table = text.parse().map_err(|e: toml::de::Error| {
            Error::config(origin, format!("invalid TOML: {}", e.message()))
        })?;
        let ctx = |e: Error| e.in_file(origin);
        let name = take_string(&mut root, "name", "")
            .map_err(ctx)?
            .ok_or_else(|| Error::config(format!("{origin}: name"), "is required"))?;
        let description = take_string(&mut root, "description", "")
            .map_err(ctx)?
            .unwrap_or_default();
        let raw_stages = root.remove("stage");
        let temporal = match root.remove("temporal") {
            None => None,
            Some(toml::Value::Integer(r)) if (0..=MAX_TEMPORAL_RADIUS as i64).contains(&r) => {
                Some(r as usize)
            }
            Some(other) => {
                return Err(Error::config(
                    format!("{origin}: temporal"),
                    format!(
                        "is {other}, allowed range is 0 to {} frames each side",
                        MAX_TEMPORAL_RADIUS
                    ),
                ))
            }
        };
        if let Some(key) = root.keys().next() {
            return Err(Error::config(
                format!("{origin}: {key}"),
                "unknown top-level key (expected name, description, temporal, stage)",
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
        let stages = parse_stage_list(raw_stages, "stage", 0, &mut 0).map_err(ctx)?;
        Ok(PipelineSpec {
            name,
            description,
            stages,
            origin: origin.to_string(),
            temporal,
        })
    }

    /// Finds a pipeline: a path (one that ends in `.toml` or holds a separator) is read as a file,
    /// any other name is the built-in pipeline of that name.
    pub fn resolve(name_or_path: &str) -> Result<Self> {
        let as_path = Path::new(name_or_path);
        let looks_like_file =
            name_or_path.ends_with(".toml") || name_or_path.contains(std::path::MAIN_SEPARATOR);
        if looks_like_file {
            let text = crate::io::read_text(as_path, MAX_PIPELINE_BYTES, "pipeline file")?;
            return Self::parse(&text, name_or_path);
        }
        // A bare name is always the built-in pipeline, never a file that happens to sit in the
        // working folder (`./pipelines/full.toml` would otherwise change what `full` means).
        Self::builtin(name_or_path)
    }

    /// A pipeline compiled into the crate ([`BUILTIN`]), never read from disk: what a program
    /// calling gsid in-process uses, whatever its working folder holds.
    pub fn builtin(name: &str) -> Result<Self> {
        match BUILTIN.iter().find(|(n, _)| *n == name) {
            Some((n, text)) => Self::parse(text, &format!("built-in pipeline {n}")),
            None => Err(Error::config(
                "--pipeline",
                format!(
                    "unknown pipeline `{name}` (known: {}; or give a .toml file)",
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
        self.set(key.trim(), parse_value(value.trim()))
    }

    /// Sets `STAGE_ID.key[.sub]` to `value` in the stage that id names: a top-level stage, else
    /// the one stage of that id anywhere in the tree (`gsid.walks` reaches `pyramid.gsid.walks`
    /// when the pyramid's `gsid` is the only one). Two or more nested stages of that id are an
    /// error listing their full paths.
    pub fn set(&mut self, key: &str, value: toml::Value) -> Result<()> {
        let key = self.full_key(key)?;
        let mut path = key.split('.');
        let stage_id = path.next().unwrap_or_default();
        let rest: Vec<&str> = path.collect();
        let stage = self
            .stages
            .iter_mut()
            .find(|s| s.id == stage_id)
            .expect("full_key names a top-level stage");
        stage.set(&rest, value)
    }

    /// `key` written from the top of the tree: unchanged when its first part is a top-level
    /// stage's id, else with the path of the one nested stage of that id put in front.
    pub fn full_key(&self, key: &str) -> Result<String> {
        let (stage_id, rest) = key.split_once('.').unwrap_or((key, ""));
        if rest.is_empty() || rest.split('.').any(str::is_empty) {
            return Err(Error::config(
                key,
                "--set key must be STAGE_ID.PARAM, e.g. gsid.walks",
            ));
        }
        if self.stages.iter().any(|s| s.id == stage_id) {
            return Ok(key.to_string());
        }
        let mut all = Vec::new();
        stage_paths(&self.stages, "", &mut all);
        let found: Vec<&String> = all
            .iter()
            .filter(|p| p.rsplit('.').next() == Some(stage_id))
            .collect();
        match found.as_slice() {
            [one] => Ok(format!("{one}.{rest}")),
            [] => Err(Error::config(
                key,
                format!(
                    "no stage `{stage_id}` in pipeline {} (stages: {})",
                    self.name,
                    all.join(", ")
                ),
            )),
            many => Err(Error::config(
                key,
                format!(
                    "`{stage_id}` is ambiguous in pipeline {}: give its full path ({})",
                    self.name,
                    many.iter()
                        .map(|p| format!("{p}.{rest}"))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            )),
        }
    }
}

/// Every stage's path from the top (`pyramid`, `pyramid.gsid`), in file order.
fn stage_paths(stages: &[StageSpec], prefix: &str, out: &mut Vec<String>) {
    for s in stages {
        let path = format!("{prefix}{}", s.id);
        out.push(path.clone());
        stage_paths(&s.children, &format!("{path}."), out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse_err(text: &str) -> String {
        PipelineSpec::parse(text, "x.toml")
            .err()
            .unwrap()
            .to_string()
    }

    const PYRAMID: &str = "name = \"p\"\n[[stage]]\nkind = \"pyramid\"\nlevels = 2\nlevel1 = { gsid = { sigma = 0.5 } }\ngsid = { walks = 4 }\n[[stage.stages]]\nkind = \"gsid\"\nsigma = 1.0\n";

    #[test]
    fn a_composite_stage_is_parsed_into_children_and_overrides() {
        let spec = PipelineSpec::parse(PYRAMID, "p.toml").unwrap();
        let p = &spec.stages[0];
        assert_eq!(p.params.keys().collect::<Vec<_>>(), ["levels"]);
        assert_eq!(p.children.len(), 1);
        assert_eq!(p.children[0].params["sigma"].as_float(), Some(1.0));
        assert_eq!(
            p.overrides.every_level["gsid"]["walks"].as_integer(),
            Some(4)
        );
        let l1 = &p.overrides.levels["level1"];
        assert_eq!(l1.level, 1);
        assert_eq!(l1.stages["gsid"]["sigma"].as_float(), Some(0.5));
    }

    #[test]
    fn set_edits_params_children_and_levels() {
        let mut spec = PipelineSpec::parse(PYRAMID, "p.toml").unwrap();
        spec.apply_set("pyramid.levels=3").unwrap();
        spec.apply_set("pyramid.gsid.window=2").unwrap();
        spec.apply_set("pyramid.level2.gsid.sigma=0.25").unwrap();
        spec.apply_set("pyramid.level1={ gsid = { walks = 8 } }")
            .unwrap();
        let p = &spec.stages[0];
        assert_eq!(p.params["levels"].as_integer(), Some(3));
        assert_eq!(
            p.overrides.every_level["gsid"]["window"].as_integer(),
            Some(2)
        );
        assert_eq!(
            p.overrides.every_level["gsid"]["walks"].as_integer(),
            Some(4)
        );
        assert_eq!(p.overrides.levels["level2"].level, 2);
        let l1 = &p.overrides.levels["level1"].stages["gsid"];
        assert_eq!(l1.get("sigma"), None);
        assert_eq!(l1["walks"].as_integer(), Some(8));
        let err = spec
            .apply_set("pyramid.level1=3")
            .err()
            .unwrap()
            .to_string();
        assert!(
            err.contains("pyramid.level1") && err.contains("table"),
            "{err}"
        );
        let err = spec
            .apply_set("pyramid.level1.gsdi.sigma=1")
            .err()
            .unwrap()
            .to_string();
        assert!(
            err.contains("pyramid.level1.gsdi: names no sub-stage"),
            "{err}"
        );
        let err = spec
            .apply_set("pyramid.stages.x=1")
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("pyramid.stages"), "{err}");
    }

    #[test]
    fn merge_deepens_tables_and_replaces_values() {
        let mut spec = PipelineSpec::parse(PYRAMID, "p.toml").unwrap();
        let child = &mut spec.stages[0].children[0];
        let over: toml::Table = "weights = { depth = 0.5 }\nsigma = 2.0".parse().unwrap();
        child.merge(&over).unwrap();
        let again: toml::Table = "weights = { normal = 0.25 }".parse().unwrap();
        child.merge(&again).unwrap();
        assert_eq!(child.params["sigma"].as_float(), Some(2.0));
        assert_eq!(child.params["weights"]["depth"].as_float(), Some(0.5));
        assert_eq!(child.params["weights"]["normal"].as_float(), Some(0.25));
    }

    #[test]
    fn sub_list_errors_name_the_file_and_the_key() {
        let text = "name = \"x\"\n[[stage]]\nkind = \"pyramid\"\n[[stage.stages]]\nsigma = 1\n";
        let err = parse_err(text);
        assert!(err.contains("x.toml: pyramid.stages[0].kind"), "{err}");
        let err = parse_err("name = \"x\"\n[[stage]]\nkind = \"pyramid\"\nlevel1 = 2\n");
        assert!(err.contains("x.toml: pyramid.level1"), "{err}");
    }

    #[test]
    fn a_nested_stage_is_found_by_its_id_unless_two_share_it() {
        let mut spec = PipelineSpec::builtin("full").unwrap();
        spec.apply_set("gsid.walks=40").unwrap();
        spec.apply_set("gsid.weights.depth=0").unwrap();
        spec.apply_set("level_noise.reuse=\"noise\"").unwrap();
        let p = spec.stages.iter().find(|s| s.id == "pyramid").unwrap();
        assert_eq!(
            p.overrides.every_level["gsid"]["walks"].as_integer(),
            Some(40)
        );
        assert_eq!(
            p.overrides.every_level["gsid"]["weights"]["depth"].as_integer(),
            Some(0)
        );
        spec.build().unwrap();
        // A top-level id is a full path: `noise` is the top-level stage, not `pyramid.level_noise`.
        assert_eq!(spec.full_key("noise.x").unwrap(), "noise.x");
        let err = spec.apply_set("gsdi.walks=4").err().unwrap().to_string();
        assert!(err.contains("pyramid.gsid"), "{err}");
        let two = "name = \"two\"\n[[stage]]\nkind = \"pyramid\"\nid = \"a\"\n[[stage.stages]]\nkind = \"gsid\"\n[[stage]]\nkind = \"pyramid\"\nid = \"b\"\n[[stage.stages]]\nkind = \"gsid\"\n";
        let mut spec = PipelineSpec::parse(two, "two.toml").unwrap();
        let err = spec.apply_set("gsid.walks=4").err().unwrap().to_string();
        assert!(
            err.contains("ambiguous") && err.contains("a.gsid.walks, b.gsid.walks"),
            "{err}"
        );
        spec.apply_set("b.gsid.walks=4").unwrap();
    }

    #[test]
    fn duplicate_stage_ids_are_rejected() {
        let err =
            parse_err("name = \"x\"\n[[stage]]\nkind = \"gsid\"\n[[stage]]\nkind = \"gsid\"\n");
        assert!(err.contains("used twice"), "{err}");
    }
}
