//! Command-line interface (clap derive). Thin: parse, call the library, print one line per error.

use std::path::PathBuf;

use clap::{Parser, Subcommand};

use crate::error::{Error, Result};

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
pub enum Command {
    /// Denoise a render set folder (color.exr plus optional feature buffers).
    Denoise(DenoiseArgs),
    /// Score an image against a reference: SSIM, PSNR, relMSE (ALGORITHM.md §5).
    Eval(EvalArgs),
    /// List the named pipelines.
    Pipelines,
    /// Render a scene file into a render set (fixture renderer).
    Render(crate::render::RenderArgs),
}

#[derive(clap::Args, Debug)]
pub struct DenoiseArgs {
    /// Render set folder.
    pub dir: PathBuf,
    /// Pipeline name (see `gsid pipelines`) or a pipeline TOML file.
    #[arg(long, short)]
    pub pipeline: Option<String>,
    /// Output EXR path.
    #[arg(long, short)]
    pub output: PathBuf,
    /// Seed for every random choice.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Override a pipeline parameter, e.g. `--set gsid.walks=40`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub sets: Vec<String>,
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
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            let code = if e.use_stderr() { 2 } else { 0 };
            let _ = e.print();
            return code;
        }
    };
    match run(cli) {
        Ok(()) => 0,
        Err(e) => {
            eprintln!("gsid: error: {e}");
            e.exit_code()
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Render(args) => crate::render::run(&args, cli.quiet),
        Command::Denoise(_) | Command::Eval(_) | Command::Pipelines => {
            Err(Error::Runtime("command under construction".into()))
        }
    }
}
