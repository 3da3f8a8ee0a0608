//! The binary as a user runs it: outputs, determinism, and bad input (exit 2, one line, nothing written).

use crate::common::*;
use gsid::io;
use std::path::Path;

#[test]
fn denoise_then_eval_on_the_fixture() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out.exr");
    let run = gsid(&[
        "denoise",
        "fixtures/mitsuba-cornell/spp16",
        "--pipeline",
        "gsid",
        "-o",
        out.to_str().unwrap(),
        "-q",
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    let eval = gsid(&[
        "eval",
        out.to_str().unwrap(),
        "--reference",
        "fixtures/mitsuba-cornell/reference.exr",
        "--json",
    ]);
    assert!(eval.status.success());
    let json: serde_json::Value = serde_json::from_slice(&eval.stdout).unwrap();
    assert!(json["ssim"].as_f64().unwrap() > 0.9);
    assert_eq!(
        files_in(tmp.path()),
        vec!["out.exr"],
        "no temporary files left behind"
    );
}

#[test]
fn same_seed_same_bits_on_one_and_two_threads() {
    let tmp = tempfile::tempdir().unwrap();
    let mut outputs = Vec::new();
    for threads in ["1", "2"] {
        let out = tmp.path().join(format!("t{threads}.exr"));
        let run = gsid(&[
            "denoise",
            "fixtures/mitsuba-cornell/spp4",
            "-p",
            "gsid",
            "-o",
            out.to_str().unwrap(),
            "--seed",
            "7",
            "--threads",
            threads,
            "-q",
        ]);
        assert!(run.status.success(), "{}", stderr(&run));
        outputs.push(io::read_image(&out, 3).unwrap());
    }
    let bits = |i: &gsid::Image| i.data().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&outputs[0]), bits(&outputs[1]));
    let other_seed = tmp.path().join("s8.exr");
    gsid(&[
        "denoise",
        "fixtures/mitsuba-cornell/spp4",
        "-p",
        "gsid",
        "-o",
        other_seed.to_str().unwrap(),
        "--seed",
        "8",
        "-q",
    ]);
    assert_ne!(
        bits(&outputs[0]),
        bits(&io::read_image(&other_seed, 3).unwrap()),
        "the seed must matter"
    );
}

/// The "N M walk steps" figure of a denoise run's summary line.
fn walk_steps(out: &std::process::Output) -> f64 {
    let err = stderr(out);
    let before = err.split(" M walk steps").next().unwrap();
    before.rsplit(' ').next().unwrap().parse().unwrap()
}

#[test]
fn set_overrides_reach_the_stage() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("o.exr");
    let o = out.to_str().unwrap();
    let set4 = "fixtures/mitsuba-cornell/spp4";
    let base = gsid(&["denoise", set4, "-p", "gsid", "-o", o]);
    let one = gsid(&[
        "denoise",
        set4,
        "-p",
        "gsid",
        "-o",
        o,
        "--set",
        "gsid.walks=1",
        "--set",
        "gsid.weights.depth=0",
    ]);
    assert!(
        base.status.success() && one.status.success(),
        "{}",
        stderr(&one)
    );
    assert!(
        walk_steps(&one) < walk_steps(&base) / 10.0,
        "{} vs {}",
        walk_steps(&one),
        walk_steps(&base)
    );
    // The nested stage's walks against an explicit 20 (not the preset's count, which may change).
    let nested = gsid(&["denoise", set4, "-o", o, "--set", "pyramid.gsid.walks=1"]);
    let twenty = gsid(&["denoise", set4, "-o", o, "--set", "pyramid.gsid.walks=20"]);
    assert!(walk_steps(&nested) < walk_steps(&twenty) / 10.0);
    let bad = gsid(&[
        "denoise",
        set4,
        "-p",
        "gsid",
        "-o",
        o,
        "--set",
        "gsid.walks=0",
    ]);
    assert_bad_input(&bad, "gsid.walks");
    // A stage is found by its id wherever it sits: on `full`, `gsid` is the pyramid's.
    let short = gsid(&["denoise", set4, "-o", o, "--set", "gsid.walks=1"]);
    assert_eq!(walk_steps(&short), walk_steps(&nested));
    let bad = gsid(&["denoise", set4, "-o", o, "--set", "gsdi.walks=3"]);
    assert_bad_input(&bad, "no stage `gsdi`");
}

#[test]
fn missing_color_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    let set = tmp.path().join("set");
    let mut b = synthetic_set(8, 8);
    b.remove("color");
    write_set(&set, &b);
    let out = tmp.path().join("out.exr");
    let run = denoise(&set, &out);
    assert_bad_input(&run, "color");
    assert!(!out.exists());
}

#[test]
fn buffers_of_different_sizes_name_both_files() {
    let tmp = tempfile::tempdir().unwrap();
    let set = tmp.path().join("set");
    write_set(&set, &synthetic_set(8, 8));
    io::write_exr(&set.join("normal.exr"), &gsid::Image::new(9, 8, 3)).unwrap();
    let out = tmp.path().join("out.exr");
    let run = denoise(&set, &out);
    assert_bad_input(&run, "normal.exr");
    assert!(
        stderr(&run).contains("color.exr") && stderr(&run).contains("9x8"),
        "{}",
        stderr(&run)
    );
    assert!(!out.exists());
}

#[test]
fn truncated_exr_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    let set = tmp.path().join("set");
    write_set(&set, &synthetic_set(16, 16));
    let bytes = std::fs::read(set.join("albedo.exr")).unwrap();
    std::fs::write(set.join("albedo.exr"), &bytes[..bytes.len() / 2]).unwrap();
    let out = tmp.path().join("out.exr");
    let run = denoise(&set, &out);
    assert_bad_input(&run, "albedo.exr");
    assert!(!out.exists());
}

#[test]
fn unknown_pipeline_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out.exr");
    let run = gsid(&[
        "denoise",
        FIXTURE_SPP1,
        "-p",
        "no-such-pipeline",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_bad_input(&run, "no-such-pipeline");
    assert!(!out.exists());
}

const FIXTURE_SPP1: &str = "fixtures/mitsuba-cornell/spp1";

#[test]
fn misspelled_pipeline_key_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("typo.toml");
    std::fs::write(
        &file,
        "name = \"typo\"\n[[stage]]\nkind = \"gsid\"\nsigam = 0.5\n",
    )
    .unwrap();
    let out = tmp.path().join("out.exr");
    let run = gsid(&[
        "denoise",
        FIXTURE_SPP1,
        "-p",
        file.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_bad_input(&run, "sigam");
    assert!(stderr(&run).contains("typo.toml"), "{}", stderr(&run));
    assert!(!out.exists());
}

#[test]
fn unwritable_output_path_is_named_and_nothing_is_left() {
    let tmp = tempfile::tempdir().unwrap();
    // A missing folder is made (tests/it/output_files.rs); a file where the folder should be is not.
    std::fs::write(tmp.path().join("a-file"), b"").unwrap();
    let out = tmp.path().join("a-file").join("out.exr");
    let run = gsid(&["denoise", FIXTURE_SPP1, "-o", out.to_str().unwrap()]);
    assert_bad_input(&run, "a-file");
    assert!(!out.exists());
    std::fs::remove_file(tmp.path().join("a-file")).unwrap();
    let run = gsid(&["denoise", FIXTURE_SPP1, "-o", tmp.path().to_str().unwrap()]);
    assert_bad_input(&run, "is a directory");
    assert!(files_in(tmp.path()).is_empty());
}

#[test]
fn refuses_to_overwrite_an_input() {
    let tmp = tempfile::tempdir().unwrap();
    let set = tmp.path().join("set");
    write_set(&set, &synthetic_set(8, 8));
    let before = std::fs::read(set.join("color.exr")).unwrap();
    let run = gsid(&[
        "denoise",
        set.to_str().unwrap(),
        "-o",
        set.join("color.exr").to_str().unwrap(),
    ]);
    assert_bad_input(&run, "color.exr");
    assert_eq!(before, std::fs::read(set.join("color.exr")).unwrap());
}

#[test]
fn eval_rejects_mismatched_sizes() {
    let tmp = tempfile::tempdir().unwrap();
    let a = tmp.path().join("a.exr");
    io::write_exr(&a, &gsid::Image::new(4, 4, 3)).unwrap();
    let run = gsid(&[
        "eval",
        a.to_str().unwrap(),
        "--reference",
        "fixtures/mitsuba-cornell/reference.exr",
    ]);
    assert_bad_input(&run, "a.exr");
}

#[test]
fn pipelines_lists_the_named_pipelines() {
    let run = gsid(&["pipelines"]);
    assert!(run.status.success());
    let text = String::from_utf8_lossy(&run.stdout);
    for name in ["sid", "gsid"] {
        assert!(text.lines().any(|l| l.starts_with(name)), "{text}");
    }
    assert!(Path::new("pipelines/gsid.toml").is_file());
}

#[test]
fn the_outlier_mask_can_be_saved_for_inspection() {
    let tmp = tempfile::tempdir().unwrap();
    let (out, mask) = (tmp.path().join("out.exr"), tmp.path().join("mask.exr"));
    let arg = format!("outlier_mask={}", mask.display());
    let run = gsid(&[
        "denoise",
        "fixtures/caustics/spp1",
        "-o",
        out.to_str().unwrap(),
        "--save-buffer",
        &arg,
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    assert!(
        stderr(&run).contains("outlier:"),
        "the run reports how many pixels it flagged"
    );
    let m = io::read_image(&mask, 1).unwrap();
    let flagged = m.data().iter().filter(|&&v| v > 0.5).count();
    assert!(
        flagged > 0 && flagged < m.pixel_count() / 10,
        "{flagged} pixels flagged"
    );
    let bad = gsid(&[
        "denoise",
        FIXTURE_SPP1,
        "-p",
        "gsid",
        "-o",
        out.to_str().unwrap(),
        "--save-buffer",
        &arg,
    ]);
    assert_bad_input(&bad, "outlier_mask");
}

#[test]
fn ablate_prints_and_writes_the_table() {
    let tmp = tempfile::tempdir().unwrap();
    let csv = tmp.path().join("ablate.csv");
    let run = gsid(&[
        "ablate",
        "fixtures/mitsuba-cornell/spp4",
        "-p",
        "full",
        "--out",
        csv.to_str().unwrap(),
        "-q",
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    let table = String::from_utf8_lossy(&run.stdout);
    for variant in [
        "full (full)",
        "without outlier",
        "without reliability",
        "reliability with median centres",
        "reliability albedo without the geometry's floor",
        "coverage without the across-edge spread",
        "coverage without the colour's own edges",
        "outlier one-sided (dark dots kept)",
        "blend without the noise-level cap",
        "blend without the leak test's level",
        "spread without highlights kept",
        "without prefilter",
        "without pyramid",
        "without atrous",
        "without regress",
        "without blend",
        "without spread",
        "without coverage",
        "fixed σ (no noise measured)",
        "one σ per image (no per-pixel noise)",
        "noise from the image only",
        "without walks (à-trous alone)",
        "weight albedo = 0",
        "weight depth = 0",
        "plain SID",
    ] {
        assert!(table.contains(variant), "missing {variant}: {table}");
    }
    let text = std::fs::read_to_string(&csv).unwrap();
    // Header, then: full, nine stages removed (the noise stage is not: later stages read it; the
    // outlier's row takes its spread with it), the reliability's median centre and its albedo
    // without the geometry's floor, coverage without
    // its across-edge spread and without its colour-edge step, the outlier without dark dots, the
    // blend without its noise-level cap and without its leak test's level, the spread without its
    // highlights, the four noise rows, eight weights zeroed, plain SID.
    assert_eq!(text.lines().count(), 1 + 31, "{text}");
    assert!(text.starts_with("variant,ssim,psnr,relmse,seconds,delta_ssim"));
    let bad = gsid(&[
        "ablate",
        "fixtures/mitsuba-cornell/spp4",
        "--out",
        tmp.path().join("t.txt").to_str().unwrap(),
    ]);
    assert_bad_input(&bad, "t.txt");
    let tmp2 = tempfile::tempdir().unwrap();
    let set = tmp2.path().join("set");
    write_set(&set, &synthetic_set(8, 8));
    assert_bad_input(&gsid(&["ablate", set.to_str().unwrap()]), "reference");
}

#[test]
fn thread_counts_outside_1_to_1024_are_refused_by_every_command() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("o.exr");
    let dir = tmp.path().join("d");
    let (o, d) = (out.to_str().unwrap(), dir.to_str().unwrap());
    let set4 = "fixtures/mitsuba-cornell/spp4";
    let scene = "fixtures/scenes/cornell.toml";
    for threads in ["0", "1025"] {
        let with_threads = |args: &[&str]| {
            let mut a = args.to_vec();
            a.extend(["--threads", threads]);
            gsid(&a)
        };
        for run in [
            with_threads(&["denoise", FIXTURE_SPP1, "-o", o]),
            with_threads(&["render", scene, "-o", d, "--spp", "1"]),
            with_threads(&["ablate", set4]),
            with_threads(&["sweep", set4, "--vary", "gsid.walks=1", "--out", d]),
        ] {
            assert_bad_input(&run, "--threads");
        }
    }
    assert!(files_in(tmp.path()).is_empty());
}

/// A bare pipeline name is the built-in pipeline, whatever the working folder holds: a
/// `pipelines/full.toml` there (here plain SID under the name `full`) is not run in its place.
#[test]
fn a_pipeline_name_is_never_a_file_in_the_working_folder() {
    let tmp = tempfile::tempdir().unwrap();
    std::fs::create_dir(tmp.path().join("pipelines")).unwrap();
    let sid = std::fs::read_to_string("pipelines/sid.toml").unwrap();
    let impostor = sid.replacen("name = \"sid\"", "name = \"full\"", 1);
    assert_ne!(sid, impostor);
    std::fs::write(tmp.path().join("pipelines/full.toml"), impostor).unwrap();
    let set = std::fs::canonicalize(format!("{FIXTURE}/spp4")).unwrap();
    let out = gsid_command()
        .current_dir(tmp.path())
        .args([
            "denoise",
            set.to_str().unwrap(),
            "-o",
            "o.exr",
            "--json",
            "-q",
        ])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let builtin = gsid::PipelineSpec::builtin("full")
        .unwrap()
        .build()
        .unwrap();
    let ids: Vec<&str> = builtin.stages.iter().map(|s| s.id()).collect();
    assert_eq!(json["pipeline"]["stages"], serde_json::json!(ids), "{json}");
}

/// A buffer file that is there but cannot be read (a link to nothing, a folder, a FIFO, a device)
/// is an error naming it: it was taken for a missing buffer ("missing buffers: albedo"), and a colour
/// so broken got "not found".
#[test]
fn a_buffer_that_exists_but_cannot_be_read_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    type Make = fn(&Path);
    let kinds: [(&str, Make); 4] = [
        ("link to nothing", |p| {
            std::os::unix::fs::symlink("/nonexistent/gsid", p).unwrap()
        }),
        ("folder", |p| std::fs::create_dir(p).unwrap()),
        ("fifo", |p| {
            let c = std::ffi::CString::new(p.to_str().unwrap()).unwrap();
            // SAFETY: mkfifo reads a valid NUL-terminated path.
            assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0);
        }),
        ("device", |p| {
            std::os::unix::fs::symlink("/dev/zero", p).unwrap()
        }),
    ];
    for (k, (what, make)) in kinds.iter().enumerate() {
        for buffer in ["albedo", "color"] {
            let set = tmp.path().join(format!("set{k}{buffer}"));
            write_set(&set, &synthetic_set(8, 6));
            std::fs::remove_file(set.join(format!("{buffer}.exr"))).unwrap();
            make(&set.join(format!("{buffer}.exr")));
            let out = tmp.path().join(format!("out{k}{buffer}.exr"));
            let run = denoise(&set, &out);
            assert_bad_input(&run, &format!("{buffer}.exr"));
            assert!(!out.exists(), "{what} {buffer}");
        }
    }
}

/// `eval` refuses what it cannot score: a reference with no finite non-negative value (it was
/// scored as black without a word) and an image with a NaN pixel (SSIM 0.9999, relMSE NaN).
/// A reference with a few bad pixels is scored, with a line saying how many became 0.
#[test]
fn eval_refuses_what_it_cannot_score() {
    let tmp = tempfile::tempdir().unwrap();
    let file = |name: &str, img: &gsid::Image| {
        let p = tmp.path().join(name);
        io::write_exr(&p, img).unwrap();
        p.to_str().unwrap().to_string()
    };
    let good = gsid::Image::from_fn(16, 12, 3, |x, y, c| 0.1 + ((x + y + c) % 7) as f32 * 0.1);
    let good_path = file("good.exr", &good);
    for (name, value) in [("nan", f32::NAN), ("inf", f32::INFINITY), ("neg", -1.0)] {
        let bad = file(
            &format!("{name}.exr"),
            &gsid::Image::filled(16, 12, 3, value),
        );
        let run = gsid(&["eval", &good_path, "--reference", &bad]);
        assert_bad_input(&run, &bad);
    }
    let mut one_nan = good.clone();
    one_nan.pixel_mut(5)[1] = f32::NAN;
    let one_nan = file("one_nan.exr", &one_nan);
    let run = gsid(&["eval", &one_nan, "--reference", &good_path]);
    assert_bad_input(&run, &one_nan);
    let run = gsid(&["eval", &good_path, "--reference", &one_nan]);
    assert_eq!(run.status.code(), Some(0), "{}", stderr(&run));
    assert!(
        stderr(&run).contains("1 NaN, infinite or negative values scored as 0"),
        "{}",
        stderr(&run)
    );
}

/// An input whose standard attribute has a mistyped type (a bit flip: `pixelAspectRatio` of type
/// `flost`) cannot be carried to the output: that is named as the input's fault before any work,
/// exit 2 (it ran the whole pipeline, then failed to write with exit 1).
#[test]
fn an_input_header_that_cannot_be_written_back_is_refused_before_the_work() {
    let tmp = tempfile::tempdir().unwrap();
    let bytes = std::fs::read("fixtures/cornell/spp4/color.exr").unwrap();
    let flipped: &[u8] = b"pixelAspectRatio\0flost\0";
    let at = bytes
        .windows(flipped.len())
        .position(|w| w == b"pixelAspectRatio\0float\0")
        .expect("the fixture has a pixel aspect ratio");
    let mut mutant = bytes.clone();
    mutant[at..at + flipped.len()].copy_from_slice(flipped);
    let color = tmp.path().join("mutant.exr");
    std::fs::write(&color, mutant).unwrap();
    let out = tmp.path().join("o.exr");
    let run = gsid(&[
        "denoise",
        "--color",
        color.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "-p",
        "fast",
    ]);
    assert_bad_input(&run, "mutant.exr");
    assert!(
        stderr(&run).contains("pixelAspectRatio"),
        "{}",
        stderr(&run)
    );
    assert!(!out.exists());
}

/// `denoise --help` describes every buffer flag and shows oidnDenoise's names as aliases (the
/// feature flags had blank descriptions and the aliases were hidden).
#[test]
fn help_describes_every_buffer_flag_and_shows_the_oidn_aliases() {
    let run = gsid(&["denoise", "--help"]);
    assert_eq!(run.status.code(), Some(0));
    let help = String::from_utf8_lossy(&run.stdout).into_owned();
    for flag in [
        "--albedo",
        "--normal",
        "--depth",
        "--material",
        "--shadow",
        "--color-b",
    ] {
        let line = help
            .lines()
            .find(|l| l.trim_start().starts_with(flag))
            .unwrap_or_else(|| panic!("{flag} not in help: {help}"));
        let described = line.split("  ").filter(|p| !p.trim().is_empty()).count() > 1;
        assert!(described, "{flag} has no description: `{line}`");
    }
    for alias in ["hdr", "alb", "nrm"] {
        assert!(help.contains(alias), "alias {alias} not shown: {help}");
    }
}

/// A missing input is "not found", naming it (it was "is not a render set folder").
#[test]
fn a_missing_input_is_not_found() {
    let tmp = tempfile::tempdir().unwrap();
    let missing = tmp.path().join("beauty.exr");
    let out = tmp.path().join("o.exr");
    let run = gsid(&[
        "denoise",
        missing.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_bad_input(&run, "beauty.exr");
    assert!(stderr(&run).contains("not found"), "{}", stderr(&run));
}
