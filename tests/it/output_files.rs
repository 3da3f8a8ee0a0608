//! Outputs as a user of a render pipeline expects them: PNG previews keep alpha, `--half` makes
//! every channel of the beauty half, compression follows the input, missing folders are made;
//! and two mistakes named plainly (missing frames of `--frames`, oidnDenoise's `-q high`).

use std::path::Path;

use crate::common::{assert_bad_input, gsid, stderr};
use exr::prelude::{read_all_flat_layers_from_file, Compression, FlatSamples};

const STUDIO: &str = "fixtures/cycles-studio/spp4.exr";
const SHOT: &str = "fixtures/cycles-static-small/spp4";

fn run_ok(args: &[&str]) -> String {
    let run = gsid(args);
    assert_eq!(run.status.code(), Some(0), "{}", stderr(&run));
    stderr(&run)
}

/// A 16×8 RGBA EXR whose alpha runs from 0 to 1 across the image.
fn rgba_colour(path: &Path) {
    exr::prelude::write_rgba_file(path, 16, 8, |x, y| {
        let v = 0.1 + 0.05 * ((x + 3 * y) % 7) as f32;
        (v, v * 0.5, v * 0.25, x as f32 / 15.0)
    })
    .unwrap();
}

#[test]
fn a_png_preview_keeps_the_alpha() {
    let tmp = tempfile::tempdir().unwrap();
    let set = tmp.path().join("set");
    std::fs::create_dir(&set).unwrap();
    rgba_colour(&set.join("color.exr"));
    let png = tmp.path().join("x.png");
    run_ok(&[
        "denoise",
        set.to_str().unwrap(),
        "-o",
        png.to_str().unwrap(),
        "-p",
        "fast",
    ]);
    let image = image::open(&png).unwrap();
    assert_eq!(
        image.color(),
        image::ColorType::Rgba8,
        "RGBA, as FORMATS.md says"
    );
    let rgba = image.to_rgba8();
    for x in 0..16 {
        let want = (x as f32 / 15.0 * 255.0).round() as u8;
        assert_eq!(rgba.get_pixel(x, 3)[3], want, "alpha at x = {x}");
    }
}

#[test]
fn half_makes_every_written_channel_half() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out.exr");
    run_ok(&[
        "denoise",
        STUDIO,
        "-o",
        out.to_str().unwrap(),
        "-p",
        "fast",
        "--half",
    ]);
    let image = read_all_flat_layers_from_file(&out).unwrap();
    let list = &image.layer_data[0].channel_data.list;
    let names: Vec<String> = list.iter().map(|c| c.name.to_string()).collect();
    assert_eq!(names, ["A", "B", "G", "R"]);
    for c in list {
        assert!(
            matches!(c.sample_data, FlatSamples::F16(_)),
            "{} is not half",
            c.name
        );
    }
}

#[test]
fn compression_follows_the_input_exr_else_zip() {
    let tmp = tempfile::tempdir().unwrap();
    let compression = |p: &Path| {
        read_all_flat_layers_from_file(p).unwrap().layer_data[0]
            .encoding
            .compression
    };
    // Blender writes ZIP: the result is ZIP too (not twice the input's size in RLE).
    let out = tmp.path().join("out.exr");
    run_ok(&["denoise", STUDIO, "-o", out.to_str().unwrap(), "-p", "fast"]);
    assert_eq!(compression(&out), Compression::ZIP16);
    // A PFM colour has none to follow: ZIP.
    let pfm = tmp.path().join("c.pfm");
    run_ok(&[
        "denoise",
        "fixtures/mitsuba-cornell/spp1",
        "-o",
        pfm.to_str().unwrap(),
        "-p",
        "fast",
    ]);
    run_ok(&[
        "denoise",
        "--color",
        pfm.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "-p",
        "fast",
    ]);
    assert_eq!(compression(&out), Compression::ZIP16);
    // An RLE input stays RLE; --compression still decides when given.
    let rle = tmp.path().join("rle.exr");
    let set = tmp.path().join("set");
    std::fs::create_dir(&set).unwrap();
    rgba_colour(&set.join("color.exr"));
    run_ok(&[
        "denoise",
        set.to_str().unwrap(),
        "-o",
        rle.to_str().unwrap(),
        "-p",
        "fast",
    ]);
    assert_eq!(
        compression(&rle),
        Compression::RLE,
        "write_rgba_file writes RLE"
    );
    run_ok(&[
        "denoise",
        STUDIO,
        "-o",
        out.to_str().unwrap(),
        "-p",
        "fast",
        "--compression",
        "piz",
    ]);
    assert_eq!(compression(&out), Compression::PIZ);
}

#[test]
fn missing_output_folders_are_made_and_removed_if_nothing_is_written() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("new/deeper/out.exr");
    run_ok(&["denoise", STUDIO, "-o", out.to_str().unwrap(), "-p", "fast"]);
    assert!(out.is_file());

    let pattern = format!("{SHOT}/frame.####.exr");
    let seq = tmp.path().join("den/frame.####.exr");
    run_ok(&[
        "denoise",
        &pattern,
        "-o",
        seq.to_str().unwrap(),
        "-p",
        "fast",
        "--frames",
        "1-2",
    ]);
    for f in 1..=2 {
        assert!(tmp.path().join(format!("den/frame.{f:04}.exr")).is_file());
    }

    // A run that fails after reserving its output leaves no folder it made behind.
    let failed = tmp.path().join("never/made/out.exr");
    let run = gsid(&[
        "denoise",
        STUDIO,
        "-o",
        failed.to_str().unwrap(),
        "--save-buffer",
        &format!("no_such_buffer={}", tmp.path().join("x.exr").display()),
    ]);
    assert_eq!(run.status.code(), Some(2), "{}", stderr(&run));
    assert!(
        !tmp.path().join("never").exists(),
        "an empty folder was left behind"
    );
}

#[test]
fn missing_frames_of_a_frames_list_are_listed_before_any_work() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("den/frame.####.exr");
    let pattern = format!("{SHOT}/frame.####.exr");
    let run = gsid(&[
        "denoise",
        &pattern,
        "-o",
        out.to_str().unwrap(),
        "--frames",
        "1-7",
    ]);
    assert_bad_input(&run, "not found: frames 6, 7 of");
    assert!(stderr(&run).contains(&pattern), "{}", stderr(&run));
    assert!(!tmp.path().join("den").exists(), "nothing written");
}

#[test]
fn oidn_quality_flag_gets_a_preset_hint() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("o.pfm");
    for args in [
        vec![
            "denoise",
            "-q",
            "high",
            "--hdr",
            "c.pfm",
            "-o",
            out.to_str().unwrap(),
        ],
        vec![
            "denoise",
            "fixtures/mitsuba-cornell/spp4",
            "-q",
            "fast",
            "-o",
            out.to_str().unwrap(),
        ],
    ] {
        let run = gsid(&args);
        assert_bad_input(&run, "-p fast|balanced|quality|full");
    }
}

/// Saved buffers are at the input's exposure, as the result is: the stages run at one internal
/// brightness, and a variance saved at it was off by that factor squared (5× on `detail`).
#[test]
fn saved_buffers_follow_the_inputs_exposure() {
    let tmp = tempfile::tempdir().unwrap();
    let src = Path::new("fixtures/detail/spp16");
    let read = |p: &Path| gsid::io::read_image(p, 3).unwrap();
    // The same render four times brighter: colour ×4, its variance ×16.
    let bright = tmp.path().join("bright");
    std::fs::create_dir(&bright).unwrap();
    for name in ["albedo", "normal", "depth"] {
        let from = src.join(format!("{name}.exr"));
        std::fs::copy(&from, bright.join(format!("{name}.exr"))).unwrap();
    }
    for (name, factor) in [("color", 4.0f32), ("variance", 16.0)] {
        let mut img = read(&src.join(format!("{name}.exr")));
        img.data_mut().iter_mut().for_each(|v| *v *= factor);
        gsid::io::write_exr(&bright.join(format!("{name}.exr")), &img).unwrap();
    }
    let saved = |set: &Path, tag: &str| {
        let (noise, light) = (
            tmp.path().join(format!("noise-{tag}.exr")),
            tmp.path().join(format!("light-{tag}.exr")),
        );
        run_ok(&[
            "denoise",
            set.to_str().unwrap(),
            "-o",
            tmp.path().join(format!("out-{tag}.exr")).to_str().unwrap(),
            "-q",
            "--save-buffer",
            &format!("noise={}", noise.display()),
            "--save-buffer",
            &format!("outlier_light={}", light.display()),
        ]);
        (read(&noise), read(&light))
    };
    let (noise, light) = saved(&bright, "bright");
    let (noise1, light1) = saved(src, "plain");
    // The variance the renderer measured and the noise stage's (smoothed over the surface) agree.
    let variance = read(&src.join("variance.exr"));
    let mean = |img: &gsid::Image| img.data().iter().map(|&v| v as f64).sum::<f64>();
    let ratio = mean(&noise1) / mean(&variance);
    assert!(
        (0.7..1.4).contains(&ratio),
        "saved noise / variance {ratio}"
    );
    for (a, b, power) in [(&noise, &noise1, 16.0), (&light, &light1, 4.0)] {
        let r = mean(a) / mean(b);
        assert!((r / power - 1.0).abs() < 1e-3, "{r} for {power}");
    }
}
