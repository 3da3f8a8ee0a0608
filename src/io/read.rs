//! Reading one image file as a float image: EXR through `exr_file`, PFM, and 8-bit PNG/JPEG decoded
//! from sRGB to linear; and a colour to score, by pass name from a multilayer EXR.

use std::path::Path;

use super::exr_file::{self, Frame};
use super::{passes, pfm};
use crate::error::{Error, Result};
use crate::image::Image;

/// Reads a text file (a pipeline, a scene) of at most `max` bytes. A larger one, or an endless
/// source (`/dev/zero`, a FIFO), is refused once `max` + 1 bytes are read, naming it: never read
/// whole into memory.
pub fn read_text(path: &Path, max: u64, what: &str) -> Result<String> {
    use std::io::Read;
    let file = std::fs::File::open(path).map_err(|e| Error::file(path, e))?;
    let mut bytes = Vec::new();
    file.take(max + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| Error::file(path, e))?;
    if bytes.len() as u64 > max {
        return Err(Error::file(
            path,
            format!("is larger than {} KiB, more than any {what}", max / 1024),
        ));
    }
    String::from_utf8(bytes)
        .map_err(|_| Error::file(path, format!("is not a {what}: not UTF-8 text")))
}

/// Reads an image file as `channels` channels (3 = RGB, 1 = a single channel).
///
/// EXR channels are matched on the last dotted component of their names, so Blender-style
/// `ViewLayer.Combined.R` works as well as `R`. One-channel reads accept `Y`, `Z`, `R`, or a file's only channel.
pub fn read_image(path: &Path, channels: usize) -> Result<Image> {
    read_framed(path, channels, false).map(|(image, _)| image)
}

/// Reads an image file and what an output keeps of it ([`Frame`]; the default for PNG/JPEG),
/// with its alpha if `alpha`.
pub(super) fn read_framed(path: &Path, channels: usize, alpha: bool) -> Result<(Image, Frame)> {
    match extension(path).as_str() {
        "exr" => read_exr(path, channels, alpha),
        "pfm" => Ok((pfm::read(path, channels)?, Frame::default())),
        "png" | "jpg" | "jpeg" => Ok((read_ldr(path, channels)?, Frame::default())),
        _ => Err(Error::file(
            path,
            "unsupported image format (expected .exr, .pfm, .png or .jpg)",
        )),
    }
}

/// A path's extension in lower case (empty if it has none).
pub(super) fn extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

/// An 8-bit sRGB image (PNG or JPEG), by extension.
pub fn is_ldr(path: &Path) -> bool {
    matches!(extension(path).as_str(), "png" | "jpg" | "jpeg")
}

/// The note a render set read from 8-bit colour carries.
pub(super) fn ldr_note(color: &Path) -> Option<String> {
    is_ldr(color).then(|| {
        format!(
            "{}: 8-bit colour is not HDR; highlights are clipped",
            color.display()
        )
    })
}

fn read_exr(path: &Path, channels: usize, alpha: bool) -> Result<(Image, Frame)> {
    if !path.is_file() {
        return Err(Error::file(path, "file not found"));
    }
    exr_file::read(path, channels, alpha)
}

fn read_ldr(path: &Path, channels: usize) -> Result<Image> {
    let img =
        image::open(path).map_err(|e| Error::file(path, format!("cannot decode image ({e})")))?;
    let rgb = img.to_rgb8();
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    let lut: Vec<f32> = (0..256).map(|v| srgb_to_linear(v as f32 / 255.0)).collect();
    let data: Vec<f32> = if channels == 3 {
        rgb.as_raw().iter().map(|&v| lut[v as usize]).collect()
    } else {
        rgb.as_raw()
            .chunks_exact(3)
            .map(|p| lut[p[0] as usize])
            .collect()
    };
    Image::from_vec(w, h, channels, data).map_err(|e| Error::file(path, e))
}

/// The sRGB decoding curve (8-bit file values to linear light).
pub fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// Reads an image to score as colour: from a multilayer EXR its colour pass by the pass-name
/// table (a Blender file's `Combined`, never the first layer that sorts before it), else RGB.
pub fn read_color(path: &Path) -> Result<Image> {
    let exr = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("exr"));
    if !exr {
        return read_image(path, 3);
    }
    let layers = passes::Layers::read(path)?;
    let mut picked = layers.resolve(path, &[])?;
    Ok(picked.swap_remove(0).image)
}
