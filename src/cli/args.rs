//! The command line's flags (clap derive), as close to what the user typed as possible; checks
//! that need no file (a `--set` key, `--threads`) happen when they are resolved.

use std::path::{Path, PathBuf};

use clap::{Parser, Subcommand};

use super::examples;
use crate::error::{Error, Result};
use crate::io;
use crate::pipeline::{Pipeline, PipelineSpec, DEFAULT_PIPELINE};
use crate::run::RunContext;

#[derive(Parser, Debug)]
#[command(
    name = "gsid",
    version,
    about = "Feature-guided stochastic denoising for path-traced renders",
    after_help = examples::TOP
)]
pub struct Cli {
    /// Errors only on stderr: no progress, notes or summaries.
    #[arg(long, short, global = true)]
    pub quiet: bool,
    /// Say more on stderr (denoise): `-v` the run's setup (version, pipeline, seed, threads) and
    /// each frame's stage times; `-vv` also every progress step (debug).
    #[arg(long, short, global = true, action = clap::ArgAction::Count, conflicts_with = "quiet")]
    pub verbose: u8,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
// Parsed once per process: the size of the largest variant (denoise's named inputs) costs nothing.
#[allow(clippy::large_enum_variant)]
pub enum Command {
    /// Denoise a render set folder (color.exr plus optional feature buffers), a multilayer EXR, a
    /// frame sequence (`beauty.####.exr`) or a folder of render-set folders.
    #[command(after_help = examples::DENOISE)]
    Denoise(DenoiseArgs),
    /// Score an image against a reference: SSIM, PSNR, relMSE (ALGORITHM.md §5).
    #[command(after_help = examples::EVAL)]
    Eval(EvalArgs),
    /// List the named pipelines.
    #[command(after_help = examples::PIPELINES)]
    Pipelines,
    /// Render a scene file into a render set (fixture renderer).
    #[command(after_help = examples::RENDER)]
    Render(crate::render::RenderArgs),
    /// Run a pipeline and variants of it (each stage removed, each feature weight zeroed, plain SID) and score them.
    #[command(after_help = examples::ABLATE)]
    Ablate(AblateArgs),
    /// Run a pipeline over a grid of parameter values; time and score each setting, plot SSIM against seconds.
    #[command(after_help = examples::SWEEP)]
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
    /// Runs of each setting, 1 to 1000; the median time is kept.
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
    /// Most memory a run may take, in MiB; one whose estimate is larger is refused before the
    /// input is decoded (default: three quarters of this machine's memory).
    #[arg(long, value_name = "MIB")]
    pub max_memory: Option<u64>,
}

impl RunOptions {
    /// Refuses, before `input` is decoded, a run of any of `pipelines` whose estimate (sized from
    /// the colour's header, read once) is above `--max-memory`; an input whose size cannot be
    /// told is left to the loader to explain.
    pub fn check_memory<'a>(
        &self,
        pipelines: impl IntoIterator<Item = &'a Pipeline>,
        input: Option<&Path>,
    ) -> Result<()> {
        let Some((w, h)) = input.and_then(io::colour_dims) else {
            return Ok(());
        };
        let limit = self.memory_limit();
        pipelines
            .into_iter()
            .try_for_each(|p| p.check_memory(w, h, limit))
    }

    /// The memory limit in bytes: `--max-memory`, else three quarters of this machine's memory.
    pub fn memory_limit(&self) -> u64 {
        crate::options::memory_limit(self.max_memory)
    }

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
    /// `%04d`, `$F4`), or a folder of render-set folders (omit with --color or --ldr). A buffer
    /// named beside a folder or a multilayer file (`--variance FILE`) replaces its own.
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
    /// Print each stage's time (and each pyramid level's) after the run (also with -v).
    #[arg(long)]
    pub timings: bool,
    /// Seconds between progress lines when stderr is not a terminal (a render farm's log); 0: a
    /// line at every step. A line is printed at each frame's end whatever this is.
    #[arg(long, value_name = "SECONDS", default_value_t = super::meter::DEFAULT_EVERY, value_parser = seconds)]
    pub progress_every: f64,
    /// Write the denoised colour and its alpha as half floats (the other layers of --keep-layers
    /// keep their type).
    #[arg(long)]
    pub half: bool,
    /// EXR compression: none, rle, zips, zip, piz, or the lossy pxr24, b44, b44a, dwaa, dwab
    /// (default: the colour EXR's own, else zip).
    #[arg(long, value_name = "METHOD", value_parser = compression)]
    pub compression: Option<io::Compression>,
    /// Also write every other channel of the colour's EXR unchanged (a multilayer input's passes).
    #[arg(long)]
    pub keep_layers: bool,
    /// Denoise each frame of a frame pattern with R frames each side, reprojected by the motion
    /// pass (0: each frame alone; overrides the pipeline's `temporal` key).
    #[arg(long, value_name = "R")]
    pub temporal: Option<usize>,
    /// With --temporal: a neighbour that is missing or unreadable fails the frame (default: the
    /// frame is merged from fewer neighbours, with a note).
    #[arg(long)]
    pub temporal_strict: bool,
}

fn seconds(text: &str) -> std::result::Result<f64, String> {
    match text.parse::<f64>() {
        Ok(s) if (0.0..=86_400.0).contains(&s) => Ok(s),
        _ => Err(format!(
            "`{text}` is not a number of seconds from 0 to 86400"
        )),
    }
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
    /// Colour (noisy beauty) image: EXR, PFM, or a multilayer EXR's colour pass (`oidnDenoise`: --hdr).
    #[arg(long, visible_alias = "hdr", conflicts_with = "dir")]
    pub color: Option<PathBuf>,
    /// Colour as an 8-bit sRGB PNG or JPEG (linearised; not HDR, so highlights are clipped).
    #[arg(long, conflicts_with_all = ["dir", "color"])]
    pub ldr: Option<PathBuf>,
    /// Albedo (surface colour without lighting; Blender's `Denoising Albedo`; oidnDenoise: --alb).
    #[arg(long, visible_alias = "alb", requires = "color")]
    pub albedo: Option<PathBuf>,
    /// Shading normals (unit XYZ in any space; oidnDenoise: --nrm).
    #[arg(long, visible_alias = "nrm", requires = "color")]
    pub normal: Option<PathBuf>,
    /// Depth (distance or Z along the camera ray; one channel).
    #[arg(long, requires = "color")]
    pub depth: Option<PathBuf>,
    /// Material weights: diffuse, reflective, refractive (RGB).
    #[arg(long, requires = "color")]
    pub material: Option<PathBuf>,
    /// Shadow: the fraction of light samples from the first hit that reach a light, 0 to 1 (one channel).
    #[arg(long, requires = "color")]
    pub shadow: Option<PathBuf>,
    /// Variance of the pixel mean (RGB, or one channel used for all three).
    #[arg(long, requires = "color")]
    pub variance: Option<PathBuf>,
    /// Colour from the first half of the samples (with --color-b, from the other half).
    #[arg(long, requires_all = ["color", "color_b"])]
    pub color_a: Option<PathBuf>,
    /// Colour from the other half of the samples (with --color-a).
    #[arg(long, requires_all = ["color", "color_a"])]
    pub color_b: Option<PathBuf>,
    /// Which layer of a multilayer input is a buffer, e.g. `--map albedo=ViewLayer.DiffCol` (repeatable).
    #[arg(long = "map", value_name = "BUFFER=LAYER")]
    pub maps: Vec<String>,
    /// The view layer of a multilayer input (Blender's `ViewLayer`) every buffer is read from,
    /// when the file holds several.
    #[arg(long = "layer", value_name = "NAME")]
    pub layer: Option<String>,
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
        // A multilayer file or a render-set folder given first keeps its buffers; a buffer named
        // beside it takes the place of its own (`shot.exr --variance var.exr`). Any other colour
        // file given first, beside buffers named one by one, is read as `--color FILE`.
        let named_buffers: Vec<(&'static str, PathBuf)> = self.slots()[2..]
            .iter()
            .filter_map(|(b, p)| p.as_ref().map(|p| (*b, p.clone())))
            .collect();
        let color = match dir {
            Some(dir) if named_buffers.is_empty() || dir.is_dir() || io::is_layered_file(dir) => {
                return io::load_input_with(dir, &maps, self.layer.as_deref(), &named_buffers)
            }
            Some(dir) => Some(dir.to_path_buf()),
            None => self.color.clone().or_else(|| self.ldr.clone()),
        };
        if !maps.is_empty() {
            return Err(Error::config("--map", "applies to a multilayer file input"));
        }
        if self.layer.is_some() {
            return Err(Error::config(
                "--layer",
                "applies to a multilayer file input; name a buffer's layer as FILE.exr:LAYER",
            ));
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

impl DenoiseArgs {
    /// The colour input: the positional path (a folder, a file, a pattern), else `--color`, else
    /// `--ldr`.
    pub fn colour_input(&self) -> Option<&Path> {
        (self.dir.as_deref())
            .or(self.inputs.color.as_deref())
            .or(self.inputs.ldr.as_deref())
    }

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
