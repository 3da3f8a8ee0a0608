//! One render set through the pipeline: its buffers read, every output checked and reserved
//! before the work (never an input, never half-written), the result and `--save-buffer`s written.

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::args::DenoiseArgs;
use super::meter::{Meter, Verbosity};
use super::report::{self, FrameReport, Outcome};
use crate::buffers::Buffers;
use crate::error::{Error, Result};
use crate::io::{self, PendingOutput};
use crate::options::DenoiseOptions;
use crate::pipeline::{Pipeline, OUTPUT_BUFFER};
use crate::run::RunContext;

/// The absolute form of a path that may not exist yet: its folder resolved, its name kept.
pub(super) fn resolved(p: &Path) -> PathBuf {
    if let Ok(full) = p.canonicalize() {
        return full;
    }
    let dir = match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    match (dir.canonicalize(), p.file_name()) {
        (Ok(d), Some(name)) => d.join(name),
        _ => p.to_path_buf(),
    }
}

fn same_file(a: &Path, b: &Path) -> bool {
    resolved(a) == resolved(b)
}

/// Before any work: every output's extension names a format, no output may be one of the run's
/// input files (buffers or the reference), and no two outputs may be one path (one would silently lose).
fn check_outputs(inputs: &[(String, PathBuf)], outputs: &[&Path]) -> Result<()> {
    for (i, out) in outputs.iter().enumerate() {
        io::ImageFormat::of_output(out)?;
        if let Some((name, _)) = inputs.iter().find(|(_, f)| same_file(f, out)) {
            return Err(Error::output(
                out,
                format!("is the input `{name}`; refusing to overwrite an input"),
            ));
        }
        if outputs[..i].iter().any(|o| same_file(o, out)) {
            return Err(Error::output(
                out,
                "is given as two outputs; each output needs its own path",
            ));
        }
    }
    Ok(())
}

/// Reads a frame's render set in place of its own files (a temporal run's merged frame).
pub(super) type Loader<'a> = &'a mut dyn FnMut(&DenoiseArgs) -> Result<io::LoadedSet>;

/// Denoises the render set `args` names, or skips it when `--skip-existing` finds its output (the
/// `-o` file, written last) already there. `say` gets each line for the user as soon as it is known.
pub(super) fn denoise_or_skip(
    args: &DenoiseArgs,
    pipeline: &Pipeline,
    ctx: &RunContext,
    meter: &Meter,
    say: &dyn Fn(&str),
    load: Option<Loader>,
) -> Result<Outcome> {
    let output = &args.output;
    io::remove_stale_beside(output);
    if args.skip_existing && output.as_os_str() != io::STDOUT && output.is_file() {
        say(&format!("skipped, {} exists", output.display()));
        return Ok(Outcome::Skipped {
            output: output.display().to_string(),
        });
    }
    let report = denoise_frame(args, pipeline, ctx, meter, say, load)?;
    let timings = args.timings || meter.verbosity() >= Verbosity::Verbose;
    report::tell(&report, timings, say);
    Ok(Outcome::Done(Box::new(report)))
}

/// How a frame ended, as its last progress line says.
pub(super) fn end_of(outcome: &Result<Outcome>) -> &'static str {
    match outcome {
        Ok(Outcome::Done(_)) => "done",
        Ok(Outcome::Skipped { .. }) => "skipped",
        Ok(Outcome::Failed { .. }) | Err(_) => "failed",
    }
}

/// Denoises the one render set `args` names, read by `load` when given (a temporal run's merged
/// frame). `say` gets the input's notes before the work starts.
fn denoise_frame(
    args: &DenoiseArgs,
    pipeline: &Pipeline,
    ctx: &RunContext,
    meter: &Meter,
    say: &dyn Fn(&str),
    load: Option<Loader>,
) -> Result<FrameReport> {
    let start = Instant::now();
    let saves = args.saves()?;
    // Sized from the colour's header before anything is decoded: a run that cannot fit in memory
    // is refused before it takes any.
    args.run.check_memory([pipeline], args.colour_input())?;
    let set = match load {
        Some(load) => load(args)?,
        None => args.inputs.load(args.dir.as_deref())?,
    };
    let outputs: Vec<&Path> = std::iter::once(args.output.as_path())
        .chain(saves.iter().map(|(_, p)| p.as_path()))
        .collect();
    check_outputs(&set.inputs(), &outputs)?;
    let inputs = report::InputJson::list(&set);
    let mut frame = set.frame;
    if args.keep_layers {
        if !frame.has_layers() {
            let (_, color) = &set.files[0];
            return Err(Error::config(
                "--keep-layers",
                format!(
                    "{} holds no channels besides the colour's; it applies to a multilayer EXR",
                    color.display()
                ),
            ));
        }
        frame.read_layers()?;
    }
    let previews = outputs
        .iter()
        .any(|p| io::ImageFormat::of_output(p).is_ok_and(|f| f != io::ImageFormat::Exr));
    if previews && (args.half || args.keep_layers) {
        return Err(Error::config(
            if args.half { "--half" } else { "--keep-layers" },
            "applies to EXR outputs only",
        ));
    }
    // Blender writes ZIP; a render that came compressed one way goes back the same way.
    let compression = args.compression.unwrap_or_else(|| {
        frame
            .compression()
            .map_or(io::Compression::Zip, io::Compression::of_exr)
    });
    let encoding = io::Encoding {
        compression,
        half: args.half,
        exposure: preview_exposure(args.exposure, &outputs)?,
    };
    let (_, color_file) = &set.files[0];
    io::check_output(
        &args.output,
        set.set.dims(),
        3,
        &frame,
        &encoding,
        color_file,
    )?;
    // Reserve every output before the work, so an unwritable path fails fast and nothing half-written remains.
    let pending = PendingOutput::create(&args.output)?;
    let pending_saves = saves
        .iter()
        .map(|(n, p)| Ok((n.clone(), PendingOutput::create(p)?)))
        .collect::<Result<Vec<_>>>()?;
    for line in &set.notes {
        say(line);
    }
    if compression.is_lossy() && (frame.has_alpha() || args.keep_layers) {
        let from = if args.compression.is_some() {
            "--compression"
        } else {
            "the input's compression,"
        };
        say(&format!(
            "{from} {} is lossy: the copied alpha and layers are not bit-exact",
            compression.name()
        ));
    }
    let read_seconds = start.elapsed().as_secs_f64();
    let (width, height) = set.set.dims();
    let input = args.dir.as_ref().unwrap_or(&set.dir).display().to_string();
    let mut buffers = Buffers::from(set.set);
    // The library's call, as a renderer makes it (`Pipeline::denoise_into` runs the same): Ctrl-C
    // cancels it through the invocation's token.
    let options = DenoiseOptions {
        max_memory: Some(args.run.memory_limit()),
        progress: Some(meter.pipeline_progress()),
        cancel: Some(super::signals::cancel_token()),
        ..ctx.denoise_options(false)
    };
    let (out, report) = pipeline.run(&mut buffers, &options)?;
    meter.writing();
    let write_start = Instant::now();
    let mut saved = Vec::new();
    for (name, pending) in pending_saves {
        let buf = if name == OUTPUT_BUFFER {
            Some(&out)
        } else {
            buffers.get(&name)
        };
        let buf = buf.ok_or_else(|| {
            Error::buffer(
                &name,
                format!(
                    "was asked for by --save-buffer but pipeline {} has no such buffer",
                    pipeline.name
                ),
            )
        })?;
        let file = pending.path().display().to_string();
        let buf = pipeline.at_input_exposure(&name, buf, &report);
        io::write_image(pending, &buf, &frame.windows_only(), &encoding)?;
        saved.push(report::SavedJson { buffer: name, file });
    }
    io::write_image(pending, &out, &frame, &encoding)?;
    let write_seconds = write_start.elapsed().as_secs_f64();
    Ok(FrameReport {
        input,
        inputs,
        width,
        height,
        input_notes: set.notes,
        walk_steps: report.walk_steps(),
        notes: report.notes,
        stages: report.stages,
        sanitized: report.sanitized,
        seconds: report::Seconds {
            read: read_seconds,
            pipeline: report.seconds,
            write: write_seconds,
            total: start.elapsed().as_secs_f64(),
        },
        output: args.output.display().to_string(),
        saved,
    })
}

/// `--exposure` in stops (0 without it). It scales previews only, so given with none it would
/// silently do nothing: that is an error.
fn preview_exposure(exposure: Option<f32>, outputs: &[&Path]) -> Result<f32> {
    let Some(ev) = exposure else {
        return Ok(0.0);
    };
    if !(-32.0..=32.0).contains(&ev) {
        return Err(Error::range("--exposure", ev, "-32 to 32 stops"));
    }
    for out in outputs {
        if io::ImageFormat::of_output(out)?.is_preview() {
            return Ok(ev);
        }
    }
    Err(Error::config(
        "--exposure",
        "applies to .png and .jpg outputs only, and no output is one (float outputs are written as computed)",
    ))
}
