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
use super::report::{Entry, FrameId, Outcome, PipelineJson, SequenceJson};
use super::stdout::print_json;
use crate::error::{Error, Result};
use crate::io;
use crate::pipeline::Pipeline;
use crate::run::RunContext;
use crate::temporal::Shot;

/// Most frames one `--frames` list may name: far beyond a shot, so a larger count is a typo.
const MAX_FRAMES: u64 = 1_000_000;

/// A path with one frame token: `#` runs (`####` = 4 digits), printf's `%04d` or Houdini's `$F4`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Pattern {
    /// The path as written, for messages.
    text: String,
    prefix: String,
    suffix: String,
    /// Fewest digits a frame number is written with (zero-padded).
    width: usize,
}

impl Pattern {
    /// The frame token of `text`, if it has one; two tokens are an error.
    pub fn find(text: &str) -> Result<Option<Pattern>> {
        let bytes = text.as_bytes();
        let mut found: Option<(usize, usize, usize)> = None;
        let mut i = 0;
        while i < bytes.len() {
            let Some((len, width)) = token_at(&bytes[i..]) else {
                i += 1;
                continue;
            };
            if found.is_some() {
                return Err(Error::config(
                    text,
                    "has two frame tokens; a path takes one (####, %04d or $F4)",
                ));
            }
            found = Some((i, i + len, width));
            i += len;
        }
        Ok(found.map(|(start, end, width)| Pattern {
            text: text.to_string(),
            prefix: text[..start].to_string(),
            suffix: text[end..].to_string(),
            width,
        }))
    }

    /// The pattern with frame `n` written in.
    pub fn frame(&self, n: u64) -> String {
        format!(
            "{}{n:0width$}{}",
            self.prefix,
            self.suffix,
            width = self.width
        )
    }

    /// The frames whose files exist, in order. The token must be in the file name (not a folder),
    /// and a `:Layer` after the file name is not part of it.
    pub fn existing_frames(&self) -> Result<Vec<u64>> {
        let shown = &self.text;
        let (dir, head) = match self.prefix.rfind('/') {
            Some(i) => (&self.prefix[..=i], &self.prefix[i + 1..]),
            None => ("", self.prefix.as_str()),
        };
        if self.suffix.contains('/') {
            return Err(Error::config(
                shown,
                "has its frame token in a folder name; give the frames with --frames",
            ));
        }
        let tail = self.suffix.split(':').next().unwrap_or("");
        let folder = if dir.is_empty() {
            Path::new(".")
        } else {
            Path::new(dir)
        };
        let entries = std::fs::read_dir(folder)
            .map_err(|e| Error::file(folder, format!("cannot list the frames of {shown}: {e}")))?;
        let mut frames: Vec<u64> = entries
            .filter_map(|e| e.ok()?.file_name().into_string().ok())
            .filter_map(|name| {
                let digits = name.strip_prefix(head)?.strip_suffix(tail)?;
                let n: u64 = digits
                    .bytes()
                    .all(|b| b.is_ascii_digit())
                    .then(|| digits.parse().ok())??;
                // Only the file this pattern writes for `n` (`0012` for `####`, not `012`).
                (format!("{n:0width$}", width = self.width) == digits).then_some(n)
            })
            .collect();
        frames.sort_unstable();
        if frames.is_empty() {
            return Err(Error::file(shown, "no frames found (no file matches)"));
        }
        Ok(frames)
    }
}

/// The frame token starting `s`, as (its length, the frame number's width).
fn token_at(s: &[u8]) -> Option<(usize, usize)> {
    let digits = |s: &[u8]| s.iter().take_while(|b| b.is_ascii_digit()).count();
    let number = |s: &[u8]| std::str::from_utf8(s).ok()?.parse::<usize>().ok();
    match s {
        [b'#', ..] => {
            let n = s.iter().take_while(|&&b| b == b'#').count();
            Some((n, n))
        }
        [b'%', b'd', ..] => Some((2, 1)),
        [b'%', b'0', rest @ ..] => {
            let n = digits(rest);
            (n > 0 && rest.get(n) == Some(&b'd')).then(|| (n + 3, number(&rest[..n]).unwrap_or(1)))
        }
        [b'$', b'F', rest @ ..] => {
            let n = digits(rest);
            if n > 0 {
                Some((n + 2, number(&rest[..n]).unwrap_or(1)))
            } else if rest
                .first()
                .is_some_and(|b| b.is_ascii_alphabetic() || *b == b'_')
            {
                None // another variable (`$FPS`, `$F_x`), not the frame
            } else {
                Some((2, 1))
            }
        }
        _ => None,
    }
}

/// Parses a `--frames` list: `A-B`, `A-BxSTEP`, single frames, comma-separated; sorted, each once.
pub fn parse_frames(text: &str) -> Result<Vec<u64>> {
    let bad = |part: &str, why: &str| Error::config("--frames", format!("`{part}` {why}"));
    let number = |part: &str, s: &str| {
        s.trim()
            .parse::<u64>()
            .map_err(|_| bad(part, "is not A, A-B or A-BxSTEP (whole frame numbers ≥ 0)"))
    };
    let mut frames = Vec::new();
    for part in text.split(',') {
        let (range, step) = match part.split_once('x') {
            Some((r, s)) => (r, number(part, s)?),
            None => (part, 1),
        };
        let (a, b) = match range.split_once('-') {
            Some((a, b)) => (number(part, a)?, number(part, b)?),
            None if part.contains('x') => return Err(bad(part, "has a step but no range")),
            None => {
                let a = number(part, range)?;
                (a, a)
            }
        };
        if a > b {
            return Err(bad(part, "ends before it starts"));
        }
        if step == 0 {
            return Err(bad(part, "has step 0"));
        }
        if (b - a) / step + 1 + frames.len() as u64 > MAX_FRAMES {
            return Err(bad(part, &format!("makes more than {MAX_FRAMES} frames")));
        }
        frames.extend((a..=b).step_by(step as usize));
    }
    frames.sort_unstable();
    frames.dedup();
    Ok(frames)
}

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
        for frame in self.frames {
            let id = FrameId::of(frame.number, &frame.label);
            let label = frame.label;
            let say = |line: &str| {
                meter.say_at(Verbosity::Normal, &format!("gsid: frame {label}: {line}"))
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

#[cfg(test)]
mod tests {
    use super::*;

    fn pattern(text: &str) -> Pattern {
        Pattern::find(text).unwrap().expect("a frame token")
    }

    #[test]
    fn frame_tokens_of_every_style_write_the_same_zero_padded_numbers() {
        for text in ["shot/b.####.exr", "shot/b.%04d.exr", "shot/b.$F4.exr"] {
            let p = pattern(text);
            assert_eq!(p.frame(7), "shot/b.0007.exr", "{text}");
            assert_eq!(p.frame(12345), "shot/b.12345.exr", "{text}");
        }
        for text in ["b.#.exr", "b.%d.exr", "b.$F.exr"] {
            assert_eq!(pattern(text).frame(7), "b.7.exr", "{text}");
        }
        assert_eq!(pattern("a_##_x").frame(3), "a_03_x");
        for plain in [
            "shot/b.0001.exr",
            "b.exr",
            "$FPS.exr",
            "100%.exr",
            "%5d.exr",
        ] {
            assert_eq!(Pattern::find(plain).unwrap(), None, "{plain}");
        }
        assert!(Pattern::find("s.####/b.####.exr").is_err());
        assert!(Pattern::find("b.%04d.$F4.exr").is_err());
    }

    #[test]
    fn frames_lists_take_ranges_steps_and_commas() {
        assert_eq!(parse_frames("1001-1004").unwrap(), [1001, 1002, 1003, 1004]);
        assert_eq!(parse_frames("1-10x3").unwrap(), [1, 4, 7, 10]);
        assert_eq!(parse_frames("5,1,3-4").unwrap(), [1, 3, 4, 5]);
        assert_eq!(parse_frames("7").unwrap(), [7]);
        assert_eq!(
            parse_frames("1-3,2-4").unwrap(),
            [1, 2, 3, 4],
            "each frame once"
        );
        assert_eq!(parse_frames("0-0").unwrap(), [0]);
        assert_eq!(parse_frames(" 2 - 4 ").unwrap(), [2, 3, 4]);
        for bad in [
            "",
            "a",
            "5-1",
            "1-5x0",
            "1-",
            "-3",
            "1,,2",
            "1-5x",
            "3x2",
            "1.5",
            "0-1000000",
        ] {
            let err = parse_frames(bad)
                .err()
                .unwrap_or_else(|| panic!("`{bad}` was accepted"));
            assert_eq!(err.exit_code(), 2);
            assert!(err.to_string().starts_with("--frames: "), "{err}");
        }
    }

    #[test]
    fn existing_frames_are_the_files_the_pattern_writes_sorted() {
        let tmp = tempfile::tempdir().unwrap();
        for name in [
            "b.0010.exr",
            "b.0002.exr",
            "b.0001.exr",
            "b.001.exr",
            "b.12345.exr",
            "b.00x1.exr",
            "c.0003.exr",
            "b.0004.exr.tmp",
        ] {
            std::fs::write(tmp.path().join(name), b"").unwrap();
        }
        let dir = tmp.path().to_str().unwrap();
        let p = pattern(&format!("{dir}/b.####.exr"));
        assert_eq!(p.existing_frames().unwrap(), [1, 2, 10, 12345]);
        let layered = pattern(&format!("{dir}/b.####.exr:ViewLayer.Combined"));
        assert_eq!(layered.existing_frames().unwrap(), [1, 2, 10, 12345]);
        let none = pattern(&format!("{dir}/d.####.exr"));
        assert_eq!(none.existing_frames().err().unwrap().exit_code(), 2);
    }
}
