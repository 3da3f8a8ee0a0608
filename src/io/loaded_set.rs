//! A render set as loaded ([`LoadedSet`]) and what every loader checks on the way in: buffers of
//! the colour's size and data window, the noise buffers read alike, the two half-sample colours together.

use std::path::{Path, PathBuf};

use super::exr_file::{self, Frame};
use super::passes;
use super::read::read_image;
use crate::error::{Error, Result};
use crate::image::Image;
use crate::render_set::{Feature, NoiseInputs, RenderSet};

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
    /// The renderer's motion pass, when a multilayer input has one (for `--temporal`).
    pub motion: Option<passes::MotionPass>,
}

impl LoadedSet {
    /// A loaded set, with the note on the feature buffers it lacks (each loader's last step).
    ///
    /// Material and shadow are gsid's own buffers (its render sets carry them; Blender, Arnold
    /// and RenderMan write nothing like them), so only a render-set folder is told it lacks them:
    /// a note on every Cycles file would tell the user nothing they could act on.
    pub(super) fn new(
        dir: PathBuf,
        set: RenderSet,
        files: Vec<(String, PathBuf)>,
        sources: Vec<(String, String)>,
        reference: Option<PathBuf>,
        mut notes: Vec<String>,
        layered: bool,
    ) -> Self {
        let folder = !layered
            && files
                .first()
                .is_some_and(|(_, c)| is_folder_colour(c, &dir));
        let missing: Vec<&str> = set
            .features
            .missing()
            .iter()
            .filter(|f| folder || !matches!(f, Feature::Material | Feature::Shadow))
            .map(|f| f.name())
            .collect();
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
            motion: None,
        }
    }

    /// The one line saying which channels became which buffer.
    pub(super) fn mapping_line(sources: &[(String, String)]) -> String {
        let pairs: Vec<String> = sources.iter().map(|(b, s)| format!("{b} ← {s}")).collect();
        pairs.join(", ")
    }

    /// The set with the colour's [`Frame`].
    pub(super) fn with_frame(mut self, frame: Frame) -> Self {
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

/// The two half-sample colours, which come together: both or neither, else the names of the
/// missing one and of the one present.
pub(super) fn both_halves<T>(
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
pub(super) struct NoiseFiles {
    pub(super) variance: Option<PathBuf>,
    /// The two half-sample colours, which only come together.
    pub(super) halves: Option<[PathBuf; 2]>,
}

impl NoiseFiles {
    /// Reads the noise buffers with `read` (buffer, spec → image, file, layer shown) into `set`,
    /// checking sizes against the colour's like every other buffer. A one-channel variance file is
    /// used for all three channels, with a note.
    pub(super) fn load(
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
pub(super) fn check_size(
    img: &Image,
    path: &Path,
    (w, h): (usize, usize),
    color_path: &Path,
) -> Result<()> {
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
pub(super) fn check_window(
    window: &Frame,
    path: &Path,
    color: &Frame,
    color_path: &Path,
) -> Result<()> {
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

/// Whether `color` is a render-set folder's colour file (`DIR/color.*`), not a file named alone.
fn is_folder_colour(color: &Path, dir: &Path) -> bool {
    color.parent() == Some(dir)
        && color
            .file_stem()
            .is_some_and(|s| s.eq_ignore_ascii_case("color"))
}
