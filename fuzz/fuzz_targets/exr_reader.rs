//! The EXR reader on arbitrary bytes: it must return an error, never panic, hang or over-allocate.
#![no_main]

use std::io::Write;
use std::path::PathBuf;
use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;

/// One file per process, rewritten for every input: the reader takes a path, not bytes.
fn scratch() -> &'static PathBuf {
    static PATH: OnceLock<PathBuf> = OnceLock::new();
    PATH.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("gsid-fuzz-exr-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir.join("input.exr")
    })
}

fuzz_target!(|data: &[u8]| {
    let path = scratch();
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
