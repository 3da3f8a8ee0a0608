//! Writing one scan-line EXR layer: its header (with the kept windows, attributes and channels),
//! the blocks built and compressed on the caller's pool, and the custom attributes in a fixed order.

use std::io::{Seek, SeekFrom, Write};

use exr::block::{self, chunk::Chunk, writer::ChunksWriter, BlockIndex, UncompressedBlock};
use exr::meta::attribute::{ChannelDescription, IntegerBounds, SampleType};
use exr::meta::header::{Header, ImageAttributes, LayerAttributes};
use exr::meta::BlockDescription;
use exr::prelude::{f16, FlatSamples, LineOrder, SmallVec, Text};
use rayon::prelude::*;

use super::frame::{Frame, Plane};
use crate::image::Image;

pub use exr::prelude::Compression;

/// Where the samples of one output channel come from.
#[derive(Clone, Copy)]
enum Source {
    /// Channel `k` of the image, stored as the header says (f32, or f16 for `--half`).
    Image(usize),
    /// A plane copied as stored.
    Plane(usize),
}

/// Attributes that mark a multilayer channel layout: dropped when only the colour is written, so
/// a plain RGBA file does not claim to be one.
const LAYOUT_ATTRIBUTES: [&str; 1] = ["BlenderMultiChannel"];

/// The header of one scan-line layer: the image's channels as `sample_type`, the planes as
/// stored, and the frame's windows and attributes (the image-level API's defaults without one).
fn header(
    image: &Image,
    names: &[String],
    sample_type: SampleType,
    planes: &[&Plane],
    frame: &Frame,
    compression: Compression,
) -> (Header, Vec<Source>) {
    let (w, h) = (image.width(), image.height());
    let mut list: Vec<(ChannelDescription, Source)> = names
        .iter()
        .enumerate()
        .map(|(k, name)| {
            let desc = ChannelDescription::named(name.as_str(), sample_type);
            (desc, Source::Image(k))
        })
        .chain(
            planes
                .iter()
                .enumerate()
                .map(|(i, p)| (p.desc.clone(), Source::Plane(i))),
        )
        .collect();
    list.sort_unstable_by(|a, b| a.0.name.cmp(&b.0.name));
    let sources = list.iter().map(|(_, s)| *s).collect();
    let descs: SmallVec<[ChannelDescription; 5]> = list.into_iter().map(|(d, _)| d).collect();
    let mut header = Header::new("".into(), (w, h), descs).with_encoding(
        compression,
        BlockDescription::ScanLines,
        LineOrder::Increasing,
    );
    match &frame.attributes {
        Some((shared, own)) => {
            header.shared_attributes = shared.clone();
            header.own_attributes = own.clone();
            // One part is written, so a part name would only repeat the channels' prefix.
            header.own_attributes.layer_name = None;
            if frame.layers.is_empty() {
                header.own_attributes.multi_view_names = None;
                for name in LAYOUT_ATTRIBUTES {
                    header.own_attributes.other.remove(&Text::from(name));
                }
            }
        }
        None => {
            header.own_attributes = LayerAttributes::default();
            header.shared_attributes = ImageAttributes::new(IntegerBounds::from_dimensions((w, h)));
        }
    }
    (header, sources)
}

/// The header's attributes in the order the exr crate writes them, its custom ones sorted by
/// name: it writes those in hash-map order, which changes from run to run.
fn sorted_header_bytes(header: &Header) -> exr::error::Result<Vec<u8>> {
    let custom = header.own_attributes.other.len() + header.shared_attributes.other.len();
    let mut attributes: Vec<_> = header.all_named_attributes().collect();
    let standard = attributes.len() - custom;
    attributes[standard..].sort_by(|a, b| a.0.cmp(b.0));
    let mut bytes = Vec::new();
    for (name, value) in &attributes {
        exr::meta::attribute::write(name, value, &mut bytes)?;
    }
    bytes.push(0);
    Ok(bytes)
}

/// Compressed blocks held at once while writing: bounds the extra memory to a slice of the image.
const BLOCKS_IN_FLIGHT: usize = 256;

/// How the denoised samples are stored.
#[derive(Clone, Copy, Debug)]
pub struct Encoding {
    pub compression: Compression,
    /// f16 samples instead of f32 (copied channels keep their own type).
    pub half: bool,
}

/// The colour's alpha as written beside a 3-channel image: named `A` unless the other layers are
/// written too (then under its own name), as stored, or as f16 with `--half` (every channel of
/// the beauty half, so an RGBA reader takes the file as one type); samples left out when only the
/// header is wanted.
fn written_alpha(c: usize, frame: &Frame, half: bool, with_samples: bool) -> Option<Plane> {
    let alpha = frame.alpha.as_ref().filter(|_| c == 3)?;
    let mut desc = alpha.desc.clone();
    if frame.layers.is_empty() {
        desc.name = Text::from("A");
    }
    let samples = match (&alpha.samples, half) {
        _ if !with_samples => FlatSamples::F32(Vec::new()),
        (FlatSamples::F32(v), true) => {
            desc.sample_type = SampleType::F16;
            FlatSamples::F16(v.iter().map(|&s| f16::from_f32(s)).collect())
        }
        (samples, _) => samples.clone(),
    };
    if half && desc.sample_type == SampleType::F32 {
        desc.sample_type = SampleType::F16;
    }
    Some(Plane { desc, samples })
}

/// The image's channel names (`R,G,B`, `Y` for one channel, or the colour's own names when its
/// other layers are written too) and the stored planes written beside them: the alpha, then the
/// other layers.
fn layout<'a>(
    c: usize,
    frame: &'a Frame,
    alpha: Option<&'a Plane>,
) -> (Vec<String>, Vec<&'a Plane>) {
    let layered = !frame.layers.is_empty();
    let names: Vec<String> = match c {
        3 if layered => frame.rgb.clone(),
        3 => ["R", "G", "B"].map(String::from).to_vec(),
        4 => ["R", "G", "B", "A"].map(String::from).to_vec(),
        _ => vec!["Y".to_string()],
    };
    let mut planes: Vec<&Plane> = alpha.into_iter().collect();
    planes.extend(&frame.layers);
    (names, planes)
}

fn sample_type(encoding: Encoding) -> SampleType {
    if encoding.half {
        SampleType::F16
    } else {
        SampleType::F32
    }
}

/// Checks, before any work, that the header [`write`] would give an output of `dims` and
/// `channels` with `frame` is valid: an input whose standard attribute is mistyped (a damaged
/// file) would otherwise fail the write after the whole run.
pub fn check(
    dims: (usize, usize),
    channels: usize,
    frame: &Frame,
    encoding: Encoding,
) -> exr::error::UnitResult {
    // Never written: its samples are the zero pages calloc hands out, not touched here.
    let image = Image::filled(dims.0, dims.1, channels, 0.0);
    let alpha = written_alpha(channels, frame, encoding.half, false);
    let (names, planes) = layout(channels, frame, alpha.as_ref());
    let (header, _) = header(
        &image,
        &names,
        sample_type(encoding),
        &planes,
        frame,
        encoding.compression,
    );
    exr::meta::MetaData::validate(&[header], true).map(|_| ())
}

/// Writes `image` as one scan-line layer with what `frame` keeps: its windows and attributes,
/// its alpha beside a 3-channel image, and its other layers once read. Channels are `R,G,B`
/// (`Y` for one channel), or the colour's own names when its other layers are written too.
pub fn write(
    mut out: impl Write + Seek + Send,
    image: &Image,
    frame: &Frame,
    encoding: Encoding,
) -> exr::error::UnitResult {
    let (w, c) = (image.width(), image.channels());
    let alpha = written_alpha(c, frame, encoding.half, true);
    let (names, planes) = layout(c, frame, alpha.as_ref());
    let (header, sources) = header(
        image,
        &names,
        sample_type(encoding),
        &planes,
        frame,
        encoding.compression,
    );
    let rewrite = header.own_attributes.other.len() + header.shared_attributes.other.len() > 1;
    let header_bytes = rewrite.then(|| sorted_header_bytes(&header)).transpose()?;
    let headers: exr::meta::Headers = SmallVec::from_elem(header, 1);
    block::write(&mut out, headers, true, |meta, writer| {
        let indices: Vec<_> =
            block::enumerate_ordered_header_block_indices(&meta.headers).collect();
        let bytes_per_pixel = meta.headers[0].channels.bytes_per_pixel;
        let compress = |group: &[(usize, BlockIndex)]| -> exr::error::Result<Vec<Chunk>> {
            group
                .par_iter()
                .map(|(_, index)| {
                    let (y0, lines) = (index.pixel_position.y(), index.pixel_size.y());
                    let mut data = Vec::with_capacity(lines * w * bytes_per_pixel);
                    for y in y0..y0 + lines {
                        let row = &image.data()[y * w * c..(y + 1) * w * c];
                        for source in &sources {
                            match *source {
                                Source::Image(k) => push_image(&mut data, row, k, c, encoding.half),
                                Source::Plane(i) => {
                                    push_plane(&mut data, &planes[i].samples, y * w..(y + 1) * w)
                                }
                            }
                        }
                    }
                    UncompressedBlock {
                        index: *index,
                        data,
                    }
                    .compress_to_chunk(&meta.headers)
                })
                .collect()
        };
        // Chunks go to the file in order, one group at a time, while the next group compresses.
        let mut groups = indices.chunks(BLOCKS_IN_FLIGHT);
        let mut pending = groups
            .next()
            .map(|g| compress(g).map(|c| (g, c)))
            .transpose()?;
        while let Some((group, chunks)) = pending {
            let next = groups.next();
            let (written, compressed) = rayon::join(
                || -> exr::error::UnitResult {
                    for ((index_in_header, _), chunk) in group.iter().zip(chunks) {
                        writer.write_chunk(*index_in_header, chunk)?;
                    }
                    Ok(())
                },
                || next.map(|g| compress(g).map(|c| (g, c))).transpose(),
            );
            written?;
            pending = compressed?;
        }
        Ok(())
    })?;
    if let Some(bytes) = header_bytes {
        // The same attributes in another order have the same length. A single-part header starts
        // after the magic number and the version field.
        out.seek(SeekFrom::Start(8))?;
        out.write_all(&bytes)?;
        out.seek(SeekFrom::End(0))?;
    }
    Ok(())
}

/// Appends channel `k` of every pixel in `row` (`c` per pixel) as little-endian f32 or f16.
fn push_image(data: &mut Vec<u8>, row: &[f32], k: usize, c: usize, half: bool) {
    for px in row.chunks_exact(c) {
        if half {
            data.extend_from_slice(&f16::from_f32(px[k]).to_le_bytes());
        } else {
            data.extend_from_slice(&px[k].to_le_bytes());
        }
    }
}

/// Appends samples `range` of a plane as its file stored them.
fn push_plane(data: &mut Vec<u8>, samples: &FlatSamples, range: std::ops::Range<usize>) {
    match samples {
        FlatSamples::F16(v) => v[range]
            .iter()
            .for_each(|s| data.extend_from_slice(&s.to_le_bytes())),
        FlatSamples::F32(v) => v[range]
            .iter()
            .for_each(|s| data.extend_from_slice(&s.to_le_bytes())),
        FlatSamples::U32(v) => v[range]
            .iter()
            .for_each(|s| data.extend_from_slice(&s.to_le_bytes())),
    }
}
