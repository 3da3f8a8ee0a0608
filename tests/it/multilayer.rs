//! Multilayer and multi-part EXR files as one input, and buffers named one by one (`--hdr` …).

use std::path::Path;

use crate::common::{assert_bad_input, gsid, stderr};
use exr::prelude::{
    read_all_flat_layers_from_file, AnyChannel, AnyChannels, Encoding, FlatSamples,
    Image as ExrImage, Layer as ExrLayer, SmallVec, WritableImage,
};
use gsid::{io, Image};

const CYCLES: &str = "fixtures/cycles-studio/spp4.exr";
const MITSUBA: &str = "fixtures/mitsuba-aov/spp4.exr";

/// The channels `names` of an EXR file, read with the exr crate, as one image.
fn channels_of(path: &str, names: &[&str]) -> Image {
    let file = read_all_flat_layers_from_file(path).expect("read fixture");
    let layer = &file.layer_data[0];
    let (w, h) = (layer.size.x(), layer.size.y());
    let mut data = vec![0.0; w * h * names.len()];
    for (k, name) in names.iter().enumerate() {
        let c = layer
            .channel_data
            .list
            .iter()
            .find(|c| c.name.to_string() == *name)
            .unwrap_or_else(|| panic!("{path} has no channel {name}"));
        for (px, v) in data
            .chunks_exact_mut(names.len())
            .zip(c.sample_data.values_as_f32())
        {
            px[k] = v;
        }
    }
    Image::from_vec(w, h, names.len(), data).unwrap()
}

/// Writes the Cycles fixture's `Combined` as a plain RGBA file with the fixture's header
/// attributes and alpha as stored: all an output keeps of it.
fn cycles_color(path: &Path) {
    let mut file = read_all_flat_layers_from_file(CYCLES).expect("read fixture");
    let layer = file.layer_data.remove(0);
    let list: SmallVec<[AnyChannel<FlatSamples>; 4]> = layer
        .channel_data
        .list
        .into_iter()
        .filter_map(|c| {
            let name = c.name.to_string();
            let short = name.strip_prefix("ViewLayer.Combined.")?.to_string();
            Some(AnyChannel {
                name: short.as_str().into(),
                ..c
            })
        })
        .collect();
    let rgba = ExrLayer::new(
        layer.size,
        layer.attributes,
        Encoding::FAST_LOSSLESS,
        AnyChannels::sort(list),
    );
    let mut image = ExrImage::from_layer(rgba);
    image.attributes = file.attributes;
    image.write().to_file(path).unwrap();
}

/// Writes the Cycles fixture's colour, albedo, normal (and depth, if asked) as a render-set folder.
fn cycles_folder(dir: &Path, depth: bool) {
    let pass = |p: &str, cs: &[&str]| {
        let names: Vec<String> = cs.iter().map(|c| format!("ViewLayer.{p}.{c}")).collect();
        let names: Vec<&str> = names.iter().map(String::as_str).collect();
        channels_of(CYCLES, &names)
    };
    cycles_color(&dir.join("color.exr"));
    io::write_exr(
        &dir.join("albedo.exr"),
        &pass("Denoising Albedo", &["R", "G", "B"]),
    )
    .unwrap();
    io::write_exr(
        &dir.join("normal.exr"),
        &pass("Denoising Normal", &["X", "Y", "Z"]),
    )
    .unwrap();
    if depth {
        io::write_exr(&dir.join("depth.exr"), &pass("Denoising Depth", &["Z"])).unwrap();
    }
}

/// The output's bytes. One compression for every run: by default an output follows its colour
/// file's, and these runs read the same pixels from files compressed differently.
fn denoise(args: &[&str], out: &Path) -> Vec<u8> {
    let mut all = vec!["denoise", "--compression", "zip"];
    all.extend_from_slice(args);
    all.extend_from_slice(&["-o", out.to_str().unwrap()]);
    let run = gsid(&all);
    assert_eq!(run.status.code(), Some(0), "{}", stderr(&run));
    std::fs::read(out).unwrap()
}

/// The `gsid: FILE: color ← …` line of a run.
fn mapping_line(args: &[&str], out: &Path) -> String {
    let mut all = vec!["denoise", "--compression", "zip"];
    all.extend_from_slice(args);
    all.extend_from_slice(&["-o", out.to_str().unwrap()]);
    let run = gsid(&all);
    assert_eq!(run.status.code(), Some(0), "{}", stderr(&run));
    stderr(&run)
        .lines()
        .find(|l| l.contains("color ←"))
        .unwrap_or_else(|| panic!("no mapping line: {}", stderr(&run)))
        .to_string()
}

#[test]
fn cycles_file_denoises_as_its_passes_split_into_a_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let folder = tmp.path().join("set");
    std::fs::create_dir(&folder).unwrap();
    cycles_folder(&folder, true);
    let from_file = tmp.path().join("file.exr");
    let line = mapping_line(&[CYCLES], &from_file);
    for used in [
        "color ← ViewLayer.Combined.{R,G,B}",
        "albedo ← ViewLayer.Denoising Albedo.{R,G,B}",
        "normal ← ViewLayer.Denoising Normal.{X,Y,Z}",
        "depth ← ViewLayer.Denoising Depth.Z",
    ] {
        assert!(line.contains(used), "`{used}` not in: {line}");
    }
    let from_folder = denoise(&[folder.to_str().unwrap()], &tmp.path().join("folder.exr"));
    assert!(
        std::fs::read(&from_file).unwrap() == from_folder,
        "file and folder outputs differ"
    );
}

/// Writes one scan-line layer of f32 channels, `(name, value at pixel i)`.
/// A channel's name and its value at each pixel index.
type Channel<'a> = (&'a str, fn(usize) -> f32);

fn write_layout(path: &Path, w: usize, h: usize, channels: &[Channel]) {
    let list: SmallVec<[AnyChannel<FlatSamples>; 4]> = channels
        .iter()
        .map(|(name, f)| AnyChannel::new(*name, FlatSamples::F32((0..w * h).map(f).collect())))
        .collect();
    ExrImage::from_channels((w, h), AnyChannels::sort(list))
        .write()
        .to_file(path)
        .unwrap();
}

fn ramp(i: usize) -> f32 {
    (i % 13) as f32 / 13.0 + 0.1
}

fn flat(_: usize) -> f32 {
    0.9
}

#[test]
fn blender_ao_pass_is_not_taken_for_colour() {
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("render.exr");
    write_layout(
        &file,
        16,
        16,
        &[
            ("ViewLayer.AO.R", flat),
            ("ViewLayer.AO.G", flat),
            ("ViewLayer.AO.B", flat),
            ("ViewLayer.Combined.R", ramp),
            ("ViewLayer.Combined.G", ramp),
            ("ViewLayer.Combined.B", ramp),
            ("ViewLayer.Combined.A", flat),
        ],
    );
    let line = mapping_line(&[file.to_str().unwrap()], &tmp.path().join("a.exr"));
    assert!(
        line.contains("color ← ViewLayer.Combined.{R,G,B}"),
        "{line}"
    );
    let folder = tmp.path().join("set");
    std::fs::create_dir(&folder).unwrap();
    // The alpha passes through, so the folder's colour has it too.
    let color = Image::from_fn(
        16,
        16,
        4,
        |x, y, c| {
            if c == 3 {
                flat(0)
            } else {
                ramp(y * 16 + x)
            }
        },
    );
    io::write_exr(&folder.join("color.exr"), &color).unwrap();
    let from_folder = denoise(&[folder.to_str().unwrap()], &tmp.path().join("b.exr"));
    assert!(std::fs::read(tmp.path().join("a.exr")).unwrap() == from_folder);
}

#[test]
fn two_unnamed_rgb_layers_exit_2_listing_the_layers() {
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("render.exr");
    write_layout(
        &file,
        8,
        8,
        &[
            ("left.R", ramp),
            ("left.G", ramp),
            ("left.B", ramp),
            ("right.R", flat),
            ("right.G", flat),
            ("right.B", flat),
        ],
    );
    let out = tmp.path().join("out.exr");
    let run = gsid(&[
        "denoise",
        file.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_bad_input(&run, "left.{B,G,R}");
    assert!(stderr(&run).contains("right.{B,G,R}"), "{}", stderr(&run));
    assert!(!out.exists());
    // Told which layer is colour, it runs.
    let run = gsid(&[
        "denoise",
        file.to_str().unwrap(),
        "--map",
        "color=left",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(run.status.code(), Some(0), "{}", stderr(&run));
}

#[test]
fn mitsuba_aov_file_is_read_with_its_depth() {
    let tmp = tempfile::tempdir().unwrap();
    let line = mapping_line(&[MITSUBA], &tmp.path().join("out.exr"));
    for used in [
        "color ← {R,G,B}",
        "albedo ← albedo.{R,G,B}",
        "normal ← nn.{X,Y,Z}",
        "depth ← dd.T",
    ] {
        assert!(line.contains(used), "`{used}` not in: {line}");
    }
}

#[test]
fn oidn_names_give_the_folder_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let folder = tmp.path().join("set");
    std::fs::create_dir(&folder).unwrap();
    cycles_folder(&folder, false);
    let from_folder = denoise(&[folder.to_str().unwrap()], &tmp.path().join("folder.exr"));
    let file = |n: &str| folder.join(n).to_str().unwrap().to_string();
    let (c, a, n) = (file("color.exr"), file("albedo.exr"), file("normal.exr"));
    let named = denoise(
        &["--hdr", &c, "--alb", &a, "--nrm", &n],
        &tmp.path().join("named.exr"),
    );
    assert!(
        named == from_folder,
        "--hdr/--alb/--nrm differ from the folder"
    );
    let layer = |p: &str| format!("{CYCLES}:ViewLayer.{p}");
    let layers = denoise(
        &[
            "--color",
            &layer("Combined"),
            "--albedo",
            &layer("Denoising Albedo"),
            "--normal",
            &layer("Denoising Normal"),
        ],
        &tmp.path().join("layers.exr"),
    );
    assert!(
        layers == from_folder,
        "file.exr:Layer inputs differ from the folder"
    );
}

/// `eval` reads a Blender file's `Combined`, not its first layer (`AO` sorts before it): the
/// score of the bundled 4 spp render against its reference is its fixture README's figure.
#[test]
fn eval_scores_the_colour_pass_of_multilayer_files() {
    let out = gsid(&[
        "eval",
        CYCLES,
        "--reference",
        "fixtures/cycles-studio/reference.exr",
        "--json",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let ssim = report["ssim"].as_f64().unwrap();
    assert!((ssim - 0.882).abs() < 5e-4, "SSIM {ssim}");
}

/// A multilayer file given for one buffer (`--color FILE`, `--albedo FILE`) gives that buffer's
/// layer by the pass table, as the positional form does: the same output bytes. It read the first
/// R, G, B that sorts, Blender's `AO`, for every buffer.
#[test]
fn a_multilayer_file_named_per_buffer_reads_each_buffers_own_layer() {
    let tmp = tempfile::tempdir().unwrap();
    let whole = denoise(&[CYCLES], &tmp.path().join("whole.exr"));
    let named = denoise(
        &[
            "--color", CYCLES, "--albedo", CYCLES, "--normal", CYCLES, "--depth", CYCLES,
        ],
        &tmp.path().join("named.exr"),
    );
    assert!(
        whole == named,
        "named buffers read other layers than the file's table"
    );
    // A file with no layer for a buffer is named, with the layers it has.
    let run = gsid(&[
        "denoise",
        "--color",
        CYCLES,
        "--shadow",
        CYCLES,
        "-o",
        tmp.path().join("x.exr").to_str().unwrap(),
    ]);
    assert_bad_input(&run, "shadow");
    assert!(stderr(&run).contains("layers found"), "{}", stderr(&run));
}

/// A buffer named beside a multilayer file given first takes the place of the file's own pass
/// and the file still gives the rest: `shot.exr --variance var.exr` keeps the albedo, normal and
/// depth (it read the file's colour alone, every feature off), and `--albedo` replaces one pass.
#[test]
fn a_buffer_named_beside_a_multilayer_file_keeps_its_other_passes() {
    let tmp = tempfile::tempdir().unwrap();
    let t = |name: &str| tmp.path().join(name);
    let variance = t("variance.exr");
    let color = channels_of(
        CYCLES,
        &[
            "ViewLayer.Combined.R",
            "ViewLayer.Combined.G",
            "ViewLayer.Combined.B",
        ],
    );
    let spread: Vec<f32> = color
        .data()
        .iter()
        .map(|c| 0.01 * c.max(0.0) + 1e-4)
        .collect();
    let (w, h) = color.dims();
    io::write_exr(&variance, &Image::from_vec(w, h, 3, spread).unwrap()).unwrap();
    let v = variance.to_str().unwrap();
    let beside = denoise(&[CYCLES, "--variance", v], &t("beside.exr"));
    let named = denoise(
        &[
            "--color",
            CYCLES,
            "--albedo",
            CYCLES,
            "--normal",
            CYCLES,
            "--depth",
            CYCLES,
            "--variance",
            v,
        ],
        &t("named.exr"),
    );
    assert!(beside == named, "the file's passes were not all read");
    assert!(
        beside != denoise(&[CYCLES], &t("plain.exr")),
        "variance unused"
    );
    let line = mapping_line(&[CYCLES, "--variance", v], &t("line.exr"));
    for part in [
        "albedo ← ViewLayer.Denoising Albedo",
        "depth ← ",
        "variance ← ",
    ] {
        assert!(line.contains(part), "{part} missing from: {line}");
    }
    // One pass replaced: the flat albedo of another file, not the file's.
    let flat = t("albedo.exr");
    io::write_exr(
        &flat,
        &Image::from_vec(w, h, 3, vec![0.5; w * h * 3]).unwrap(),
    )
    .unwrap();
    let a = flat.to_str().unwrap();
    let replaced = denoise(&[CYCLES, "--albedo", a], &t("replaced.exr"));
    let named = denoise(
        &[
            "--color", CYCLES, "--albedo", a, "--normal", CYCLES, "--depth", CYCLES,
        ],
        &t("named2.exr"),
    );
    assert!(
        replaced == named,
        "--albedo did not replace the file's albedo alone"
    );
    // A named buffer of another size is still named, exit 2.
    let small = t("small.exr");
    io::write_exr(&small, &Image::from_vec(2, 2, 3, vec![0.5; 12]).unwrap()).unwrap();
    let run = gsid(&[
        "denoise",
        CYCLES,
        "--albedo",
        small.to_str().unwrap(),
        "-o",
        t("x.exr").to_str().unwrap(),
    ]);
    assert_bad_input(&run, "small.exr");
    assert!(!t("x.exr").exists());
}

/// A buffer named beside a render-set folder takes the place of the folder's file of its name or
/// joins them, as the file would in the folder (it was refused: "the colour as a file"). Beside a
/// folder of render sets it is refused: one file cannot be every set's buffer.
#[test]
fn a_buffer_named_beside_a_folder_is_read_as_the_folders_own() {
    let tmp = tempfile::tempdir().unwrap();
    let set = crate::common::copy_fixture(4, &tmp.path().join("given"));
    let color = io::read_image(&set.join("color.exr"), 3).unwrap();
    let (w, h) = color.dims();
    let spread: Vec<f32> = color
        .data()
        .iter()
        .map(|c| 0.02 * c.max(0.0) + 1e-4)
        .collect();
    let variance = tmp.path().join("v.exr");
    io::write_exr(&variance, &Image::from_vec(w, h, 3, spread).unwrap()).unwrap();
    let flat = tmp.path().join("a.exr");
    io::write_exr(&flat, &Image::filled(w, h, 3, 0.5)).unwrap();
    let (v, a) = (variance.to_str().unwrap(), flat.to_str().unwrap());
    let s = set.to_str().unwrap();
    let t = |name: &str| tmp.path().join(name);
    let beside = denoise(&[s, "--variance", v, "--albedo", a], &t("beside.exr"));
    // The same files inside a copy of the folder.
    let inside = crate::common::copy_fixture(4, &tmp.path().join("inside"));
    std::fs::copy(&variance, inside.join("variance.exr")).unwrap();
    std::fs::copy(&flat, inside.join("albedo.exr")).unwrap();
    let folder = denoise(&[inside.to_str().unwrap()], &t("folder.exr"));
    assert!(
        beside == folder,
        "named buffers were not read as the folder's"
    );
    assert!(
        beside != denoise(&[s], &t("plain.exr")),
        "the named buffers were unused"
    );
    // A folder of render sets: refused before any set is read, nothing written.
    let out = t("out");
    let run = gsid(&[
        "denoise",
        tmp.path().join("given").to_str().unwrap(),
        "--variance",
        v,
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_bad_input(&run, "--variance");
    assert!(!out.exists());
}
