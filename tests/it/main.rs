//! The integration tests, one binary: each file beside this one is a topic (`cargo test --test it
//! cli::` runs one). One binary links gsid once instead of once per file. Binaries of their own: `layout` (the house rules), `docs` (the docs hold together),
//! `walk_miri` (run by name under Miri, `scripts/miri.sh`) and `resources` (children's peak memory,
//! which a large parent process would inflate). proptest keeps the failing cases it saved for a
//! file here in `tests/proptest-regressions/FILE.txt` (its place for a crate rooted in `main.rs`).

// Shared helpers: run the binary, make render sets (`common`); score a denoised fixture (`score`).
mod common;
mod score;

mod atrous;
mod blender_files;
mod calibration;
mod cli;
mod dark_dots;
mod embed;
mod embedding;
mod examples;
mod exr_fidelity;
mod farm;
mod formats;
mod gsid_beats_sid;
mod hard_cases;
mod highlights;
mod inputs_kept;
mod io;
mod metrics;
mod multilayer;
mod noise;
mod options;
mod outlier;
mod output_files;
mod outputs;
mod pipeline_keys;
mod prefilter;
mod progress;
mod pyramid;
mod quality;
mod regress;
mod reliability;
mod render;
mod sequence;
mod spec_walks;
mod stdout;
mod sweep;
mod temporal;
mod walk_kernel;
