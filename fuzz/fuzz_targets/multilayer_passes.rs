//! Multilayer pass mapping on arbitrary bytes: a Blender-style multilayer or multi-part EXR is read,
//! its layers grouped and each buffer picked by the pass table or by `--map`, as the command line
//! does for `gsid denoise file.exr`. It must return an error or a consistent render set, never panic,
//! hang or over-allocate.
//!
//! Input: one byte choosing a set of `--map` assignments, then the file's bytes.
#![no_main]

use std::io::Write;

use libfuzzer_sys::fuzz_target;

#[path = "scratch.rs"]
mod scratch;

/// The `--map` sets a run may use: none (the pass table alone), a feature from another pass, the
/// colour and a feature by full layer name, and a map naming a layer no file has.
const MAPS: [&[(&str, &str)]; 4] = [
    &[],
    &[("albedo", "DiffCol")],
    &[("color", "ViewLayer.Combined"), ("normal", "Normal")],
    &[("depth", "Depth"), ("shadow", "No Such Pass")],
];

fuzz_target!(|data: &[u8]| {
    let Some((&choice, file)) = data.split_first() else {
        return;
    };
    let path = scratch::file("input.exr");
    std::fs::File::create(path)
        .and_then(|mut f| f.write_all(file))
        .unwrap();
    let maps: Vec<(String, String)> = MAPS[choice as usize % MAPS.len()]
        .iter()
        .map(|&(b, l)| (b.to_string(), l.to_string()))
        .collect();
    if let Ok(loaded) = gsid::io::load_input(path, &maps) {
        let dims = loaded.set.color.dims();
        for feature in gsid::Feature::ALL {
            if let Some(img) = loaded.set.features.get(feature) {
                assert_eq!(img.dims(), dims, "{feature:?} is not the colour's size");
                assert_eq!(img.data().len(), dims.0 * dims.1 * img.channels());
            }
        }
    }
    // What the temporal mode and `gsid eval` read of the same file.
    if let Ok(layers) = gsid::io::passes::Layers::read(path) {
        let _ = layers.motion();
        let _ = layers.recorded();
    }
    let _ = gsid::io::read_color(path);
});
