//! Scoring through the binary: `gsid denoise` then `gsid eval --json`, as a user scores a pipeline.
#![allow(dead_code)]

use std::path::Path;
use std::process::Command;

fn gsid(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_gsid"))
        .args(args)
        .output()
        .expect("run gsid");
    assert!(
        out.status.success(),
        "gsid {}: {}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// SSIM of `image` against `reference` (ALGORITHM.md §5), from `gsid eval --json`.
pub fn ssim(image: &Path, reference: &Path) -> f64 {
    let json = gsid(&[
        "eval",
        image.to_str().unwrap(),
        "--reference",
        reference.to_str().unwrap(),
        "--json",
    ]);
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    v["ssim"].as_f64().expect("eval --json has ssim")
}

/// SSIM of `gsid denoise SET --pipeline PIPELINE --set ...` against `reference`; the output goes to `out`.
pub fn denoised_ssim(
    set: &Path,
    pipeline: &str,
    sets: &[String],
    out: &Path,
    reference: &Path,
) -> f64 {
    let mut args = vec![
        "denoise",
        set.to_str().unwrap(),
        "--pipeline",
        pipeline,
        "-o",
        out.to_str().unwrap(),
        "-q",
    ];
    for s in sets {
        args.extend(["--set", s.as_str()]);
    }
    gsid(&args);
    ssim(out, reference)
}
