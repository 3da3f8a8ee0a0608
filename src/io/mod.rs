//! Reading and writing images and render sets (FORMATS.md).
//!
//! EXR goes through the `exr` crate (any channel names, f16/f32/u32 samples); PFM is read and written
//! as Open Image Denoise does (`pfm.rs`); 8-bit PNG/JPEG colour through `image`, decoded from sRGB to
//! linear. An output's extension picks its format (`format.rs`). Writes go to a temporary file in the target folder
//! that is renamed into place, so a failed run never leaves a half-written image.

use rayon::prelude::*;
use std::path::{Path, PathBuf};

mod exr_file;
mod format;
mod output;
pub mod passes;
pub mod pfm;
mod preview;

pub use exr_file::{Frame, Plane};
pub use format::{write_image, Encoding, ImageFormat};
pub use output::{remove_pending_outputs, PendingFolder, PendingOutput, STDOUT};

use crate::error::{Error, Result};
use crate::image::Image;
use crate::render_set::{Feature, NoiseInputs, RenderSet};

/// Reads an image file as `channels` channels (3 = RGB, 1 = a single channel).
///
/// EXR channels are matched on the last dotted component of their names, so Blender-style
/// `ViewLayer.Combined.R` works as well as `R`. One-channel reads accept `Y`, `Z`, `R`, or a file's only channel.
pub fn read_image(path: &Path, channels: usize) -> Result<Image> {
    read_framed(path, channels, false).map(|(image, _)| image)
}

/// Reads an image file and what an output keeps of it ([`Frame`]; the default for PNG/JPEG),
/// with its alpha if `alpha`.
fn read_framed(path: &Path, channels: usize, alpha: bool) -> Result<(Image, Frame)> {
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
fn extension(path: &Path) -> String {
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
fn ldr_note(color: &Path) -> Option<String> {
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

/// How an EXR's pixels are compressed: every method the exr crate writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Compression {
    /// Deflate: a third smaller on noisy renders, but about 5 ms per 128×128 image to write.
    Zip,
    /// Run-length: almost free to write. Denoised float colour barely compresses either way (ZIP
    /// saved 1.5 %, 187 against 190 KB at 128×128), so results are written with it.
    Rle,
    None,
    /// Deflate, one scan line per block.
    Zips,
    Piz,
    /// Lossy for f32 (rounded to 24 bits), lossless for f16.
    Pxr24,
    /// Lossy for f16, which it alone compresses.
    B44,
    /// B44 that also packs flat blocks (lossy for f16).
    B44a,
    /// Lossy (DCT) for colour channels, 32 lines per block.
    Dwaa,
    /// Lossy (DCT) for colour channels, 256 lines per block.
    Dwab,
}

impl Compression {
    /// The `--compression` names, in the order they are listed.
    pub const NAMES: [(&'static str, Compression); 10] = [
        ("none", Compression::None),
        ("rle", Compression::Rle),
        ("zips", Compression::Zips),
        ("zip", Compression::Zip),
        ("piz", Compression::Piz),
        ("pxr24", Compression::Pxr24),
        ("b44", Compression::B44),
        ("b44a", Compression::B44a),
        ("dwaa", Compression::Dwaa),
        ("dwab", Compression::Dwab),
    ];

    pub fn name(self) -> &'static str {
        Self::NAMES
            .iter()
            .find(|(_, c)| *c == self)
            .map_or("", |(n, _)| n)
    }

    pub fn from_name(name: &str) -> Option<Compression> {
        Self::NAMES
            .iter()
            .find(|(n, _)| n.eq_ignore_ascii_case(name))
            .map(|&(_, c)| c)
    }

    /// Whether the method can change samples: then copied channels are no longer bit-exact.
    pub fn is_lossy(self) -> bool {
        self.exr().may_loose_data()
    }

    fn exr(self) -> exr_file::Compression {
        use exr_file::Compression as C;
        match self {
            Compression::Zip => C::ZIP16,
            Compression::Rle => C::RLE,
            Compression::None => C::Uncompressed,
            Compression::Zips => C::ZIP1,
            Compression::Piz => C::PIZ,
            Compression::Pxr24 => C::PXR24,
            Compression::B44 => C::B44,
            Compression::B44a => C::B44A,
            Compression::Dwaa => C::DWAA(None),
            Compression::Dwab => C::DWAB(None),
        }
    }
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
    /// What the output keeps of the colour's file (FORMATS.md, "What the output keeps").
    pub frame: Frame,
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
            frame: Frame::default(),
        }
    }

    /// The one line saying which channels became which buffer.
    fn mapping_line(sources: &[(String, String)]) -> String {
        let pairs: Vec<String> = sources.iter().map(|(b, s)| format!("{b} ← {s}")).collect();
        pairs.join(", ")
    }

    /// The set with the colour's [`Frame`].
    fn with_frame(mut self, frame: Frame) -> Self {
        self.frame = frame;
        self
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

/// Finds a buffer file `name.{exr,pfm,png,jpg}` in `dir`.
fn find_buffer_file(dir: &Path, name: &str) -> Option<PathBuf> {
    ["exr", "pfm", "png", "jpg", "jpeg"]
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
    let mut files = Vec::new();
    let color_path = find_buffer_file(dir, "color")
        .ok_or_else(|| Error::file(dir.join("color.exr"), "required buffer `color` not found"))?;
    let mut notes: Vec<String> = ldr_note(&color_path).into_iter().collect();
    // The files are independent: decode them all on all threads (colour, the largest, beside the
    // features), then check them in order, so the first error reported is the same on every run.
    let found: Vec<(Feature, Option<PathBuf>)> = Feature::ALL
        .iter()
        .map(|&f| (f, find_buffer_file(dir, f.name())))
        .collect();
    type Decoded = Result<(Image, Frame)>;
    let (color, decoded): (Decoded, Vec<Option<Decoded>>) = rayon::join(
        || read_framed(&color_path, 3, true),
        || {
            found
                .par_iter()
                .map(|(f, path)| path.as_ref().map(|p| read_framed(p, f.channels(), false)))
                .collect()
        },
    );
    let (color, frame) = color?;
    let (w, h) = color.dims();
    let mut set = RenderSet::new(color);
    files.push(("color".to_string(), color_path.clone()));
    for ((feature, path), img) in found.into_iter().zip(decoded) {
        let (Some(path), Some(img)) = (path, img) else {
            continue;
        };
        let (img, window) = img?;
        check_size(&img, &path, (w, h), &color_path)?;
        check_window(&window, &path, &frame, &color_path)?;
        set = set.with(feature, img)?;
        files.push((feature.name().to_string(), path));
    }
    let exr = |name: &str| Some(dir.join(format!("{name}.exr"))).filter(|p| p.is_file());
    let halves = both_halves(NoiseInputs::HALVES.map(exr)).map_err(|(missing, have)| {
        Error::file(
            dir.join(format!("{missing}.exr")),
            format!("not found, but {have}.exr is: the two half-sample colours come together"),
        )
    })?;
    let noise = NoiseFiles {
        variance: exr(NoiseInputs::VARIANCE),
        halves,
    };
    let read_file = |_: &'static str, p: &Path| Ok((read_image(p, 3)?, p.to_path_buf(), None));
    noise.load(&mut set, read_file, &color_path, &mut files, &mut notes)?;
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
    )
    .with_frame(frame))
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
    let frame = layers.frame(path, &color);
    let mut sources = vec![("color".to_string(), color.source)];
    let mut set = RenderSet::new(color.image);
    let mut notes = Vec::new();
    let mut files = vec![("color".to_string(), path.to_path_buf())];
    let mut halves = [None, None];
    for mut p in picked {
        if let Some(k) = NoiseInputs::HALVES.iter().position(|&h| h == p.buffer) {
            sources.push((p.buffer.to_string(), p.source));
            files.push((p.buffer.to_string(), path.to_path_buf()));
            halves[k] = Some(p.image);
            continue;
        }
        if p.buffer == NoiseInputs::VARIANCE {
            sources.push((p.buffer.to_string(), p.source));
            files.push((p.buffer.to_string(), path.to_path_buf()));
            set.noise.variance = Some(p.image);
            continue;
        }
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
    set.noise.halves = both_halves(halves).map_err(|(missing, _)| {
        Error::file(
            path,
            format!(
                "has one half-sample colour but no `{missing}` layer: the two come together (use --map {missing}=LAYER)"
            ),
        )
    })?;
    let mapping = LoadedSet::mapping_line(&sources);
    notes.insert(0, format!("{}: {mapping}", path.display()));
    let recorded = layers.recorded();
    if !recorded.is_empty() {
        notes.push(format!("not used: {}", recorded.join(", ")));
    }
    let dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let reference = Some(dir.join("reference.exr")).filter(|r| r.is_file() && r != path);
    Ok(LoadedSet::new(dir, set, files, sources, reference, notes, true).with_frame(frame))
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
    let read = |buffer: &'static str, spec: &Path| -> Result<(Image, Frame, PathBuf, String)> {
        let channels = passes::channels_of(buffer);
        let colour = buffer == "color";
        match split_layer(spec) {
            (file, None) => {
                let (image, frame) = read_framed(&file, channels, colour)?;
                let shown = file.display().to_string();
                Ok((image, frame, file, shown))
            }
            (file, Some(layer)) => {
                let layers = passes::Layers::read(&file)?;
                let picked = layers.layer(&file, &layer, buffer)?;
                let frame = layers.frame(&file, &picked);
                let shown = format!("{}:{}", file.display(), picked.source);
                Ok((picked.image, frame, file, shown))
            }
        }
    };
    let color_spec = named
        .iter()
        .find(|(b, _)| *b == "color")
        .ok_or_else(|| Error::config("--color", "is required with named inputs"))?;
    let (color, frame, color_path, shown) = read("color", &color_spec.1)?;
    let (w, h) = color.dims();
    let mut sources = vec![("color".to_string(), shown)];
    let mut set = RenderSet::new(color);
    let mut files = vec![("color".to_string(), color_path.clone())];
    for feature in Feature::ALL {
        let Some((_, spec)) = named.iter().find(|(b, _)| *b == feature.name()) else {
            continue;
        };
        let (img, window, file, shown) = read(feature.name(), spec)?;
        check_size(&img, &file, (w, h), &color_path)?;
        check_window(&window, &file, &frame, &color_path)?;
        set = set.with(feature, img)?;
        sources.push((feature.name().to_string(), shown));
        files.push((feature.name().to_string(), file));
    }
    let spec_of = |buffer: &str| {
        named
            .iter()
            .find(|(b, _)| *b == buffer)
            .map(|(_, p)| p.clone())
    };
    let halves = both_halves(NoiseInputs::HALVES.map(spec_of)).map_err(|(missing, have)| {
        Error::config(
            format!("--{}", missing.replace('_', "-")),
            format!(
                "is required with --{}: the two half-sample colours come together",
                have.replace('_', "-")
            ),
        )
    })?;
    let noise = NoiseFiles {
        variance: spec_of(NoiseInputs::VARIANCE),
        halves,
    };
    let mut notes = Vec::new();
    let before = files.len();
    let read_noise = |buffer: &'static str, spec: &Path| {
        let layered = split_layer(spec).1.is_some();
        read(buffer, spec).map(|(img, _, file, shown)| (img, file, layered.then_some(shown)))
    };
    noise.load(&mut set, read_noise, &color_path, &mut files, &mut notes)?;
    for (buffer, file) in &files[before..] {
        sources.push((buffer.clone(), file.display().to_string()));
    }
    notes.insert(0, LoadedSet::mapping_line(&sources));
    notes.extend(ldr_note(&color_path));
    let dir = color_path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let reference = find_reference(&dir);
    Ok(LoadedSet::new(dir, set, files, sources, reference, notes, false).with_frame(frame))
}

/// The two half-sample colours, which come together: both or neither, else the names of the
/// missing one and of the one present.
fn both_halves<T>(
    [a, b]: [Option<T>; 2],
) -> std::result::Result<Option<[T; 2]>, (&'static str, &'static str)> {
    match (a, b) {
        (Some(a), Some(b)) => Ok(Some([a, b])),
        (None, None) => Ok(None),
        (a, _) => {
            let [first, second] = NoiseInputs::HALVES;
            Err(if a.is_some() {
                (second, first)
            } else {
                (first, second)
            })
        }
    }
}

/// Where a set's noise buffers are (files, or `file.exr:Layer` for named inputs).
struct NoiseFiles {
    variance: Option<PathBuf>,
    /// The two half-sample colours, which only come together.
    halves: Option<[PathBuf; 2]>,
}

impl NoiseFiles {
    /// Reads the noise buffers with `read` (buffer, spec → image, file, layer shown) into `set`,
    /// checking sizes against the colour's like every other buffer. A one-channel variance file is
    /// used for all three channels, with a note.
    fn load(
        self,
        set: &mut RenderSet,
        read: impl Fn(&'static str, &Path) -> Result<(Image, PathBuf, Option<String>)>,
        color_path: &Path,
        files: &mut Vec<(String, PathBuf)>,
        notes: &mut Vec<String>,
    ) -> Result<()> {
        let dims = set.dims();
        let mut read_checked = |buffer: &'static str, spec: &Path| -> Result<(Image, bool)> {
            let (img, file, layer) = read(buffer, spec)?;
            check_size(&img, &file, dims, color_path)?;
            let plain_exr = layer.is_none() && file.extension().is_some_and(|e| e == "exr");
            let one_channel = plain_exr && exr_file::channel_count(&file)? == 1;
            files.push((buffer.to_string(), file));
            Ok((img, one_channel))
        };
        if let Some(spec) = &self.variance {
            let (img, one_channel) = read_checked(NoiseInputs::VARIANCE, spec)?;
            if one_channel {
                notes.push(format!(
                    "{}: one-channel variance, used for R, G and B",
                    spec.display()
                ));
            }
            set.noise.variance = Some(img);
        }
        if let Some([a, b]) = &self.halves {
            let [name_a, name_b] = NoiseInputs::HALVES;
            let a = read_checked(name_a, a)?.0;
            let b = read_checked(name_b, b)?.0;
            set.noise.halves = Some([a, b]);
        }
        Ok(())
    }
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

/// Every buffer of a render set must lie where the colour does: an output keeps the colour's
/// data window, so a buffer shifted against it would guide the wrong pixels.
fn check_window(window: &Frame, path: &Path, color: &Frame, color_path: &Path) -> Result<()> {
    let (at, want) = (window.origin(), color.origin());
    if at == want {
        return Ok(());
    }
    Err(Error::file(
        path,
        format!(
            "has its data window at ({}, {}) but {} has it at ({}, {}); all buffers of a render set must share the colour's data window",
            at.0,
            at.1,
            color_path.display(),
            want.0,
            want.1
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
