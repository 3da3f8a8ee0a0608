//! `gsid denoise`: the pipeline built and the thread pool started once, then one render set
//! (`frame`) or many (`batch`).

use super::args::DenoiseArgs;
use super::batch::Batch;
use super::frame::denoise_or_skip;
use super::report::{PipelineJson, SingleJson};
use super::stdout::print_json;
use crate::error::{Error, Result};
use crate::io;
use crate::run::RunContext;

pub(super) fn denoise(args: &DenoiseArgs, quiet: bool) -> Result<()> {
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
            crate::progress::say_err!("gsid: {line}");
        }
    };
    let outcome = denoise_or_skip(args, &pipeline, ctx, ctx.progress, &say, None)?;
    if args.json {
        print_json(&SingleJson {
            pipeline: PipelineJson::of(&pipeline),
            seed: ctx.seed,
            outcome,
        })?;
    }
    Ok(())
}
