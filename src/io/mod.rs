//! Reading and writing images and render sets (FORMATS.md).
//!
//! EXR goes through the `exr` crate (any channel names, f16/f32/u32 samples); 8-bit PNG/JPEG colour
//! through `image`, decoded from sRGB to linear. Writes go to a temporary file in the target folder
//! that is renamed into place, so a failed run never leaves a half-written image.

use rayon::prelude::*;
use std::path::{Path, PathBuf};

mod exr_file;
mod output;

pub use output::{remove_pending_outputs, PendingFolder, PendingOutput};

use crate::error::{Error, Result};
use crate::image::Image;
use crate::render_set::{Feature, RenderSet};

/// Reads an image file as `channels` channels (3 = RGB, 1 = a single channel).
///
/// EXR channels are matched on the last dotted component of their names, so Blender-style
/// `ViewLayer.Combined.R` works as well as `R`. One-channel reads accept `Y`, `Z`, `R`, or a file's only channel.
pub fn read_image(path: &Path, channels: usize) -> Result<Image> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "exr" => read_exr(path, channels),
        "png" | "jpg" | "jpeg" => read_ldr(path, channels),
        _ => Err(Error::file(
            path,
            "unsupported image format (expected .exr, .png or .jpg)",
        )),
    }
}

fn read_exr(path: &Path, channels: usize) -> Result<Image> {
    if !path.is_file() {
        return Err(Error::file(path, "file not found"));
    }
    exr_file::read(path, channels)
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

/// How an EXR's pixels are compressed (both lossless).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Compression {
    /// Deflate: a third smaller on noisy renders, but about 5 ms per 128×128 image to write.
    Zip,
    /// Run-length: almost free to write. Denoised float colour barely compresses either way (ZIP
    /// saved 1.5 %, 187 against 190 KB at 128×128), so results are written with it.
    Rle,
}

/// Writes an EXR (float32, zip-compressed): RGB for 3 channels, `Y` for one.
///
/// The data goes to a temporary file next to `path`, which is renamed over `path` only once complete.
pub fn write_exr(path: &Path, image: &Image) -> Result<()> {
    let pending = PendingOutput::create(path)?;
    pending.write_exr(image, Compression::Zip)
}

/// A render set as loaded from disk: its buffers, the files they came from, and notes for the user.
pub struct LoadedSet {
    pub dir: PathBuf,
    pub set: RenderSet,
    /// Path of each loaded buffer, by name.
    pub files: Vec<(String, PathBuf)>,
    /// The reference image path, if one was found (in the folder or one level up).
    pub reference: Option<PathBuf>,
    /// One line per thing worth telling the user (missing buffers, LDR input).
    pub notes: Vec<String>,
}

impl LoadedSet {
    /// Every file the set was read from, by buffer name, the reference included.
    pub fn inputs(&self) -> Vec<(String, PathBuf)> {
        let mut files = self.files.clone();
        files.extend(
            self.reference
                .iter()
                .map(|r| ("reference".to_string(), r.clone())),
        );
        files
    }
}

/// Finds a buffer file `name.{exr,png,jpg}` in `dir`.
fn find_buffer_file(dir: &Path, name: &str) -> Option<PathBuf> {
    ["exr", "png", "jpg", "jpeg"]
        .iter()
        .map(|ext| dir.join(format!("{name}.{ext}")))
        .find(|p| p.is_file())
}

/// Loads a render set folder: `color` is required, feature buffers are optional.
pub fn load_render_set(dir: &Path) -> Result<LoadedSet> {
    if !dir.is_dir() {
        return Err(Error::file(dir, "is not a render set folder"));
    }
    let mut notes = Vec::new();
    let mut files = Vec::new();
    let color_path = find_buffer_file(dir, "color")
        .ok_or_else(|| Error::file(dir.join("color.exr"), "required buffer `color` not found"))?;
    if color_path.extension().is_some_and(|e| e != "exr") {
        notes.push(format!(
            "{}: 8-bit colour is not HDR; highlights are clipped",
            color_path.display()
        ));
    }
    // The files are independent: decode them all on all threads (colour, the largest, beside the
    // features), then check them in order, so the first error reported is the same on every run.
    let found: Vec<(Feature, Option<PathBuf>)> = Feature::ALL
        .iter()
        .map(|&f| (f, find_buffer_file(dir, f.name())))
        .collect();
    let (color, decoded): (Result<Image>, Vec<Option<Result<Image>>>) = rayon::join(
        || read_image(&color_path, 3),
        || {
            found
                .par_iter()
                .map(|(f, path)| path.as_ref().map(|p| read_image(p, f.channels())))
                .collect()
        },
    );
    let color = color?;
    let (w, h) = color.dims();
    let mut set = RenderSet::new(color);
    files.push(("color".to_string(), color_path.clone()));
    let mut missing = Vec::new();
    for ((feature, path), img) in found.into_iter().zip(decoded) {
        let (Some(path), Some(img)) = (path, img) else {
            missing.push(feature.name());
            continue;
        };
        let img = img?;
        if img.dims() != (w, h) {
            return Err(Error::file(
                &path,
                format!(
                    "is {}x{} but {} is {w}x{h}; all buffers of a render set must have one size",
                    img.width(),
                    img.height(),
                    color_path.display()
                ),
            ));
        }
        set = set.with(feature, img)?;
        files.push((feature.name().to_string(), path));
    }
    if !missing.is_empty() {
        notes.push(format!(
            "missing buffers (their features are off): {}",
            missing.join(", ")
        ));
    }
    let reference = find_reference(dir);
    Ok(LoadedSet {
        dir: dir.to_path_buf(),
        set,
        files,
        reference,
        notes,
    })
}

/// The converged reference of a render set: `reference.exr` in the folder or one level up.
pub fn find_reference(dir: &Path) -> Option<PathBuf> {
    let here = dir.join("reference.exr");
    if here.is_file() {
        return Some(here);
    }
    dir.parent()
        .map(|p| p.join("reference.exr"))
        .filter(|p| p.is_file())
}
