//! Reading and writing: half floats, tiles and mip maps, channel naming, files byte-identical to the
//! exr crate's own writer, PNG, and parsers that never panic on garbage.

use std::path::Path;

use exr::prelude::*;
use gsid::pipeline::PipelineSpec;
use gsid::{io, Image};
use proptest::prelude::*;

/// Writes one layer with the exr crate's own image-level writer.
fn write_layer(
    path: &Path,
    size: (usize, usize),
    encoding: Encoding,
    list: SmallVec<[AnyChannel<FlatSamples>; 4]>,
) {
    let layer = Layer::new(
        size,
        LayerAttributes::default(),
        encoding,
        AnyChannels::sort(list),
    );
    exr::prelude::Image::from_layer(layer)
        .write()
        .to_file(path)
        .unwrap();
}

fn write_channels(path: &Path, w: usize, h: usize, channels: Vec<(&str, FlatSamples)>) {
    let list = channels
        .into_iter()
        .map(|(n, s)| AnyChannel::new(n, s))
        .collect();
    write_layer(path, (w, h), Encoding::FAST_LOSSLESS, list);
}

#[test]
fn half_float_exr_reads_as_f32() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("half.exr");
    let vals = |o: f32| {
        (0..6)
            .map(|i| f16::from_f32(i as f32 * 0.25 + o))
            .collect::<Vec<_>>()
    };
    write_channels(
        &path,
        3,
        2,
        vec![
            ("R", FlatSamples::F16(vals(0.0))),
            ("G", FlatSamples::F16(vals(1.0))),
            ("B", FlatSamples::F16(vals(2.0))),
        ],
    );
    let img = io::read_image(&path, 3).unwrap();
    assert_eq!(img.dims(), (3, 2));
    assert_eq!(img.pixel(1), &[0.25, 1.25, 2.25]);
}

#[test]
fn layer_prefixed_and_single_channel_names_are_found() {
    let tmp = tempfile::tempdir().unwrap();
    let rgb = tmp.path().join("blender.exr");
    let plane = |v: f32| FlatSamples::F32(vec![v; 4]);
    write_channels(
        &rgb,
        2,
        2,
        vec![
            ("ViewLayer.Combined.R", plane(0.1)),
            ("ViewLayer.Combined.G", plane(0.2)),
            ("ViewLayer.Combined.B", plane(0.3)),
        ],
    );
    assert_eq!(io::read_image(&rgb, 3).unwrap().pixel(3), &[0.1, 0.2, 0.3]);
    let depth = tmp.path().join("depth.exr");
    write_channels(&depth, 2, 2, vec![("Z", plane(7.0))]);
    assert_eq!(io::read_image(&depth, 1).unwrap().pixel(0), &[7.0]);
    let odd = tmp.path().join("odd.exr");
    write_channels(&odd, 2, 2, vec![("distance", plane(3.0))]);
    assert_eq!(io::read_image(&odd, 1).unwrap().pixel(0), &[3.0]);
}

#[test]
fn written_exr_round_trips_bit_exactly() {
    let tmp = tempfile::tempdir().unwrap();
    let img = Image::from_fn(5, 3, 3, |x, y, c| {
        (x as f32 - 2.0) * 1e-3 + y as f32 * 1e4 + c as f32
    });
    let path = tmp.path().join("rt.exr");
    io::write_exr(&path, &img).unwrap();
    assert_eq!(io::read_image(&path, 3).unwrap(), img);
    let one = Image::from_fn(5, 3, 1, |x, y, _| (x + 10 * y) as f32);
    io::write_exr(&path, &one).unwrap();
    assert_eq!(io::read_image(&path, 1).unwrap(), one);
}

/// What the exr crate's image-level API writes for `img` (gsid's writer must give the same bytes).
fn crate_written(path: &Path, img: &Image, compression: Compression) {
    let names = ["R", "G", "B", "A"];
    let c = img.channels();
    let names: &[&str] = if c == 1 { &["Y"] } else { &names[..c] };
    let list: SmallVec<[AnyChannel<FlatSamples>; 4]> = names
        .iter()
        .enumerate()
        .map(|(k, n)| {
            let plane = img.data().chunks_exact(c).map(|px| px[k]).collect();
            AnyChannel::new(*n, FlatSamples::F32(plane))
        })
        .collect();
    let encoding = Encoding {
        compression,
        blocks: Blocks::ScanLines,
        line_order: LineOrder::Increasing,
    };
    write_layer(path, img.dims(), encoding, list);
}

#[test]
fn written_exr_is_byte_identical_to_the_crates_own_writer() {
    let tmp = tempfile::tempdir().unwrap();
    let ours = tmp.path().join("ours.exr");
    let theirs = tmp.path().join("theirs.exr");
    for (w, h) in [(1, 1), (5, 3), (37, 23), (64, 70)] {
        for c in [1, 3, 4] {
            let img = Image::from_fn(w, h, c, |x, y, k| {
                ((x * 7 + y * 13 + k) % 11) as f32 * 0.37 - 1.0
            });
            io::write_exr(&ours, &img).unwrap();
            crate_written(&theirs, &img, Compression::ZIP16);
            assert_eq!(
                std::fs::read(&ours).unwrap(),
                std::fs::read(&theirs).unwrap(),
                "zip {w}x{h}x{c}"
            );
            io::PendingOutput::create(&ours)
                .unwrap()
                .write_exr(&img, io::Compression::Rle)
                .unwrap();
            crate_written(&theirs, &img, Compression::RLE);
            assert_eq!(
                std::fs::read(&ours).unwrap(),
                std::fs::read(&theirs).unwrap(),
                "rle {w}x{h}x{c}"
            );
            assert_eq!(
                io::read_image(&ours, c.min(3)).unwrap().pixel(w * h - 1)[0],
                img.pixel(w * h - 1)[0]
            );
        }
    }
}

#[test]
fn tiled_mixed_sample_and_mip_mapped_files_read_exactly() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("f.exr");
    let (w, h) = (37, 23);
    let value = |x: usize, y: usize, k: usize| (x + 40 * y) as f32 * 0.5 + k as f32 * 1000.0;
    let plane = |k: usize, w: usize, h: usize| -> Vec<f32> {
        (0..w * h).map(|i| value(i % w, i / w, k)).collect()
    };
    // G is stored as u32, so it reads back truncated.
    let want = Image::from_fn(w, h, 3, |x, y, k| {
        let v = value(x, y, k);
        if k == 1 {
            v.trunc()
        } else {
            v
        }
    });
    let channels = || -> SmallVec<[AnyChannel<FlatSamples>; 4]> {
        SmallVec::from_vec(vec![
            AnyChannel::new("R", FlatSamples::F32(plane(0, w, h))),
            AnyChannel::new(
                "G",
                FlatSamples::U32(plane(1, w, h).iter().map(|&v| v as u32).collect()),
            ),
            AnyChannel::new("B", FlatSamples::F32(plane(2, w, h))),
            AnyChannel::new("extra", FlatSamples::F16(vec![f16::from_f32(0.5); w * h])),
        ])
    };
    for (blocks, line_order, compression) in [
        (
            Blocks::Tiles(Vec2(16, 8)),
            LineOrder::Increasing,
            Compression::ZIP16,
        ),
        (
            Blocks::Tiles(Vec2(5, 5)),
            LineOrder::Decreasing,
            Compression::PIZ,
        ),
        (Blocks::ScanLines, LineOrder::Decreasing, Compression::ZIP1),
        (
            Blocks::Tiles(Vec2(64, 64)),
            LineOrder::Unspecified,
            Compression::Uncompressed,
        ),
    ] {
        let encoding = Encoding {
            compression,
            blocks,
            line_order,
        };
        write_layer(&path, (w, h), encoding, channels());
        assert_eq!(
            io::read_image(&path, 3).unwrap(),
            want,
            "{blocks:?} {line_order:?} {compression:?}"
        );
    }

    // A mip-mapped file reads at its largest level; the smaller levels hold other values.
    let level_count = (w.max(h) as f32).log2().floor() as usize + 1;
    let mips = |k: usize| Levels::Mip {
        rounding_mode: exr::math::RoundingMode::Down,
        level_data: (0..level_count)
            .map(|l| {
                let (lw, lh) = ((w >> l).max(1), (h >> l).max(1));
                FlatSamples::F32(if l == 0 {
                    plane(k, lw, lh)
                } else {
                    vec![-9.0; lw * lh]
                })
            })
            .collect(),
    };
    let list: SmallVec<[AnyChannel<Levels<FlatSamples>>; 4]> = (0..3)
        .map(|k| AnyChannel::new(["R", "G", "B"][k], mips(k)))
        .collect();
    let encoding = Encoding {
        compression: Compression::RLE,
        blocks: Blocks::Tiles(Vec2(8, 8)),
        line_order: LineOrder::Increasing,
    };
    let layer = Layer::new(
        (w, h),
        LayerAttributes::default(),
        encoding,
        AnyChannels::sort(list),
    );
    exr::prelude::Image::from_layer(layer)
        .write()
        .to_file(&path)
        .unwrap();
    assert_eq!(
        io::read_image(&path, 3).unwrap(),
        Image::from_fn(w, h, 3, value)
    );
}

#[test]
fn png_colour_is_decoded_from_srgb() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("c.png");
    image::RgbImage::from_raw(1, 1, vec![255, 128, 0])
        .unwrap()
        .save(&path)
        .unwrap();
    let img = io::read_image(&path, 3).unwrap();
    assert!((img.pixel(0)[0] - 1.0).abs() < 1e-6);
    assert!((img.pixel(0)[1] - 0.2158605).abs() < 1e-5);
    assert_eq!(img.pixel(0)[2], 0.0);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// Corrupting or truncating a valid EXR gives an error or an image, never a panic.
    #[test]
    fn corrupted_exr_never_panics(tiled in any::<bool>(), cut in 0usize..2000, flips in proptest::collection::vec((0usize..2000, any::<u8>()), 0..8)) {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("c.exr");
        if tiled {
            let list = (0..3)
                .map(|k| AnyChannel::new(["R", "G", "B"][k], FlatSamples::F32((0..16 * 8).map(|i| (i * k) as f32).collect())))
                .collect();
            let encoding = Encoding { compression: Compression::ZIP1, blocks: Blocks::Tiles(Vec2(4, 4)), line_order: LineOrder::Increasing };
            write_layer(&path, (16, 8), encoding, list);
        } else {
            io::write_exr(&path, &Image::from_fn(16, 8, 3, |x, y, c| (x * y + c) as f32)).unwrap();
        }
        let mut bytes = std::fs::read(&path).unwrap();
        for (at, v) in flips {
            let n = bytes.len();
            bytes[at % n] = v;
        }
        bytes.truncate(cut.max(1).min(bytes.len()));
        std::fs::write(&path, &bytes).unwrap();
        let _ = io::read_image(&path, 3);
    }

    /// Arbitrary text as a pipeline file is an error or a pipeline, never a panic.
    #[test]
    fn pipeline_parser_never_panics(text in "(name|description|stage|kind|gsid|sigma|walks|weights|\\[|\\]|=|\"|\\.|\n| |[0-9]|-|e)*") {
        if let Ok(spec) = PipelineSpec::parse(&text, "fuzz.toml") {
            let _ = spec.build();
        }
    }

    /// Arbitrary `--set` assignments are an error or accepted, never a panic.
    #[test]
    fn overrides_never_panic(key in "[a-z_.]{0,20}", value in "[a-z0-9_.\\[\\]\"{}=-]{0,12}") {
        let mut spec = PipelineSpec::resolve("gsid").unwrap();
        if spec.apply_set(&format!("{key}={value}")).is_ok() {
            let _ = spec.build();
        }
    }
}

/// A 4×2 render set folder with colour and the named extra buffers (RGB unless one channel).
fn noise_set(dir: &Path, extra: &[(&str, Image)]) {
    std::fs::create_dir_all(dir).unwrap();
    let color = Image::from_fn(4, 2, 3, |x, y, c| (x + y + c) as f32 * 0.1);
    io::write_exr(&dir.join("color.exr"), &color).unwrap();
    for (name, img) in extra {
        io::write_exr(&dir.join(format!("{name}.exr")), img).unwrap();
    }
}

fn rgb(v: f32) -> Image {
    Image::from_fn(4, 2, 3, |x, _, c| v + (x + c) as f32)
}

#[test]
fn a_folders_variance_and_halves_are_loaded_into_the_noise_inputs() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("set");
    noise_set(
        &dir,
        &[
            ("variance", rgb(0.5)),
            ("color_a", rgb(1.0)),
            ("color_b", rgb(2.0)),
        ],
    );
    let loaded = io::load_render_set(&dir).unwrap();
    let noise = &loaded.set.noise;
    assert_eq!(noise.variance.as_ref().unwrap().data(), rgb(0.5).data());
    let [a, b] = noise.halves.as_ref().unwrap();
    assert_eq!((a.data(), b.data()), (rgb(1.0).data(), rgb(2.0).data()));
    let names: Vec<&str> = loaded.files.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["color", "variance", "color_a", "color_b"]);
    // Optional buffers: the missing-buffers note lists features only.
    let missing = loaded
        .notes
        .iter()
        .find(|n| n.starts_with("missing"))
        .unwrap();
    assert!(!missing.contains("variance") && !missing.contains("color_a"));

    // Named inputs give the same buffers.
    let named = io::load_named(&[
        ("color", dir.join("color.exr")),
        ("variance", dir.join("variance.exr")),
        ("color_a", dir.join("color_a.exr")),
        ("color_b", dir.join("color_b.exr")),
    ])
    .unwrap();
    assert_eq!(
        named.set.noise.variance.as_ref().unwrap().data(),
        rgb(0.5).data()
    );
    let [a, b] = named.set.noise.halves.as_ref().unwrap();
    assert_eq!((a.data(), b.data()), (rgb(1.0).data(), rgb(2.0).data()));
}

#[test]
fn a_one_channel_variance_is_used_for_all_three_with_a_note() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("set");
    let y = Image::from_fn(4, 2, 1, |x, y, _| (x + 4 * y) as f32);
    noise_set(&dir, &[("variance", y.clone())]);
    let loaded = io::load_render_set(&dir).unwrap();
    let v = loaded.set.noise.variance.as_ref().unwrap();
    assert_eq!(v.channels(), 3);
    for p in 0..8 {
        assert_eq!(v.pixel(p), &[y.data()[p]; 3]);
    }
    assert!(loaded.set.noise.halves.is_none());
    assert!(
        loaded
            .notes
            .iter()
            .any(|n| n.contains("one-channel variance")),
        "{:?}",
        loaded.notes
    );
}

#[test]
fn one_half_alone_or_a_wrong_size_is_an_error_naming_the_buffer() {
    let tmp = tempfile::tempdir().unwrap();
    for (have, missing) in [("color_a", "color_b"), ("color_b", "color_a")] {
        let dir = tmp.path().join(have);
        noise_set(&dir, &[(have, rgb(1.0))]);
        let e = io::load_render_set(&dir).err().unwrap();
        assert_eq!(e.exit_code(), 2);
        assert!(
            e.to_string().contains(&format!("{missing}.exr: not found")),
            "{e} does not name {missing} as the missing one"
        );
        let e = io::load_named(&[
            ("color", dir.join("color.exr")),
            (have, dir.join(format!("{have}.exr"))),
        ])
        .err()
        .unwrap();
        assert_eq!(e.exit_code(), 2);
        let flag = |b: &str| format!("--{}", b.replace('_', "-"));
        assert!(
            e.to_string().starts_with(&format!(
                "{}: is required with {}",
                flag(missing),
                flag(have)
            )),
            "{e} does not name {missing} as the missing one"
        );
    }
    let dir = tmp.path().join("small");
    noise_set(&dir, &[("variance", Image::new(2, 2, 3))]);
    let e = io::load_render_set(&dir).err().unwrap();
    assert!(e.to_string().contains("variance.exr") && e.to_string().contains("2x2"));
}

#[test]
fn a_multilayer_variance_pass_is_loaded() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("render.exr");
    let plane = |v: f32| FlatSamples::F32(vec![v; 6]);
    write_channels(
        &path,
        3,
        2,
        vec![
            ("ViewLayer.Combined.R", plane(1.0)),
            ("ViewLayer.Combined.G", plane(1.0)),
            ("ViewLayer.Combined.B", plane(1.0)),
            ("ViewLayer.Denoising Variance.R", plane(0.25)),
            ("ViewLayer.Denoising Variance.G", plane(0.5)),
            ("ViewLayer.Denoising Variance.B", plane(0.75)),
        ],
    );
    let loaded = io::load_input(&path, &[]).unwrap();
    let v = loaded.set.noise.variance.as_ref().unwrap();
    assert_eq!(v.pixel(5), &[0.25, 0.5, 0.75]);
    assert!(loaded.notes[0].contains("variance ← ViewLayer.Denoising Variance"));
}

/// A header is checked against the file's bytes by its compression method before anything is
/// decoded: an uncompressed 256² file whose header says 1024² cannot hold its samples and is
/// refused naming the file; a flat 1024² DWAB file (1,330 bytes from OpenEXR 3.5: the DWA codecs
/// store a flat channel in a few bytes whatever its size) is read, also as a multilayer file.
#[test]
fn declared_sizes_are_checked_against_what_the_compression_can_hold() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("stored.exr");
    crate_written(
        &path,
        &Image::filled(256, 256, 3, 0.5),
        Compression::Uncompressed,
    );
    let mut bytes = std::fs::read(&path).unwrap();
    let value = |bytes: &[u8], tag: &[u8]| {
        bytes.windows(tag.len()).position(|w| w == tag).unwrap() + tag.len() + 4
    };
    for tag in [&b"dataWindow\0box2i\0"[..], &b"displayWindow\0box2i\0"[..]] {
        let at = value(&bytes, tag);
        for field in [8, 12] {
            bytes[at + field..at + field + 4].copy_from_slice(&1023i32.to_le_bytes());
        }
    }
    // One scan line a chunk when stored: the chunk count to match the new size.
    if let Some(at) = bytes.windows(15).position(|w| w == b"chunkCount\0int\0") {
        let at = at + 15 + 4;
        bytes[at..at + 4].copy_from_slice(&1024i32.to_le_bytes());
    }
    std::fs::write(&path, bytes).unwrap();
    let err = io::read_image(&path, 3).unwrap_err().to_string();
    assert!(
        err.contains("stored.exr") && err.contains("1024x1024") && err.contains("file can hold"),
        "{err}"
    );

    let flat = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/flat-1024-dwab.exr");
    let img = io::read_image(&flat, 3).unwrap();
    assert_eq!(img.dims(), (1024, 1024));
    assert!(img.data().iter().all(|&v| v == 0.0));
    let set = io::load_input(&flat, &[]).unwrap();
    assert_eq!(set.set.color.dims(), (1024, 1024));
}
