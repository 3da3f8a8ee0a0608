//! Blender files as they come: `Noisy Image` read before the denoised `Combined`, `--layer` for a
//! file of several view layers, and notes only for what the renderer could have written.

use std::collections::HashMap;
use std::path::Path;

use crate::common::{assert_bad_input, gsid, stderr};
use exr::prelude::{read_all_flat_layers_from_file, FlatSamples};

const NOISY: &str = "fixtures/blender-passes/denoiser-on.exr";
const TWO: &str = "fixtures/blender-passes/two-view-layers.exr";
const STUDIO: &str = "fixtures/cycles-studio/spp4.exr";

/// Every channel of a file as f32, by name.
fn channels(path: &Path) -> HashMap<String, Vec<f32>> {
    let image = read_all_flat_layers_from_file(path).expect("read EXR");
    let mut out = HashMap::new();
    for layer in &image.layer_data {
        let prefix = layer
            .attributes
            .layer_name
            .as_ref()
            .map(|n| format!("{n}."))
            .unwrap_or_default();
        for c in &layer.channel_data.list {
            let v = match &c.sample_data {
                FlatSamples::F16(v) => v.iter().map(|s| s.to_f32()).collect(),
                FlatSamples::F32(v) => v.clone(),
                FlatSamples::U32(v) => v.iter().map(|&s| s as f32).collect(),
            };
            out.insert(format!("{prefix}{}", c.name), v);
        }
    }
    out
}

fn run_ok(args: &[&str]) -> String {
    let run = gsid(args);
    assert_eq!(run.status.code(), Some(0), "{}", stderr(&run));
    stderr(&run)
}

/// Mean absolute difference of two planes.
fn diff(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs() as f64)
        .sum::<f64>()
        / a.len() as f64
}

#[test]
fn noisy_image_is_denoised_not_the_denoised_combined() {
    let tmp = tempfile::tempdir().unwrap();
    let (out, kept) = (tmp.path().join("out.exr"), tmp.path().join("kept.exr"));
    let err = run_ok(&["denoise", NOISY, "-o", out.to_str().unwrap(), "-p", "fast"]);
    assert!(
        err.contains("color ← ViewLayer.Noisy Image.{R,G,B}"),
        "the mapping names Noisy Image: {err}"
    );
    let notes: Vec<&str> = err
        .lines()
        .filter(|l| l.contains("denoised result"))
        .collect();
    assert_eq!(notes.len(), 1, "one note says why: {err}");
    assert!(notes[0].contains("ViewLayer.Combined"), "{err}");

    // The result is not what denoising the clean `Combined` gives (what gsid read before).
    let input = channels(Path::new(NOISY));
    let got = channels(&out);
    let clean = tmp.path().join("clean.exr");
    run_ok(&[
        "denoise",
        NOISY,
        "--map",
        "color=Combined",
        "-o",
        clean.to_str().unwrap(),
        "-p",
        "fast",
    ]);
    assert_ne!(got["R"], channels(&clean)["R"], "Combined was read");
    assert_eq!(
        got["A"], input["ViewLayer.Noisy Image.A"],
        "alpha is the render's"
    );

    // With the other layers, the denoised colour is written where a compositor reads the
    // beauty (`Combined`), and `Noisy Image` is kept as it was.
    run_ok(&[
        "denoise",
        NOISY,
        "-o",
        kept.to_str().unwrap(),
        "-p",
        "fast",
        "--keep-layers",
    ]);
    let kept = channels(&kept);
    assert_eq!(kept["ViewLayer.Combined.R"], got["R"]);
    assert_eq!(
        kept["ViewLayer.Noisy Image.R"],
        input["ViewLayer.Noisy Image.R"]
    );
}

#[test]
fn a_file_of_two_view_layers_names_them_once_and_layer_picks_one() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out.exr");
    let o = out.to_str().unwrap();
    let run = gsid(&["denoise", TWO, "-o", o, "-p", "fast"]);
    assert_bad_input(&run, "--layer");
    let err = stderr(&run);
    assert!(
        err.contains("2 view layers (Mirror, ViewLayer)")
            || err.contains("2 view layers (ViewLayer, Mirror)"),
        "{err}"
    );
    assert!(!out.exists());

    let mut results = Vec::new();
    for layer in ["ViewLayer", "Mirror"] {
        let err = run_ok(&["denoise", TWO, "-o", o, "-p", "fast", "--layer", layer]);
        for buffer in [
            "Combined",
            "Denoising Albedo",
            "Denoising Normal",
            "Denoising Depth",
        ] {
            assert!(err.contains(&format!("{layer}.{buffer}")), "{layer}: {err}");
        }
        results.push(channels(&out)["R"].clone());
    }
    // The mirrored layer's result is the other one flipped back (up to the filter's
    // asymmetry): far closer than to the unflipped image.
    let flip =
        |v: &[f32]| -> Vec<f32> { v.chunks(48).flat_map(|r| r.iter().rev().copied()).collect() };
    assert!(diff(&flip(&results[1]), &results[0]) < diff(&results[1], &results[0]) / 2.0);

    let run = gsid(&["denoise", TWO, "-o", o, "--layer", "Beauty"]);
    assert_bad_input(&run, "Beauty");
    assert!(stderr(&run).contains("view layers: "), "{}", stderr(&run));
    let run = gsid(&[
        "denoise",
        "fixtures/mitsuba-cornell/spp4",
        "-o",
        o,
        "--layer",
        "ViewLayer",
    ]);
    assert_bad_input(&run, "--layer");
}

#[test]
fn a_cycles_file_is_not_told_of_passes_blender_never_writes() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out.exr");
    let err = run_ok(&["denoise", STUDIO, "-o", out.to_str().unwrap(), "-p", "fast"]);
    assert!(!err.contains("material"), "{err}");
    assert!(!err.contains("shadow"), "{err}");
    // A render-set folder without them is told: its format has a place for them.
    let set = tmp.path().join("set");
    std::fs::create_dir(&set).unwrap();
    for f in ["color", "albedo", "normal"] {
        std::fs::copy(
            format!("fixtures/mitsuba-cornell/spp4/{f}.exr"),
            set.join(format!("{f}.exr")),
        )
        .unwrap();
    }
    let err = run_ok(&[
        "denoise",
        set.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "-p",
        "fast",
    ]);
    let note = err
        .lines()
        .find(|l| l.contains("missing buffers"))
        .unwrap_or_default();
    assert!(
        note.contains("material") && note.contains("shadow"),
        "{err}"
    );
}

#[test]
fn a_note_the_same_for_every_frame_is_said_once() {
    let tmp = tempfile::tempdir().unwrap();
    let shot = tmp.path().join("shot");
    std::fs::create_dir(&shot).unwrap();
    for f in 1..=3 {
        std::fs::copy(NOISY, shot.join(format!("render.{f:04}.exr"))).unwrap();
    }
    let pattern = shot.join("render.####.exr");
    let out = tmp.path().join("render.####.exr");
    let err = run_ok(&[
        "denoise",
        pattern.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "-p",
        "fast",
    ]);
    let count = |s: &str| err.lines().filter(|l| l.contains(s)).count();
    assert_eq!(count("denoised result"), 1, "{err}");
    assert_eq!(count("albedo ← "), 1, "the mapping once: {err}");
    assert_eq!(count(") → "), 3, "each frame's result line stays: {err}");
}

#[test]
fn the_sanitised_note_names_the_buffer() {
    let tmp = tempfile::tempdir().unwrap();
    let set = tmp.path().join("set");
    std::fs::create_dir(&set).unwrap();
    std::fs::copy(
        "fixtures/mitsuba-cornell/spp4/color.exr",
        set.join("color.exr"),
    )
    .unwrap();
    // An albedo above 1 everywhere: every sample is clamped, and the note says whose.
    let color = gsid::io::read_image(&set.join("color.exr"), 3).unwrap();
    let (w, h) = color.dims();
    let albedo = gsid::Image::from_vec(w, h, 3, vec![1.5; w * h * 3]).unwrap();
    gsid::io::write_exr(&set.join("albedo.exr"), &albedo).unwrap();
    let out = tmp.path().join("out.exr");
    let err = run_ok(&[
        "denoise",
        set.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "-p",
        "fast",
    ]);
    assert!(
        err.contains(&format!("{} albedo samples clamped", w * h * 3)),
        "{err}"
    );
}
