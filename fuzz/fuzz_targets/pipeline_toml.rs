//! A pipeline file plus `--set` overrides, parsed and built as `gsid denoise` does before any work.
//!
//! Input: the pipeline TOML, then zero or more `--set` assignments, each after a NUL byte.
#![no_main]

use gsid::pipeline::PipelineSpec;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let mut parts = text.split('\0');
    let toml = parts.next().unwrap_or_default();
    let Ok(mut spec) = PipelineSpec::parse(toml, "fuzz.toml") else {
        return;
    };
    for assignment in parts {
        if spec.apply_set(assignment).is_err() {
            return;
        }
    }
    let _ = spec.build();
});
