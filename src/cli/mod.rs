//! The `gsid` binary's code. Thin: parse the flags (`args`), call the library, print one line per
//! error. `denoise` runs the command over one render set (`frame`) or many (`batch`, which hands
//! each to `frame`); `report` says what a frame did, as text or JSON; `meter` shows progress and
//! filters what is said by verbosity; `studies` holds ablate, sweep, eval and the pipeline list;
//! `stdout` prints without panicking; `signals` turns Ctrl-C into the run's cancel. Uses run one
//! way: denoise → batch → frame → report, and each of them → args, meter, signals, stdout.

mod args;
pub mod batch;
mod denoise;
mod examples;
mod frame;
mod hints;
pub mod meter;
mod pattern;
mod report;
mod signals;
mod stdout;
mod studies;

use clap::Parser;

pub use args::{
    AblateArgs, Cli, Command, DenoiseArgs, EvalArgs, NamedInputs, RunOptions, SweepArgs,
};
pub use report::{FrameReport, Outcome};

use crate::error::Error;

/// Runs the CLI and returns the process exit code.
pub fn main() -> i32 {
    keep_freed_memory();
    signals::remove_outputs_on_signal();
    let argv: Vec<std::ffi::OsString> = std::env::args_os().collect();
    let parsed = Cli::try_parse_from(&argv);
    if let Some(hint) = hints::quality_flag(&argv, parsed.is_err()) {
        crate::progress::say_err!("gsid: error: {hint}");
        return 2;
    }
    let cli = match parsed {
        Ok(cli) => cli,
        Err(e) => {
            // Help and version go to stdout (exit 0), usage errors to stderr (exit 2). Help that
            // cannot be written fails like any output; a reader that went away ends quietly.
            let code = if e.use_stderr() { 2 } else { 0 };
            return match e.print() {
                Err(err) if code == 0 && err.kind() != std::io::ErrorKind::BrokenPipe => {
                    crate::progress::say(&format!(
                        "gsid: error: cannot write standard output: {err}"
                    ));
                    1
                }
                _ => code,
            };
        }
    };
    match run(cli) {
        Ok(()) | Err(Error::StdoutClosed) => 0,
        Err(Error::Cancelled) => {
            // Only a signal cancels the command line's runs; the shell's code for it.
            crate::progress::say_err!("gsid: cancelled");
            signals::cancelled_exit_code()
        }
        Err(e) => {
            crate::progress::say_err!("gsid: error: {e}");
            e.exit_code()
        }
    }
}

/// Keeps the memory a run frees for its later buffers, instead of handing it back to the kernel.
///
/// A pipeline allocates and drops many image-sized buffers (stage outputs, planes, tables). By
/// default glibc serves those from several arenas (one per thread that allocates), maps the largest
/// fresh and unmaps them on free, and trims the heap's top: every such buffer is faulted in again,
/// page by page, when it is next written, and every unmap stops the other cores to flush their TLBs.
/// With two threads those faults and flushes contend, so stages that allocate much scale worst. One
/// arena, no mapped chunks and no trimming make a freed buffer the next one's memory. Measured on
/// 1 and 4 MP (docs/RESULTS.md "Speed"): fewer faults, less system time, and a peak that moves by a few
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

fn run(cli: Cli) -> crate::error::Result<()> {
    match cli.command {
        Command::Denoise(args) => {
            denoise::denoise(&args, meter::Verbosity::of(cli.quiet, cli.verbose))
        }
        Command::Render(args) => crate::render::run(&args, cli.quiet),
        Command::Eval(args) => studies::eval(&args, cli.quiet),
        Command::Ablate(args) => studies::ablate(&args, cli.quiet),
        Command::Sweep(args) => studies::sweep(&args, cli.quiet),
        Command::Pipelines => studies::list_pipelines(),
    }
}
