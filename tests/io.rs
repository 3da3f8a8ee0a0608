//! Reading and writing: half floats, channel naming, PNG, and parsers that never panic on garbage.

use std::path::Path;

use exr::prelude::*;
use gsid::pipeline::PipelineSpec;
use gsid::{io, Image};
use proptest::prelude::*;

fn write_channels(path: &Path, w: usize, h: usize, channels: Vec<(&str, FlatSamples)>) {
    let list: SmallVec<[AnyChannel<FlatSamples>; 4]> = channels
        .into_iter()
        .map(|(n, s)| AnyChannel::new(n, s))
        .collect();
    let layer = Layer::new(
        (w, h),
        LayerAttributes::default(),
        Encoding::FAST_LOSSLESS,
        AnyChannels::sort(list),
    );
    exr::prelude::Image::from_layer(layer)
        .write()
        .to_file(path)
        .unwrap();
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
    fn corrupted_exr_never_panics(cut in 0usize..2000, flips in proptest::collection::vec((0usize..2000, any::<u8>()), 0..8)) {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("c.exr");
        io::write_exr(&path, &Image::from_fn(16, 8, 3, |x, y, c| (x * y + c) as f32)).unwrap();
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
