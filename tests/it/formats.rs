//! Image formats by extension: PFM in and out (bit-exact, either byte order, as the folder form
//! with EXR gives), 8-bit PNG/JPEG previews, unknown extensions refused before any work, `--ldr`.

use std::path::{Path, PathBuf};

use crate::common::*;
use gsid::{io, Image};
use proptest::prelude::*;

const PNG_MAGIC: [u8; 8] = [0x89, b'P', b'N', b'G', b'\r', b'\n', 0x1a, b'\n'];
const JPEG_MAGIC: [u8; 3] = [0xff, 0xd8, 0xff];

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn bits(img: &Image) -> Vec<u32> {
    img.data().iter().map(|v| v.to_bits()).collect()
}

/// Runs gsid and asserts it succeeded.
fn ok(args: &[&str]) -> std::process::Output {
    let run = gsid(args);
    assert!(run.status.success(), "{}", stderr(&run));
    run
}

fn write_pfm(path: &Path, img: &Image) {
    std::fs::write(path, io::pfm::encode(img).unwrap()).unwrap();
}

/// A 16×12 render set with all six buffers, in `dir/set`.
fn small_set(dir: &Path) -> PathBuf {
    let set = dir.join("set");
    write_set(&set, &synthetic_set(16, 12));
    set
}

/// sRGB encoding written out here from the standard, not taken from gsid.
fn srgb8(linear: f32) -> u8 {
    let v = linear.clamp(0.0, 1.0) as f64;
    let e = if v <= 0.0031308 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    };
    (e * 255.0).round() as u8
}

#[test]
fn png_output_is_the_exposed_srgb_preview_of_the_float_output() {
    let tmp = tempfile::tempdir().unwrap();
    let set = small_set(tmp.path());
    let (exr, png) = (tmp.path().join("out.exr"), tmp.path().join("out.png"));
    ok(&["denoise", s(&set), "-o", s(&exr), "-q"]);
    ok(&["denoise", s(&set), "-o", s(&png), "--exposure", "1", "-q"]);
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(bytes[..8], PNG_MAGIC);
    let decoded = image::load_from_memory(&bytes).unwrap().to_rgb8();
    assert_eq!(decoded.dimensions(), (16, 12));
    let float = io::read_image(&exr, 3).unwrap();
    let want: Vec<u8> = float.data().iter().map(|&v| srgb8(2.0 * v)).collect();
    assert_eq!(decoded.as_raw(), &want);
    assert!(
        want.iter().any(|&v| v > 0 && v < 255),
        "a test image with midtones"
    );
}

#[test]
fn jpg_and_jpeg_outputs_are_jpegs() {
    let tmp = tempfile::tempdir().unwrap();
    let set = small_set(tmp.path());
    for name in ["out.jpg", "OUT.JPEG"] {
        let out = tmp.path().join(name);
        ok(&["denoise", s(&set), "-o", s(&out), "-q"]);
        let bytes = std::fs::read(&out).unwrap();
        assert_eq!(bytes[..3], JPEG_MAGIC, "{name}");
        let decoded = image::load_from_memory(&bytes).unwrap();
        assert_eq!((decoded.width(), decoded.height()), (16, 12));
    }
}

#[test]
fn an_unknown_or_missing_extension_is_refused_before_any_work() {
    let tmp = tempfile::tempdir().unwrap();
    let set = small_set(tmp.path());
    let out = tmp.path().join("out.exr");
    let cases: [(Vec<String>, &str); 3] = [
        (
            vec!["-o".into(), s(&tmp.path().join("out.tiff")).into()],
            "out.tiff",
        ),
        (
            vec!["-o".into(), s(&tmp.path().join("out")).into()],
            "no extension",
        ),
        (
            vec![
                "-o".into(),
                s(&out).into(),
                "--save-buffer".into(),
                format!("outlier_mask={}", s(&tmp.path().join("mask.exr.bak"))),
            ],
            "mask.exr.bak",
        ),
    ];
    // A buffer no pipeline makes, saved first: a run that got as far as the pipeline fails on it
    // instead, after the work.
    let late = format!("no_such_buffer={}", s(&tmp.path().join("late.exr")));
    for (outputs, culprit) in cases {
        let mut args = vec!["denoise", s(&set), "--save-buffer", &late];
        args.extend(outputs.iter().map(String::as_str));
        let run = gsid(&args);
        assert_bad_input(&run, culprit);
        assert!(
            stderr(&run).contains(".exr, .pfm, .png, .jpg"),
            "{}",
            stderr(&run)
        );
        assert_eq!(files_in(tmp.path()), vec!["set"], "nothing written");
    }
}

#[test]
fn exposure_without_a_preview_output_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let set = small_set(tmp.path());
    for out in ["out.exr", "out.pfm"] {
        let out = tmp.path().join(out);
        let run = gsid(&["denoise", s(&set), "-o", s(&out), "--exposure", "-1"]);
        assert_bad_input(&run, "--exposure");
        assert_eq!(files_in(tmp.path()), vec!["set"]);
    }
}

#[test]
fn oidn_style_pfm_inputs_and_output_give_the_folder_forms_bits() {
    let tmp = tempfile::tempdir().unwrap();
    let fixture = copy_fixture(4, tmp.path());
    let (exr_set, pfm_set) = (tmp.path().join("exr"), tmp.path().join("pfm"));
    std::fs::create_dir_all(&exr_set).unwrap();
    std::fs::create_dir_all(&pfm_set).unwrap();
    for name in ["color", "albedo", "normal"] {
        let from = fixture.join(format!("{name}.exr"));
        std::fs::copy(&from, exr_set.join(format!("{name}.exr"))).unwrap();
        write_pfm(
            &pfm_set.join(format!("{name}.pfm")),
            &io::read_image(&from, 3).unwrap(),
        );
    }
    let folder_out = tmp.path().join("folder.exr");
    ok(&["denoise", s(&exr_set), "-o", s(&folder_out), "-q"]);
    let want = bits(&io::read_image(&folder_out, 3).unwrap());

    let named_out = tmp.path().join("named.pfm");
    let pfm = |n: &str| pfm_set.join(format!("{n}.pfm"));
    ok(&[
        "denoise",
        "--hdr",
        s(&pfm("color")),
        "--alb",
        s(&pfm("albedo")),
        "--nrm",
        s(&pfm("normal")),
        "-o",
        s(&named_out),
        "-q",
    ]);
    assert!(std::fs::read(&named_out)
        .unwrap()
        .starts_with(b"PF\n128 128\n-1.0\n"));
    assert_eq!(bits(&io::pfm::read(&named_out, 3).unwrap()), want);

    // A folder of PFM files is found by name as EXR files are.
    let folder_pfm_out = tmp.path().join("folder-pfm.exr");
    ok(&["denoise", s(&pfm_set), "-o", s(&folder_pfm_out), "-q"]);
    assert_eq!(bits(&io::read_image(&folder_pfm_out, 3).unwrap()), want);
}

/// Floats that break careless readers: signed zeros, denormals, extremes, infinities, NaNs
/// with payloads.
const AWKWARD: [u32; 12] = [
    0x0000_0000,
    0x8000_0000,
    0x0000_0001,
    0x807f_ffff,
    0x7f7f_ffff,
    0xff7f_ffff,
    0x7f80_0000,
    0xff80_0000,
    0x7fc0_0000,
    0x7f80_0001,
    0xffff_ffff,
    0x3f80_0000,
];

fn awkward_image(w: usize, h: usize, c: usize, salt: u32) -> Image {
    Image::from_fn(w, h, c, |x, y, k| {
        let i = (x * 31 + y * 17 + k * 7) as u32 ^ salt;
        let mixed = i.wrapping_mul(0x9e37_79b9).rotate_left(13);
        if i.is_multiple_of(3) {
            f32::from_bits(AWKWARD[(mixed % 12) as usize])
        } else {
            f32::from_bits(mixed)
        }
    })
}

#[test]
fn pfm_round_trips_bit_exactly_through_a_file() {
    let tmp = tempfile::tempdir().unwrap();
    for (w, h) in [(1, 1), (1, 7), (5, 3), (33, 2)] {
        for c in [1, 3] {
            let img = awkward_image(w, h, c, (w * 100 + h * 10 + c) as u32);
            let path = tmp.path().join(format!("x{w}-{h}-{c}.pfm"));
            write_pfm(&path, &img);
            let back = io::read_image(&path, c).unwrap();
            assert_eq!((back.dims(), back.channels()), ((w, h), c));
            assert_eq!(bits(&back), bits(&img), "{w}x{h}x{c}");
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn pfm_round_trips_any_floats(
        w in 1usize..9,
        h in 1usize..9,
        rgb in any::<bool>(),
        samples in proptest::collection::vec(any::<u32>(), 8 * 8 * 3),
    ) {
        let c = if rgb { 3 } else { 1 };
        let img = Image::from_vec(w, h, c, samples[..w * h * c].iter().map(|&b| f32::from_bits(b)).collect()).unwrap();
        let back = io::pfm::decode(&io::pfm::encode(&img).unwrap(), c).unwrap();
        prop_assert_eq!(bits(&back), bits(&img));
    }
}

#[test]
fn a_big_endian_file_reads_with_its_rows_bottom_up() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("be.pfm");
    // Two pixels wide, two rows; the file's first row is the image's bottom row.
    let mut bytes = b"PF\n2 2\n1.0\n".to_vec();
    for v in [7.0f32, 8.0, 9.0, 10.0, 11.0, 12.0] {
        bytes.extend_from_slice(&v.to_be_bytes());
    }
    for v in [1.0f32, 2.0, 3.0, 4.0, 5.0, f32::from_bits(0x0000_0003)] {
        bytes.extend_from_slice(&v.to_be_bytes());
    }
    std::fs::write(&path, &bytes).unwrap();
    let img = io::read_image(&path, 3).unwrap();
    assert_eq!(img.dims(), (2, 2));
    let want = [
        1.0,
        2.0,
        3.0,
        4.0,
        5.0,
        f32::from_bits(3),
        7.0,
        8.0,
        9.0,
        10.0,
        11.0,
        12.0,
    ];
    assert_eq!(bits(&img), want.map(f32::to_bits).to_vec());
}

#[test]
fn a_damaged_pfm_input_is_one_line_naming_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let set = tmp.path().join("set");
    std::fs::create_dir_all(&set).unwrap();
    let color = set.join("color.pfm");
    let good = io::pfm::encode(&Image::filled(4, 4, 3, 0.5)).unwrap();
    let out = tmp.path().join("out.exr");
    let cases: [(Vec<u8>, &str); 5] = [
        (good[..good.len() - 1].to_vec(), "truncated"),
        // Control bytes in a header field are shown escaped, never echoed raw onto the terminal.
        (
            b"PF\nfo\0ur\x1b[2J 4\n-1.0\n".to_vec(),
            "width `fo\\0ur\\u{1b}[2J`",
        ),
        (
            [b"PX".as_slice(), &good[2..]].concat(),
            "does not start with PF",
        ),
        (b"PF\n100000 100000\n-1.0\n".to_vec(), "more than the"),
        (b"PF\nfour 4\n-1.0\n".to_vec(), "width `four`"),
    ];
    for (bytes, why) in cases {
        std::fs::write(&color, bytes).unwrap();
        let run = gsid(&["denoise", s(&set), "-o", s(&out)]);
        assert_bad_input(&run, "color.pfm");
        assert!(stderr(&run).contains(why), "{}", stderr(&run));
        assert!(!stderr(&run).contains(['\0', '\x1b']), "{:?}", stderr(&run));
        assert!(!out.exists());
    }
}

#[test]
fn ldr_colour_is_linearised_and_exclusive_with_hdr_colour() {
    let tmp = tempfile::tempdir().unwrap();
    let set = gsid::io::load_render_set(&small_set(tmp.path()))
        .unwrap()
        .set;
    // The colour as an 8-bit sRGB PNG, and as the EXR of its linear values (decoded here).
    let color = &set.color;
    let png_path = tmp.path().join("beauty.png");
    let srgb: Vec<u8> = color.data().iter().map(|&v| srgb8(v)).collect();
    image::RgbImage::from_raw(16, 12, srgb.clone())
        .unwrap()
        .save(&png_path)
        .unwrap();
    let linear = |v: u8| {
        let e = v as f32 / 255.0;
        if e <= 0.04045 {
            e / 12.92
        } else {
            ((e + 0.055) / 1.055).powf(2.4)
        }
    };
    let linear_set = tmp.path().join("linear");
    std::fs::create_dir_all(&linear_set).unwrap();
    io::write_exr(
        &linear_set.join("color.exr"),
        &Image::from_vec(16, 12, 3, srgb.iter().map(|&v| linear(v)).collect()).unwrap(),
    )
    .unwrap();
    let albedo = tmp.path().join("set/albedo.exr");
    std::fs::copy(&albedo, linear_set.join("albedo.exr")).unwrap();

    let (ldr_out, linear_out) = (tmp.path().join("ldr.exr"), tmp.path().join("linear.exr"));
    let run = ok(&[
        "denoise",
        "--ldr",
        s(&png_path),
        "--alb",
        s(&albedo),
        "-o",
        s(&ldr_out),
    ]);
    assert!(
        stderr(&run).contains("8-bit colour is not HDR"),
        "{}",
        stderr(&run)
    );
    ok(&["denoise", s(&linear_set), "-o", s(&linear_out), "-q"]);
    assert_eq!(
        std::fs::read(&ldr_out).unwrap(),
        std::fs::read(&linear_out).unwrap()
    );

    let other = tmp.path().join("other.exr");
    let exr_color = tmp.path().join("set/color.exr");
    for (args, culprit) in [
        (vec!["--ldr", s(&png_path), "--hdr", s(&exr_color)], "--ldr"),
        (
            vec!["--ldr", s(&png_path), "--color", s(&exr_color)],
            "--ldr",
        ),
        (vec!["--ldr", s(&exr_color)], "color.exr"),
    ] {
        let mut all = vec!["denoise"];
        all.extend(args);
        all.extend(["-o", s(&other)]);
        let run = gsid(&all);
        assert_eq!(run.status.code(), Some(2), "{}", stderr(&run));
        assert!(stderr(&run).contains(culprit), "{}", stderr(&run));
        assert!(!other.exists());
    }
}
