//! How much memory reading an image file takes, told from its header before anything is decoded:
//! what lets a run refuse an input too large for the machine instead of aborting half way.

use std::path::Path;

use super::exr_file;
use super::read::extension;

/// Bytes a decoded pixel of a float image takes: three f32 channels, the most any reader asks for.
const DECODED: u64 = 12;
/// Bytes a pixel takes in the `image` crate on its way to floats: the decoded file (16-bit RGBA at
/// most, 8 bytes) and its 8-bit RGB copy.
const LDR_STAGING: u64 = 8 + 3;

/// The most bytes reading `file` as a three-channel float image takes, from its header alone:
/// the decoded image, the samples as stored (decompressed EXR blocks, the PFM raster, the PNG or
/// JPEG decoder's image) and the compressed chunks held while they are decompressed (at most the
/// file). `None` when the header cannot be read (the reader explains why when it runs).
pub fn read_bytes(file: &Path) -> Option<u64> {
    let len = std::fs::metadata(file).ok()?.len();
    let (pixels, stored) = match extension(file).as_str() {
        "exr" => exr_file::declared_layout(file)?,
        "pfm" => {
            let (w, h) = super::pfm::dims(file)?;
            (w as u64 * h as u64, 0)
        }
        "png" | "jpg" | "jpeg" => {
            let (w, h) = image::image_dimensions(file).ok()?;
            (w as u64 * h as u64, LDR_STAGING)
        }
        _ => return None,
    };
    Some(pixels.saturating_mul(DECODED + stored).saturating_add(len))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Image;

    #[test]
    fn a_pfm_counts_its_pixels_and_its_raster() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.pfm");
        let img = Image::new(40, 30, 3);
        std::fs::write(&path, crate::io::pfm::encode(&img).unwrap()).unwrap();
        let len = std::fs::metadata(&path).unwrap().len();
        assert_eq!(read_bytes(&path), Some(40 * 30 * DECODED + len));
    }

    #[test]
    fn an_unreadable_header_has_no_estimate() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.exr");
        std::fs::write(&path, b"not an exr").unwrap();
        assert_eq!(read_bytes(&path), None);
        assert_eq!(read_bytes(&dir.path().join("missing.png")), None);
    }
}
