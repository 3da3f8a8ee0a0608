//! Every allowed maximum of a setting runs in bounded memory (or is refused up front): the binary
//! runs on tiny images with each key at the top of its range, and the child's peak RSS is read
//! from `wait4`, which reports it for that child alone (tests run in parallel threads).
//!
//! A test binary of its own, not a module of `tests/it`: the peak `wait4` reports is at least the
//! parent's resident size when it spawned the child (Linux carries the old memory's high-water mark
//! across `exec`), so the parent must be this small binary, not one whose other tests hold images.

#[path = "it/common.rs"]
mod common;

use std::path::Path;
use std::process::{Command, Stdio};

use common::{synthetic_set, write_set};

/// Peak RSS any setting may reach on a tiny image.
const RSS_LIMIT_KIB: i64 = 512 * 1024;

/// Runs `gsid ARGS` and returns its exit code, stderr and peak RSS in KiB.
// The child is reaped by `wait4`, which clippy does not see.
#[allow(clippy::zombie_processes)]
fn run(args: &[&str]) -> (Option<i32>, String, i64) {
    let dir = tempfile::tempdir().unwrap();
    let err_path = dir.path().join("stderr");
    let bin = std::env::var_os("GSID_BIN").unwrap_or_else(|| env!("CARGO_BIN_EXE_gsid").into());
    let child = Command::new(bin)
        .args(args)
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&err_path).unwrap())
        .spawn()
        .expect("run gsid");
    let mut status = 0;
    // SAFETY: an all-zero rusage is a valid value; wait4 fills it for this child.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: the pid is our own unreaped child; `status` and `usage` outlive the call.
    let pid = unsafe { libc::wait4(child.id() as i32, &mut status, 0, &mut usage) };
    assert_eq!(pid, child.id() as i32, "wait4 failed");
    let code = libc::WIFEXITED(status).then(|| libc::WEXITSTATUS(status));
    let err = std::fs::read_to_string(&err_path).unwrap();
    (code, err, usage.ru_maxrss)
}

/// Runs `gsid denoise -q` of a synthetic `w`×`h` set with `extra` arguments; returns what [`run`]
/// does and whether the output was written.
fn denoise(w: usize, h: usize, extra: &[&str]) -> (Option<i32>, String, i64, bool) {
    let dir = tempfile::tempdir().unwrap();
    let set = dir.path().join("set");
    write_set(&set, &synthetic_set(w, h));
    let out = dir.path().join("out.exr");
    let mut args = vec![
        "denoise",
        set.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "-q",
    ];
    args.extend_from_slice(extra);
    let (code, err, rss) = run(&args);
    (code, err, rss, Path::new(&out).exists())
}

/// `gsid denoise` of a `w`×`h` set with `extra` arguments succeeds with a peak RSS under
/// `limit_kib`.
fn denoise_within(w: usize, h: usize, extra: &[&str], limit_kib: i64) {
    let (code, err, rss, written) = denoise(w, h, extra);
    assert_eq!(code, Some(0), "{w}x{h} {extra:?} failed: {err}");
    assert!(written);
    assert!(
        rss < limit_kib,
        "{w}x{h} {extra:?} peaked at {rss} KiB (limit {limit_kib} KiB)"
    );
}

/// `gsid denoise` of a 3×2 set with `extra` arguments must exit 2 naming `key`.
fn refused(extra: &[&str], key: &str) {
    let (code, err, _, _) = denoise(3, 2, extra);
    assert_eq!(code, Some(2), "{extra:?} was not refused: {err}");
    assert!(err.contains(key), "error does not name `{key}`: {err}");
}

/// walks × max_steps is bounded by 65 536 steps a pixel: the settings that would have run for
/// hours on 256² (40 × 100 000 at σ 1e-6, p_min 1e-300; 100 000 × 40) are refused when the
/// pipeline is built, naming the key.
#[test]
fn walks_times_max_steps_beyond_the_cap_is_refused() {
    for (walks, steps) in [("100000", "100000"), ("40", "100000"), ("100000", "40")] {
        refused(
            &[
                "--pipeline",
                "gsid",
                "--set",
                &format!("gsid.walks={walks}"),
                "--set",
                &format!("gsid.max_steps={steps}"),
                "--set",
                "gsid.sigma=1e-6",
                "--set",
                "gsid.p_min=1e-300",
            ],
            "gsid.",
        );
    }
}

/// On a 2×1 image every step has probability 1, so every walk takes all its steps: the step
/// records would be walks × max_steps a batch if they were not weighed in bounded chunks.
#[test]
fn longest_walks_run_in_memory_independent_of_their_length() {
    for (w, h) in [(2, 1), (2, 2)] {
        let walks = ["--pipeline", "gsid", "--set", "gsid.sigma=1e-3"];
        for (n, steps) in [("1", "10000"), ("10000", "1"), ("40", "250")] {
            let walks_n = format!("gsid.walks={n}");
            let steps_n = format!("gsid.max_steps={steps}");
            let args = [&walks[..], &["--set", &walks_n, "--set", &steps_n]].concat();
            // Tighter than the general limit: these runs must not grow with walks × max_steps.
            denoise_within(w, h, &args, 64 * 1024);
        }
    }
}

#[test]
fn widest_window_is_clipped_to_the_image() {
    for (w, h) in [(3, 2), (1, 1)] {
        let args = ["--pipeline", "gsid", "--set", "gsid.window=1024"];
        denoise_within(w, h, &args, RSS_LIMIT_KIB);
    }
}

#[test]
fn most_atrous_iterations_run_in_bounded_memory() {
    let args = ["--pipeline", "full", "--set", "atrous.iterations=5"];
    denoise_within(3, 2, &args, RSS_LIMIT_KIB);
    let set = tempfile::tempdir().unwrap();
    write_set(set.path(), &synthetic_set(3, 2));
    let out = set.path().join("out.exr");
    let run = common::gsid(&[
        "denoise",
        set.path().to_str().unwrap(),
        "--set",
        "atrous.iterations=6",
        "-o",
        out.to_str().unwrap(),
    ]);
    common::assert_bad_input(&run, "atrous.iterations");
}

#[test]
fn widest_regression_window_runs_in_bounded_memory() {
    // Band planes hold the window's reach above and below: 33 rows of a 3-pixel-wide image.
    let args = ["--pipeline", "full", "--set", "regress.radius=16"];
    denoise_within(3, 2, &args, RSS_LIMIT_KIB);
    refused(&["--set", "regress.radius=17"], "regress.radius");
}

#[test]
fn largest_pyramid_settings_run_in_bounded_memory() {
    let args = [
        "--pipeline",
        "pyramid",
        "--set",
        "pyramid.levels=12",
        "--set",
        "pyramid.clamp_radius=8",
    ];
    denoise_within(3, 2, &args, RSS_LIMIT_KIB);
    denoise_within(1, 1, &args, RSS_LIMIT_KIB);
    refused(
        &["--pipeline", "pyramid", "--set", "pyramid.clamp_radius=9"],
        "clamp_radius",
    );
}

#[test]
fn most_threads_start_quickly_in_bounded_memory() {
    let start = std::time::Instant::now();
    denoise_within(3, 2, &["--threads", "1024"], RSS_LIMIT_KIB);
    let took = start.elapsed();
    assert!(took.as_secs() < 10, "1024 threads took {took:?}");
}

/// A header that declares more pixels than the reader allocates for is refused before any
/// allocation, naming the file and the cap (2^28 pixels), even when the file is long enough to
/// hold them.
#[test]
fn exr_declaring_too_many_pixels_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let set = dir.path().join("set");
    write_set(&set, &synthetic_set(1, 1));
    let color = set.join("color.exr");
    let mut bytes = std::fs::read(&color).unwrap();
    // Where the value of attribute `tag` (name, type, then a 4-byte size) starts.
    let value = |bytes: &[u8], tag: &[u8]| {
        bytes
            .windows(tag.len())
            .position(|w| w == tag)
            .unwrap_or_else(|| panic!("no {} attribute", String::from_utf8_lossy(tag)))
            + tag.len()
            + 4
    };
    // xMax and yMax: 17000² pixels, just above the cap; the chunk count to match, and padding
    // that makes the file large enough to hold that many compressed samples.
    let side: i32 = 17_000;
    let at = value(&bytes, b"dataWindow\0box2i\0");
    for field in [8, 12] {
        bytes[at + field..at + field + 4].copy_from_slice(&(side - 1).to_le_bytes());
    }
    let lines_per_chunk = match bytes[value(&bytes, b"compression\0compression\0")] {
        0..=2 => 1u32,
        3 | 5 => 16,
        _ => 32,
    };
    let at = value(&bytes, b"chunkCount\0int\0");
    let chunks = (side as u32).div_ceil(lines_per_chunk) as i32;
    bytes[at..at + 4].copy_from_slice(&chunks.to_le_bytes());
    bytes.resize(bytes.len() + 1_000_000, 0);
    std::fs::write(&color, bytes).unwrap();
    let out = dir.path().join("out.exr");
    // A memory limit the estimate never reaches, so the reader's own pixel cap is what refuses.
    let (code, err, rss) = run(&[
        "denoise",
        set.to_str().unwrap(),
        "--max-memory",
        "1000000000",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, Some(2), "not refused: {err}");
    assert!(
        err.contains("268435456"),
        "error does not give the cap: {err}"
    );
    assert!(
        err.contains("color.exr"),
        "error does not name the file: {err}"
    );
    assert!(rss < RSS_LIMIT_KIB, "peaked at {rss} KiB");
}

/// A pipeline or scene file is read with a cap: an endless source (`/dev/zero`) or a huge file is
/// refused after 1 MiB (pipeline) or 4 MiB (scene), naming it (both read 8 GB before failing).
#[test]
fn pipeline_and_scene_files_are_read_with_a_cap() {
    let (code, err, _, written) = denoise(3, 2, &["--pipeline", "/dev/zero"]);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("/dev/zero") && err.contains("larger than"),
        "{err}"
    );
    assert!(!written);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r");
    let (code, err, rss) = run(&["render", "/dev/zero", "-q", "-o", out.to_str().unwrap()]);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("/dev/zero") && err.contains("larger than"),
        "{err}"
    );
    assert!(rss < 64 * 1024, "peaked at {rss} KiB");
    assert!(!out.exists());
}

/// Above 10 000 steps a pixel, an image may take 1.2 G steps in all (a minute at the slowest
/// steps): 50 000 a pixel are refused on 256², before the work, naming the estimate, and taken on a
/// 24×24 crop.
#[test]
fn the_walk_budget_follows_the_image_size() {
    let args = [
        "--pipeline",
        "gsid",
        "--set",
        "gsid.walks=500",
        "--set",
        "gsid.max_steps=100",
    ];
    let (code, err, _, written) = denoise(256, 256, &args);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("walks") && err.contains("G on this 256x256 image"),
        "{err}"
    );
    assert!(!written);
    denoise_within(24, 24, &args, RSS_LIMIT_KIB);
}

/// A colour file of `w`×`h` pixels by its header, holding the data of a 4×4 image: what a small
/// file declaring a huge image looks like (a ZIP of zeros is one).
fn declaring(dir: &Path, w: i32, h: i32) -> std::path::PathBuf {
    let path = dir.join("color.exr");
    gsid::io::write_exr(&path, &gsid::Image::filled(4, 4, 3, 0.5)).unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    for name in [&b"dataWindow\0box2i\0"[..], &b"displayWindow\0box2i\0"[..]] {
        let at = bytes.windows(name.len()).position(|b| b == name).unwrap() + name.len() + 4;
        bytes[at + 8..at + 12].copy_from_slice(&(w - 1).to_le_bytes());
        bytes[at + 12..at + 16].copy_from_slice(&(h - 1).to_le_bytes());
    }
    std::fs::write(&path, bytes).unwrap();
    path
}

/// The memory a run will take is estimated from the colour's header before anything is decoded,
/// and a run above `--max-memory` (default: three quarters of the machine's) is refused, naming
/// the estimate: a 16384² image declared by a small file took gigabytes and then aborted.
#[test]
fn a_run_larger_than_the_memory_limit_is_refused_before_decoding() {
    let (code, err, _, written) = denoise(3, 2, &["--max-memory", "1"]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("--max-memory") && err.contains("MiB"), "{err}");
    assert!(!written);
    // The studies run the pipeline many times on the set: checked the same way, before reading it.
    let studies = tempfile::tempdir().unwrap();
    let small = studies.path().join("set");
    write_set(&small, &synthetic_set(3, 2));
    let sweep_out = studies.path().join("sweep");
    let s = small.to_str().unwrap();
    for args in [
        vec!["ablate", s, "--max-memory", "1", "-q"],
        vec![
            "sweep",
            s,
            "--max-memory",
            "1",
            "-p",
            "gsid",
            "--vary",
            "gsid.walks=1,2",
            "-q",
            "--out",
            sweep_out.to_str().unwrap(),
        ],
    ] {
        let (code, err, _) = run(&args);
        assert_eq!(code, Some(2), "{args:?}: {err}");
        assert!(err.contains("--max-memory"), "{args:?}: {err}");
    }
    assert!(!sweep_out.exists());
    let dir = tempfile::tempdir().unwrap();
    let set = dir.path().join("set");
    std::fs::create_dir(&set).unwrap();
    declaring(&set, 16384, 16384);
    let out = dir.path().join("o.exr");
    let (code, err, rss) = run(&[
        "denoise",
        set.to_str().unwrap(),
        "--max-memory",
        "4000",
        "-q",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("16384x16384") && err.contains("--max-memory"),
        "{err}"
    );
    assert!(rss < 64 * 1024, "peaked at {rss} KiB");
    assert!(!out.exists());
}

/// A scene of `side`² pixels with one image texture at `texture` (relative to the scene), written
/// to `dir/scene.toml`.
fn scene_with_texture(dir: &Path, side: u32, texture: &str) -> std::path::PathBuf {
    let cornell = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/scenes/cornell.toml"),
    )
    .unwrap();
    let sized = cornell
        .replace("width = 128", &format!("width = {side}"))
        .replace("height = 128", &format!("height = {side}"));
    assert_ne!(sized, cornell, "the Cornell scene's size moved");
    let path = dir.join("scene.toml");
    let text = format!("{sized}\n[textures.picture]\ntype = \"image\"\npath = \"{texture}\"\n");
    std::fs::write(&path, text).unwrap();
    path
}

/// `gsid render` estimates its memory from the scene's size and its image textures' headers
/// before decoding anything: a texture declaring 16384² pixels in a small file (a ZIP of zeros
/// is one) is refused, naming the estimate, and nothing is written; a render that is accepted
/// stays within its estimate.
#[test]
fn a_render_larger_than_the_memory_limit_is_refused_before_decoding() {
    let dir = tempfile::tempdir().unwrap();
    declaring(dir.path(), 16384, 16384);
    let scene = scene_with_texture(dir.path(), 8, "color.exr");
    let out = dir.path().join("r");
    let render = |scene: &Path, limit: &str| {
        run(&[
            "render",
            scene.to_str().unwrap(),
            "--spp",
            "1",
            "--reference-spp",
            "0",
            "--max-memory",
            limit,
            "-q",
            "-o",
            out.to_str().unwrap(),
        ])
    };
    let (code, err, rss) = render(&scene, "4000");
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("--max-memory") && err.contains("MiB") && err.contains("texture"),
        "{err}"
    );
    assert!(rss < 64 * 1024, "peaked at {rss} KiB");
    assert!(!out.exists());

    // A real 1024² texture and a 256² render: accepted, and the estimate is an upper bound.
    let real = tempfile::tempdir().unwrap();
    gsid::io::write_exr(
        &real.path().join("t.exr"),
        &gsid::Image::filled(1024, 1024, 3, 0.25),
    )
    .unwrap();
    let scene = scene_with_texture(real.path(), 256, "t.exr");
    let spec =
        gsid::render::scene_file::SceneSpec::parse(&std::fs::read_to_string(&scene).unwrap())
            .unwrap();
    let estimate = spec.peak_bytes(real.path());
    let (code, err, rss) = render(&scene, "100000");
    assert_eq!(code, Some(0), "{err}");
    assert!(
        (rss as u64) * 1024 <= estimate,
        "peaked at {rss} KiB, above the estimate of {} KiB",
        estimate / 1024
    );
}
