//! `gsid denoise` over many frames: a frame pattern (`beauty.####.exr`) or a folder of render-set
//! folders, one frame after another with the same pipeline and seed (a static scene must not
//! flicker from seed changes), and the run's JSON report.
//!
//! Everything that can be wrong with the arguments (patterns, `--frames`, an output without the
//! frame token) is found before the first frame is read. A failing frame is named by its number;
//! the run stops there unless `--keep-going`, which ends with one summary error instead.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::args::DenoiseArgs;
use super::frame::{denoise_or_skip, end_of, resolved, Loader};
use super::meter::{Meter, Verbosity};
pub use super::pattern::{parse_frames, Pattern};
use super::report::{Entry, FrameId, Outcome, PipelineJson, SequenceJson};
use super::stdout::print_json;
use crate::error::{Error, Result};
use crate::io;
use crate::pipeline::Pipeline;
use crate::run::RunContext;
use crate::temporal::Shot;

/// Before any work, over the whole plan: no frame's output (`-o`, `--save-buffer`) is an input of
/// any frame, nor inside a folder that is one (a render set's folder, whose buffers are found by
/// name: a file written there would be read as a buffer by a later frame or run).
fn check_plan(frames: &[Frame]) -> Result<()> {
    let mut inputs: HashMap<PathBuf, &str> = HashMap::new();
    for frame in frames {
        let a = &frame.args;
        let named = a.inputs.slots().into_iter().filter_map(|(_, p)| p.as_ref());
        for path in a.dir.iter().chain(named) {
            inputs.insert(resolved(&io::split_layer(path).0), &frame.label);
        }
    }
    for frame in frames {
        let a = &frame.args;
        let saves = a.saves()?;
        for out in std::iter::once(&a.output).chain(saves.iter().map(|(_, p)| p)) {
            let full = resolved(out);
            for (depth, place) in full.ancestors().enumerate() {
                let Some(label) = inputs.get(place) else {
                    continue;
                };
                let what = if depth == 0 {
                    "an input"
                } else {
                    "inside the input folder"
                };
                return Err(Error::output(
                    out,
                    format!(
                        "is {what} {} of frame {label}; refusing to write over an input",
                        place.display()
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// One frame of a batch: its label (number or render set name) and the arguments of its run.
struct Frame {
    label: String,
    /// The frame number of a pattern's frame.
    number: Option<u64>,
    args: DenoiseArgs,
}

/// The paths of a frame pattern's frames: any frame's arguments, also a neighbour's outside
/// `--frames` (read-only, for `--temporal`).
struct FramePaths {
    base: DenoiseArgs,
    pattern: Pattern,
    inputs: Vec<(&'static str, Option<Pattern>)>,
    output: Pattern,
    saves: Vec<(String, Pattern)>,
}

impl FramePaths {
    /// The arguments of frame `n`'s run.
    fn args(&self, n: u64) -> DenoiseArgs {
        let mut a = self.base.clone();
        let frame = |p: &Pattern| PathBuf::from(p.frame(n));
        if a.dir.is_some() {
            a.dir = Some(frame(&self.pattern));
        }
        for (name, slot) in a.inputs.slots_mut() {
            let pat = self
                .inputs
                .iter()
                .find(|(n, _)| *n == name)
                .and_then(|(_, p)| p.as_ref());
            if let (Some(path), Some(pat)) = (slot, pat) {
                *path = frame(pat);
            }
        }
        a.output = frame(&self.output);
        a.save_buffers = self
            .saves
            .iter()
            .map(|(name, p)| format!("{name}={}", p.frame(n)))
            .collect();
        a
    }

    /// Frame `n`'s render set for a neighbour: `None` outside the shot's files (`first..=last`).
    fn load(&self, n: u64, (first, last): (u64, u64)) -> Option<Result<io::LoadedSet>> {
        if n < first || n > last {
            return None;
        }
        let a = self.args(n);
        Some(a.inputs.load(a.dir.as_deref()))
    }
}

/// Frames to denoise one after another.
pub struct Batch {
    frames: Vec<Frame>,
    /// A folder that `-o` names, created before the first frame if missing.
    out_dir: Option<PathBuf>,
    /// A frame pattern's paths (not for a folder of render sets).
    paths: Option<FramePaths>,
}

/// A path as text, if it could hold a frame token (and does not name a file as it is).
fn pattern_of(path: &Path) -> Result<Option<Pattern>> {
    match path.to_str() {
        Some(text) if !path.exists() => Pattern::find(text),
        _ => Ok(None),
    }
}

impl Batch {
    /// The batch `args` asks for, or `None` for one render set (the arguments are checked either way).
    pub fn plan(args: &DenoiseArgs) -> Result<Option<Batch>> {
        if let Some(dir) = args.dir.as_deref().filter(|d| is_batch_folder(d)) {
            return Self::folders(args, dir).map(Some);
        }
        let color = args
            .colour_input()
            .ok_or_else(|| Error::config("--color", "is required with named inputs"))?;
        let Some(pattern) = pattern_of(color)? else {
            return Self::single(args).map(|()| None);
        };
        let output = args
            .output
            .to_str()
            .and_then(|o| Pattern::find(o).transpose());
        let output = output.transpose()?.ok_or_else(|| {
            Error::output(
                &args.output,
                "needs a frame token (####, %04d or $F4), as the input has one",
            )
        })?;
        let saves = args.saves()?;
        let mut save_patterns = Vec::new();
        for (name, path) in &saves {
            let p = path.to_str().and_then(|p| Pattern::find(p).transpose());
            let p = p
                .transpose()?
                .ok_or_else(|| Error::output(path, "needs a frame token, as the input has one"))?;
            save_patterns.push((name.clone(), p));
        }
        let numbers = match &args.frames {
            Some(list) => parse_frames(list)?,
            None => pattern.existing_frames()?,
        };
        if numbers.is_empty() {
            return Err(Error::config("--frames", "names no frame"));
        }
        if !args.keep_going {
            missing_frames(args, &pattern, &output, &numbers)?;
        }
        // Named inputs without a token (a static albedo) are the same file in every frame.
        let mut inputs = Vec::new();
        for (name, slot) in args.inputs.slots() {
            if let Some(p) = slot {
                inputs.push((name, pattern_of(p)?));
            }
        }
        let paths = FramePaths {
            base: args.clone(),
            pattern,
            inputs,
            output,
            saves: save_patterns,
        };
        let frames = numbers
            .into_iter()
            .map(|n| Frame {
                label: n.to_string(),
                number: Some(n),
                args: paths.args(n),
            })
            .collect::<Vec<_>>();
        check_plan(&frames)?;
        Ok(Some(Batch {
            frames,
            out_dir: None,
            paths: Some(paths),
        }))
    }

    /// A folder of render-set folders: each becomes `OUT/<name>.exr`.
    fn folders(args: &DenoiseArgs, dir: &Path) -> Result<Batch> {
        no_temporal(args)?;
        if args.frames.is_some() {
            return Err(Error::config(
                "--frames",
                "applies to a frame pattern input",
            ));
        }
        if !args.save_buffers.is_empty() {
            return Err(Error::config(
                "--save-buffer",
                "applies to one render set or a frame pattern, not a folder of render sets",
            ));
        }
        // One file named for a buffer cannot be every set's: each set has its own.
        let named = args.inputs.slots().into_iter().find(|(_, p)| p.is_some());
        if let Some((buffer, _)) = named {
            return Err(Error::config(
                format!("--{}", buffer.replace('_', "-")),
                "names one file; a folder of render sets takes each set's buffers from its own folder",
            ));
        }
        let names_an_image =
            !args.output.exists() && io::ImageFormat::of_output(&args.output).is_ok();
        if (args.output.exists() && !args.output.is_dir()) || names_an_image {
            return Err(Error::output(
                &args.output,
                "is not a folder (a folder of render sets is written into one, one image per set)",
            ));
        }
        let frames = render_set_folders(dir)?
            .into_iter()
            .map(|name| {
                let mut a = args.clone();
                a.dir = Some(dir.join(&name));
                a.output = args.output.join(format!("{name}.exr"));
                Frame {
                    label: name,
                    number: None,
                    args: a,
                }
            })
            .collect::<Vec<_>>();
        check_plan(&frames)?;
        Ok(Batch {
            frames,
            out_dir: Some(args.output.clone()),
            paths: None,
        })
    }

    /// One render set: a frame token anywhere else (`-o`, `--albedo`) would be written literally.
    fn single(args: &DenoiseArgs) -> Result<()> {
        no_temporal(args)?;
        if args.frames.is_some() {
            return Err(Error::config(
                "--frames",
                "applies to a frame pattern input",
            ));
        }
        let named = args
            .inputs
            .slots()
            .into_iter()
            .filter_map(|(_, p)| p.as_ref());
        for path in named.chain([&args.output]) {
            if pattern_of(path)?.is_some() {
                return Err(Error::config(
                    path.display().to_string(),
                    "has a frame token but the colour input is not a frame pattern",
                ));
            }
        }
        Ok(())
    }

    /// How many frames the batch denoises.
    pub fn frame_count(&self) -> usize {
        self.frames.len()
    }

    /// Denoises every frame in order, `meter` showing progress over all of them.
    pub fn run(
        self,
        args: &DenoiseArgs,
        pipeline: &Pipeline,
        ctx: &RunContext,
        meter: &Meter,
    ) -> Result<()> {
        if let Some(dir) = &self.out_dir {
            std::fs::create_dir_all(dir).map_err(|e| Error::output(dir, e))?;
        }
        let total = self.frames.len();
        let mut entries = Vec::with_capacity(total);
        let mut failed: Vec<(FrameId, i32)> = Vec::new();
        let mut stop = None;
        let radius = args.temporal.or(pipeline.temporal).unwrap_or(0);
        let mut shot = match &self.paths {
            Some(paths) if radius > 0 => {
                let files = paths.pattern.existing_frames().unwrap_or_default();
                let range = (
                    files.first().copied().unwrap_or(0),
                    files.last().copied().unwrap_or(0),
                );
                Some((Shot::new(radius, args.temporal_strict)?, paths, range))
            }
            _ => None,
        };
        // A note is said once a run, at the first frame it applies to (the channel mapping, a
        // missing buffer, a clamp): notes of one kind differ from frame to frame only in numbers.
        let said = std::cell::RefCell::new(std::collections::HashSet::new());
        for frame in self.frames {
            let id = FrameId::of(frame.number, &frame.label);
            let label = frame.label;
            let say = |line: &str| {
                let new = once_a_run(line).is_none_or(|key| said.borrow_mut().insert(key));
                if new {
                    meter.say_at(Verbosity::Normal, &format!("gsid: frame {label}: {line}"));
                }
            };
            meter.start_frame(Some(&label));
            let temporal = shot.is_some() && frame.number.is_some();
            let mut merged = |_: &DenoiseArgs| -> Result<io::LoadedSet> {
                let (shot, paths, range) = shot.as_mut().expect("a temporal run");
                let n = frame.number.expect("a pattern's frame");
                shot.frame(n, &|k| paths.load(k, *range))
            };
            let load: Option<Loader> = if temporal { Some(&mut merged) } else { None };
            let result = denoise_or_skip(&frame.args, pipeline, ctx, meter, &say, load);
            meter.end_frame(end_of(&result));
            let outcome = match result {
                Ok(outcome) => outcome,
                // A signal stops the whole batch, `--keep-going` or not: no summary, one line.
                Err(Error::Cancelled) => {
                    meter.finish();
                    return Err(Error::Cancelled);
                }
                Err(e) => {
                    let e = Error::Frame {
                        frame: label.clone(),
                        source: Box::new(e),
                    };
                    failed.push((id.clone(), e.exit_code()));
                    let outcome = Outcome::Failed {
                        error: e.to_string(),
                        exit_code: e.exit_code(),
                    };
                    if args.keep_going {
                        meter.error(&format!("gsid: error: {e}"));
                    } else {
                        stop = Some(e);
                    }
                    outcome
                }
            };
            entries.push(Entry { frame: id, outcome });
            if stop.is_some() {
                break;
            }
        }
        meter.finish();
        let skipped = entries
            .iter()
            .filter(|e| matches!(e.outcome, Outcome::Skipped { .. }))
            .count();
        let done = entries.len() - skipped - failed.len();
        if meter.talks() {
            let not_started = total - entries.len();
            let rest = if not_started > 0 {
                format!(", {not_started} not started")
            } else {
                String::new()
            };
            crate::progress::say_err!(
                "gsid: {total} frames: {done} denoised, {skipped} skipped (output exists), {} failed{rest}",
                failed.len()
            );
        }
        if args.json {
            let json = SequenceJson {
                version: env!("CARGO_PKG_VERSION"),
                pipeline: PipelineJson::of(pipeline),
                seed: ctx.seed,
                frames: entries,
                done,
                skipped,
                failed: failed.iter().map(|(id, _)| id.clone()).collect(),
            };
            print_json(&json)?;
        }
        if let Some(e) = stop {
            return Err(e);
        }
        if failed.is_empty() {
            return Ok(());
        }
        Err(Error::Frames {
            code: if failed.iter().any(|(_, c)| *c == 1) {
                1
            } else {
                2
            },
            failed: failed.into_iter().map(|(id, _)| id.to_string()).collect(),
            total,
        })
    }
}

/// `--temporal` needs a shot: a frame pattern, not one render set or a folder of them.
fn no_temporal(args: &DenoiseArgs) -> Result<()> {
    if args.temporal.unwrap_or(0) > 0 || args.temporal_strict {
        let flag = if args.temporal_strict && args.temporal.unwrap_or(0) == 0 {
            "--temporal-strict"
        } else {
            "--temporal"
        };
        return Err(Error::config(
            flag,
            "applies to a frame pattern input (shot/beauty.####.exr): its neighbours are found by frame number",
        ));
    }
    Ok(())
}

/// A folder without a `color` file whose subfolders are render sets.
fn is_batch_folder(dir: &Path) -> bool {
    dir.is_dir() && !io::is_render_set(dir) && render_set_folders(dir).is_ok_and(|f| !f.is_empty())
}

/// The subfolders of `dir` that are render sets, by name.
fn render_set_folders(dir: &Path) -> Result<Vec<String>> {
    let entries = std::fs::read_dir(dir).map_err(|e| Error::file(dir, e))?;
    let mut names: Vec<String> = entries
        .filter_map(|e| e.ok())
        .filter(|e| io::is_render_set(&e.path()))
        .filter_map(|e| e.file_name().into_string().ok())
        .collect();
    // As people number them: `spp4` before `spp16` (by a trailing number, then by name).
    names.sort_by_cached_key(|name| {
        let stem = name.trim_end_matches(|c: char| c.is_ascii_digit());
        let number = name[stem.len()..].parse::<u64>().ok();
        (stem.to_string(), number, name.clone())
    });
    Ok(names)
}

/// Frames of `--frames` whose colour input does not exist, listed in one error before any work
/// (`--skip-existing` frames whose output is there need no input; with `--keep-going` each missing
/// frame fails on its own and the others are done).
fn missing_frames(
    args: &DenoiseArgs,
    pattern: &Pattern,
    output: &Pattern,
    numbers: &[u64],
) -> Result<()> {
    if args.frames.is_none() {
        return Ok(());
    }
    let missing: Vec<String> = numbers
        .iter()
        .filter(|&&n| {
            let input = io::split_layer(Path::new(&pattern.frame(n))).0;
            let skipped = args.skip_existing && Path::new(&output.frame(n)).is_file();
            !skipped && std::fs::metadata(input).is_err()
        })
        .map(u64::to_string)
        .collect();
    if missing.is_empty() {
        return Ok(());
    }
    const SHOWN: usize = 20;
    let more = match missing.len() {
        n if n > SHOWN => format!(" and {} more", n - SHOWN),
        _ => String::new(),
    };
    let frames = if missing.len() == 1 {
        "frame"
    } else {
        "frames"
    };
    Err(Error::config(
        "--frames",
        format!(
            "not found: {frames} {}{more} of {}",
            missing[..missing.len().min(SHOWN)].join(", "),
            pattern.text()
        ),
    ))
}

/// The key a note is said once a run by (its text with every number as `#`), or `None` for a line
/// each frame says: its result (`IN (WxH) → OUT in …`), a skip, a timing.
fn once_a_run(line: &str) -> Option<String> {
    let per_frame =
        line.contains(") → ") || line.starts_with("skipped, ") || line.starts_with("  ");
    if per_frame {
        return None;
    }
    let mut key = String::with_capacity(line.len());
    for c in line.chars() {
        if !c.is_ascii_digit() {
            key.push(c);
        } else if !key.ends_with('#') {
            key.push('#');
        }
    }
    Some(key)
}
