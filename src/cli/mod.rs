//! Command-line interface (clap derive). Thin: parse, call the library, print one line per error.

pub mod batch;

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::{Parser, Subcommand};

use crate::buffers::Buffers;
use crate::condition::sanitize_reference;
use crate::error::{Error, Result};
use crate::io::{self, PendingOutput};
use crate::metrics;
use crate::pipeline::{Pipeline, PipelineSpec, BUILTIN, DEFAULT_PIPELINE, OUTPUT_BUFFER};
use crate::run::RunContext;
use crate::study::table::{self, Format};
use crate::study::{ablate, sweep};
use batch::{Batch, FrameReport};

/// `print!` that returns an error instead of panicking (see [`say`]).
macro_rules! say {
    ($($arg:tt)*) => {
        say(format_args!($($arg)*))
    };
}

#[derive(Parser, Debug)]
#[command(
    name = "gsid",
    version,
    about = "Feature-guided stochastic denoising for path-traced renders"
)]
pub struct Cli {
    /// Silence the progress bar and notes on stderr.
    #[arg(long, short, global = true)]
    pub quiet: bool,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
// Parsed once per process: the size of the largest variant (denoise's named inputs) costs nothing.
#[allow(clippy::large_enum_variant)]
pub enum Command {
    /// Denoise a render set folder (color.exr plus optional feature buffers), a multilayer EXR, a
    /// frame sequence (`beauty.####.exr`) or a folder of render-set folders.
    Denoise(DenoiseArgs),
    /// Score an image against a reference: SSIM, PSNR, relMSE (ALGORITHM.md §5).
    Eval(EvalArgs),
    /// List the named pipelines.
    Pipelines,
    /// Render a scene file into a render set (fixture renderer).
    Render(crate::render::RenderArgs),
    /// Run a pipeline and variants of it (each stage removed, each feature weight zeroed, plain SID) and score them.
    Ablate(AblateArgs),
    /// Run a pipeline over a grid of parameter values; time and score each setting, plot SSIM against seconds.
    Sweep(SweepArgs),
}

#[derive(clap::Args, Debug)]
pub struct SweepArgs {
    /// Render set folder, or one multilayer EXR file.
    pub dir: PathBuf,
    #[command(flatten)]
    pub run: RunOptions,
    /// A key and its values, e.g. `--vary gsid.walks=5,10,20` (any key `--set` takes; repeatable:
    /// the sweep runs every combination, the first --vary varying slowest).
    #[arg(long = "vary", value_name = "KEY=V1,V2,...")]
    pub varies: Vec<String>,
    /// Runs of each setting; the median time is kept.
    #[arg(long, default_value_t = 3)]
    pub repeat: usize,
    /// Folder for sweep.csv, sweep.png and sweep.svg (created if missing).
    #[arg(long, default_value = "sweep-out")]
    pub out: PathBuf,
    /// Reference image (default: reference.exr in the folder or one level up).
    #[arg(long, short)]
    pub reference: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
pub struct AblateArgs {
    /// Render set folder, or one multilayer EXR file.
    pub dir: PathBuf,
    #[command(flatten)]
    pub run: RunOptions,
    /// Reference image (default: reference.exr in the folder or one level up).
    #[arg(long, short)]
    pub reference: Option<PathBuf>,
    /// Also write the table as CSV (`.csv`) or JSON (`.json`).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Options shared by every command that runs a pipeline.
#[derive(clap::Args, Debug, Clone)]
pub struct RunOptions {
    /// Pipeline name (see `gsid pipelines`) or a pipeline TOML file.
    #[arg(long, short, default_value = DEFAULT_PIPELINE)]
    pub pipeline: String,
    /// Seed for every random choice: same inputs, pipeline and seed give the same bits on any thread count.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Worker threads, 1 to 1024 (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Override a pipeline parameter, e.g. `--set gsid.walks=40` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub sets: Vec<String>,
}

impl RunOptions {
    /// The pipeline with the overrides applied, as a spec (not yet built).
    pub fn spec(&self) -> Result<PipelineSpec> {
        let mut spec = PipelineSpec::resolve(&self.pipeline)?;
        for s in &self.sets {
            spec.apply_set(s)?;
        }
        Ok(spec)
    }

    /// The thread pool, progress and seed the run asks for (`--threads` checked here).
    pub fn context(&self, quiet: bool) -> Result<RunContext> {
        RunContext::new(self.threads, !quiet, self.seed)
    }
}

#[derive(clap::Args, Debug, Clone)]
pub struct DenoiseArgs {
    /// Render set folder, one multilayer EXR file, a frame pattern (`shot/beauty.####.exr`, also
    /// `%04d`, `$F4`), or a folder of render-set folders (omit with --color or --ldr).
    #[arg(required_unless_present_any = ["color", "ldr"])]
    pub dir: Option<PathBuf>,
    #[command(flatten)]
    pub inputs: NamedInputs,
    #[command(flatten)]
    pub run: RunOptions,
    /// Output path (written atomically; never an input file); a frame pattern for a sequence, a
    /// folder for a folder of render sets. Its extension picks the format: .exr or .pfm (float),
    /// .png or .jpg (8-bit preview); `-` writes EXR to stdout.
    #[arg(long, short)]
    pub output: PathBuf,
    /// Frames of a sequence: `1001-1100`, `1001-1100x2`, `1,5,9-12` (default: the files that exist).
    #[arg(long)]
    pub frames: Option<String>,
    /// Leave a frame whose output exists as it is (a requeued render-farm task redoes nothing).
    #[arg(long)]
    pub skip_existing: bool,
    /// Go on after a frame fails; exit non-zero at the end, naming the failed frames.
    #[arg(long)]
    pub keep_going: bool,
    /// Print one JSON object on stdout: inputs, channel mapping, pipeline, stage times, output.
    #[arg(long)]
    pub json: bool,
    /// Also save an intermediate buffer, e.g. `--save-buffer outlier_mask=mask.exr` (repeatable;
    /// formats as for -o).
    #[arg(long = "save-buffer", value_name = "NAME=FILE")]
    pub save_buffers: Vec<String>,
    /// Exposure of .png/.jpg previews in stops (×2^EV before clamping and the sRGB curve). Float
    /// outputs are written as computed, so it is an error when no output is a preview.
    #[arg(long, value_name = "EV", allow_negative_numbers = true)]
    pub exposure: Option<f32>,
    /// Print each stage's time (and each pyramid level's) after the run.
    #[arg(long)]
    pub timings: bool,
    /// Write the denoised colour as half floats; copied channels (alpha, layers) keep their type.
    #[arg(long)]
    pub half: bool,
    /// EXR compression: none, rle, zips, zip, piz, or the lossy pxr24, b44, b44a, dwaa, dwab.
    #[arg(long, value_name = "METHOD", default_value = "rle", value_parser = compression)]
    pub compression: io::Compression,
    /// Also write every other channel of the colour's EXR unchanged (a multilayer input's passes).
    #[arg(long)]
    pub keep_layers: bool,
}

fn compression(name: &str) -> std::result::Result<io::Compression, String> {
    io::Compression::from_name(name).ok_or_else(|| {
        let names: Vec<&str> = io::Compression::NAMES.iter().map(|(n, _)| *n).collect();
        format!("expected one of {}", names.join(", "))
    })
}

/// Buffers named one by one instead of a folder; each a file or `file.exr:Layer`.
///
/// `requires = "color"` is also met by `--ldr` or a colour file given first, as both conflict with
/// `--color`; clap does not extend that to a group of the two, so there is none.
#[derive(clap::Args, Debug, Clone)]
pub struct NamedInputs {
    /// Colour (noisy beauty) image.
    #[arg(long, alias = "hdr", conflicts_with = "dir")]
    pub color: Option<PathBuf>,
    /// Colour as an 8-bit sRGB PNG or JPEG (linearised; not HDR, so highlights are clipped).
    #[arg(long, conflicts_with_all = ["dir", "color"])]
    pub ldr: Option<PathBuf>,
    #[arg(long, alias = "alb", requires = "color")]
    pub albedo: Option<PathBuf>,
    #[arg(long, alias = "nrm", requires = "color")]
    pub normal: Option<PathBuf>,
    #[arg(long, requires = "color")]
    pub depth: Option<PathBuf>,
    #[arg(long, requires = "color")]
    pub material: Option<PathBuf>,
    #[arg(long, requires = "color")]
    pub shadow: Option<PathBuf>,
    /// Variance of the pixel mean (RGB, or one channel used for all three).
    #[arg(long, requires = "color")]
    pub variance: Option<PathBuf>,
    /// Colour from the first half of the samples (with --color-b, from the other half).
    #[arg(long, requires_all = ["color", "color_b"])]
    pub color_a: Option<PathBuf>,
    #[arg(long, requires_all = ["color", "color_a"])]
    pub color_b: Option<PathBuf>,
    /// Which layer of a multilayer input is a buffer, e.g. `--map albedo=ViewLayer.DiffCol` (repeatable).
    #[arg(long = "map", value_name = "BUFFER=LAYER")]
    pub maps: Vec<String>,
}

impl NamedInputs {
    /// The buffers that can be named one by one, each with its flag's path (`ldr` is the colour too).
    pub fn slots(&self) -> [(&'static str, &Option<PathBuf>); 10] {
        [
            ("color", &self.color),
            ("ldr", &self.ldr),
            ("albedo", &self.albedo),
            ("normal", &self.normal),
            ("depth", &self.depth),
            ("material", &self.material),
            ("shadow", &self.shadow),
            ("variance", &self.variance),
            ("color_a", &self.color_a),
            ("color_b", &self.color_b),
        ]
    }

    pub fn slots_mut(&mut self) -> [(&'static str, &mut Option<PathBuf>); 10] {
        [
            ("color", &mut self.color),
            ("ldr", &mut self.ldr),
            ("albedo", &mut self.albedo),
            ("normal", &mut self.normal),
            ("depth", &mut self.depth),
            ("material", &mut self.material),
            ("shadow", &mut self.shadow),
            ("variance", &mut self.variance),
            ("color_a", &mut self.color_a),
            ("color_b", &mut self.color_b),
        ]
    }

    /// Loads the folder or multilayer file `dir`, or the buffers named one by one.
    pub fn load(&self, dir: Option<&Path>) -> Result<io::LoadedSet> {
        let mut maps = Vec::new();
        for m in &self.maps {
            let (buffer, layer) = m
                .split_once('=')
                .filter(|(b, _)| io::passes::PASSES.iter().any(|(n, _)| n == b))
                .ok_or_else(|| {
                    Error::config(
                        "--map",
                        format!("`{m}` is not BUFFER=LAYER with a known buffer"),
                    )
                })?;
            maps.push((buffer.to_string(), layer.to_string()));
        }
        // A colour file given first, beside buffers named one by one, is read as `--color FILE`.
        let features_named = self.slots()[2..].iter().any(|(_, p)| p.is_some());
        let color = match dir {
            Some(dir) if !features_named => return io::load_input(dir, &maps),
            Some(dir) if dir.is_dir() => {
                return Err(Error::config(
                    "--albedo",
                    format!("buffers named one by one (--albedo, --normal, …) need the colour as a file, not the folder {}", dir.display()),
                ))
            }
            Some(dir) => Some(dir.to_path_buf()),
            None => self.color.clone().or_else(|| self.ldr.clone()),
        };
        if !maps.is_empty() {
            return Err(Error::config("--map", "applies to a multilayer file input"));
        }
        if let Some(ldr) = self.ldr.as_deref().filter(|p| !io::is_ldr(p)) {
            return Err(Error::file(
                ldr,
                "--ldr takes an 8-bit sRGB PNG or JPEG; give HDR colour with --color",
            ));
        }
        let named: Vec<(&'static str, PathBuf)> = std::iter::once(("color", &color))
            .chain(self.slots().into_iter().skip(2))
            .filter_map(|(b, p)| p.clone().map(|p| (b, p)))
            .collect();
        io::load_named(&named)
    }
}

#[derive(clap::Args, Debug)]
pub struct EvalArgs {
    /// Image to score.
    pub image: PathBuf,
    /// Converged reference of the same frame.
    #[arg(long, short)]
    pub reference: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Runs the CLI and returns the process exit code.
pub fn main() -> i32 {
    keep_freed_memory();
    remove_outputs_on_signal();
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            let code = if e.use_stderr() { 2 } else { 0 };
            let _ = e.print();
            return code;
        }
    };
    match run(cli) {
        Ok(()) | Err(Error::StdoutClosed) => 0,
        Err(e) => {
            eprintln!("gsid: error: {e}");
            e.exit_code()
        }
    }
}

/// On SIGINT or SIGTERM: removes the temporary files and folders of outputs not yet committed,
/// then exits 128 + the signal's number (130, 143), as a shell reports a process it stopped.
fn remove_outputs_on_signal() {
    use signal_hook::consts::{SIGINT, SIGTERM};
    // Without the handler (it cannot be installed) a signal still ends the run, leaving its temp files.
    let Ok(mut signals) = signal_hook::iterator::Signals::new([SIGINT, SIGTERM]) else {
        return;
    };
    std::thread::spawn(move || {
        if let Some(signal) = signals.forever().next() {
            io::remove_pending_outputs();
            std::process::exit(128 + signal);
        }
    });
}

/// Keeps the memory a run frees for its later buffers, instead of handing it back to the kernel.
///
/// A pipeline allocates and drops many image-sized buffers (stage outputs, planes, tables). By
/// default glibc serves those from several arenas (one per thread that allocates), maps the largest
/// fresh and unmaps them on free, and trims the heap's top: every such buffer is faulted in again,
/// page by page, when it is next written, and every unmap stops the other cores to flush their TLBs.
/// With two threads those faults and flushes contend, so stages that allocate much scale worst. One
/// arena, no mapped chunks and no trimming make a freed buffer the next one's memory. Measured on
/// 1 and 4 MP (README "Speed"): fewer faults, less system time, and a peak that moves by a few
/// percent either way. Only the binary sets this; a program using the library keeps its own policy.
fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes allocator settings; called before any thread starts.
    unsafe {
        libc::mallopt(libc::M_ARENA_MAX, 1);
        libc::mallopt(libc::M_MMAP_MAX, 0);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Denoise(args) => denoise(&args, cli.quiet),
        Command::Render(args) => crate::render::run(&args, cli.quiet),
        Command::Eval(args) => eval(&args),
        Command::Ablate(args) => ablate(&args, cli.quiet),
        Command::Sweep(args) => sweep(&args, cli.quiet),
        Command::Pipelines => list_pipelines(),
    }
}

/// The absolute form of a path that may not exist yet: its folder resolved, its name kept.
fn resolved(p: &Path) -> PathBuf {
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

fn denoise(args: &DenoiseArgs, quiet: bool) -> Result<()> {
    let ctx = args.run.context(quiet)?;
    // Reading and writing run on the same pool as the pipeline, so `--threads` bounds the whole job.
    ctx.install(|| denoise_in_pool(args, &ctx))
}

fn denoise_in_pool(args: &DenoiseArgs, ctx: &RunContext) -> Result<()> {
    let pipeline = args.run.spec()?.build()?;
    if args.json && args.output.as_os_str() == io::STDOUT {
        return Err(Error::config(
            "--json",
            "prints on standard output, where -o - writes the image",
        ));
    }
    if let Some(batch) = Batch::plan(args)? {
        return batch.run(args, &pipeline, ctx);
    }
    let say = |line: &str| {
        if ctx.progress {
            eprintln!("gsid: {line}");
        }
    };
    let outcome = batch::denoise_or_skip(args, &pipeline, ctx, ctx.progress, &say)?;
    if args.json {
        print_json(&batch::SingleJson {
            pipeline: batch::PipelineJson::of(&pipeline),
            seed: ctx.seed,
            outcome,
        })?;
    }
    Ok(())
}

impl DenoiseArgs {
    /// The `--save-buffer` requests as (buffer, file).
    pub fn saves(&self) -> Result<Vec<(String, PathBuf)>> {
        self.save_buffers
            .iter()
            .map(|s| {
                let (name, path) = s.split_once('=').ok_or_else(|| {
                    Error::config("--save-buffer", format!("`{s}` is not NAME=FILE.exr"))
                })?;
                Ok((name.to_string(), PathBuf::from(path)))
            })
            .collect()
    }
}

/// Denoises the one render set `args` names. `say` gets the input's notes before the work starts.
pub(crate) fn denoise_frame(
    args: &DenoiseArgs,
    pipeline: &Pipeline,
    ctx: &RunContext,
    stage_progress: bool,
    say: &dyn Fn(&str),
) -> Result<FrameReport> {
    let start = Instant::now();
    let saves = args.saves()?;
    let set = args.inputs.load(args.dir.as_deref())?;
    let outputs: Vec<&Path> = std::iter::once(args.output.as_path())
        .chain(saves.iter().map(|(_, p)| p.as_path()))
        .collect();
    check_outputs(&set.inputs(), &outputs)?;
    let inputs = batch::InputJson::list(&set);
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
    let encoding = io::Encoding {
        compression: args.compression,
        half: args.half,
        exposure: preview_exposure(args.exposure, &outputs)?,
    };
    // Reserve every output before the work, so an unwritable path fails fast and nothing half-written remains.
    let pending = PendingOutput::create(&args.output)?;
    let pending_saves = saves
        .iter()
        .map(|(n, p)| Ok((n.clone(), PendingOutput::create(p)?)))
        .collect::<Result<Vec<_>>>()?;
    for line in &set.notes {
        say(line);
    }
    if args.compression.is_lossy() && (frame.has_alpha() || args.keep_layers) {
        say(&format!(
            "--compression {} is lossy: the copied alpha and layers are not bit-exact",
            args.compression.name()
        ));
    }
    let read_seconds = start.elapsed().as_secs_f64();
    let (width, height) = set.set.dims();
    let input = args.dir.as_ref().unwrap_or(&set.dir).display().to_string();
    let mut buffers = Buffers::from(set.set);
    let (out, report) = pipeline.run(&mut buffers, ctx.seed, stage_progress)?;
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
        io::write_image(pending, buf, &frame.windows_only(), &encoding)?;
        saved.push(batch::SavedJson { buffer: name, file });
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
        seconds: batch::Seconds {
            read: read_seconds,
            pipeline: report.seconds,
            write: write_seconds,
            total: start.elapsed().as_secs_f64(),
        },
        output: args.output.display().to_string(),
        saved,
    })
}

/// What a denoised frame tells the user after the work: the run's notes, `--timings`, the summary.
pub(crate) fn tell(report: &FrameReport, timings: bool, say: &dyn Fn(&str)) {
    for line in &report.notes {
        say(line);
    }
    let seconds = &report.seconds;
    if timings {
        say(&format!("  {:<12}         {:>8.4} s", "read", seconds.read));
        for st in &report.stages {
            say(&format!(
                "  {:<12} level {} {:>8.4} s {:>6.2} M walk steps",
                st.id,
                st.level,
                st.seconds,
                st.walk_steps as f64 / 1e6
            ));
        }
        say(&format!(
            "  {:<12}         {:>8.4} s",
            "write", seconds.write
        ));
    }
    say(&format!(
        "{} ({}x{}) → {} in {:.3} s (pipeline {:.3} s, {:.1} M walk steps)",
        report.input,
        report.width,
        report.height,
        report.output,
        seconds.total,
        seconds.pipeline,
        report.walk_steps as f64 / 1e6
    ));
}

/// Prints `value` as one line of JSON on standard output.
pub(crate) fn print_json(value: &impl serde::Serialize) -> Result<()> {
    let text = serde_json::to_string(value)
        .map_err(|e| Error::Runtime(format!("cannot write JSON: {e}")))?;
    say!("{text}\n")
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

fn ablate(args: &AblateArgs, quiet: bool) -> Result<()> {
    let ctx = args.run.context(quiet)?;
    let spec = args.run.spec()?;
    spec.build()?;
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

/// The files `sweep` writes into its `--out` folder.
const SWEEP_FILES: [&str; 3] = ["sweep.csv", "sweep.png", "sweep.svg"];

fn sweep(args: &SweepArgs, quiet: bool) -> Result<()> {
    // Everything that can be wrong with the arguments is found before the render set is even read.
    let ctx = args.run.context(quiet)?;
    if args.repeat == 0 {
        return Err(Error::config("--repeat", "must be at least 1"));
    }
    let base = args.run.spec()?;
    base.build()?;
    let axes = sweep::parse_axes(&args.varies, &args.run.sets)?;
    let settings = sweep::settings(&base, &axes)?;
    let set = io::load_input(&args.dir, &[])?;
    let reference = reference_for(&set, args.reference.as_ref())?;
    if args.out.exists() && !args.out.is_dir() {
        return Err(Error::output(&args.out, "is not a folder"));
    }
    let created = !args.out.exists();
    std::fs::create_dir_all(&args.out).map_err(|e| Error::output(&args.out, e))?;
    let notes = set.notes;
    let buffers = Buffers::from(set.set);
    let result = sweep_into(args, &ctx, &notes, &buffers, &reference, &axes, &settings);
    if result.is_err() && created {
        // Leave nothing behind: the folder is empty again once the reserved files are dropped.
        let _ = std::fs::remove_dir(&args.out);
    }
    result
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
            eprintln!("gsid: {line}");
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
            eprintln!("gsid: {line}");
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

fn eval(args: &EvalArgs) -> Result<()> {
    let image = io::read_color(&args.image)?;
    let mut reference = io::read_color(&args.reference)?;
    sanitize_reference(&mut reference);
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

fn list_pipelines() -> Result<()> {
    for (name, _) in BUILTIN {
        match PipelineSpec::resolve(name) {
            Ok(spec) => say!("{name:<14} {}\n", spec.description)?,
            Err(e) => say!("{name:<14} (invalid: {e})\n")?,
        }
    }
    Ok(())
}

/// Writes to standard output. A reader that went away (`gsid pipelines | head -1`) ends the run
/// quietly, as `ls | head` does; any other failure (a full disk) is an error, exit 1.
fn say(text: std::fmt::Arguments) -> Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    out.write_fmt(text)
        .and_then(|()| out.flush())
        .map_err(|e| match e.kind() {
            std::io::ErrorKind::BrokenPipe => Error::StdoutClosed,
            _ => Error::write("standard output", e),
        })
}
