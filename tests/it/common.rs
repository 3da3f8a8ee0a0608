//! Helpers shared by the integration tests: run the real binary, make render sets in temp folders.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use gsid::features::{Features, Tone, Weights};
use gsid::{io, Buffers, Image};

pub const FIXTURE: &str = "fixtures/mitsuba-cornell";

/// Runs the binary: this build's, or the one `GSID_BIN` names (to watch a test fail on an older
/// build: `GSID_BIN=old/gsid cargo test --test it cli::`).
pub fn gsid(args: &[&str]) -> Output {
    gsid_command().args(args).output().expect("run gsid")
}

/// The command [`gsid`] runs, to be given arguments, a working folder, standard streams.
pub fn gsid_command() -> Command {
    let bin = std::env::var_os("GSID_BIN").unwrap_or_else(|| env!("CARGO_BIN_EXE_gsid").into());
    Command::new(bin)
}

/// `gsid denoise DIR -o OUT` with the default pipeline.
pub fn denoise(dir: &Path, out: &Path) -> Output {
    gsid(&[
        "denoise",
        dir.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ])
}

pub fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Asserts exit code 2 with exactly one error line that mentions `culprit`.
pub fn assert_bad_input(out: &Output, culprit: &str) {
    let err = stderr(out);
    assert_eq!(
        out.status.code(),
        Some(2),
        "expected exit 2, got {:?}; stderr: {err}",
        out.status.code()
    );
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "expected one line, got: {err}");
    assert!(
        lines[0].contains(culprit),
        "error does not name `{culprit}`: {err}"
    );
    assert!(!err.contains("panicked"), "{err}");
}

/// `gsid denoise` of the Mitsuba box at 1 spp with `full` and `--set KEY=VALUE` must exit 2 with one
/// line naming `culprit`, and write nothing.
pub fn assert_set_refused(key_value: &str, culprit: &str) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.exr");
    let set = format!("{FIXTURE}/spp1");
    let res = gsid(&[
        "denoise",
        &set,
        "--pipeline",
        "full",
        "--set",
        key_value,
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_bad_input(&res, culprit);
    assert!(!out.exists(), "{key_value}: nothing written");
}

/// A small synthetic render set: colour with a bright square, and all five features.
pub fn synthetic_set(w: usize, h: usize) -> Buffers {
    let mut b = Buffers::new();
    let inside = |x: usize, y: usize| x >= w / 4 && x < 3 * w / 4 && y >= h / 4 && y < 3 * h / 4;
    let noise =
        |x: usize, y: usize, c: usize| ((x * 7919 + y * 104729 + c * 31) % 97) as f32 / 97.0 - 0.5;
    b.insert(
        "color",
        Image::from_fn(w, h, 3, |x, y, c| {
            (if inside(x, y) { 0.8 } else { 0.2 } + 0.3 * noise(x, y, c)).max(0.0)
        }),
    )
    .unwrap();
    b.insert(
        "albedo",
        Image::from_fn(w, h, 3, |x, y, _| if inside(x, y) { 0.9 } else { 0.3 }),
    )
    .unwrap();
    b.insert(
        "normal",
        Image::from_fn(
            w,
            h,
            3,
            |x, y, c| if (c == 2) == inside(x, y) { 1.0 } else { 0.0 },
        ),
    )
    .unwrap();
    b.insert(
        "material",
        Image::from_fn(w, h, 3, |_, _, c| if c == 0 { 1.0 } else { 0.0 }),
    )
    .unwrap();
    b.insert(
        "shadow",
        Image::from_fn(w, h, 1, |x, _, _| if x < w / 2 { 1.0 } else { 0.3 }),
    )
    .unwrap();
    b.insert(
        "depth",
        Image::from_fn(w, h, 1, |x, y, _| if inside(x, y) { 2.0 } else { 3.0 }),
    )
    .unwrap();
    b
}

pub fn write_set(dir: &Path, buffers: &Buffers) {
    std::fs::create_dir_all(dir).unwrap();
    for name in buffers.names() {
        io::write_exr(&dir.join(format!("{name}.exr")), buffers.get(name).unwrap()).unwrap();
    }
}

/// Copies a fixture render set (and its reference, one level up) into `dir`.
pub fn copy_fixture(spp: u32, dir: &Path) -> PathBuf {
    let set = dir.join(format!("spp{spp}"));
    std::fs::create_dir_all(&set).unwrap();
    for entry in std::fs::read_dir(Path::new(FIXTURE).join(format!("spp{spp}"))).unwrap() {
        let entry = entry.unwrap();
        std::fs::copy(entry.path(), set.join(entry.file_name())).unwrap();
    }
    std::fs::copy(
        Path::new(FIXTURE).join("reference.exr"),
        dir.join("reference.exr"),
    )
    .unwrap();
    set
}

pub fn files_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// The features (records) of `set` with the report's weights and the Reinhard tone curve.
pub fn default_features(color: &Image, set: &Buffers) -> Features {
    Features::build(
        color,
        set.features(),
        &Weights::default(),
        Tone::Reinhard,
        1.0,
    )
    .unwrap()
    .0
}
