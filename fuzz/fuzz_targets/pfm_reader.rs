//! The PFM reader on arbitrary bytes: it must return an error, never panic, hang or over-allocate;
//! what it reads must write back and read again to the same bits, and the file reader (header
//! first, then the raster) must agree with the in-memory decoder.
#![no_main]

use std::io::Write;

use libfuzzer_sys::fuzz_target;

#[path = "scratch.rs"]
mod scratch;

fn bits(img: &gsid::Image) -> Vec<u32> {
    img.data().iter().map(|v| v.to_bits()).collect()
}

fuzz_target!(|data: &[u8]| {
    let path = scratch::file("input.pfm");
    std::fs::File::create(path)
        .and_then(|mut f| f.write_all(data))
        .unwrap();
    for channels in [3, 1] {
        let decoded = gsid::io::pfm::decode(data, channels);
        let read = gsid::io::read_image(path, channels);
        assert_eq!(
            decoded.is_ok(),
            read.is_ok(),
            "{decoded:?} / {:?}",
            read.as_ref().err()
        );
        let Ok(img) = decoded else { continue };
        assert_eq!(img.data().len(), img.width() * img.height() * channels);
        assert_eq!(bits(&img), bits(&read.unwrap()));
        let again = gsid::io::pfm::decode(&gsid::io::pfm::encode(&img).unwrap(), channels).unwrap();
        assert_eq!(bits(&img), bits(&again));
    }
});
