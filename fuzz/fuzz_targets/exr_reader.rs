//! The EXR reader on arbitrary bytes: it must return an error, never panic, hang or over-allocate.
#![no_main]

use std::io::Write;

use libfuzzer_sys::fuzz_target;

#[path = "scratch.rs"]
mod scratch;

fuzz_target!(|data: &[u8]| {
    let path = scratch::file("input.exr");
    std::fs::File::create(path)
        .and_then(|mut f| f.write_all(data))
        .unwrap();
    // Both ways the render-set loader reads a file: colour (RGB) and a one-channel feature.
    for channels in [3, 1] {
        if let Ok(img) = gsid::io::read_image(path, channels) {
            assert_eq!(img.data().len(), img.width() * img.height() * channels);
        }
    }
});
