//! Which layers of a multilayer or multi-part EXR become which buffer.
//!
//! Renderers name their passes differently (Blender `ViewLayer.Denoising Albedo.R`, Mitsuba
//! `albedo.R`, Arnold `diffuse_albedo.R`), so the known names live in one table, with a preference
//! order per buffer. Nothing is guessed: a colour that is missing or matched by two layers is an
//! error naming every layer found, and `--map` says what the table cannot.

use std::path::Path;

use exr::prelude::FlatSamples;

use super::exr_file::{self, Frame, Plane};
use crate::error::{Error, Result};
use crate::image::Image;
use crate::render_set::Feature;

/// Pass names (the last dotted part of a layer's name, compared ignoring case) per buffer, most
/// preferred first. `""` is the unprefixed `R,G,B` of a plain or Mitsuba file.
///
/// `variance` is the variance of the pixel mean, as Arnold and RenderMan variance AOVs and Cycles'
/// old denoising data (`Denoising Variance`; 2.79: `Denoising Image Variance`) store it. Mitsuba's
/// `moment` integrator writes a second moment (`m2_*`, in XYZ), which needs the sample count to
/// become one, so it is not read.
///
/// `Noisy Image` is Blender's noisy beauty, written beside a `Combined` its denoiser already
/// filtered: gsid denoises the noisy one. Any pass `X` also gives way to a `Noisy X` beside it.
pub const PASSES: [(&str, &[&str]); 9] = [
    ("color", &["Noisy Image", "Combined", "", "beauty", "rgba"]),
    (
        "albedo",
        &["Denoising Albedo", "albedo", "diffuse_albedo", "DiffCol"],
    ),
    (
        "normal",
        &["Denoising Normal", "Normal", "nn", "sh_normal", "N"],
    ),
    ("depth", &["Denoising Depth", "Depth", "dd", "Z"]),
    ("material", &["material"]),
    ("shadow", &["shadow"]),
    (
        "variance",
        &["variance", "Denoising Variance", "Denoising Image Variance"],
    ),
    ("color_a", &["color_a"]),
    ("color_b", &["color_b"]),
];

/// How a motion pass's channels point (docs/FORMATS.md "Motion"): every kind becomes offsets in
/// pixels, x right and y down, from a pixel to where its surface is in the previous / next frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MotionKind {
    /// Blender's `Vector`: X,Y = previous − current, Z,W = current − next, y up (checked on a
    /// Cycles render: warped neighbours match the frame's albedo only this way round).
    BlenderVector,
    /// An offset to the previous frame (RenderMan `motionBack`), R,G or X,Y, y up.
    Back,
    /// An offset to the next frame (RenderMan `motionFore`, Arnold `motionvector`), y up.
    Fore,
}

/// Motion pass names (compared ignoring case) and how their channels point.
pub const MOTION: [(&str, MotionKind); 4] = [
    ("Vector", MotionKind::BlenderVector),
    ("motionBack", MotionKind::Back),
    ("motionFore", MotionKind::Fore),
    ("motionvector", MotionKind::Fore),
];

/// A frame's motion pass, as offsets in pixels (x right, y down), 2 channels each.
#[derive(Clone, Debug)]
pub struct MotionPass {
    /// From each pixel to its surface's place in the previous frame.
    pub back: Option<Image>,
    /// From each pixel to its surface's place in the next frame.
    pub fore: Option<Image>,
    /// The layers read, for notes.
    pub source: String,
}

/// Passes recognised but not loaded: Cycles 2.79's variances of its feature passes.
const RECORDED: [&str; 3] = [
    "Denoising Normal Variance",
    "Denoising Albedo Variance",
    "Denoising Depth Variance",
];

/// Channels of one buffer, by preference: a 3-channel buffer takes R,G,B or X,Y,Z.
const RGB: [[&str; 2]; 3] = [["R", "X"], ["G", "Y"], ["B", "Z"]];
/// A one-channel layer's channel, when it has more than one.
const SINGLE: [&str; 5] = ["Z", "Y", "T", "R", "V"];

/// The channels of an EXR grouped into layers by name prefix.
pub struct Layers {
    width: usize,
    height: usize,
    layers: Vec<Layer>,
    /// Each part's windows and attributes.
    parts: Vec<Frame>,
    /// Channels in the file, those of view layers not chosen included.
    channels_in_file: usize,
}

/// The pass a `Noisy …` pass is the noisy twin of (`Noisy Image` → `Combined`).
fn denoised_twin(pass: &str) -> Option<&str> {
    let rest = pass.strip_prefix("Noisy ")?;
    Some(if rest.eq_ignore_ascii_case("Image") {
        "Combined"
    } else {
        rest
    })
}

struct Layer {
    /// The full prefix (`ViewLayer.Combined`), `""` for unprefixed colour channels.
    name: String,
    /// The part the layer's channels are in.
    part: usize,
    /// Short channel names and the channels as stored.
    channels: Vec<(String, Plane)>,
}

impl Layer {
    fn pass(&self) -> &str {
        self.name.rsplit('.').next().unwrap_or("")
    }

    /// The view layer (`ViewLayer` of `ViewLayer.Combined`), `""` for an unprefixed pass.
    fn view_layer(&self) -> &str {
        self.name.rsplit_once('.').map_or("", |(v, _)| v)
    }

    fn describe(&self) -> String {
        let shorts: Vec<&str> = self.channels.iter().map(|(c, _)| c.as_str()).collect();
        let list = format!("{{{}}}", shorts.join(","));
        if self.name.is_empty() {
            list
        } else {
            format!("{}.{list}", self.name)
        }
    }

    fn find(&self, wanted: &[&str]) -> Option<usize> {
        wanted.iter().find_map(|w| {
            self.channels
                .iter()
                .position(|(c, _)| c.eq_ignore_ascii_case(w))
        })
    }

    /// The layer's channels for a buffer of `channels` channels, in buffer order.
    fn pick(&self, channels: usize) -> Option<Vec<usize>> {
        if channels == 3 {
            RGB.iter().map(|w| self.find(w)).collect()
        } else if self.channels.len() == 1 {
            Some(vec![0])
        } else {
            self.find(&SINGLE).map(|c| vec![c])
        }
    }
}

/// One buffer as read: its image and where it came from, for the mapping line.
pub struct Picked {
    pub buffer: &'static str,
    pub image: Image,
    pub source: String,
    /// Index of its layer.
    layer: usize,
}

impl Layers {
    pub fn read(path: &Path) -> Result<Layers> {
        let file = exr_file::read_all_channels(path)?;
        let mut layers: Vec<Layer> = Vec::new();
        for (part, plane) in file.channels {
            let full = plane.desc.name.to_string();
            let (prefix, short) = match full.rsplit_once('.') {
                Some((p, s)) => (p.to_string(), s.to_string()),
                // Unprefixed channels other than colour (Arnold's `Z`) are layers of their own.
                None if ["R", "G", "B", "A"].contains(&full.as_str()) => (String::new(), full),
                None => (full.clone(), full),
            };
            match layers.iter_mut().find(|l| l.name == prefix) {
                Some(l) => l.channels.push((short, plane)),
                None => layers.push(Layer {
                    name: prefix,
                    part,
                    channels: vec![(short, plane)],
                }),
            }
        }
        let channels_in_file = layers.iter().map(|l| l.channels.len()).sum();
        Ok(Layers {
            width: file.width,
            height: file.height,
            layers,
            parts: file.parts,
            channels_in_file,
        })
    }

    /// The distinct view layers of the file's passes, in file order.
    fn view_layers(&self) -> Vec<&str> {
        let mut names: Vec<&str> = Vec::new();
        for l in &self.layers {
            let v = l.view_layer();
            if !v.is_empty() && !names.contains(&v) {
                names.push(v);
            }
        }
        names
    }

    /// Keeps only the passes of view layer `name` (`--layer`): every buffer is then read from it.
    pub fn choose_view_layer(&mut self, path: &Path, name: &str) -> Result<()> {
        let known: Vec<String> = self.view_layers().iter().map(|v| v.to_string()).collect();
        if !known.iter().any(|v| v == name) {
            let list = if known.is_empty() {
                "it has none (its passes are not prefixed by a view layer)".to_string()
            } else {
                format!("view layers: {}", known.join(", "))
            };
            return Err(Error::file(
                path,
                format!("has no view layer `{name}` (--layer); {list}"),
            ));
        }
        self.layers.retain(|l| l.view_layer() == name);
        Ok(())
    }

    /// The error for a buffer that two or more layers match: across view layers it names them
    /// once and asks for `--layer`; inside one, it asks for `--map`.
    fn ambiguous(&self, path: &Path, buffer: &str, matches: &[usize]) -> Error {
        let mut views: Vec<&str> = Vec::new();
        for &m in matches {
            let v = self.layers[m].view_layer();
            if !views.contains(&v) {
                views.push(v);
            }
        }
        if views.len() > 1 && views.iter().all(|v| !v.is_empty()) {
            let all = self.view_layers();
            return Error::file(
                path,
                format!(
                    "holds {} view layers ({}): choose one with --layer NAME",
                    all.len(),
                    all.join(", ")
                ),
            );
        }
        Error::file(
            path,
            format!(
                "{buffer} is ambiguous (use --map {buffer}=LAYER); {}",
                self.found()
            ),
        )
    }

    /// The denoised pass beside `colour` when it is a `Noisy …` pass (Blender's `Combined`
    /// beside `Noisy Image`), by index.
    fn twin_of(&self, colour: &Picked) -> Option<usize> {
        let layer = &self.layers[colour.layer];
        let twin = denoised_twin(layer.pass())?;
        self.layers.iter().position(|l| {
            l.view_layer() == layer.view_layer()
                && l.pass().eq_ignore_ascii_case(twin)
                && l.pick(3).is_some()
        })
    }

    /// The note for a noisy colour read in place of the denoised pass beside it, if that is so.
    pub fn noisy_note(&self, colour: &Picked) -> Option<String> {
        let twin = &self.layers[self.twin_of(colour)?];
        Some(format!(
            "color ← {} (the noisy beauty), not {}: that is the renderer's own denoised result",
            self.layers[colour.layer].name, twin.name
        ))
    }

    /// What an output keeps when `colour` is the colour: its part's windows and attributes, its
    /// layer's `A`, and the file's other channels (there are some unless the layer is all).
    ///
    /// A `Noisy Image` colour is written back as the `Combined` beside it (the pass a compositor
    /// reads as the beauty), its alpha its own or else `Combined`'s.
    pub fn frame(&self, path: &Path, colour: &Picked) -> Frame {
        let noisy = &self.layers[colour.layer];
        let layer = self.twin_of(colour).map_or(noisy, |t| &self.layers[t]);
        let full = |c: usize| layer.channels[c].1.desc.name.to_string();
        let rgb: Vec<String> = layer
            .pick(3)
            .unwrap_or_default()
            .into_iter()
            .map(full)
            .collect();
        let alpha_of = |l: &Layer| l.find(&["A"]).map(|a| l.channels[a].1.clone());
        let alpha = alpha_of(noisy).or_else(|| alpha_of(layer));
        let all = self.channels_in_file;
        let own = rgb.len() + alpha.is_some() as usize;
        self.parts[layer.part]
            .clone()
            .of_colour(rgb, alpha, (all > own).then_some(path))
    }

    fn found(&self) -> String {
        let all: Vec<String> = self.layers.iter().map(Layer::describe).collect();
        format!("layers found: {}", all.join(", "))
    }

    fn image(&self, layer: &Layer, channels: usize) -> Option<Image> {
        let picked = layer.pick(channels)?;
        let n = self.width * self.height;
        let mut data = vec![0.0f32; n * channels];
        for (k, &c) in picked.iter().enumerate() {
            let pixels = data.chunks_exact_mut(channels);
            match &layer.channels[c].1.samples {
                FlatSamples::F16(v) => pixels.zip(v).for_each(|(px, s)| px[k] = s.to_f32()),
                FlatSamples::F32(v) => pixels.zip(v).for_each(|(px, &s)| px[k] = s),
                FlatSamples::U32(v) => pixels.zip(v).for_each(|(px, &s)| px[k] = s as f32),
            }
        }
        Image::from_vec(self.width, self.height, channels, data).ok()
    }

    fn source(layer: &Layer, channels: usize) -> String {
        let picked = layer.pick(channels).unwrap_or_default();
        let shorts: Vec<&str> = picked
            .iter()
            .map(|&c| layer.channels[c].0.as_str())
            .collect();
        let list = if shorts.len() == 1 {
            shorts[0].to_string()
        } else {
            format!("{{{}}}", shorts.join(","))
        };
        if layer.name.is_empty() {
            list
        } else {
            format!("{}.{list}", layer.name)
        }
    }

    /// The layer `--map` or `file.exr:Layer` names: its full name, else its pass name if unique.
    fn named(&self, path: &Path, name: &str) -> Result<usize> {
        if let Some(l) = self.layers.iter().position(|l| l.name == name) {
            return Ok(l);
        }
        let by_pass: Vec<usize> = (0..self.layers.len())
            .filter(|&l| self.layers[l].pass().eq_ignore_ascii_case(name))
            .collect();
        match by_pass.as_slice() {
            [one] => Ok(*one),
            _ => Err(Error::file(
                path,
                format!("has no single layer `{name}`; {}", self.found()),
            )),
        }
    }

    /// Reads the layer `name` as `buffer`.
    pub fn layer(&self, path: &Path, name: &str, buffer: &'static str) -> Result<Picked> {
        let channels = channels_of(buffer);
        let index = self.named(path, name)?;
        let layer = &self.layers[index];
        let image = self.image(layer, channels).ok_or_else(|| {
            Error::file(
                path,
                format!(
                    "layer {} does not have {channels} usable channels",
                    layer.describe()
                ),
            )
        })?;
        Ok(Picked {
            buffer,
            image,
            source: Self::source(layer, channels),
            layer: index,
        })
    }

    /// Every buffer the file holds: `maps` (`buffer=layer`) first, then the table. The colour is
    /// required and must be unambiguous; a feature matched by two layers is an error too.
    pub fn resolve(&self, path: &Path, maps: &[(String, String)]) -> Result<Vec<Picked>> {
        let mut out = Vec::new();
        for (buffer, _) in PASSES {
            if let Some((_, name)) = maps.iter().find(|(b, _)| b == buffer) {
                out.push(self.layer(path, name, buffer)?);
                continue;
            }
            match self.by_table(path, buffer)? {
                Some(picked) => out.push(picked),
                None if buffer == "color" => {
                    return Err(Error::file(
                        path,
                        format!(
                            "has no known colour layer (use --map color=LAYER); {}",
                            self.found()
                        ),
                    ))
                }
                None => {}
            }
        }
        Ok(out)
    }

    /// The layer the table names for `buffer` (its most preferred pass name that some layer with
    /// the buffer's channels carries), if any; two such layers are an error.
    pub fn by_table(&self, path: &Path, buffer: &'static str) -> Result<Option<Picked>> {
        let channels = channels_of(buffer);
        let names = PASSES
            .iter()
            .find(|(b, _)| *b == buffer)
            .map_or(&[][..], |(_, names)| *names);
        // Each name's noisy twin (`Noisy Shadow Catcher` before `Shadow Catcher`) first.
        let wanted = names
            .iter()
            .flat_map(|n| [format!("Noisy {n}"), n.to_string()])
            .filter(|n| !n.eq_ignore_ascii_case("Noisy "));
        let Some(matches) = wanted.into_iter().find_map(|n| {
            let m: Vec<usize> = (0..self.layers.len())
                .filter(|&l| {
                    let l = &self.layers[l];
                    l.pass().eq_ignore_ascii_case(&n) && l.pick(channels).is_some()
                })
                .collect();
            (!m.is_empty()).then_some(m)
        }) else {
            return Ok(None);
        };
        if matches.len() > 1 {
            return Err(self.ambiguous(path, buffer, &matches));
        }
        let layer = &self.layers[matches[0]];
        let image = self.image(layer, channels).expect("picked channels");
        Ok(Some(Picked {
            buffer,
            image,
            source: Self::source(layer, channels),
            layer: matches[0],
        }))
    }

    /// A file given for `buffer` alone: the layer the table names for it, else the file's
    /// unprefixed channels; an error naming the layers found when neither exists.
    pub fn for_buffer(&self, path: &Path, buffer: &'static str) -> Result<Picked> {
        if let Some(picked) = self.by_table(path, buffer)? {
            return Ok(picked);
        }
        let channels = channels_of(buffer);
        match self.layers.iter().position(|l| l.name.is_empty()) {
            Some(plain) if self.layers[plain].pick(channels).is_some() => {
                let layer = &self.layers[plain];
                Ok(Picked {
                    buffer,
                    image: self.image(layer, channels).expect("picked channels"),
                    source: Self::source(layer, channels),
                    layer: plain,
                })
            }
            _ => Err(Error::file(
                path,
                format!(
                    "has no layer that is `{buffer}` by its name; name one as {}:LAYER; {}",
                    path.display(),
                    self.found()
                ),
            )),
        }
    }

    /// The motion pass, if the file has one the [`MOTION`] table names.
    pub fn motion(&self) -> Option<MotionPass> {
        let (mut back, mut fore, mut sources) = (None, None, Vec::new());
        for (name, kind) in MOTION {
            let Some(layer) = self
                .layers
                .iter()
                .find(|l| l.pass().eq_ignore_ascii_case(name))
            else {
                continue;
            };
            let channel = |names: &[&str]| layer.find(names);
            let plane = |c: usize, sign: f32| -> Vec<f32> {
                match &layer.channels[c].1.samples {
                    FlatSamples::F16(v) => v.iter().map(|s| sign * s.to_f32()).collect(),
                    FlatSamples::F32(v) => v.iter().map(|&s| sign * s).collect(),
                    FlatSamples::U32(v) => v.iter().map(|&s| sign * s as f32).collect(),
                }
            };
            // Interleaved (dx, dy) with y turned downwards; `sx`, `sy` turn each into an offset.
            let offsets = |x: usize, y: usize, sx: f32, sy: f32| {
                let (xs, ys) = (plane(x, sx), plane(y, sy));
                let data = xs.iter().zip(&ys).flat_map(|(&a, &b)| [a, b]).collect();
                Image::from_vec(self.width, self.height, 2, data).ok()
            };
            let xy = || Some((channel(&["R", "X"])?, channel(&["G", "Y"])?));
            match kind {
                MotionKind::BlenderVector => {
                    let zw = || Some((channel(&["Z", "B"])?, channel(&["W", "A"])?));
                    let (Some((x, y)), Some((z, w))) = (xy(), zw()) else {
                        continue;
                    };
                    back = offsets(x, y, 1.0, -1.0);
                    fore = offsets(z, w, -1.0, 1.0);
                }
                MotionKind::Back => {
                    let Some((x, y)) = xy() else { continue };
                    back = back.or_else(|| offsets(x, y, 1.0, -1.0));
                }
                MotionKind::Fore => {
                    let Some((x, y)) = xy() else { continue };
                    fore = fore.or_else(|| offsets(x, y, 1.0, -1.0));
                }
            }
            sources.push(layer.describe());
        }
        (back.is_some() || fore.is_some()).then(|| MotionPass {
            back,
            fore,
            source: sources.join(", "),
        })
    }

    /// Layers recognised as passes gsid does not load (feature variances), for a note.
    pub fn recorded(&self) -> Vec<String> {
        self.layers
            .iter()
            .filter(|l| RECORDED.iter().any(|r| l.pass().eq_ignore_ascii_case(r)))
            .map(Layer::describe)
            .collect()
    }
}

/// Channels of a buffer named in [`PASSES`].
pub fn channels_of(buffer: &str) -> usize {
    Feature::from_name(buffer).map_or(3, Feature::channels)
}

/// Whether a normal buffer is stored in 0..1 (`n * 0.5 + 0.5`): no negative component, and most
/// non-zero pixels have `2n − 1`, not `n`, of unit length.
pub fn is_unit_encoded(normal: &Image) -> bool {
    if normal.data().iter().any(|&v| v < 0.0) {
        return false;
    }
    let near_one =
        |v: [f32; 3]| ((v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() - 1.0).abs() < 0.1;
    let (mut lit, mut encoded, mut plain) = (0usize, 0usize, 0usize);
    for px in normal.data().chunks_exact(3) {
        if px.iter().all(|&v| v == 0.0) {
            continue;
        }
        lit += 1;
        encoded += near_one([2.0 * px[0] - 1.0, 2.0 * px[1] - 1.0, 2.0 * px[2] - 1.0]) as usize;
        plain += near_one([px[0], px[1], px[2]]) as usize;
    }
    lit > 0 && encoded * 10 >= lit * 9 && plain * 2 < lit
}

/// Maps a 0..1 encoded normal buffer back to unit vectors; empty (zero) pixels stay zero.
pub fn decode_normal(normal: &mut Image) {
    for px in normal.data_mut().chunks_exact_mut(3) {
        if px.iter().any(|&v| v != 0.0) {
            for v in px {
                *v = 2.0 * *v - 1.0;
            }
        }
    }
}
