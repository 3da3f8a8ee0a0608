//! Loading a render set: a folder of buffer files, one multilayer or multi-part EXR, or buffers
//! named one by one (each a file or `file.exr:Layer`).

use rayon::prelude::*;
use std::path::{Path, PathBuf};

use super::exr_file::{self, Frame};
use super::loaded_set::{
    both_halves, check_size, check_window, find_reference, LoadedSet, NoiseFiles,
};
use super::passes;
use super::read::{extension, ldr_note, read_framed, read_image};
use crate::error::{Error, Result};
use crate::image::Image;
use crate::render_set::{Feature, NoiseInputs, RenderSet};

/// The buffer file `name.{exr,pfm,png,jpg}` in `dir`, if one is there. Something by that name
/// that is not a readable file (a dangling link, a folder, a FIFO or a device) is an error naming
/// it, never taken for a missing buffer.
fn find_buffer_file(dir: &Path, name: &str) -> Result<Option<PathBuf>> {
    for ext in ["exr", "pfm", "png", "jpg", "jpeg"] {
        let path = dir.join(format!("{name}.{ext}"));
        if let Some(path) = present(&path)? {
            return Ok(Some(path));
        }
    }
    Ok(None)
}

/// `path` if it is a regular file (through links), `None` if nothing is there, an error naming
/// what is there instead.
pub(super) fn present(path: &Path) -> Result<Option<PathBuf>> {
    let Ok(entry) = std::fs::symlink_metadata(path) else {
        return Ok(None);
    };
    let what = match std::fs::metadata(path) {
        Ok(m) if m.is_file() => return Ok(Some(path.to_path_buf())),
        Ok(m) if m.is_dir() => "a folder",
        Ok(_) => "not a regular file (a FIFO, socket or device)",
        Err(_) if entry.file_type().is_symlink() => "a link to nothing",
        Err(_) => "not readable",
    };
    Err(Error::file(path, format!("is {what}, not an image file")))
}

/// Whether `dir` is a render set folder (it holds a `color` file, or something by that name).
pub fn is_render_set(dir: &Path) -> bool {
    find_buffer_file(dir, "color").map_or(true, |c| c.is_some())
}

/// The width and height of the colour `input` names (a render-set folder, a file, `file.exr:Layer`),
/// read from its header alone, so a run can be sized before anything is decoded. `None` when it
/// cannot be told: loading then says why.
pub fn colour_dims(input: &Path) -> Option<(usize, usize)> {
    let file = if input.is_dir() {
        find_buffer_file(input, "color").ok()??
    } else {
        split_layer(input).0
    };
    match extension(&file).as_str() {
        "exr" => exr_file::declared_size(&file),
        "pfm" => super::pfm::dims(&file),
        "png" | "jpg" | "jpeg" => image::image_dimensions(&file)
            .ok()
            .map(|(w, h)| (w as usize, h as usize)),
        _ => None,
    }
}

/// Loads a render set folder: `color` is required, feature buffers are optional.
pub fn load_render_set(dir: &Path) -> Result<LoadedSet> {
    load_render_set_with(dir, &[])
}

/// [`load_render_set`], with buffers named one by one in place of the folder's files of their
/// names or beside them (`gsid denoise DIR --variance v.exr`).
fn load_render_set_with(dir: &Path, named: &[(&'static str, PathBuf)]) -> Result<LoadedSet> {
    if !dir.exists() {
        return Err(Error::file(dir, "not found"));
    }
    if !dir.is_dir() {
        return Err(Error::file(dir, "is not a render set folder"));
    }
    let mut files = Vec::new();
    let color_path = find_buffer_file(dir, "color")?
        .ok_or_else(|| Error::file(dir.join("color.exr"), "required buffer `color` not found"))?;
    let mut notes: Vec<String> = ldr_note(&color_path).into_iter().collect();
    // A buffer named beside the folder is read from its own file alone, never decoded here too.
    let named_here = |name: &str| named.iter().any(|(b, _)| *b == name);
    // The files are independent: decode them all on all threads (colour, the largest, beside the
    // features), then check them in order, so the first error reported is the same on every run.
    let found: Vec<(Feature, Option<PathBuf>)> = Feature::ALL
        .iter()
        .filter(|f| !named_here(f.name()))
        .map(|&f| Ok((f, find_buffer_file(dir, f.name())?)))
        .collect::<Result<_>>()?;
    type Decoded = Result<(Image, Frame)>;
    let (color, decoded): (Decoded, Vec<Option<Decoded>>) = rayon::join(
        || read_buffer(&color_path, "color", true).map(|(i, f, _)| (i, f)),
        || {
            found
                .par_iter()
                .map(|(f, path)| {
                    path.as_ref()
                        .map(|p| read_buffer(p, f.name(), false).map(|(i, f, _)| (i, f)))
                })
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
    let exr = |name: &str| {
        if named_here(name) {
            Ok(None)
        } else {
            present(&dir.join(format!("{name}.exr")))
        }
    };
    // Named halves take the place of the folder's pair whole, as the two come together.
    let named_halves = NoiseInputs::HALVES.iter().any(|h| named_here(h));
    let [a, b] = NoiseInputs::HALVES.map(|h| if named_halves { Ok(None) } else { exr(h) });
    let halves = both_halves([a?, b?]).map_err(|(missing, have)| {
        Error::file(
            dir.join(format!("{missing}.exr")),
            format!("not found, but {have}.exr is: the two half-sample colours come together"),
        )
    })?;
    let noise = NoiseFiles {
        variance: exr(NoiseInputs::VARIANCE)?,
        halves,
    };
    let read_file = |_: &'static str, p: &Path| Ok((read_image(p, 3)?, p.to_path_buf(), None));
    noise.load(&mut set, read_file, &color_path, &mut files, &mut notes)?;
    let reference = find_reference(dir);
    let mut sources = files
        .iter()
        .map(|(b, p)| (b.clone(), p.display().to_string()))
        .collect();
    let at = (color_path.as_path(), &frame);
    override_named(&mut set, named, at, &mut files, &mut sources, &mut notes)?;
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
    load_input_from(path, maps, None)
}

/// [`load_input`], with every buffer of a multilayer file read from the view layer `view_layer`
/// (Blender's `ViewLayer` of `ViewLayer.Combined`) when one is given.
pub fn load_input_from(
    path: &Path,
    maps: &[(String, String)],
    view_layer: Option<&str>,
) -> Result<LoadedSet> {
    load_input_with(path, maps, view_layer, &[])
}

/// Whether `path` is a multilayer or multi-part EXR file, whose passes a buffer named beside it
/// replaces one by one ([`load_input_with`]); an unreadable file is not (its loader says why).
pub fn is_layered_file(path: &Path) -> bool {
    path.is_file() && extension(path) == "exr" && exr_file::is_multilayer(path).unwrap_or(false)
}

/// [`load_input_from`], with buffers named one by one (`shot.exr --variance var.exr`, `DIR --albedo
/// FILE.exr:Layer`) in place of the file's passes or the folder's files of their names, or beside
/// them: the input still gives every buffer not named, so naming one does not turn off the others.
pub fn load_input_with(
    path: &Path,
    maps: &[(String, String)],
    view_layer: Option<&str>,
    named: &[(&'static str, PathBuf)],
) -> Result<LoadedSet> {
    if !path.is_file() {
        for (flag, given) in [
            ("--map", !maps.is_empty()),
            ("--layer", view_layer.is_some()),
        ] {
            if given {
                return Err(Error::config(
                    flag,
                    "applies to a multilayer file, not a folder",
                ));
            }
        }
        return load_render_set_with(path, named);
    }
    let mut layers = passes::Layers::read(path)?;
    if let Some(name) = view_layer {
        layers.choose_view_layer(path, name)?;
    }
    let mut picked = layers.resolve(path, maps)?.into_iter();
    let color = picked.next().expect("colour is resolved first");
    let frame = layers.frame(path, &color);
    let noisy_note = layers.noisy_note(&color);
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
    let named_halves = named.iter().any(|(b, _)| NoiseInputs::HALVES.contains(b));
    if named_halves {
        halves = [None, None];
    }
    set.noise.halves = both_halves(halves).map_err(|(missing, _)| {
        Error::file(
            path,
            format!(
                "has one half-sample colour but no `{missing}` layer: the two come together (use --map {missing}=LAYER)"
            ),
        )
    })?;
    override_named(
        &mut set,
        named,
        (path, &frame),
        &mut files,
        &mut sources,
        &mut notes,
    )?;
    let mapping = LoadedSet::mapping_line(&sources);
    notes.insert(0, format!("{}: {mapping}", path.display()));
    notes.extend(noisy_note);
    let recorded = layers.recorded();
    if !recorded.is_empty() {
        notes.push(format!("not used: {}", recorded.join(", ")));
    }
    let dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let reference = Some(dir.join("reference.exr")).filter(|r| r.is_file() && r != path);
    let mut loaded = LoadedSet::new(dir, set, files, sources, reference, notes, true);
    loaded.motion = layers.motion();
    Ok(loaded.with_frame(frame))
}

/// Splits `file.exr:Layer` into the file and the layer; a path that exists is taken whole.
pub fn split_layer(spec: &Path) -> (PathBuf, Option<String>) {
    if spec.is_file() {
        return (spec.to_path_buf(), None);
    }
    match spec.to_str().and_then(|s| s.rsplit_once(':')) {
        Some((file, layer)) if Path::new(file).is_file() => (file.into(), Some(layer.to_string())),
        _ => (spec.to_path_buf(), None),
    }
}

/// Reads `buffer` from a file given for it alone (`--albedo FILE`, a folder's `albedo.exr`). From a
/// multilayer EXR that is the layer the pass table names for the buffer, as when the file is the
/// input (a Blender file's `Combined` for the colour, never `AO`, which sorts first); any other file
/// is read as it is. Returns the image, what an output keeps of the file, and its source as shown.
fn read_buffer(file: &Path, buffer: &'static str, alpha: bool) -> Result<(Image, Frame, String)> {
    if extension(file) == "exr" && file.is_file() && exr_file::is_multilayer(file)? {
        let layers = passes::Layers::read(file)?;
        let picked = layers.for_buffer(file, buffer)?;
        let frame = layers.frame(file, &picked);
        let shown = format!("{}:{}", file.display(), picked.source);
        return Ok((picked.image, frame, shown));
    }
    let (image, frame) = read_framed(file, passes::channels_of(buffer), alpha)?;
    Ok((image, frame, file.display().to_string()))
}

/// Reads one buffer named by itself: a file, or `file.exr:Layer`. Returns the image, what an
/// output keeps of the file, the file, and its source as shown.
fn read_spec(buffer: &'static str, spec: &Path) -> Result<(Image, Frame, PathBuf, String)> {
    let colour = buffer == "color";
    match split_layer(spec) {
        (file, None) => {
            let (image, frame, shown) = read_buffer(&file, buffer, colour)?;
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
}

/// The noise buffers among `named` (variance, the two halves), which come together as in a folder.
fn named_noise(named: &[(&'static str, PathBuf)]) -> Result<NoiseFiles> {
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
    Ok(NoiseFiles {
        variance: spec_of(NoiseInputs::VARIANCE),
        halves,
    })
}

/// Reads the buffers `named` (colour left out) into `set`, each checked against the colour
/// (`color`: its file and data window) and taking the place of a buffer of its name already there.
fn override_named(
    set: &mut RenderSet,
    named: &[(&'static str, PathBuf)],
    (color_path, frame): (&Path, &Frame),
    files: &mut Vec<(String, PathBuf)>,
    sources: &mut Vec<(String, String)>,
    notes: &mut Vec<String>,
) -> Result<()> {
    let named: Vec<(&'static str, PathBuf)> = named
        .iter()
        .filter(|(b, _)| *b != "color")
        .cloned()
        .collect();
    let replaced = |b: &String| named.iter().any(|(n, _)| n == b);
    files.retain(|(b, _)| !replaced(b));
    sources.retain(|(b, _)| !replaced(b));
    let dims = set.dims();
    for feature in Feature::ALL {
        let Some((_, spec)) = named.iter().find(|(b, _)| *b == feature.name()) else {
            continue;
        };
        let (img, window, file, shown) = read_spec(feature.name(), spec)?;
        check_size(&img, &file, dims, color_path)?;
        check_window(&window, &file, frame, color_path)?;
        set.features.set(feature, img)?;
        sources.push((feature.name().to_string(), shown));
        files.push((feature.name().to_string(), file));
    }
    let before = files.len();
    let read_noise = |buffer: &'static str, spec: &Path| {
        let layered = split_layer(spec).1.is_some();
        read_spec(buffer, spec).map(|(img, _, file, shown)| (img, file, layered.then_some(shown)))
    };
    named_noise(&named)?.load(set, read_noise, color_path, files, notes)?;
    for (buffer, file) in &files[before..] {
        sources.push((buffer.clone(), file.display().to_string()));
    }
    Ok(())
}

/// Loads buffers named one by one (`--color`, `--albedo`, …): each a file, or `file.exr:Layer`.
/// A plain file is read as in a folder, so the two forms give the same bits.
pub fn load_named(named: &[(&'static str, PathBuf)]) -> Result<LoadedSet> {
    let color_spec = named
        .iter()
        .find(|(b, _)| *b == "color")
        .ok_or_else(|| Error::config("--color", "is required with named inputs"))?;
    let (color, frame, color_path, shown) = read_spec("color", &color_spec.1)?;
    let mut sources = vec![("color".to_string(), shown)];
    let mut set = RenderSet::new(color);
    let mut files = vec![("color".to_string(), color_path.clone())];
    let mut notes = Vec::new();
    let at = (color_path.as_path(), &frame);
    override_named(&mut set, named, at, &mut files, &mut sources, &mut notes)?;
    notes.insert(0, LoadedSet::mapping_line(&sources));
    notes.extend(ldr_note(&color_path));
    let dir = color_path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let reference = find_reference(&dir);
    Ok(LoadedSet::new(dir, set, files, sources, reference, notes, false).with_frame(frame))
}
