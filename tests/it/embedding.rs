//! gsid inside other programs, against the command line: the C API (capi/tests/denoise.c,
//! compiled with `cc` against the committed header) and the Python package (pytest, python/tests)
//! each denoise a fixture and must give the CLI's bits.
//!
//! They need what `.ci/run` builds before `cargo test`: the C library
//! (`cargo build -p gsid-capi --profile ci-embed` there, found at `GSID_CAPI_LIB`; by default
//! target/embed/libgsid.a, from `--profile embed`) and a venv with the package installed
//! (`GSID_CI_VENV`). Without them each test prints "skipped: ..." and passes, except under
//! `CI=true`, where it fails.

use crate::common;
use std::path::{Path, PathBuf};
use std::process::Command;

use gsid::{io, Image};

const FIXTURE: &str = "fixtures/cornell/spp4";

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Whether the test can run; prints why not, and fails under `CI=true`.
fn available(ok: bool, why_not: &str) -> bool {
    if !ok {
        assert!(
            std::env::var("CI").map_or(true, |v| v != "true"),
            "{why_not} (required under CI=true)"
        );
        eprintln!("skipped: {why_not}");
    }
    ok
}

fn raw(image: &Image, path: &Path) {
    let bytes: Vec<u8> = image.data().iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(path, bytes).unwrap();
}

/// The CLI's result on the fixture's colour, albedo, normal and variance only (what the C test
/// hands over).
fn cli_on_four_buffers(dir: &Path) -> Image {
    let set = io::load_render_set(&root().join(FIXTURE)).unwrap().set;
    let albedo = set.features.get(gsid::Feature::Albedo).unwrap();
    let normal = set.features.get(gsid::Feature::Normal).unwrap();
    let variance = set.noise.variance.as_ref().unwrap();
    for (name, img) in [
        ("color", &set.color),
        ("albedo", albedo),
        ("normal", normal),
        ("variance", variance),
    ] {
        io::write_exr(&dir.join(format!("{name}.exr")), img).unwrap();
        raw(img, &dir.join(format!("{name}.f32")));
    }
    let out = dir.join("cli.exr");
    let p = |n: &str| dir.join(n).to_str().unwrap().to_string();
    let run = common::gsid(&[
        "denoise",
        "--color",
        &p("color.exr"),
        "--albedo",
        &p("albedo.exr"),
        "--normal",
        &p("normal.exr"),
        "--variance",
        &p("variance.exr"),
        "-q",
        "-o",
        &p("cli.exr"),
    ]);
    assert!(run.status.success(), "{}", common::stderr(&run));
    io::read_image(&out, 3).unwrap()
}

#[test]
fn the_c_api_gives_the_clis_pixels_and_codes_for_bad_arguments() {
    let lib = std::env::var_os("GSID_CAPI_LIB")
        .map(PathBuf::from)
        .unwrap_or_else(|| root().join("target/embed/libgsid.a"));
    let cc = Command::new("cc").arg("--version").output().is_ok();
    if !available(cc, "no C compiler (`cc`)")
        || !available(
            lib.is_file(),
            &format!(
                "no C library at {} (cargo build -p gsid-capi --profile embed)",
                lib.display()
            ),
        )
    {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let want = cli_on_four_buffers(dir.path());
    let exe = dir.path().join("denoise");
    let build = Command::new("cc")
        .args(["-std=c99", "-Wall", "-Wextra", "-Werror", "-O1", "-I"])
        .arg(root().join("capi/include"))
        .arg(root().join("capi/tests/denoise.c"))
        .arg(&lib)
        .args(["-lpthread", "-ldl", "-lm", "-o"])
        .arg(&exe)
        .output()
        .unwrap();
    assert!(
        build.status.success(),
        "{}",
        String::from_utf8_lossy(&build.stderr)
    );
    let (w, h) = want.dims();
    let run = Command::new(&exe)
        .args([w.to_string(), h.to_string()])
        .args(
            ["color", "albedo", "normal", "variance", "out"]
                .map(|n| dir.path().join(format!("{n}.f32"))),
        )
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}{}",
        String::from_utf8_lossy(&run.stdout),
        String::from_utf8_lossy(&run.stderr)
    );
    let got: Vec<u32> = std::fs::read(dir.path().join("out.f32"))
        .unwrap()
        .chunks_exact(4)
        .map(|b| u32::from_le_bytes(b.try_into().unwrap()))
        .collect();
    let want: Vec<u32> = want.data().iter().map(|v| v.to_bits()).collect();
    assert!(got == want, "the C API's pixels differ from the CLI's");
}

#[test]
fn the_python_package_passes_its_tests() {
    let venv = std::env::var_os("GSID_CI_VENV").map(PathBuf::from);
    let python = venv.as_ref().map(|v| v.join("bin/python"));
    let ok = python.as_ref().is_some_and(|p| p.is_file());
    if !available(ok, "no venv (GSID_CI_VENV, made by .ci/run)") {
        return;
    }
    let run = Command::new(python.unwrap())
        .args([
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            "python/tests",
        ])
        .current_dir(root())
        .env("GSID_BIN", env!("CARGO_BIN_EXE_gsid"))
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&run.stdout);
    eprintln!("{out}");
    assert!(
        run.status.success(),
        "{out}{}",
        String::from_utf8_lossy(&run.stderr)
    );
}

#[test]
fn the_committed_header_is_cbindgens_output() {
    let cbindgen = std::env::var_os("GSID_CBINDGEN").unwrap_or_else(|| "cbindgen".into());
    let has = Command::new(&cbindgen).arg("--version").output().is_ok();
    if !has {
        // Not installed in CI (it takes longer to build than the tests run); regenerate with the
        // command in capi/cbindgen.toml.
        eprintln!("skipped: cbindgen not on PATH");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let made = dir.path().join("gsid.h");
    let run = Command::new(&cbindgen)
        .arg("--config")
        .arg(root().join("capi/cbindgen.toml"))
        .args(["--crate", "gsid-capi", "--output"])
        .arg(&made)
        .arg(root().join("capi"))
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let committed = std::fs::read_to_string(root().join("capi/include/gsid.h")).unwrap();
    assert!(
        std::fs::read_to_string(&made).unwrap() == committed,
        "capi/include/gsid.h is stale: regenerate it with the command in capi/cbindgen.toml"
    );
}

/// Without cbindgen (CI): every function, struct, enum and type the C API exports is declared in
/// the committed header, so a new entry point cannot ship without regenerating it. Signatures and
/// comments are compared only by [`the_committed_header_is_cbindgens_output`].
#[test]
fn the_committed_header_declares_every_export() {
    let src = std::fs::read_to_string(root().join("capi/src/lib.rs")).unwrap();
    let header = std::fs::read_to_string(root().join("capi/include/gsid.h")).unwrap();
    let exports: Vec<&str> = src
        .lines()
        .filter_map(|line| {
            let line = line.trim_start();
            [
                "pub unsafe extern \"C\" fn ",
                "pub extern \"C\" fn ",
                "pub struct ",
                "pub enum ",
                "pub type ",
            ]
            .iter()
            .find_map(|p| line.strip_prefix(p))
        })
        .map(|rest| {
            rest.split(|c: char| !c.is_alphanumeric() && c != '_')
                .next()
                .unwrap()
        })
        .collect();
    assert!(exports.contains(&"gsid_denoise"), "{exports:?}");
    // Every word of the header's code, its comments left out.
    let declared: std::collections::HashSet<&str> = header
        .lines()
        .filter(|line| !line.trim_start().starts_with("//"))
        .flat_map(|line| line.split(|c: char| !c.is_alphanumeric() && c != '_'))
        .collect();
    let missing: Vec<&&str> = exports
        .iter()
        .filter(|name| !declared.contains(**name))
        .collect();
    assert!(
        missing.is_empty(),
        "capi/include/gsid.h does not declare {missing:?}: regenerate it with the command in capi/cbindgen.toml"
    );
}
