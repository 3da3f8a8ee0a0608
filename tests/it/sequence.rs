//! `gsid denoise` over frame sequences and folders of render sets, and `--json`: the binary as a
//! render farm runs it.

use crate::common::*;
use std::path::{Path, PathBuf};

const SRC: &str = "fixtures/cornell/spp4";

/// `shot/beauty.000N.exr` and `shot/albedo.000N.exr` for frames 1–3 (copies of one render, so every
/// frame must come out the same); frame `damaged`, if any, has its colour file cut short.
fn shot(root: &Path, damaged: Option<u32>) -> PathBuf {
    let dir = root.join("shot");
    std::fs::create_dir_all(&dir).unwrap();
    let color = std::fs::read(Path::new(SRC).join("color.exr")).unwrap();
    for n in 1..=3 {
        let bytes = if Some(n) == damaged {
            &color[..color.len() / 3]
        } else {
            &color[..]
        };
        std::fs::write(dir.join(format!("beauty.{n:04}.exr")), bytes).unwrap();
        std::fs::copy(
            Path::new(SRC).join("albedo.exr"),
            dir.join(format!("albedo.{n:04}.exr")),
        )
        .unwrap();
    }
    dir
}

/// `gsid denoise shot/beauty.####.exr --albedo shot/albedo.####.exr -o out/b.####.exr` plus `extra`.
fn sequence(root: &Path, extra: &[&str]) -> std::process::Output {
    let shot = root.join("shot");
    let out = root.join("out");
    std::fs::create_dir_all(&out).unwrap();
    let (beauty, albedo, output) = (
        shot.join("beauty.####.exr"),
        shot.join("albedo.####.exr"),
        out.join("b.####.exr"),
    );
    let mut args = vec![
        "denoise",
        beauty.to_str().unwrap(),
        "--albedo",
        albedo.to_str().unwrap(),
        "-o",
        output.to_str().unwrap(),
        "-p",
        "gsid",
    ];
    args.extend_from_slice(extra);
    gsid(&args)
}

#[test]
fn keep_going_writes_the_good_frames_names_the_bad_one_and_fails_at_the_end() {
    let tmp = tempfile::tempdir().unwrap();
    shot(tmp.path(), Some(2));
    let run = sequence(tmp.path(), &["--keep-going", "-q"]);
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(2), "{err}");
    assert_eq!(
        files_in(&tmp.path().join("out")),
        ["b.0001.exr", "b.0003.exr"],
        "the good frames, and no temporary file"
    );
    let line = err
        .lines()
        .find(|l| l.contains("frame 2:"))
        .unwrap_or_else(|| panic!("no line names frame 2: {err}"));
    assert!(line.contains("beauty.0002.exr"), "{line}");
    assert!(err.contains("1 of 3 frames failed: 2"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn without_keep_going_the_run_stops_at_the_bad_frame() {
    let tmp = tempfile::tempdir().unwrap();
    shot(tmp.path(), Some(2));
    let run = sequence(tmp.path(), &["-q"]);
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(2), "{err}");
    assert_eq!(files_in(&tmp.path().join("out")), ["b.0001.exr"], "{err}");
    assert_eq!(err.lines().count(), 1, "one line: {err}");
    assert!(
        err.contains("frame 2: ") && err.contains("beauty.0002.exr"),
        "{err}"
    );
}

#[test]
fn skip_existing_rerun_reads_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let shot_dir = shot(tmp.path(), None);
    let first = sequence(tmp.path(), &["-q"]);
    assert!(first.status.success(), "{}", stderr(&first));
    let out = tmp.path().join("out");
    let before = snapshot(&out);
    assert_eq!(before.len(), 3);
    // The inputs go: a rerun that read one frame would fail.
    std::fs::remove_dir_all(&shot_dir).unwrap();
    let rerun = sequence(tmp.path(), &["--frames", "1-3", "--skip-existing"]);
    let err = stderr(&rerun);
    assert!(rerun.status.success(), "{err}");
    assert_eq!(err.matches(": skipped, ").count(), 3, "{err}");
    assert!(err.contains("3 skipped"), "{err}");
    assert!(
        snapshot(&out) == before,
        "outputs changed on a --skip-existing rerun"
    );
}

/// Every file of `dir` with its bytes and modification time.
fn snapshot(dir: &Path) -> Vec<(String, Vec<u8>, std::time::SystemTime)> {
    files_in(dir)
        .into_iter()
        .map(|f| {
            let p = dir.join(&f);
            let modified = p.metadata().unwrap().modified().unwrap();
            (f, std::fs::read(&p).unwrap(), modified)
        })
        .collect()
}

#[test]
fn every_frame_equals_its_single_file_run_and_folders_of_sets_too() {
    let tmp = tempfile::tempdir().unwrap();
    let shot_dir = shot(tmp.path(), None);
    let run = sequence(tmp.path(), &["-q"]);
    assert!(run.status.success(), "{}", stderr(&run));
    let single = tmp.path().join("single.exr");
    let one = gsid(&[
        "denoise",
        "--color",
        shot_dir.join("beauty.0002.exr").to_str().unwrap(),
        "--albedo",
        shot_dir.join("albedo.0002.exr").to_str().unwrap(),
        "-o",
        single.to_str().unwrap(),
        "-p",
        "gsid",
        "-q",
    ]);
    assert!(one.status.success(), "{}", stderr(&one));
    let single = std::fs::read(&single).unwrap();
    for n in 1..=3 {
        let frame = std::fs::read(tmp.path().join(format!("out/b.{n:04}.exr"))).unwrap();
        assert!(
            frame == single,
            "frame {n} differs from the single-file run: the same render, settings and seed must give the same bits"
        );
    }

    // A folder of render-set folders: each set as its own run would write it.
    let sets = tmp.path().join("sets");
    for name in ["spp1", "spp4"] {
        copy_dir(&Path::new("fixtures/cornell").join(name), &sets.join(name));
    }
    std::fs::create_dir_all(sets.join("notes")).unwrap(); // not a render set: passed over
    let outdir = tmp.path().join("denoised");
    let run = gsid(&[
        "denoise",
        sets.to_str().unwrap(),
        "-o",
        outdir.to_str().unwrap(),
        "-p",
        "gsid",
        "-q",
        "--json",
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    assert_eq!(files_in(&outdir), ["spp1.exr", "spp4.exr"]);
    let json: serde_json::Value = serde_json::from_slice(&run.stdout).expect("stdout is JSON");
    assert_eq!(
        json["frames"][0]["frame"], "spp1",
        "a render set's name stays a string"
    );
    let alone = tmp.path().join("alone.exr");
    let one = gsid(&[
        "denoise",
        sets.join("spp4").to_str().unwrap(),
        "-o",
        alone.to_str().unwrap(),
        "-p",
        "gsid",
        "-q",
    ]);
    assert!(one.status.success(), "{}", stderr(&one));
    assert!(std::fs::read(outdir.join("spp4.exr")).unwrap() == std::fs::read(&alone).unwrap());
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
    }
}

#[test]
fn an_output_without_the_frame_token_is_refused_before_any_work() {
    let tmp = tempfile::tempdir().unwrap();
    let shot_dir = shot(tmp.path(), None);
    let out = tmp.path().join("out.exr");
    let run = gsid(&[
        "denoise",
        shot_dir.join("beauty.####.exr").to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_bad_input(&run, "frame token");
    assert!(!out.exists());
    let run = gsid(&[
        "denoise",
        shot_dir.join("beauty.####.exr").to_str().unwrap(),
        "-o",
        tmp.path().join("o.####.exr").to_str().unwrap(),
        "--frames",
        "3-1",
    ]);
    assert_bad_input(&run, "--frames");
    assert_eq!(files_in(tmp.path()), ["shot"]);
}

#[test]
fn json_is_one_object_on_stdout_for_a_frame_and_for_a_sequence() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out.exr");
    let run = gsid(&[
        "denoise",
        SRC,
        "-o",
        out.to_str().unwrap(),
        "-p",
        "gsid",
        "--json",
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    assert!(stderr(&run).contains("→"), "the human lines stay on stderr");
    let json: serde_json::Value = serde_json::from_slice(&run.stdout).expect("stdout is JSON");
    for key in [
        "pipeline",
        "seed",
        "status",
        "input",
        "inputs",
        "stages",
        "seconds",
        "sanitized",
        "notes",
        "output",
    ] {
        assert!(json.get(key).is_some(), "no `{key}` in {json}");
    }
    assert_eq!(json["status"], "done");
    assert_eq!(
        json["version"],
        env!("CARGO_PKG_VERSION"),
        "the gsid that wrote it"
    );
    assert_eq!(json["pipeline"]["name"], "gsid");
    assert_eq!(json["pipeline"]["stages"][0], "gsid");
    assert_eq!(json["output"], out.to_str().unwrap());
    assert_eq!(json["inputs"][0]["buffer"], "color");
    assert!(json["stages"][0]["seconds"].as_f64().unwrap() > 0.0);
    assert!(json["sanitized"]["depth_background"].as_u64().unwrap() > 0);

    shot(tmp.path(), Some(3));
    let run = sequence(tmp.path(), &["--json", "--keep-going", "-q"]);
    assert_eq!(run.status.code(), Some(2), "{}", stderr(&run));
    let json: serde_json::Value = serde_json::from_slice(&run.stdout).expect("stdout is JSON");
    let frames = json["frames"].as_array().unwrap();
    let status: Vec<_> = frames
        .iter()
        .map(|f| f["status"].as_str().unwrap())
        .collect();
    assert_eq!(status, ["done", "done", "failed"]);
    assert_eq!(json["version"], env!("CARGO_PKG_VERSION"));
    // Frame numbers are numbers, in the frames and in the failed list alike.
    assert_eq!(frames[0]["frame"], 1);
    assert_eq!(frames[1]["inputs"][1]["buffer"], "albedo");
    assert!(frames[2]["error"]
        .as_str()
        .unwrap()
        .contains("beauty.0003.exr"));
    assert_eq!(json["failed"], serde_json::json!([3]));
}

#[test]
fn noise_buffers_take_the_frame_and_every_frame_gets_the_output_options() {
    let tmp = tempfile::tempdir().unwrap();
    let shot_dir = shot(tmp.path(), None);
    let copy = |from: &str, to: String| {
        std::fs::copy(Path::new(SRC).join(from), shot_dir.join(to)).unwrap();
    };
    // Frame 2 has no variance: only a per-frame path can make that frame alone fail.
    for n in [1, 3] {
        copy("variance.exr", format!("variance.{n:04}.exr"));
    }
    for n in 1..=3 {
        copy("color_a.exr", format!("half_a.{n:04}.exr"));
        copy("color_b.exr", format!("half_b.{n:04}.exr"));
    }
    let inputs = |frame: &str| {
        ["beauty", "variance", "half_a", "half_b"].map(|name| {
            shot_dir
                .join(format!("{name}.{frame}.exr"))
                .display()
                .to_string()
        })
    };
    let denoise = |frame: &str, output: &Path, extra: &[&str]| {
        let [color, variance, a, b] = inputs(frame);
        let mut args = vec![
            "denoise",
            "--color",
            &color,
            "--variance",
            &variance,
            "--color-a",
            &a,
            "--color-b",
            &b,
            "-o",
            output.to_str().unwrap(),
            "--half",
            "--compression",
            "zip",
            "-p",
            "gsid",
            "-q",
        ];
        args.extend_from_slice(extra);
        gsid(&args)
    };
    let out = tmp.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    let run = denoise("####", &out.join("d.####.exr"), &["--keep-going", "--json"]);
    assert_eq!(run.status.code(), Some(2), "{}", stderr(&run));
    assert_eq!(files_in(&out), ["d.0001.exr", "d.0003.exr"]);
    let json: serde_json::Value = serde_json::from_slice(&run.stdout).expect("stdout is JSON");
    let frames = json["frames"].as_array().unwrap();
    assert!(
        frames[1]["error"]
            .as_str()
            .unwrap()
            .contains("variance.0002.exr"),
        "{}",
        frames[1]
    );
    let loaded: Vec<(&str, &str)> = frames[2]["inputs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|i| (i["buffer"].as_str().unwrap(), i["file"].as_str().unwrap()))
        .collect();
    let [color, variance, a, b] = inputs("0003");
    assert_eq!(
        loaded,
        [
            ("color", color.as_str()),
            ("variance", variance.as_str()),
            ("color_a", a.as_str()),
            ("color_b", b.as_str()),
        ]
    );

    let single = tmp.path().join("single.exr");
    let one = denoise("0003", &single, &[]);
    assert!(one.status.success(), "{}", stderr(&one));
    assert!(
        std::fs::read(out.join("d.0003.exr")).unwrap() == std::fs::read(&single).unwrap(),
        "a frame must be written as its single run writes it (--half, --compression)"
    );
}

#[test]
fn an_ldr_colour_takes_the_frame() {
    let tmp = tempfile::tempdir().unwrap();
    let shot_dir = tmp.path().join("shot");
    std::fs::create_dir_all(&shot_dir).unwrap();
    let preview = shot_dir.join("beauty.0001.png");
    let made = gsid(&[
        "denoise",
        SRC,
        "-o",
        preview.to_str().unwrap(),
        "-p",
        "gsid",
        "-q",
    ]);
    assert!(made.status.success(), "{}", stderr(&made));
    std::fs::copy(&preview, shot_dir.join("beauty.0002.png")).unwrap();
    let out = tmp.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    let run = gsid(&[
        "denoise",
        "--ldr",
        shot_dir.join("beauty.####.png").to_str().unwrap(),
        "-o",
        out.join("l.####.exr").to_str().unwrap(),
        "-p",
        "gsid",
        "-q",
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    assert_eq!(files_in(&out), ["l.0001.exr", "l.0002.exr"]);
}
