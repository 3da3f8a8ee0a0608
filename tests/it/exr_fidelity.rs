//! What an EXR output keeps of the colour's file: alpha copied bit for bit, the data and display
//! windows, header attributes, the other layers with `--keep-layers`; `--half` and `--compression`.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use crate::common::{assert_bad_input, gsid, stderr};
use exr::meta::attribute::{AttributeValue, IntegerBounds, SampleType, Text};
use exr::meta::header::LayerAttributes;
use exr::prelude::{
    f16, read_all_flat_layers_from_file, AnyChannel, AnyChannels, Compression, Encoding, FlatImage,
    FlatSamples, Image as ExrImage, Layer, SmallVec, Vec2, WritableImage,
};

const CYCLES: &str = "fixtures/cycles-studio/spp4.exr";
const W: usize = 24;
const H: usize = 16;

/// A small layer's worth of header: data window origin, display window, custom attributes.
struct Header {
    origin: (i32, i32),
    display: IntegerBounds,
    custom: Vec<(&'static str, &'static str)>,
}

impl Default for Header {
    fn default() -> Self {
        Header {
            origin: (0, 0),
            display: IntegerBounds::from_dimensions((W, H)),
            custom: Vec::new(),
        }
    }
}

fn ramp(i: usize, c: usize) -> f32 {
    ((i * 7 + c * 3) % 17) as f32 / 17.0 + 0.05
}

/// Writes a `W`×`H` EXR of f32 `names` channels (a ramp) plus `extra` channels as given.
fn write(path: &Path, names: &[&str], extra: Vec<(&str, FlatSamples)>, header: &Header) {
    let mut list: SmallVec<[AnyChannel<FlatSamples>; 4]> = names
        .iter()
        .enumerate()
        .map(|(c, n)| {
            AnyChannel::new(
                *n,
                FlatSamples::F32((0..W * H).map(|i| ramp(i, c)).collect()),
            )
        })
        .collect();
    list.extend(extra.into_iter().map(|(n, s)| AnyChannel::new(n, s)));
    let mut attributes = LayerAttributes {
        layer_position: Vec2(header.origin.0, header.origin.1),
        ..LayerAttributes::default()
    };
    for (k, v) in &header.custom {
        attributes
            .other
            .insert(Text::from(*k), AttributeValue::Text(Text::from(*v)));
    }
    let layer = Layer::new(
        (W, H),
        attributes,
        Encoding::FAST_LOSSLESS,
        AnyChannels::sort(list),
    );
    let mut image = ExrImage::from_layer(layer);
    image.attributes.display_window = header.display;
    image.write().to_file(path).unwrap();
}

fn read(path: &Path) -> FlatImage {
    read_all_flat_layers_from_file(path).expect("read output")
}

/// Every channel of a file's first layer by name.
fn channels(image: &FlatImage) -> HashMap<String, &FlatSamples> {
    image.layer_data[0]
        .channel_data
        .list
        .iter()
        .map(|c| (c.name.to_string(), &c.sample_data))
        .collect()
}

/// Sample bits, so that two NaNs with the same payload compare equal and -0 differs from 0.
fn bits(s: &FlatSamples) -> Vec<u32> {
    match s {
        FlatSamples::F16(v) => v.iter().map(|x| x.to_bits() as u32).collect(),
        FlatSamples::F32(v) => v.iter().map(|x| x.to_bits()).collect(),
        FlatSamples::U32(v) => v.clone(),
    }
}

fn sample_type(s: &FlatSamples) -> SampleType {
    match s {
        FlatSamples::F16(_) => SampleType::F16,
        FlatSamples::F32(_) => SampleType::F32,
        FlatSamples::U32(_) => SampleType::U32,
    }
}

/// `gsid denoise INPUT -o OUT FLAGS…`.
fn denoise_run(input: &Path, out: &Path, flags: &[&str]) -> std::process::Output {
    let mut args = vec![
        "denoise",
        input.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(flags);
    gsid(&args)
}

fn denoise(input: &Path, out: &Path, flags: &[&str]) {
    let run = denoise_run(input, out, &[&["-q"], flags].concat());
    assert_eq!(run.status.code(), Some(0), "{}", stderr(&run));
}

/// A render-set folder `set` in `dir` whose `color.exr` has R, G, B, the `extra` channels and
/// `header`.
fn colour_set(dir: &Path, extra: Vec<(&str, FlatSamples)>, header: &Header) -> PathBuf {
    let set = dir.join("set");
    std::fs::create_dir(&set).unwrap();
    write(&set.join("color.exr"), &["R", "G", "B"], extra, header);
    set
}

/// An alpha no filter would leave alone: half floats with a NaN payload, a subnormal and -0.
fn odd_alpha() -> FlatSamples {
    let special = [
        f16::from_bits(0x7e01),
        f16::from_bits(0x0001),
        f16::from_bits(0x8000),
    ];
    FlatSamples::F16(
        (0..W * H)
            .map(|i| {
                special
                    .get(i)
                    .copied()
                    .unwrap_or(f16::from_f32((i % 5) as f32 / 4.0))
            })
            .collect(),
    )
}

#[test]
fn rgba_alpha_comes_back_bit_exact() {
    let tmp = tempfile::tempdir().unwrap();
    let alpha = odd_alpha();
    let set = colour_set(tmp.path(), vec![("A", alpha.clone())], &Header::default());
    let out = tmp.path().join("out.exr");
    denoise(&set, &out, &[]);
    let image = read(&out);
    let got = channels(&image);
    assert_eq!(bits(got["A"]), bits(&alpha), "alpha changed");
    assert_eq!(
        sample_type(got["A"]),
        SampleType::F16,
        "alpha keeps its type"
    );
    assert_eq!(sample_type(got["R"]), SampleType::F32);

    // A multilayer file's `Combined.A` comes back as the plain output's `A`.
    let out = tmp.path().join("cycles.exr");
    denoise(Path::new(CYCLES), &out, &["--pipeline", "fast"]);
    let input = read(Path::new(CYCLES));
    let output = read(&out);
    assert_eq!(
        bits(channels(&output)["A"]),
        bits(channels(&input)["ViewLayer.Combined.A"])
    );
}

#[test]
fn data_and_display_windows_survive_and_buffers_must_share_them() {
    let tmp = tempfile::tempdir().unwrap();
    let header = Header {
        origin: (-8, 12),
        display: IntegerBounds::new((0, 0), (40, 48)),
        custom: Vec::new(),
    };
    let set = colour_set(tmp.path(), vec![], &header);
    write(&set.join("albedo.exr"), &["R", "G", "B"], vec![], &header);
    let out = tmp.path().join("out.exr");
    denoise(&set, &out, &[]);
    let image = read(&out);
    assert_eq!(image.layer_data[0].attributes.layer_position, Vec2(-8, 12));
    assert_eq!(image.layer_data[0].size, Vec2(W, H));
    assert_eq!(image.attributes.display_window, header.display);

    let shifted = Header {
        origin: (0, 12),
        ..header
    };
    write(&set.join("albedo.exr"), &["R", "G", "B"], vec![], &shifted);
    let run = denoise_run(&set, &out, &[]);
    assert_bad_input(&run, "albedo.exr");
    assert!(stderr(&run).contains("data window"), "{}", stderr(&run));
}

#[test]
fn custom_attributes_survive_in_the_same_order_every_run() {
    let tmp = tempfile::tempdir().unwrap();
    let custom = vec![
        ("renderer", "Cycles 4.5"),
        ("Camera", "shotcam"),
        ("Frame", "1001"),
        ("Scene", "studio"),
        ("Date", "2026/12/01"),
        ("Note", "crop"),
    ];
    let header = Header {
        custom: custom.clone(),
        ..Header::default()
    };
    let set = colour_set(tmp.path(), vec![], &header);
    let (a, b) = (tmp.path().join("a.exr"), tmp.path().join("b.exr"));
    denoise(&set, &a, &[]);
    denoise(&set, &b, &[]);
    let other = &read(&a).layer_data[0].attributes.other;
    for (k, v) in &custom {
        assert_eq!(
            other.get(&Text::from(*k)),
            Some(&AttributeValue::Text(Text::from(*v))),
            "attribute {k}"
        );
    }
    assert!(
        std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap(),
        "two runs wrote the attributes in different orders"
    );
}

#[test]
fn half_and_compression_set_the_header() {
    let tmp = tempfile::tempdir().unwrap();
    let alpha = FlatSamples::F32((0..W * H).map(|i| i as f32 / 1000.0).collect());
    let set = colour_set(tmp.path(), vec![("A", alpha.clone())], &Header::default());
    let out = tmp.path().join("out.exr");
    denoise(&set, &out, &["--half", "--compression", "piz"]);
    let image = read(&out);
    let got = channels(&image);
    for c in ["R", "G", "B"] {
        assert_eq!(sample_type(got[c]), SampleType::F16, "{c} is not half");
    }
    // Every channel of the beauty is half, so an RGBA reader takes the file as one type.
    let FlatSamples::F32(a) = &alpha else {
        unreachable!()
    };
    let halved = FlatSamples::F16(a.iter().map(|&v| f16::from_f32(v)).collect());
    assert_eq!(bits(got["A"]), bits(&halved), "alpha is written as half");
    assert_eq!(image.layer_data[0].encoding.compression, Compression::PIZ);

    // Without --compression, the colour file's own (this one RLE).
    denoise(&set, &out, &[]);
    assert_eq!(
        read(&out).layer_data[0].encoding.compression,
        Compression::RLE
    );

    let run = denoise_run(&set, &out, &["--compression", "jpeg"]);
    assert_eq!(run.status.code(), Some(2), "{}", stderr(&run));
    assert!(stderr(&run).contains("piz"), "{}", stderr(&run));
}

#[test]
fn keep_layers_writes_every_other_channel_unchanged() {
    let tmp = tempfile::tempdir().unwrap();
    let input = tmp.path().join("spp4.exr");
    std::fs::copy(CYCLES, &input).unwrap();
    let (kept, plain) = (tmp.path().join("kept.exr"), tmp.path().join("plain.exr"));
    denoise(&input, &kept, &["--pipeline", "fast", "--keep-layers"]);
    denoise(&input, &plain, &["--pipeline", "fast"]);
    let (source, kept, plain) = (read(&input), read(&kept), read(&plain));
    let (source, got, plain) = (channels(&source), channels(&kept), channels(&plain));
    let mut names: Vec<&String> = source.keys().collect();
    names.sort();
    assert_eq!(got.len(), source.len(), "the same channels");
    for name in names {
        let out = got.get(name).unwrap_or_else(|| panic!("{name} is missing"));
        let beauty = ["R", "G", "B"].map(|c| format!("ViewLayer.Combined.{c}"));
        if let Some(c) = beauty.iter().position(|b| b == name) {
            let denoised = plain[["R", "G", "B"][c]];
            assert_eq!(
                bits(out),
                bits(denoised),
                "{name} is not the denoised colour"
            );
            assert_ne!(bits(out), bits(source[name]), "{name} was not replaced");
        } else {
            assert_eq!(bits(out), bits(source[name]), "{name} changed");
            assert_eq!(sample_type(out), sample_type(source[name]));
        }
    }
    assert!(kept.layer_data[0]
        .attributes
        .other
        .contains_key(&Text::from("BlenderMultiChannel")));
}

#[test]
fn keep_layers_without_other_layers_exits_2() {
    let tmp = tempfile::tempdir().unwrap();
    let alpha = FlatSamples::F32(vec![1.0; W * H]);
    let set = colour_set(tmp.path(), vec![("A", alpha)], &Header::default());
    let out = tmp.path().join("out.exr");
    let run = denoise_run(&set, &out, &["--keep-layers"]);
    assert_bad_input(&run, "--keep-layers");
    assert!(!out.exists());
}
