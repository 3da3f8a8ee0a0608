//! The scene-file parser of `gsid render`, from TOML text to a resolved scene.
#![no_main]

use std::path::Path;

use gsid::render::Scene;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    // Image textures resolve against a folder with no images: they must fail cleanly.
    let _ = Scene::parse(text, Path::new("/nonexistent-gsid-fuzz"));
});
