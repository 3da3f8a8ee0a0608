//! What an EXR output keeps of its input ([`Frame`]), the channels it copies as stored ([`Plane`]),
//! and every channel of a file read as stored ([`read_all_channels`]).

use std::path::{Path, PathBuf};

use exr::meta::attribute::{ChannelDescription, SampleType};
use exr::meta::header::{Header, ImageAttributes, LayerAttributes};
use exr::prelude::{FlatSamples, Text, Vec2};

use crate::error::{Error, Result};

/// One channel as its file stores it, so it can be written back bit for bit.
#[derive(Clone, Debug)]
pub struct Plane {
    pub desc: ChannelDescription,
    pub samples: FlatSamples,
}

/// What an EXR output keeps of the colour's file besides the denoised RGB: its windows and
/// attributes, its alpha, and (asked for) its other channels. The default keeps nothing.
#[derive(Clone, Debug, Default)]
pub struct Frame {
    /// The colour's part: display window, data window origin, every other attribute.
    pub(super) attributes: Option<(ImageAttributes, LayerAttributes)>,
    /// The colour's R, G, B channels, named as [`read_all_channels`] names them.
    pub(super) rgb: Vec<String>,
    pub(super) alpha: Option<Plane>,
    /// The colour's file, when it holds channels besides the colour's.
    source: Option<PathBuf>,
    /// Those channels, once [`Frame::read_layers`] has read them.
    pub(super) layers: Vec<Plane>,
    /// How the colour's part was compressed, which an output follows unless told otherwise.
    compression: Option<exr::compression::Compression>,
}

impl Frame {
    pub(super) fn new(header: &Header) -> Self {
        Frame {
            attributes: Some((
                header.shared_attributes.clone(),
                header.own_attributes.clone(),
            )),
            compression: Some(header.compression),
            ..Frame::default()
        }
    }

    /// This frame (a part's) as the colour's: its R, G, B names, its alpha, and its file if that
    /// holds other channels.
    pub(crate) fn of_colour(
        mut self,
        rgb: Vec<String>,
        alpha: Option<Plane>,
        others_in: Option<&Path>,
    ) -> Frame {
        self.rgb = rgb;
        self.alpha = alpha;
        self.source = others_in.map(Path::to_path_buf);
        self
    }

    /// The data window's top-left corner (its size is the image's).
    pub fn origin(&self) -> (i32, i32) {
        self.attributes
            .as_ref()
            .map_or((0, 0), |(_, own)| own.layer_position.into())
    }

    /// Whether the colour's file holds channels besides the colour's (what `--keep-layers` keeps).
    pub fn has_layers(&self) -> bool {
        self.source.is_some()
    }

    pub fn has_alpha(&self) -> bool {
        self.alpha.is_some()
    }

    /// The colour's compression, when it came from an EXR file.
    pub fn compression(&self) -> Option<exr::compression::Compression> {
        self.compression
    }

    /// The colour's alpha as f32, one value a pixel (for an 8-bit preview, which keeps it).
    pub fn alpha_values(&self) -> Option<Vec<f32>> {
        Some(match &self.alpha.as_ref()?.samples {
            FlatSamples::F16(v) => v.iter().map(|s| s.to_f32()).collect(),
            FlatSamples::F32(v) => v.clone(),
            FlatSamples::U32(v) => v.iter().map(|&s| s as f32).collect(),
        })
    }

    /// The same windows and attributes, without alpha or layers (for intermediate buffers).
    pub fn windows_only(&self) -> Frame {
        Frame {
            attributes: self.attributes.clone(),
            ..Frame::default()
        }
    }

    /// Reads every channel of the colour's file but the colour's own, to be written unchanged.
    /// Read at the end, not kept from the start, so they take no memory while the pipeline runs.
    pub fn read_layers(&mut self) -> Result<()> {
        let Some(path) = &self.source else {
            return Ok(());
        };
        let all = read_all_channels(path)?.channels;
        let alpha = self.alpha.as_ref().map(|a| a.desc.name.to_string());
        self.layers = all
            .into_iter()
            .map(|(_, p)| p)
            .filter(|p| {
                let name = p.desc.name.to_string();
                !self.rgb.contains(&name) && alpha.as_ref() != Some(&name)
            })
            .collect();
        Ok(())
    }
}

/// Every channel of every non-deep part of an EXR file, as stored.
pub struct Channels {
    pub width: usize,
    pub height: usize,
    /// Each channel and the index of its part in `parts`. A part's name (if it has one) is
    /// prefixed to its channels' names, so multi-part and multilayer files name alike.
    pub channels: Vec<(usize, Plane)>,
    /// Each part's windows and attributes.
    pub parts: Vec<Frame>,
}

/// Reads [`Channels`]; every channel must cover the first part's data window at full resolution.
pub fn read_all_channels(path: &Path) -> Result<Channels> {
    use exr::prelude::{ReadChannels, ReadLayers};
    let bad = |e: exr::error::Error| Error::file(path, format!("not a readable EXR file ({e})"));
    let file_len = std::fs::metadata(path)
        .map_err(|e| Error::file(path, e))?
        .len();
    let meta = exr::meta::MetaData::read_from_file(path, false).map_err(bad)?;
    for header in meta.headers.iter().filter(|h| !h.deep) {
        super::declared::check_declared(path, header, file_len)?;
    }
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .all_layers()
        .all_attributes()
        .from_file(path)
        .map_err(bad)?;
    let window = |l: &exr::image::Layer<_>| (l.attributes.layer_position, l.size);
    let first = image.layer_data.first().map(window);
    let mut channels = Vec::new();
    let mut parts = Vec::new();
    for (k, layer) in image.layer_data.into_iter().enumerate() {
        let part = layer.attributes.layer_name.as_ref().map(|n| n.to_string());
        let here = window(&layer);
        for c in layer.channel_data.list {
            let name = match &part {
                Some(p) => format!("{p}.{}", c.name),
                None => c.name.to_string(),
            };
            if Some(here) != first {
                return Err(Error::file(
                    path,
                    format!("channel {name} is not in the data window of the file's first part, which is not supported"),
                ));
            }
            if c.sampling != Vec2(1, 1) {
                return Err(Error::file(
                    path,
                    format!(
                        "channel {name} is not at the image's full size, which is not supported"
                    ),
                ));
            }
            let desc = ChannelDescription {
                name: Text::from(name.as_str()),
                sample_type: match &c.sample_data {
                    FlatSamples::F16(_) => SampleType::F16,
                    FlatSamples::F32(_) => SampleType::F32,
                    FlatSamples::U32(_) => SampleType::U32,
                },
                quantize_linearly: c.quantize_linearly,
                sampling: c.sampling,
            };
            channels.push((
                k,
                Plane {
                    desc,
                    samples: c.sample_data,
                },
            ));
        }
        parts.push(Frame {
            attributes: Some((image.attributes.clone(), layer.attributes)),
            compression: Some(layer.encoding.compression),
            ..Frame::default()
        });
    }
    let size = first.map_or(Vec2(0, 0), |(_, size)| size);
    Ok(Channels {
        width: size.x(),
        height: size.y(),
        channels,
        parts,
    })
}
