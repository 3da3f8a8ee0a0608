//! The farm job files under `farm/`, run as far as this machine allows: the Open Job Description
//! template with `openjd run` (from the CI venv), the OpenCue task command through `sh`, the Flamenco
//! job type's `compileJob` under node with Flamenco's functions stubbed, and the Deadline plugin's
//! progress regex against gsid's own lines.
//!
//! The venv is `GSID_CI_VENV` (`.ci/run` sets it), else `target/ci-venv`; without one, the tests
//! that need it say "skipped: no venv" and pass, except under `CI=true`, where they fail.

use crate::common::*;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::SystemTime;

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// The venv's `openjd`, or `None` (after saying why) when there is none outside CI.
fn openjd() -> Option<PathBuf> {
    let venv = std::env::var_os("GSID_CI_VENV")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(ROOT).join("target/ci-venv"));
    let bin = venv.join("bin/openjd");
    if bin.is_file() {
        return Some(bin);
    }
    let why = format!(
        "no venv with openjd-cli at {} (GSID_CI_VENV)",
        venv.display()
    );
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!("{why}: .ci/run installs it");
    }
    eprintln!("skipped: no venv: {why}");
    None
}

/// The gsid binary the tests run, as an absolute path.
fn gsid_bin() -> String {
    let bin = std::env::var("GSID_BIN").unwrap_or_else(|_| env!("CARGO_BIN_EXE_gsid").into());
    std::fs::canonicalize(bin).unwrap().display().to_string()
}

/// An 8-frame static shot, frames 1001–1008, from the five frames of `fixtures/cycles-static-small`.
fn eight_frame_shot(dir: &Path) -> String {
    std::fs::create_dir_all(dir).unwrap();
    for i in 0..8u32 {
        let from = format!(
            "fixtures/cycles-static-small/spp4/frame.{:04}.exr",
            i % 5 + 1
        );
        std::fs::copy(from, dir.join(format!("frame.{}.exr", 1001 + i))).unwrap();
    }
    dir.join("frame.####.exr").display().to_string()
}

fn snapshot(dir: &Path) -> Vec<(String, Vec<u8>, SystemTime)> {
    files_in(dir)
        .into_iter()
        .map(|f| {
            let p = dir.join(&f);
            let modified = p.metadata().unwrap().modified().unwrap();
            (f, std::fs::read(&p).unwrap(), modified)
        })
        .collect()
}

fn text(out: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

#[test]
fn the_openjd_template_in_three_chunks_equals_one_whole_shot_run_and_a_rerun_does_nothing() {
    let Some(openjd) = openjd() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let tmp = tmp.path().canonicalize().unwrap();
    let input = eight_frame_shot(&tmp.join("shot"));
    let whole = tmp.join("whole");
    std::fs::create_dir_all(&whole).unwrap();
    let common = ["-p", "fast", "--temporal", "1"];
    let one = gsid(
        &[
            &[
                "denoise",
                &input,
                "-o",
                whole.join("d.####.exr").to_str().unwrap(),
                "-q",
            ][..],
            &common,
        ]
        .concat(),
    );
    assert!(one.status.success(), "{}", stderr(&one));
    let chunked = tmp.join("chunked");
    let output = chunked.join("d.####.exr").display().to_string();
    let params = [
        format!("GsidBinary={}", gsid_bin()),
        format!("InputPattern={input}"),
        format!("OutputPattern={output}"),
        "Frames=1001-1008".into(),
        "ChunkSize=3".into(),
        "Pipeline=fast".into(),
        "Temporal=1".into(),
        "Threads=0".into(),
    ];
    let run = || {
        let mut cmd = Command::new(&openjd);
        cmd.arg("run")
            .arg(Path::new(ROOT).join("farm/gsid-denoise.openjd.yaml"));
        for p in &params {
            cmd.args(["-p", p]);
        }
        cmd.current_dir(&tmp).output().unwrap()
    };
    let first = run();
    let log = text(&first);
    assert!(first.status.success(), "{log}");
    assert!(
        log.contains("Chunks run: 3"),
        "three chunks of 3, 3 and 2 frames: {log}"
    );
    for chunk in ["1001-1003", "1004-1006", "1007-1008"] {
        assert!(
            log.contains(&format!("denoising frames {chunk} ")),
            "{chunk}: {log}"
        );
    }
    assert!(
        log.contains("openjd_progress: 100"),
        "gsid's lines become the task's progress: {log}"
    );
    let want = snapshot(&whole);
    assert_eq!(want.len(), 8);
    let got = snapshot(&chunked);
    assert_eq!(
        got.iter().map(|f| &f.0).collect::<Vec<_>>(),
        want.iter().map(|f| &f.0).collect::<Vec<_>>()
    );
    for (g, w) in got.iter().zip(&want) {
        assert!(g.1 == w.1, "{} differs from the whole-shot run", g.0);
    }
    // A requeue of the whole job: every frame is skipped, nothing is read or written.
    let again = run();
    let log = text(&again);
    assert!(again.status.success(), "{log}");
    assert_eq!(
        snapshot(&chunked),
        got,
        "outputs untouched, mtimes unchanged"
    );
    assert_eq!(log.matches(": skipped, ").count(), 8, "{log}");
    assert_eq!(
        log.matches(" 0 denoised, ").count(),
        3,
        "no chunk denoised a frame: {log}"
    );
}

/// The line of `file` that starts with `key = r"`, as the raw string it holds.
fn python_raw_string(file: &str, key: &str) -> String {
    let text = std::fs::read_to_string(Path::new(ROOT).join(file)).unwrap();
    let start = format!("{key} = r\"");
    let line = text.lines().find(|l| l.starts_with(&start)).unwrap();
    line[start.len()..line.len() - 1].to_string()
}

#[test]
fn the_deadline_progress_regex_reads_the_run_percent_from_real_output() {
    let re = regex::Regex::new(&python_raw_string(
        "farm/deadline/GsidDenoise/GsidDenoise.py",
        "PROGRESS_REGEX",
    ))
    .unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let input = eight_frame_shot(&tmp.path().join("shot"));
    std::fs::create_dir_all(tmp.path().join("out")).unwrap();
    let output = tmp.path().join("out/d.####.exr");
    // As Deadline runs it: no terminal, a chunk of frames.
    let run = gsid(&[
        "denoise",
        &input,
        "-o",
        output.to_str().unwrap(),
        "--frames",
        "1001-1004",
        "-p",
        "fast",
        "--progress-every",
        "0",
    ]);
    let err = stderr(&run);
    assert!(run.status.success(), "{err}");
    let documented = regex::Regex::new(gsid::cli::meter::LINE_REGEX).unwrap();
    let mut percents = Vec::new();
    for line in err.lines() {
        match (re.captures(line), documented.captures(line)) {
            (Some(deadline), Some(doc)) => {
                assert_eq!(&deadline[1], &doc[5], "{line}");
                percents.push(deadline[1].parse::<u32>().unwrap());
            }
            (None, None) => {}
            _ => panic!("the Deadline regex and the documented one disagree on: {line}"),
        }
    }
    assert!(percents.len() > 8, "{err}");
    assert!(percents.windows(2).all(|w| w[0] <= w[1]), "{percents:?}");
    assert_eq!(percents.last(), Some(&100));
    assert!(
        percents.contains(&25) && percents.contains(&50),
        "a frame's end is a quarter: {percents:?}"
    );
}

#[test]
fn the_opencue_task_command_runs_one_frame_with_the_booked_threads() {
    let tmp = tempfile::tempdir().unwrap();
    let tmp = tmp.path().canonicalize().unwrap();
    let input = eight_frame_shot(&tmp.join("shot"));
    std::fs::create_dir_all(tmp.join("out")).unwrap();
    let output = tmp.join("out/d.####.exr").display().to_string();
    let printed = Command::new("python3")
        .arg(Path::new(ROOT).join("farm/opencue/denoise_shot.py"))
        .args([
            "--gsid",
            &gsid_bin(),
            "--input",
            &input,
            "--output",
            &output,
        ])
        .args(["--frames", "1001-1008", "--pipeline", "fast", "--print"])
        .output()
        .unwrap();
    assert!(printed.status.success(), "{}", text(&printed));
    let cmd = String::from_utf8(printed.stdout).unwrap();
    assert!(cmd.contains("#IFRAME#"), "{cmd}");
    // What RQD does with the layer's command on frame 1003, having booked 1 core.
    let task = cmd.trim().replace("#IFRAME#", "1003");
    let run = Command::new("/bin/sh")
        .args(["-c", &task])
        .env("CUE_THREADS", "1")
        .output()
        .unwrap();
    let log = text(&run);
    assert!(run.status.success(), "{log}");
    assert_eq!(files_in(&tmp.join("out")), ["d.1003.exr"], "{log}");
    let relative = Command::new("python3")
        .arg(Path::new(ROOT).join("farm/opencue/denoise_shot.py"))
        .args(["--gsid", "gsid", "--input", &input, "--output", &output])
        .args(["--frames", "1", "--print"])
        .output()
        .unwrap();
    assert_eq!(relative.status.code(), Some(2), "a bare `gsid` is refused");
}

#[test]
fn the_flamenco_job_type_compiles_to_chunks_that_run() {
    if Command::new("node").arg("--version").output().is_err() {
        eprintln!("skipped: no node");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let tmp = tmp.path().canonicalize().unwrap();
    let input = eight_frame_shot(&tmp.join("shot"));
    std::fs::create_dir_all(tmp.join("out")).unwrap();
    let output = tmp.join("out/d.####.exr").display().to_string();
    // Flamenco's job compiler functions, stubbed: `frameChunker` as Flamenco writes chunks
    // (`1001-1003`), `author` recording each task's command.
    let harness = format!(
        r#"
const fs = require("fs");
function frameChunker(frames, size) {{
    const [a, b] = frames.split("-").map(Number);
    const chunks = [];
    for (let s = a; s <= b; s += size) {{
        const e = Math.min(b, s + size - 1);
        chunks.push(s == e ? `${{s}}` : `${{s}}-${{e}}`);
    }}
    return chunks;
}}
const author = {{
    Task: (name, type) => ({{ name, type, commands: [], addCommand(c) {{ this.commands.push(c); }} }}),
    Command: (name, params) => ({{ name, params }}),
}};
eval(fs.readFileSync({script:?}, "utf8"));
const job = {{ settings: {{ gsid: {gsid:?}, input: {input:?}, output: {output:?}, frames: "1001-1008",
    chunk_size: 3, pipeline: "fast", temporal: 1, threads: 2 }}, tasks: [], addTask(t) {{ this.tasks.push(t); }} }};
compileJob(job);
console.log(JSON.stringify(job.tasks));
"#,
        script = Path::new(ROOT)
            .join("farm/flamenco/gsid_denoise.js")
            .display()
            .to_string(),
        gsid = gsid_bin(),
    );
    let compiled = Command::new("node")
        .args(["-e", &harness])
        .output()
        .unwrap();
    assert!(compiled.status.success(), "{}", text(&compiled));
    let tasks: serde_json::Value = serde_json::from_slice(&compiled.stdout).unwrap();
    let tasks = tasks.as_array().unwrap();
    assert_eq!(tasks.len(), 3, "{tasks:?}");
    for task in tasks {
        let params = &task["commands"][0]["params"];
        assert_eq!(task["commands"][0]["name"], "exec");
        let exe = params["exe"].as_str().unwrap();
        let args: Vec<&str> = params["args"]
            .as_array()
            .unwrap()
            .iter()
            .map(|a| a.as_str().unwrap())
            .collect();
        let run = Command::new(exe).args(&args).output().unwrap();
        assert!(run.status.success(), "{args:?}: {}", text(&run));
    }
    assert_eq!(files_in(&tmp.join("out")).len(), 8);
}
