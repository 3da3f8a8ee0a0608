//! `gsid denoise PATTERN --temporal R`: frames merged with their neighbours (README "Temporal
//! denoising"), on crops of the Cycles shots in `fixtures/cycles-*-small` and on synthetic shots.

use crate::common::*;
use std::path::{Path, PathBuf};

use exr::prelude::{AnyChannel, AnyChannels, FlatSamples, Image as ExrImage};
use gsid::io;

const STATIC: &str = "fixtures/cycles-static-small";
const ANIM: &str = "fixtures/cycles-anim-small";

/// `gsid denoise SHOT/spp4/frame.####.exr -o OUT/f.####.exr` plus `extra`, quiet.
fn run(shot: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    std::fs::create_dir_all(out).unwrap();
    let input = shot.join("spp4/frame.####.exr");
    let output = out.join("f.####.exr");
    let mut args = vec![
        "denoise",
        input.to_str().unwrap(),
        "-o",
        output.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    gsid(&args)
}

fn colour(path: &Path) -> gsid::Image {
    io::load_input(path, &[]).unwrap().set.color
}

fn ok(out: &std::process::Output) {
    assert_eq!(out.status.code(), Some(0), "{}", stderr(out));
}

#[test]
fn the_static_shot_merged_over_its_neighbours_beats_each_frame_alone() {
    let tmp = tempfile::tempdir().unwrap();
    let (alone, merged) = (tmp.path().join("alone"), tmp.path().join("merged"));
    ok(&run(Path::new(STATIC), &alone, &["-q"]));
    ok(&run(Path::new(STATIC), &merged, &["-q", "--temporal", "2"]));
    let reference = colour(&Path::new(STATIC).join("reference.exr"));
    let (mut a, mut m) = (0.0, 0.0);
    for n in 1..=5 {
        let name = format!("f.{n:04}.exr");
        a += gsid::metrics::rel_mse(&colour(&alone.join(&name)), &reference);
        m += gsid::metrics::rel_mse(&colour(&merged.join(&name)), &reference);
    }
    assert!(m < 0.8 * a, "relMSE merged {m:.5} against alone {a:.5}");
}

fn bytes(dir: &Path) -> Vec<(String, Vec<u8>)> {
    files_in(dir)
        .into_iter()
        .map(|f| {
            let b = std::fs::read(dir.join(&f)).unwrap();
            (f, b)
        })
        .collect()
}

#[test]
fn a_frame_is_the_same_bits_in_one_run_or_in_chunks_on_any_thread_count() {
    let tmp = tempfile::tempdir().unwrap();
    let whole = tmp.path().join("whole");
    let chunks = tmp.path().join("chunks");
    let shot = Path::new(ANIM);
    ok(&run(
        shot,
        &whole,
        &["-q", "--temporal", "2", "--threads", "2"],
    ));
    for frames in ["1-2", "3", "4-5"] {
        let extra = [
            "-q",
            "--temporal",
            "2",
            "--threads",
            "1",
            "--frames",
            frames,
        ];
        ok(&run(shot, &chunks, &extra));
    }
    let (w, c) = (bytes(&whole), bytes(&chunks));
    assert_eq!(w.len(), 5);
    assert!(w == c, "a chunked or 1-thread run wrote other bits");
}

/// The anim crop's frames copied to `root/spp4`, without frame `missing`.
fn copied_shot(root: &Path, missing: u32) -> PathBuf {
    let spp = root.join("spp4");
    std::fs::create_dir_all(&spp).unwrap();
    for n in (1..=5).filter(|&n| n != missing) {
        let name = format!("frame.{n:04}.exr");
        std::fs::copy(Path::new(ANIM).join("spp4").join(&name), spp.join(&name)).unwrap();
    }
    root.to_path_buf()
}

#[test]
fn a_missing_neighbour_is_named_and_left_out_or_fails_under_strict() {
    let tmp = tempfile::tempdir().unwrap();
    let shot = copied_shot(&tmp.path().join("shot"), 3);
    let out = tmp.path().join("out");
    let fell_back = run(&shot, &out, &["--temporal", "1", "--frames", "2"]);
    ok(&fell_back);
    let err = stderr(&fell_back);
    assert!(
        err.contains("neighbour frame 3 left out") && err.contains("frame.0003.exr"),
        "{err}"
    );
    assert!(out.join("f.0002.exr").is_file());
    let strict = tmp.path().join("strict");
    let refused = run(
        &shot,
        &strict,
        &[
            "-q",
            "--temporal",
            "1",
            "--temporal-strict",
            "--frames",
            "4",
        ],
    );
    assert_bad_input(&refused, "frame.0003.exr");
    assert!(files_in(&strict).is_empty(), "a refused frame wrote output");
}

#[test]
fn a_shot_without_a_motion_pass_is_said_to_be_assumed_static_once() {
    let tmp = tempfile::tempdir().unwrap();
    let out = run(Path::new(STATIC), tmp.path(), &["--temporal", "1"]);
    ok(&out);
    assert_eq!(
        stderr(&out).matches("assumed static").count(),
        1,
        "{}",
        stderr(&out)
    );
    let moving = run(Path::new(ANIM), &tmp.path().join("a"), &["--temporal", "1"]);
    ok(&moving);
    assert!(!stderr(&moving).contains("assumed static"));
}

#[test]
fn temporal_needs_a_frame_pattern() {
    let tmp = tempfile::tempdir().unwrap();
    let one = Path::new(ANIM).join("spp4/frame.0001.exr");
    let out = tmp.path().join("o.exr");
    let refused = gsid(&[
        "denoise",
        one.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--temporal",
        "2",
    ]);
    assert_bad_input(&refused, "--temporal");
    assert!(!out.exists());
    let too_far = run(Path::new(ANIM), tmp.path(), &["--temporal", "99"]);
    assert_bad_input(&too_far, "--temporal");
}

/// A noise-free texture that moves (+2, −1) pixels (right, up) a frame, written as Blender writes
/// a shot: `Combined`, `Denoising Albedo` and the `Vector` pass (X,Y = previous − current and
/// Z,W = current − next, in pixels, y up).
fn moving_frame(path: &Path, t: i64, last: i64) {
    let n = 24usize;
    let texture = |x: i64, y: i64| {
        let h = (x.wrapping_mul(73_856_093) ^ y.wrapping_mul(19_349_663)) as u64;
        0.1 + 0.8 * ((h % 1000) as f32 / 1000.0)
    };
    let mut value = Vec::with_capacity(n * n);
    for y in 0..n as i64 {
        for x in 0..n as i64 {
            // The surface at (x, y) in frame t sits at (x − 2t, y + t) in frame 0.
            value.push(texture(x - 2 * t, y + t));
        }
    }
    let flat = |v: f32| FlatSamples::F32(vec![v; n * n]);
    let mut channels = Vec::new();
    for c in ["R", "G", "B"] {
        channels.push(AnyChannel::new(
            format!("ViewLayer.Combined.{c}").as_str(),
            FlatSamples::F32(value.clone()),
        ));
        channels.push(AnyChannel::new(
            format!("ViewLayer.Denoising Albedo.{c}").as_str(),
            FlatSamples::F32(value.clone()),
        ));
    }
    let (back, fore) = (t > 1, t < last);
    let on = |v: f32, yes: bool| if yes { v } else { 0.0 };
    channels.push(AnyChannel::new("ViewLayer.Vector.X", flat(on(-2.0, back))));
    channels.push(AnyChannel::new("ViewLayer.Vector.Y", flat(on(-1.0, back))));
    channels.push(AnyChannel::new("ViewLayer.Vector.Z", flat(on(-2.0, fore))));
    channels.push(AnyChannel::new("ViewLayer.Vector.W", flat(on(-1.0, fore))));
    let image = ExrImage::from_channels((n, n), AnyChannels::sort(channels.into()));
    use exr::prelude::WritableImage;
    image.write().to_file(path).unwrap();
}

/// The mean weights of the note `temporal: merged with frames (mean weight) 1 97 %, 3 96 %`.
fn weights(err: &str, frame: u32) -> Vec<(u32, f64)> {
    let line = err
        .lines()
        .find(|l| l.contains(&format!("frame {frame}: temporal: merged")))
        .unwrap_or_else(|| panic!("no merge note for frame {frame}: {err}"));
    let list = line.split("(mean weight) ").nth(1).unwrap();
    list.split(", ")
        .map(|part| {
            let mut it = part.split(' ');
            let n = it.next().unwrap().parse().unwrap();
            let w = it.next().unwrap().parse().unwrap();
            (n, w)
        })
        .collect()
}

#[test]
fn neighbours_reprojected_by_the_vector_pass_line_up_with_the_frame() {
    let tmp = tempfile::tempdir().unwrap();
    let spp = tmp.path().join("spp4");
    std::fs::create_dir_all(&spp).unwrap();
    for t in 1..=5 {
        moving_frame(&spp.join(format!("frame.{t:04}.exr")), t, 5);
    }
    let out = run(
        tmp.path(),
        &tmp.path().join("out"),
        &["--temporal", "2", "--frames", "3"],
    );
    ok(&out);
    let got = weights(&stderr(&out), 3);
    assert_eq!(
        got.iter().map(|(n, _)| *n).collect::<Vec<_>>(),
        [1, 2, 4, 5]
    );
    // Every pixel whose surface is in the neighbour lines up: all but the border it left by.
    for (n, w) in got {
        let shift = 3i64.abs_diff(n as i64) as f64;
        let inside = 100.0 * (24.0 - 2.0 * shift) * (24.0 - shift) / (24.0 * 24.0);
        assert!(
            w >= inside - 2.0,
            "frame {n}: weight {w} %, {inside:.0} % of its pixels are in it"
        );
    }
}

#[test]
fn a_pipeline_key_turns_it_on_and_the_flag_overrides_it() {
    let tmp = tempfile::tempdir().unwrap();
    let full = std::fs::read_to_string("pipelines/full.toml").unwrap();
    let keyed = tmp.path().join("keyed.toml");
    std::fs::write(&keyed, format!("temporal = 1\n{full}")).unwrap();
    let keyed = keyed.to_str().unwrap();
    let on = run(Path::new(STATIC), &tmp.path().join("on"), &["-p", keyed]);
    ok(&on);
    assert!(stderr(&on).contains("temporal: merged"), "{}", stderr(&on));
    // `--temporal 0` is each frame alone: the same bits as a run without the key or the flag.
    let off = tmp.path().join("off");
    ok(&run(
        Path::new(STATIC),
        &off,
        &["-q", "-p", keyed, "--temporal", "0"],
    ));
    let plain = tmp.path().join("plain");
    ok(&run(Path::new(STATIC), &plain, &["-q"]));
    assert!(
        bytes(&off) == bytes(&plain),
        "--temporal 0 changed the bits"
    );
    let bad = tmp.path().join("bad.toml");
    std::fs::write(&bad, format!("temporal = 99\n{full}")).unwrap();
    let refused = run(
        Path::new(STATIC),
        &tmp.path().join("x"),
        &["-p", bad.to_str().unwrap()],
    );
    assert_bad_input(&refused, "temporal");
}

#[test]
fn a_damaged_neighbour_is_named_and_the_frame_merged_from_fewer() {
    let tmp = tempfile::tempdir().unwrap();
    let shot = copied_shot(&tmp.path().join("shot"), 0);
    let damaged = shot.join("spp4/frame.0004.exr");
    let bytes = std::fs::read(&damaged).unwrap();
    std::fs::write(&damaged, &bytes[..bytes.len() / 3]).unwrap();
    let out = tmp.path().join("out");
    let fell_back = run(&shot, &out, &["--temporal", "1", "--frames", "3"]);
    ok(&fell_back);
    let err = stderr(&fell_back);
    assert!(
        err.contains("neighbour frame 4 left out") && err.contains("frame.0004.exr"),
        "{err}"
    );
    // Its own frame fails by its number, as without --temporal; --keep-going goes on to frame 5.
    let own = run(
        &shot,
        &out,
        &["-q", "--temporal", "1", "--frames", "4-5", "--keep-going"],
    );
    assert_eq!(own.status.code(), Some(2), "{}", stderr(&own));
    assert!(stderr(&own).contains("frame 4"), "{}", stderr(&own));
    assert!(out.join("f.0005.exr").is_file() && !out.join("f.0004.exr").exists());
}
