//! `gsid sweep`: the files it writes, bad input (exit 2, one line, nothing written), and the Pareto
//! front it marks (property-tested).

use std::path::Path;
use std::process::{Command, Output};

use crate::common::*;
use gsid::study::sweep::{dominates, pareto_front};
use proptest::prelude::*;

const SET: &str = "fixtures/mitsuba-cornell/spp4";

/// `gsid ARGS` run from `cwd` (so the default `sweep-out` lands in a temporary folder).
fn gsid_in(cwd: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gsid"))
        .args(args)
        .current_dir(cwd)
        .output()
        .expect("run gsid")
}

/// A 2×2 sweep of the single-scale pipeline on the 128×128 fixture: 4 fast runs.
fn small_sweep(cwd: &Path, extra: &[&str]) -> Output {
    let set = Path::new(env!("CARGO_MANIFEST_DIR")).join(SET);
    let mut args = vec![
        "sweep",
        set.to_str().unwrap(),
        "--pipeline",
        "gsid",
        "--vary",
        "gsid.walks=2,4",
        "--vary",
        "gsid.sigma=0.5,1.0",
        "--repeat",
        "1",
        "-q",
    ];
    args.extend_from_slice(extra);
    gsid_in(cwd, &args)
}

fn parse_csv(text: &str) -> (Vec<String>, Vec<Vec<String>>) {
    // Labels never hold commas (so they are not quoted), so a plain split is enough here.
    let split = |l: &str| l.split(',').map(String::from).collect();
    let mut lines = text.lines();
    let header = split(lines.next().expect("header"));
    (header, lines.map(split).collect())
}

#[test]
fn sweep_writes_csv_png_and_svg() {
    let tmp = tempfile::tempdir().unwrap();
    let run = small_sweep(tmp.path(), &[]);
    assert!(run.status.success(), "{}", stderr(&run));
    let out = tmp.path().join("sweep-out");
    assert_eq!(
        files_in(&out),
        ["sweep.csv", "sweep.png", "sweep.svg"],
        "the default folder, and no temporary files left"
    );

    let (header, rows) = parse_csv(&std::fs::read_to_string(out.join("sweep.csv")).unwrap());
    assert_eq!(
        header,
        [
            "label",
            "gsid.walks",
            "gsid.sigma",
            "seconds",
            "seconds_min",
            "seconds_max",
            "ssim",
            "psnr",
            "relmse",
            "walk_steps",
            "pareto"
        ]
    );
    // One row per combination, the first --vary slowest.
    let settings: Vec<(&str, &str, &str)> = rows
        .iter()
        .map(|r| (r[0].as_str(), r[1].as_str(), r[2].as_str()))
        .collect();
    assert_eq!(
        settings,
        [
            ("walks=2 sigma=0.5", "2", "0.5"),
            ("walks=2 sigma=1.0", "2", "1.0"),
            ("walks=4 sigma=0.5", "4", "0.5"),
            ("walks=4 sigma=1.0", "4", "1.0"),
        ]
    );
    let num = |r: &Vec<String>, i: usize| r[i].parse::<f64>().unwrap();
    for r in &rows {
        let (t, t0, t1) = (num(r, 3), num(r, 4), num(r, 5));
        assert!(t > 0.0 && t0 <= t && t <= t1, "{r:?}");
        assert!((0.0..=1.0).contains(&num(r, 6)), "{r:?}");
        assert!(num(r, 9) > 0.0, "walk steps: {r:?}");
    }
    // More walks walk more steps.
    assert!(num(&rows[2], 9) > num(&rows[0], 9));
    let marked: Vec<bool> = rows.iter().map(|r| r[10] == "true").collect();
    assert!(marked.iter().any(|&m| m), "{rows:?}");
    let points: Vec<(f64, f64)> = rows.iter().map(|r| (num(r, 3), num(r, 6))).collect();
    assert_eq!(marked, pareto_front(&points));

    let png = image::open(out.join("sweep.png")).expect("the PNG decodes");
    assert_eq!((png.width(), png.height()), (1000, 680));
    let svg = std::fs::read_to_string(out.join("sweep.svg")).unwrap();
    assert!(svg.contains("<svg") && svg.contains("walks=4 sigma=0.5"));

    let table = String::from_utf8_lossy(&run.stdout);
    assert!(
        table.contains("walks=2 sigma=0.5") && table.contains('*'),
        "{table}"
    );
    assert!(
        table.contains("sweep.csv"),
        "says where the files went: {table}"
    );

    // Same inputs and seed: the same scores and steps (only the times differ), into --out.
    let again = tmp.path().join("again");
    let run = small_sweep(tmp.path(), &["--out", again.to_str().unwrap()]);
    assert!(run.status.success(), "{}", stderr(&run));
    let (_, rows2) = parse_csv(&std::fs::read_to_string(again.join("sweep.csv")).unwrap());
    let scores = |rows: &[Vec<String>]| -> Vec<Vec<String>> {
        rows.iter()
            .map(|r| [0, 6, 7, 8, 9].iter().map(|&i| r[i].clone()).collect())
            .collect()
    };
    assert_eq!(scores(&rows), scores(&rows2));
}

#[test]
fn bad_input_exits_2_with_one_line_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let out_arg = out.to_str().unwrap();
    let set = Path::new(env!("CARGO_MANIFEST_DIR")).join(SET);
    let set = set.to_str().unwrap();
    let many = format!(
        "gsid.walks={}",
        (1..=120)
            .map(|n| n.to_string())
            .collect::<Vec<_>>()
            .join(",")
    );
    let many_sigma = format!(
        "gsid.sigma={}",
        (1..=120)
            .map(|n| format!("0.{n:03}"))
            .collect::<Vec<_>>()
            .join(",")
    );
    let cases: &[(&[&str], &str)] = &[
        (&["--vary", "gsid.walkz=2,4"], "gsid.walkz"),
        (&["--vary", "gsid.walks=4,-1"], "gsid.walks=-1"),
        (&["--vary", "gsid.walks=abc"], "gsid.walks=abc"),
        (&["--vary", "gsid.walks"], "gsid.walks"),
        (&["--vary", "gsid.walks="], "gsid.walks"),
        (&["--vary", "gsid.walks=2,,4"], "gsid.walks"),
        (&["--vary", "nostage.walks=2"], "nostage"),
        (
            &["--vary", "gsid.walks=2", "--vary", "gsid.walks=4"],
            "gsid.walks",
        ),
        (&["--vary", "gsid.walks=2", "--repeat", "0"], "--repeat"),
        // Refused before allocating a table of 4 G runs (it aborted).
        (
            &["--vary", "gsid.walks=2", "--repeat", "4294967295"],
            "--repeat",
        ),
        // 120 × 120 settings: refused before building any (3.6 M took 7.7 GB).
        (&["--vary", &many, "--vary", &many_sigma], "--vary"),
        (&[], "--vary"),
    ];
    for (extra, culprit) in cases {
        let mut args = vec!["sweep", set, "-p", "gsid", "--out", out_arg];
        args.extend_from_slice(extra);
        let run = gsid(&args);
        assert_bad_input(&run, culprit);
        assert!(!out.exists(), "{extra:?} left {out:?} behind");
    }

    // No reference: named by the folder; an existing --out folder stays empty.
    let lone = tmp.path().join("lone");
    write_set(&lone, &synthetic_set(8, 8));
    std::fs::create_dir(&out).unwrap();
    let run = gsid(&[
        "sweep",
        lone.to_str().unwrap(),
        "-p",
        "gsid",
        "--vary",
        "gsid.walks=2,4",
        "--out",
        out_arg,
    ]);
    assert_bad_input(&run, lone.to_str().unwrap());
    assert!(stderr(&run).contains("reference"), "{}", stderr(&run));
    assert!(files_in(&out).is_empty(), "{:?}", files_in(&out));
}

fn points() -> impl Strategy<Value = Vec<(f64, f64)>> {
    // Few distinct values, so ties in one coordinate or both are common.
    prop::collection::vec((1u32..8, 0u32..8), 0..24).prop_map(|v| {
        v.into_iter()
            .map(|(t, s)| (t as f64 * 0.25, s as f64 / 8.0))
            .collect()
    })
}

proptest! {
    #[test]
    fn the_front_is_exactly_the_non_dominated_points(pts in points()) {
        let front = pareto_front(&pts);
        prop_assert_eq!(front.len(), pts.len());
        for (i, &p) in pts.iter().enumerate() {
            if front[i] {
                // Front points do not dominate each other (nor does anything else dominate them).
                prop_assert!(!pts.iter().any(|&q| dominates(q, p)), "{:?} is dominated", p);
            } else {
                // A point off the front is dominated by a point on it.
                prop_assert!(
                    pts.iter().zip(&front).any(|(&q, &on)| on && dominates(q, p)),
                    "no front point dominates {:?}", p
                );
            }
        }
        if let Some(t_min) = pts.iter().map(|p| p.0).min_by(f64::total_cmp) {
            // The fastest point with the best SSIM among the fastest is on the front, and so is the
            // fastest of the best-SSIM points.
            let best_fast = pts.iter().filter(|p| p.0 == t_min).map(|p| p.1).fold(f64::MIN, f64::max);
            let s_max = pts.iter().map(|p| p.1).fold(f64::MIN, f64::max);
            let fast_best = pts.iter().filter(|p| p.1 == s_max).map(|p| p.0).fold(f64::MAX, f64::min);
            for (i, &p) in pts.iter().enumerate() {
                if p == (t_min, best_fast) || p == (fast_best, s_max) {
                    prop_assert!(front[i], "{:?} should be on the front", p);
                }
            }
        }
        // Identical points share their fate.
        for i in 0..pts.len() {
            for j in 0..pts.len() {
                if pts[i] == pts[j] {
                    prop_assert_eq!(front[i], front[j]);
                }
            }
        }
    }

    #[test]
    fn the_front_does_not_depend_on_order(pts in points(), k in 0usize..24) {
        let k = if pts.is_empty() { 0 } else { k % pts.len() };
        let mut rotated = pts.clone();
        rotated.rotate_left(k);
        let mut expect = pareto_front(&pts);
        expect.rotate_left(k);
        prop_assert_eq!(pareto_front(&rotated), expect);
    }
}

/// A sweep stopped by SIGTERM removes the `--out` folder it created (it stayed, empty), and exits
/// 143; an `--out` folder that was already there stays.
#[test]
fn a_stopped_sweep_leaves_no_folder_it_made() {
    let tmp = tempfile::tempdir().unwrap();
    let set = tmp.path().join("set");
    let buffers = synthetic_set(384, 384);
    write_set(&set, &buffers);
    gsid::io::write_exr(&set.join("reference.exr"), buffers.get("color").unwrap()).unwrap();
    for existed in [false, true] {
        let out = tmp.path().join(format!("sweep{existed}"));
        if existed {
            std::fs::create_dir(&out).unwrap();
        }
        let child = gsid_command()
            .args(["sweep", set.to_str().unwrap(), "-p", "full", "-q"])
            .args([
                "--vary",
                "pyramid.gsid.walks=1,2,3,4",
                "--repeat",
                "50",
                "--out",
            ])
            .arg(&out)
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        // Until the folder is made (the inputs are read first), then a little into the work.
        let start = std::time::Instant::now();
        while !out.exists() && start.elapsed().as_secs() < 20 {
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        std::thread::sleep(std::time::Duration::from_millis(500));
        // SAFETY: kill sends a signal to the child we started; no memory-safety preconditions.
        assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGTERM) }, 0);
        let done = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&done.stderr);
        assert_eq!(done.status.code(), Some(143), "{err}");
        assert_eq!(out.exists(), existed, "existed before: {existed}");
        if existed {
            assert!(files_in(&out).is_empty(), "{:?}", files_in(&out));
        }
    }
}

#[test]
fn a_nested_stage_is_varied_by_its_id_and_clashes_with_its_full_path() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let set = Path::new(env!("CARGO_MANIFEST_DIR")).join(SET);
    let run = gsid(&[
        "sweep",
        set.to_str().unwrap(),
        "--vary",
        "gsid.walks=2,4",
        "--set",
        "pyramid.gsid.walks=8",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_bad_input(&run, "also fixed by --set");
    assert!(!out.exists());
}
