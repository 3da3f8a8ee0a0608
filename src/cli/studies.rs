//! The commands that study a pipeline or score an image: `ablate`, `sweep`, `eval`, and
//! `pipelines`, which lists the named ones.

use std::path::PathBuf;

use super::args::{AblateArgs, EvalArgs, SweepArgs};
use super::stdout::say;
use crate::buffers::Buffers;
use crate::condition::sanitize_reference;
use crate::error::{Error, Result};
use crate::io::{self, PendingOutput};
use crate::metrics;
use crate::pipeline::{PipelineSpec, BUILTIN};
use crate::run::RunContext;
use crate::study::table::{self, Format};
use crate::study::{ablate, sweep};

/// The reference for scoring a render set: `--reference`, else the one FORMATS.md places.
fn reference_for(set: &io::LoadedSet, given: Option<&PathBuf>) -> Result<crate::image::Image> {
    let path = given
        .cloned()
        .or_else(|| set.reference.clone())
        .ok_or_else(|| {
            Error::file(
                set.dir.join("reference.exr"),
                "no reference found (here or one level up); pass --reference",
            )
        })?;
    let mut reference = set.read_reference(&path)?;
    if reference.dims() != set.set.dims() {
        return Err(Error::file(&path, "does not have the render set's size"));
    }
    sanitize_reference(&mut reference);
    Ok(reference)
}

pub(super) fn ablate(args: &AblateArgs, quiet: bool) -> Result<()> {
    let ctx = args.run.context(quiet)?;
    let spec = args.run.spec()?;
    let pipeline = spec.build()?;
    args.run.check_memory([&pipeline], Some(&args.dir))?;
    let variants = ablate::variants(&spec)?;
    let set = io::load_input(&args.dir, &[])?;
    let reference = reference_for(&set, args.reference.as_ref())?;
    // Reserved before the work, so an unwritable path fails fast.
    let pending = args
        .out
        .as_deref()
        .map(|p| Ok((Format::of(p)?, PendingOutput::create(p)?)))
        .transpose()?;
    let progress = crate::progress::Progress::new(ctx.progress, "ablate", variants.len() as u64);
    let buffers = Buffers::from(set.set);
    let rows = ctx.install(|| {
        ablate::run(&variants, &buffers, &reference, ctx.seed, &|_| {
            progress.inc(1)
        })
    })?;
    progress.finish();
    say!("{}", ablate::table(&rows))?;
    if let Some((format, pending)) = pending {
        let text = match format {
            Format::Json => table::json(&rows)?,
            Format::Csv => ablate::csv(&rows)?,
        };
        pending.write_bytes(text.as_bytes())?;
    }
    Ok(())
}

/// Most runs of one sweep setting: a median of more says nothing new, so a larger count is a typo.
const MAX_REPEAT: usize = 1000;

/// The files `sweep` writes into its `--out` folder.
const SWEEP_FILES: [&str; 3] = ["sweep.csv", "sweep.png", "sweep.svg"];

pub(super) fn sweep(args: &SweepArgs, quiet: bool) -> Result<()> {
    // Everything that can be wrong with the arguments is found before the render set is even read.
    let ctx = args.run.context(quiet)?;
    if !(1..=MAX_REPEAT).contains(&args.repeat) {
        return Err(Error::range(
            "--repeat",
            args.repeat,
            &format!("1 to {MAX_REPEAT}"),
        ));
    }
    let base = args.run.spec()?;
    base.build()?;
    // Keys written from the top of the tree, so `--vary gsid.walks` and `--set pyramid.gsid.walks`
    // are seen as one key; a key that names no stage stays as typed for the error to quote.
    let full = |args: &[String]| -> Vec<String> {
        args.iter()
            .map(|a| match a.split_once('=') {
                Some((k, v)) => base
                    .full_key(k.trim())
                    .map_or_else(|_| a.clone(), |k| format!("{k}={v}")),
                None => a.clone(),
            })
            .collect()
    };
    let axes = sweep::parse_axes(&full(&args.varies), &full(&args.run.sets))?;
    let settings = sweep::settings(&base, &axes)?;
    let pipelines = settings.iter().map(|s| &s.pipeline);
    args.run.check_memory(pipelines, Some(&args.dir))?;
    let set = io::load_input(&args.dir, &[])?;
    let reference = reference_for(&set, args.reference.as_ref())?;
    // Made if missing; removed again (if empty) on failure or a signal, kept once filled.
    let folder = io::NewFolder::create(&args.out)?;
    let notes = set.notes;
    let buffers = Buffers::from(set.set);
    sweep_into(args, &ctx, &notes, &buffers, &reference, &axes, &settings)?;
    folder.keep();
    Ok(())
}

fn sweep_into(
    args: &SweepArgs,
    ctx: &RunContext,
    notes: &[String],
    buffers: &Buffers,
    reference: &crate::image::Image,
    axes: &[sweep::Axis],
    settings: &[sweep::Setting],
) -> Result<()> {
    let [csv, png, svg] = SWEEP_FILES.map(|f| args.out.join(f));
    // Reserved before the work, so an unwritable folder fails fast and nothing half-written remains.
    let (csv_out, png_out, svg_out) = (
        PendingOutput::create(&csv)?,
        PendingOutput::create(&png)?,
        PendingOutput::create(&svg)?,
    );
    if ctx.progress {
        for line in notes {
            crate::progress::say_err!("gsid: {line}");
        }
    }
    let runs = (settings.len() * args.repeat) as u64;
    let progress = crate::progress::Progress::new(ctx.progress, "sweep", runs);
    let rows = ctx.install(|| {
        sweep::run(settings, buffers, reference, ctx.seed, args.repeat, &|| {
            progress.inc(1)
        })
    })?;
    progress.finish();
    let pipeline = settings.first().map_or("", |s| s.spec.name.as_str());
    let title = format!(
        "SSIM vs seconds — {} — pipeline {pipeline}",
        args.dir.display()
    );
    let png_bytes = sweep::plot_png(&rows, &title)?;
    let svg_text = sweep::plot_svg(&rows, &title)?;
    csv_out.write_bytes(sweep::csv(axes, &rows)?.as_bytes())?;
    png_out.write_bytes(&png_bytes)?;
    svg_out.write_bytes(svg_text.as_bytes())?;
    if ctx.progress {
        for line in sweep::notes(&rows) {
            crate::progress::say_err!("gsid: {line}");
        }
    }
    say!("{}", sweep::table(&rows))?;
    say!(
        "wrote {}, {}, {} (seconds: median of {} in-process runs)\n",
        csv.display(),
        png.display(),
        svg.display(),
        args.repeat
    )
}

pub(super) fn eval(args: &EvalArgs, quiet: bool) -> Result<()> {
    let image = io::read_color(&args.image)?;
    let mut reference = io::read_color(&args.reference)?;
    // A score of non-finite pixels means nothing: SSIM passes over them, relMSE turns NaN.
    let bad = image.data().iter().filter(|v| !v.is_finite()).count();
    if bad > 0 {
        return Err(Error::file(
            &args.image,
            format!("has {bad} NaN or infinite values; it cannot be scored"),
        ));
    }
    let fixed = sanitize_reference(&mut reference);
    let fixed = fixed.color_nonfinite + fixed.color_negative;
    if fixed > 0 && fixed == reference.data().len() {
        return Err(Error::file(
            &args.reference,
            "has no finite, non-negative value (NaN, infinite or negative everywhere); it cannot be a reference",
        ));
    }
    if fixed > 0 && !quiet {
        crate::progress::say(&format!(
            "gsid: {}: {fixed} NaN, infinite or negative values scored as 0",
            args.reference.display()
        ));
    }
    if image.dims() != reference.dims() {
        return Err(Error::file(
            &args.image,
            format!(
                "is {}x{} but reference {} is {}x{}",
                image.width(),
                image.height(),
                args.reference.display(),
                reference.width(),
                reference.height()
            ),
        ));
    }
    let s = metrics::score(&image, &reference)?;
    if args.json {
        let json = serde_json::json!({
            "image": args.image.display().to_string(),
            "reference": args.reference.display().to_string(),
            "ssim": s.ssim,
            "psnr": if s.psnr.is_finite() { serde_json::json!(s.psnr) } else { serde_json::json!("inf") },
            "relmse": s.relmse,
        });
        say!("{json}\n")
    } else {
        say!(
            "SSIM {:.4}  PSNR {:.2} dB  relMSE {:.5}\n",
            s.ssim,
            s.psnr,
            s.relmse
        )
    }
}

pub(super) fn list_pipelines() -> Result<()> {
    for (name, _) in BUILTIN {
        match PipelineSpec::resolve(name) {
            Ok(spec) => say!("{name:<14} {}\n", spec.description)?,
            Err(e) => say!("{name:<14} (invalid: {e})\n")?,
        }
    }
    Ok(())
}
