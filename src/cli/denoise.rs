//! `gsid denoise`: the pipeline built and the thread pool started once, then one render set
//! (`frame`) or many (`batch`).

use super::args::DenoiseArgs;
use super::batch::Batch;
use super::frame::{denoise_or_skip, end_of};
use super::meter::{Meter, Verbosity};
use super::report::{PipelineJson, SingleJson};
use super::stdout::print_json;
use crate::error::{Error, Result};
use crate::io;
use crate::pipeline::Pipeline;
use crate::run::RunContext;

pub(super) fn denoise(args: &DenoiseArgs, verbosity: Verbosity) -> Result<()> {
    // From here a signal cancels the run (every frame holds the token) instead of ending the process.
    super::signals::cancel_token();
    let ctx = args.run.context(verbosity == Verbosity::Quiet)?;
    // Reading and writing run on the same pool as the pipeline, so `--threads` bounds the whole job.
    ctx.install(|| denoise_in_pool(args, &ctx, verbosity))
}

fn denoise_in_pool(args: &DenoiseArgs, ctx: &RunContext, verbosity: Verbosity) -> Result<()> {
    let pipeline = args.run.spec()?.build()?;
    if args.json && args.output.as_os_str() == io::STDOUT {
        return Err(Error::config(
            "--json",
            "prints on standard output, where -o - writes the image",
        ));
    }
    if let Some(batch) = Batch::plan(args)? {
        let meter = Meter::new(verbosity, batch.frame_count(), args.progress_every);
        meter.say_at(Verbosity::Verbose, &setup(&pipeline, ctx));
        return batch.run(args, &pipeline, ctx, &meter);
    }
    let meter = Meter::new(verbosity, 1, args.progress_every);
    meter.say_at(Verbosity::Verbose, &setup(&pipeline, ctx));
    let say = |line: &str| meter.say_at(Verbosity::Normal, &format!("gsid: {line}"));
    meter.start_frame(None);
    let outcome = denoise_or_skip(args, &pipeline, ctx, &meter, &say, None);
    meter.end_frame(end_of(&outcome));
    meter.finish();
    let outcome = outcome?;
    if args.json {
        print_json(&SingleJson {
            version: env!("CARGO_PKG_VERSION"),
            pipeline: PipelineJson::of(&pipeline),
            seed: ctx.seed,
            outcome,
        })?;
    }
    Ok(())
}

/// The run's setup, said once with `-v`: the version, the pipeline and its stages, seed and threads.
fn setup(pipeline: &Pipeline, ctx: &RunContext) -> String {
    let stages: Vec<&str> = pipeline.stages.iter().map(|s| s.id()).collect();
    format!(
        "gsid: gsid {}, pipeline {} ({}), seed {}, {} threads",
        env!("CARGO_PKG_VERSION"),
        pipeline.name,
        stages.join(", "),
        ctx.seed,
        ctx.threads()
    )
}
