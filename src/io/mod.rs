//! Reading and writing images and render sets (FORMATS.md).
//!
//! EXR goes through the `exr` crate (any channel names, f16/f32/u32 samples); 8-bit PNG/JPEG colour
//! through `image`, decoded from sRGB to linear. Writes go to a temporary file in the target folder
//! that is renamed into place, so a failed run never leaves a half-written image.

use rayon::prelude::*;
use std::path::{Path, PathBuf};

mod exr_file;
mod output;
pub mod passes;

pub use output::{remove_pending_outputs, PendingFolder, PendingOutput, STDOUT};

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
    /// Where each buffer's channels came from, by name: its file, `file:Layer`, or a layer's
    /// channels (the mapping line's data).
    pub sources: Vec<(String, String)>,
    /// The reference image path, if one was found (in the folder or one level up).
    pub reference: Option<PathBuf>,
    /// One line per thing worth telling the user (missing buffers, LDR input).
    pub notes: Vec<String>,
    /// The input was one multilayer file, so its reference is read by pass name too.
    pub layered: bool,
}

impl LoadedSet {
    /// A loaded set, with the note on the feature buffers it lacks (each loader's last step).
    fn new(
        dir: PathBuf,
        set: RenderSet,
        files: Vec<(String, PathBuf)>,
        sources: Vec<(String, String)>,
        reference: Option<PathBuf>,
        mut notes: Vec<String>,
        layered: bool,
    ) -> Self {
        let missing: Vec<&str> = set.features.missing().iter().map(|f| f.name()).collect();
        if !missing.is_empty() {
            notes.push(format!(
                "missing buffers (their features are off): {}",
                missing.join(", ")
            ));
        }
        LoadedSet {
            dir,
            set,
            files,
            sources,
            reference,
            notes,
            layered,
        }
    }

    /// The one line saying which channels became which buffer.
    fn mapping_line(sources: &[(String, String)]) -> String {
        let pairs: Vec<String> = sources.iter().map(|(b, s)| format!("{b} ← {s}")).collect();
        pairs.join(", ")
    }

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

    /// Reads the reference as colour: by pass name (its `Combined`) for a multilayer input.
    pub fn read_reference(&self, path: &Path) -> Result<Image> {
        if !self.layered {
            return read_image(path, 3);
        }
        let layers = passes::Layers::read(path)?;
        let mut picked = layers.resolve(path, &[])?;
        Ok(picked.swap_remove(0).image)
    }
}

/// Finds a buffer file `name.{exr,png,jpg}` in `dir`.
fn find_buffer_file(dir: &Path, name: &str) -> Option<PathBuf> {
    ["exr", "png", "jpg", "jpeg"]
        .iter()
        .map(|ext| dir.join(format!("{name}.{ext}")))
        .find(|p| p.is_file())
}

/// Whether `dir` is a render set folder (it holds a `color` file).
pub fn is_render_set(dir: &Path) -> bool {
    find_buffer_file(dir, "color").is_some()
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
    for ((feature, path), img) in found.into_iter().zip(decoded) {
        let (Some(path), Some(img)) = (path, img) else {
            continue;
        };
        let img = img?;
        check_size(&img, &path, (w, h), &color_path)?;
        set = set.with(feature, img)?;
        files.push((feature.name().to_string(), path));
    }
    let reference = find_reference(dir);
    let sources = files
        .iter()
        .map(|(b, p)| (b.clone(), p.display().to_string()))
        .collect();
    Ok(LoadedSet::new(
        dir.to_path_buf(),
        set,
        files,
        sources,
        reference,
        notes,
        false,
    ))
}

/// Loads a render set folder, or one multilayer or multi-part EXR file (`maps`: `buffer=layer`).
pub fn load_input(path: &Path, maps: &[(String, String)]) -> Result<LoadedSet> {
    if !path.is_file() {
        if !maps.is_empty() {
            return Err(Error::config(
                "--map",
                "applies to a multilayer file, not a folder",
            ));
        }
        return load_render_set(path);
    }
    let layers = passes::Layers::read(path)?;
    let mut picked = layers.resolve(path, maps)?.into_iter();
    let color = picked.next().expect("colour is resolved first");
    let mut sources = vec![("color".to_string(), color.source)];
    let mut set = RenderSet::new(color.image);
    let mut notes = Vec::new();
    let mut files = vec![("color".to_string(), path.to_path_buf())];
    for mut p in picked {
        let feature = Feature::from_name(p.buffer).expect("a feature name");
        if feature == Feature::Normal && passes::is_unit_encoded(&p.image) {
            passes::decode_normal(&mut p.image);
            notes.push(format!(
                "{}: normal {} is stored in 0..1; remapped to -1..1",
                path.display(),
                p.source
            ));
        }
        sources.push((p.buffer.to_string(), p.source));
        set = set.with(feature, p.image)?;
        files.push((p.buffer.to_string(), path.to_path_buf()));
    }
    let mapping = LoadedSet::mapping_line(&sources);
    notes.insert(0, format!("{}: {mapping}", path.display()));
    let recorded = layers.recorded();
    if !recorded.is_empty() {
        notes.push(format!("not used: {}", recorded.join(", ")));
    }
    let dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let reference = Some(dir.join("reference.exr")).filter(|r| r.is_file() && r != path);
    Ok(LoadedSet::new(
        dir, set, files, sources, reference, notes, true,
    ))
}

/// Splits `file.exr:Layer` into the file and the layer; a path that exists is taken whole.
fn split_layer(spec: &Path) -> (PathBuf, Option<String>) {
    if spec.is_file() {
        return (spec.to_path_buf(), None);
    }
    match spec.to_str().and_then(|s| s.rsplit_once(':')) {
        Some((file, layer)) if Path::new(file).is_file() => (file.into(), Some(layer.to_string())),
        _ => (spec.to_path_buf(), None),
    }
}

/// Loads buffers named one by one (`--color`, `--albedo`, …): each a file, or `file.exr:Layer`.
/// A plain file is read as in a folder, so the two forms give the same bits.
pub fn load_named(named: &[(&'static str, PathBuf)]) -> Result<LoadedSet> {
    let read = |buffer: &str, spec: &Path| -> Result<(Image, PathBuf, String)> {
        let channels = passes::channels_of(buffer);
        match split_layer(spec) {
            (file, None) => Ok((
                read_image(&file, channels)?,
                file.clone(),
                file.display().to_string(),
            )),
            (file, Some(layer)) => {
                let (image, source) =
                    passes::Layers::read(&file)?.layer(&file, &layer, channels)?;
                let shown = format!("{}:{source}", file.display());
                Ok((image, file, shown))
            }
        }
    };
    let color_spec = named
        .iter()
        .find(|(b, _)| *b == "color")
        .ok_or_else(|| Error::config("--color", "is required with named inputs"))?;
    let (color, color_path, shown) = read("color", &color_spec.1)?;
    let (w, h) = color.dims();
    let mut sources = vec![("color".to_string(), shown)];
    let mut set = RenderSet::new(color);
    let mut files = vec![("color".to_string(), color_path.clone())];
    for feature in Feature::ALL {
        let Some((_, spec)) = named.iter().find(|(b, _)| *b == feature.name()) else {
            continue;
        };
        let (img, file, shown) = read(feature.name(), spec)?;
        check_size(&img, &file, (w, h), &color_path)?;
        set = set.with(feature, img)?;
        sources.push((feature.name().to_string(), shown));
        files.push((feature.name().to_string(), file));
    }
    let notes = vec![LoadedSet::mapping_line(&sources)];
    let dir = color_path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let reference = find_reference(&dir);
    Ok(LoadedSet::new(
        dir, set, files, sources, reference, notes, false,
    ))
}

/// Every buffer of a render set must have the colour's size.
fn check_size(img: &Image, path: &Path, (w, h): (usize, usize), color_path: &Path) -> Result<()> {
    if img.dims() == (w, h) {
        return Ok(());
    }
    Err(Error::file(
        path,
        format!(
            "is {}x{} but {} is {w}x{h}; all buffers of a render set must have one size",
            img.width(),
            img.height(),
            color_path.display()
        ),
    ))
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
