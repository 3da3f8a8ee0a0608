//! What `gsid denoise` prints on stderr while it works without a terminal (a render farm's log):
//! progress lines in the documented form (`gsid::cli::meter::LINE_REGEX`), arriving as the frame
//! runs, and the verbosity levels.

use crate::common::*;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::Stdio;

use gsid::cli::meter::LINE_REGEX;
use gsid::{Buffers, Image};

fn line_regex() -> regex::Regex {
    regex::Regex::new(LINE_REGEX).unwrap()
}

/// The progress lines of `stderr`, as (frame percent, run percent, stage).
fn progress_lines(stderr: &str) -> Vec<(u32, u32, String)> {
    let re = line_regex();
    stderr
        .lines()
        .filter_map(|l| re.captures(l))
        .map(|c| {
            (
                c[2].parse().unwrap(),
                c[5].parse().unwrap(),
                c[6].to_string(),
            )
        })
        .collect()
}

#[test]
fn progress_lines_arrive_while_a_2048_square_frame_runs() {
    let tmp = tempfile::tempdir().unwrap();
    let set = tmp.path().join("big");
    // The colour alone: the frame's size is what matters, and a smaller set is quicker to write and read.
    let mut buffers = Buffers::new();
    let noise =
        |x: usize, y: usize, c: usize| ((x * 7919 + y * 104729 + c * 31) % 97) as f32 / 97.0;
    buffers
        .insert(
            "color",
            Image::from_fn(2048, 2048, 3, |x, y, c| 0.2 + 0.3 * noise(x, y, c)),
        )
        .unwrap();
    write_set(&set, &buffers);
    let out = tmp.path().join("out.exr");
    let mut child = gsid_command()
        .args([
            "denoise",
            set.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ])
        .args(["-p", "fast", "--progress-every", "0"])
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    let re = line_regex();
    let mut lines = Vec::new();
    // Whether the output existed when the first line from inside the frame (between 0 and 100 %) was read.
    let mut first_inside: Option<bool> = None;
    for line in BufReader::new(child.stderr.take().unwrap()).lines() {
        let line = line.unwrap();
        if let Some(c) = re.captures(&line) {
            let pct: u32 = c[2].parse().unwrap();
            if first_inside.is_none() && pct > 0 && pct < 100 {
                first_inside = Some(out.exists());
            }
        }
        lines.push(line);
    }
    let status = child.wait().unwrap();
    let all = lines.join("\n");
    assert!(status.success(), "{all}");
    assert_eq!(
        first_inside,
        Some(false),
        "a progress line inside the frame, read before the output was written: {all}"
    );
    let progress = progress_lines(&all);
    let stages: Vec<&str> = progress.iter().map(|(_, _, s)| s.as_str()).collect();
    assert_eq!(stages.first(), Some(&"read"), "{all}");
    assert!(
        stages.contains(&"outlier") && stages.contains(&"write"),
        "{all}"
    );
    assert_eq!(
        progress.last().map(|p| (p.0, p.1)),
        Some((100, 100)),
        "{all}"
    );
    assert_eq!(stages.last(), Some(&"done"), "{all}");
    let runs: Vec<u32> = progress.iter().map(|p| p.1).collect();
    assert!(
        runs.windows(2).all(|w| w[0] <= w[1]),
        "never backwards: {runs:?}"
    );
}

/// A three-frame shot of the Cycles crop in `dir`, frames 1001–1003.
fn shot(dir: &Path) -> String {
    std::fs::create_dir_all(dir).unwrap();
    for n in 1..=3u32 {
        let from = format!("fixtures/cycles-static-small/spp4/frame.{n:04}.exr");
        std::fs::copy(from, dir.join(format!("frame.{:04}.exr", 1000 + n))).unwrap();
    }
    dir.join("frame.####.exr").display().to_string()
}

#[test]
fn a_sequence_says_which_frame_of_how_many_and_ends_each_frame_with_a_line() {
    let tmp = tempfile::tempdir().unwrap();
    let input = shot(&tmp.path().join("shot"));
    std::fs::create_dir_all(tmp.path().join("out")).unwrap();
    let output = tmp.path().join("out/d.####.exr");
    let run = gsid(&[
        "denoise",
        &input,
        "-o",
        output.to_str().unwrap(),
        "-p",
        "fast",
    ]);
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(0), "{err}");
    let re = line_regex();
    let ends: Vec<(String, String, String, String)> = err
        .lines()
        .filter_map(|l| re.captures(l))
        .filter(|c| &c[6] == "done")
        .map(|c| {
            (
                c[1].to_string(),
                c[3].to_string(),
                c[4].to_string(),
                c[5].to_string(),
            )
        })
        .collect();
    let want = |f: &str, i: &str, run: &str| (f.into(), i.into(), "3".into(), run.into());
    assert_eq!(
        ends,
        [
            want("1001", "1", "33"),
            want("1002", "2", "66"),
            want("1003", "3", "100")
        ],
        "{err}"
    );
    // A re-run that skips every frame still ends each with its line.
    let again = gsid(&[
        "denoise",
        &input,
        "-o",
        output.to_str().unwrap(),
        "--skip-existing",
    ]);
    let skipped = progress_lines(&stderr(&again));
    assert_eq!(
        skipped.iter().filter(|p| p.2 == "skipped").count(),
        3,
        "{}",
        stderr(&again)
    );
}

#[test]
fn verbosity_goes_from_errors_only_to_every_step() {
    let tmp = tempfile::tempdir().unwrap();
    let input = shot(&tmp.path().join("shot"));
    let run = |n: usize, extra: &[&str]| {
        std::fs::create_dir_all(tmp.path().join(format!("out{n}"))).unwrap();
        let output = tmp.path().join(format!("out{n}/d.####.exr"));
        let mut args = vec![
            "denoise",
            &input,
            "-o",
            output.to_str().unwrap(),
            "-p",
            "fast",
        ];
        args.extend_from_slice(extra);
        let out = gsid(&args);
        assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
        stderr(&out)
    };
    let quiet = run(0, &["-q"]);
    assert_eq!(quiet, "", "-q prints nothing but errors");
    let normal = run(1, &[]);
    let verbose = run(2, &["-v"]);
    let debug = run(3, &["-vv"]);
    assert!(!progress_lines(&normal).is_empty(), "{normal}");
    assert!(normal.contains("3 frames: 3 denoised"), "{normal}");
    let stage_times = |text: &str| text.lines().any(|l| l.ends_with(" M walk steps"));
    assert!(!stage_times(&normal), "no stage times by default: {normal}");
    assert!(!normal.contains("debug:"), "{normal}");
    assert!(
        verbose.contains("pipeline fast ("),
        "the run's setup: {verbose}"
    );
    assert!(stage_times(&verbose), "stage times: {verbose}");
    assert!(!verbose.contains("debug:"), "{verbose}");
    assert!(
        debug.contains("debug:") && debug.contains("stage regress"),
        "{debug}"
    );
    assert!(debug.lines().count() > verbose.lines().count(), "{debug}");
    let both = gsid(&["denoise", &input, "-o", "x.####.exr", "-q", "-v"]);
    assert_eq!(both.status.code(), Some(2), "-q and -v conflict");
}
