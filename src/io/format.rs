//! Which format an image output is written in: the one its extension names, checked before any
//! work so a typo costs nothing.

use std::path::Path;

use super::compression::Compression;
use super::exr_file::{self, Frame};
use super::output::{PendingOutput, STDOUT};
use super::pfm;
use super::preview::{self, Preview};
use crate::error::{Error, Result};
use crate::image::Image;

/// The formats an image output can be written in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageFormat {
    /// Float EXR.
    Exr,
    /// Float PFM, as Open Image Denoise writes it.
    Pfm,
    /// 8-bit tone-mapped preview.
    Png,
    /// 8-bit tone-mapped preview, without alpha.
    Jpeg,
}

/// The extensions an image output may have, for error messages.
const KNOWN: &str = ".exr, .pfm, .png, .jpg, .jpeg";

impl ImageFormat {
    /// The format of an output path by its extension (any case). `-`, a device, a FIFO (and a
    /// folder, which fails later as one) without a known extension are EXR, as they always were;
    /// any other path without a known extension is an error.
    pub fn of_output(path: &Path) -> Result<Self> {
        let ext = super::read::extension(path);
        match ext.as_str() {
            "exr" => return Ok(ImageFormat::Exr),
            "pfm" => return Ok(ImageFormat::Pfm),
            "png" => return Ok(ImageFormat::Png),
            "jpg" | "jpeg" => return Ok(ImageFormat::Jpeg),
            _ => {}
        }
        if path.as_os_str() == STDOUT || std::fs::metadata(path).is_ok_and(|m| !m.is_file()) {
            return Ok(ImageFormat::Exr);
        }
        let what = if ext.is_empty() {
            "has no extension to pick its format by".to_string()
        } else {
            format!("has the unknown image extension .{ext}")
        };
        Err(Error::output(path, format!("{what} (known: {KNOWN})")))
    }

    /// An 8-bit preview, which `--exposure` applies to.
    pub fn is_preview(self) -> bool {
        matches!(self, ImageFormat::Png | ImageFormat::Jpeg)
    }
}

/// How outputs are encoded beyond their format.
#[derive(Clone, Copy, Debug)]
pub struct Encoding {
    pub compression: Compression,
    /// EXR only: half-float colour channels.
    pub half: bool,
    /// Stops of exposure for previews (float outputs are written as computed).
    pub exposure: f32,
}

/// Checks, before any work, that an output at `path` of `dims` and `channels` can carry what `frame`
/// keeps of the colour's file (`color`): a damaged input's mistyped standard attribute is named as
/// that input's fault now, not found when the result is written.
pub fn check_output(
    path: &Path,
    dims: (usize, usize),
    channels: usize,
    frame: &Frame,
    encoding: &Encoding,
    color: &Path,
) -> Result<()> {
    if ImageFormat::of_output(path)? != ImageFormat::Exr {
        return Ok(());
    }
    let exr = exr_file::Encoding {
        compression: encoding.compression.exr(),
        half: encoding.half,
    };
    exr_file::check(dims, channels, frame, exr).map_err(|e| {
        Error::file(
            color,
            format!("its header cannot be written to an output: {e}"),
        )
    })
}

/// `image` (RGB) with the colour's alpha as a fourth channel, when the colour had one.
fn with_alpha(image: &Image, frame: &Frame) -> Option<Image> {
    let alpha = frame.alpha_values().filter(|_| image.channels() == 3)?;
    let (w, h) = (image.width(), image.height());
    if alpha.len() != w * h {
        return None;
    }
    let data = image
        .data()
        .chunks_exact(3)
        .zip(&alpha)
        .flat_map(|(px, &a)| [px[0], px[1], px[2], a])
        .collect();
    Image::from_vec(w, h, 4, data).ok()
}

/// Writes `image` to a reserved output in the format its path names, and commits it.
/// An EXR output keeps what `frame` holds of the colour's file (windows, attributes, alpha, layers).
pub fn write_image(
    pending: PendingOutput,
    image: &Image,
    frame: &Frame,
    encoding: &Encoding,
) -> Result<()> {
    let bytes = match ImageFormat::of_output(pending.path())? {
        ImageFormat::Exr => {
            return pending.write_exr_framed(image, frame, encoding.compression, encoding.half)
        }
        ImageFormat::Pfm => pfm::encode(image),
        ImageFormat::Png => match with_alpha(image, frame) {
            Some(rgba) => preview::encode(&rgba, Preview::Png, encoding.exposure),
            None => preview::encode(image, Preview::Png, encoding.exposure),
        },
        ImageFormat::Jpeg => preview::encode(image, Preview::Jpeg, encoding.exposure),
    }
    .map_err(|m| Error::output(pending.path(), m))?;
    pending.write_bytes(&bytes)
}
