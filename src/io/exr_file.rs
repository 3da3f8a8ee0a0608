//! EXR files decoded and encoded block by block on the caller's thread pool.
//!
//! The exr crate's image-level API compresses on a pool of its own (one per file, every core,
//! whatever `--threads` says) and moves samples through per-line generic readers, leaving the
//! channel interleave serial. Here the file's chunks are read in order (cheap), then decompressed
//! and converted to interleaved f32, or built and compressed, in parallel on the pool the caller
//! runs in. Headers are the ones the image-level API writes, so files are byte-identical (tested).

use std::io::{BufReader, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use exr::block::{self, chunk::Chunk, writer::ChunksWriter, BlockIndex, UncompressedBlock};
use exr::meta::attribute::{ChannelDescription, IntegerBounds, SampleType};
use exr::meta::header::{Header, ImageAttributes, LayerAttributes};
use exr::meta::BlockDescription;
use exr::prelude::{f16, FlatSamples, LineOrder, SmallVec, Text, Vec2};
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::image::{par_vec, Image};

pub use exr::prelude::Compression;

/// Most pixels [`read`] accepts (2^28, a 16384² image): it allocates 4 bytes per pixel per channel
/// asked for (12 for colour) whatever the file's sample types, so a header may not declare more
/// than this, however small its samples.
pub const MAX_PIXELS: u64 = 1 << 28;

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
    attributes: Option<(ImageAttributes, LayerAttributes)>,
    /// The colour's R, G, B channels, named as [`read_all_channels`] names them.
    rgb: Vec<String>,
    alpha: Option<Plane>,
    /// The colour's file, when it holds channels besides the colour's.
    source: Option<PathBuf>,
    /// Those channels, once [`Frame::read_layers`] has read them.
    layers: Vec<Plane>,
}

impl Frame {
    fn new(header: &Header) -> Self {
        Frame {
            attributes: Some((
                header.shared_attributes.clone(),
                header.own_attributes.clone(),
            )),
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

/// Reads the first non-deep layer of an EXR file at its full resolution as `channels` channels,
/// and what an output keeps of it: with `alpha`, the `A` channel beside the R, G, B read.
pub fn read(path: &Path, channels: usize, alpha: bool) -> Result<(Image, Frame)> {
    let bad = |e: exr::error::Error| Error::file(path, format!("not a readable EXR file ({e})"));
    let file = std::fs::File::open(path).map_err(|e| Error::file(path, e))?;
    let file_len = file.metadata().map_err(|e| Error::file(path, e))?.len();
    let reader = block::read(BufReader::new(file), false).map_err(bad)?;
    let meta = reader.meta_data().clone();
    let layer = meta
        .headers
        .iter()
        .position(|h| !h.deep)
        .ok_or_else(|| Error::file(path, "holds only deep data, which is not supported"))?;
    let header = &meta.headers[layer];
    let list = &header.channels.list;
    let picked = pick_channels(list, channels).map_err(|m| Error::file(path, m))?;
    let alpha = alpha.then(|| alpha_beside(list, &picked)).flatten();
    if let Some(c) = picked
        .iter()
        .chain(&alpha)
        .find(|&&c| list[c].sampling != Vec2(1, 1))
    {
        return Err(Error::file(
            path,
            format!(
                "channel {} is subsampled, which is not supported",
                list[*c].name
            ),
        ));
    }
    let size = format!("{}x{}", header.layer_size.x(), header.layer_size.y());
    let pixels = header.layer_size.x() as u64 * header.layer_size.y() as u64;
    if pixels > MAX_PIXELS {
        return Err(Error::file(
            path,
            format!(
                "its header declares {size} pixels, more than the {MAX_PIXELS} this program reads"
            ),
        ));
    }
    // A damaged header can declare gigapixels in a small file, and every block is allocated at
    // its declared size before its data is checked. No codec the crate reads packs more than about
    // 1000 bytes of samples into one byte (deflate's limit), so a larger claim is an error.
    let declared = (header.layer_size.x() as u128)
        * (header.layer_size.y() as u128)
        * (header.channels.bytes_per_pixel as u128);
    if declared > file_len as u128 * 4096 + (1 << 20) {
        return Err(Error::file(
            path,
            format!(
                "not a readable EXR file (its header declares {size} pixels, more than a {file_len}-byte file can hold)"
            ),
        ));
    }
    let chunks: Vec<Chunk> = reader
        .filter_chunks(false, |_, tile, block| {
            block.layer == layer && tile.is_largest_resolution_level()
        })
        .map_err(bad)?
        .collect::<std::result::Result<_, _>>()
        .map_err(bad)?;
    let mut blocks: Vec<UncompressedBlock> = chunks
        .into_par_iter()
        .map(|chunk| UncompressedBlock::decompress_chunk(chunk, &meta, false))
        .collect::<std::result::Result<_, _>>()
        .map_err(bad)?;
    let (w, h) = (header.layer_size.x(), header.layer_size.y());
    blocks.sort_unstable_by_key(|b| (b.index.pixel_position.y(), b.index.pixel_position.x()));
    let bands = bands(&blocks, w, h).map_err(|m| Error::file(path, m))?;

    // Byte offset of each channel's samples within one line of a block, per pixel of width.
    let mut offset = Vec::with_capacity(list.len());
    let mut bytes_per_pixel = 0;
    for c in list.iter() {
        offset.push(bytes_per_pixel);
        bytes_per_pixel += c.sample_type.bytes_per_sample();
    }
    let mut data = par_vec(0.0f32, w * h * channels);
    let alpha_bytes = alpha.map_or(0, |a| list[a].sample_type.bytes_per_sample());
    let mut alpha_data = vec![0u8; w * h * alpha_bytes];
    let (mut rest, mut alpha_rest) = (data.as_mut_slice(), alpha_data.as_mut_slice());
    let mut rows = Vec::with_capacity(bands.len());
    for band in &bands {
        let (head, tail) = rest.split_at_mut(band.height * w * channels);
        let (alpha_head, alpha_tail) = alpha_rest.split_at_mut(band.height * w * alpha_bytes);
        rows.push((head, alpha_head));
        (rest, alpha_rest) = (tail, alpha_tail);
    }
    rows.into_par_iter()
        .zip(bands.par_iter())
        .try_for_each(|((rows, alpha_rows), band)| {
            for b in &blocks[band.blocks.clone()] {
                let (x0, bw) = (b.index.pixel_position.x(), b.index.pixel_size.x());
                if b.data.len() != bw * band.height * bytes_per_pixel {
                    return Err(Error::file(path, "a pixel block has the wrong size"));
                }
                for (y, line) in b.data.chunks_exact(bw * bytes_per_pixel).enumerate() {
                    let row = &mut rows[(y * w + x0) * channels..(y * w + x0 + bw) * channels];
                    for (k, &c) in picked.iter().enumerate() {
                        let samples = &line[bw * offset[c]..];
                        convert(list[c].sample_type, samples, row, k, channels);
                    }
                    if let Some(a) = alpha {
                        let at = (y * w + x0) * alpha_bytes;
                        let from = bw * offset[a];
                        alpha_rows[at..at + bw * alpha_bytes]
                            .copy_from_slice(&line[from..from + bw * alpha_bytes]);
                    }
                }
            }
            Ok(())
        })?;
    let image = Image::from_vec(w, h, channels, data).map_err(|e| Error::file(path, e))?;
    // Channels are named as `read_all_channels` names them, so `--keep-layers` finds them there.
    let part = header.own_attributes.layer_name.as_ref();
    let full = |c: usize| match part {
        Some(p) => format!("{p}.{}", list[c].name),
        None => list[c].name.to_string(),
    };
    let mut own: Vec<usize> = picked.iter().chain(&alpha).copied().collect();
    own.sort_unstable();
    own.dedup();
    let in_file: usize = meta
        .headers
        .iter()
        .filter(|h| !h.deep)
        .map(|h| h.channels.list.len())
        .sum();
    let alpha = alpha.map(|a| Plane {
        desc: ChannelDescription {
            name: full(a).as_str().into(),
            ..list[a].clone()
        },
        samples: samples_from_le(list[a].sample_type, &alpha_data),
    });
    let rgb = picked.iter().map(|&c| full(c)).collect();
    let frame = Frame::new(header).of_colour(rgb, alpha, (in_file > own.len()).then_some(path));
    Ok((image, frame))
}

/// The `A` channel in the same layer as the colour's R (`ViewLayer.Combined.A` beside
/// `ViewLayer.Combined.R`), if there is one.
fn alpha_beside(list: &[ChannelDescription], picked: &[usize]) -> Option<usize> {
    if picked.len() != 3 || picked[0] == picked[1] {
        return None;
    }
    let red = list[picked[0]].name.to_string();
    let prefix = red.rsplit_once('.').map_or("", |(p, _)| p);
    list.iter().position(|c| {
        let name = c.name.to_string();
        let (p, short) = name.rsplit_once('.').unwrap_or(("", &name));
        p == prefix && short.eq_ignore_ascii_case("A")
    })
}

/// Samples of one type from their little-endian bytes.
fn samples_from_le(kind: SampleType, bytes: &[u8]) -> FlatSamples {
    match kind {
        SampleType::F16 => FlatSamples::F16(
            bytes
                .chunks_exact(2)
                .map(|s| f16::from_le_bytes([s[0], s[1]]))
                .collect(),
        ),
        SampleType::F32 => FlatSamples::F32(
            bytes
                .chunks_exact(4)
                .map(|s| f32::from_le_bytes([s[0], s[1], s[2], s[3]]))
                .collect(),
        ),
        SampleType::U32 => FlatSamples::U32(
            bytes
                .chunks_exact(4)
                .map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
                .collect(),
        ),
    }
}

/// Writes sample `k` of every pixel in `row` (`channels` per pixel) from little-endian `samples`.
fn convert(kind: SampleType, samples: &[u8], row: &mut [f32], k: usize, channels: usize) {
    let pixels = row.chunks_exact_mut(channels);
    match kind {
        SampleType::F32 => {
            for (px, s) in pixels.zip(samples.chunks_exact(4)) {
                px[k] = f32::from_le_bytes([s[0], s[1], s[2], s[3]]);
            }
        }
        SampleType::F16 => {
            for (px, s) in pixels.zip(samples.chunks_exact(2)) {
                px[k] = f16::from_le_bytes([s[0], s[1]]).to_f32();
            }
        }
        SampleType::U32 => {
            for (px, s) in pixels.zip(samples.chunks_exact(4)) {
                px[k] = u32::from_le_bytes([s[0], s[1], s[2], s[3]]) as f32;
            }
        }
    }
}

/// Blocks sharing one row range: one scan-line block, or one row of tiles.
struct Band {
    height: usize,
    blocks: std::ops::Range<usize>,
}

/// Groups blocks (sorted by y, then x) into bands and checks that they tile the `w`×`h` image
/// exactly, so every output pixel is written once: a damaged offset table cannot leave holes.
fn bands(
    blocks: &[UncompressedBlock],
    w: usize,
    h: usize,
) -> std::result::Result<Vec<Band>, &'static str> {
    const BROKEN: &str = "not a readable EXR file (its pixel blocks do not tile the image)";
    let mut bands = Vec::new();
    let (mut y, mut i) = (0, 0);
    while i < blocks.len() {
        let first = &blocks[i].index;
        let height = first.pixel_size.y();
        if first.pixel_position.y() != y || height == 0 {
            return Err(BROKEN);
        }
        let start = i;
        let mut x = 0;
        while i < blocks.len() && blocks[i].index.pixel_position.y() == y {
            let b = &blocks[i].index;
            if b.pixel_position.x() != x || b.pixel_size.y() != height || b.pixel_size.x() == 0 {
                return Err(BROKEN);
            }
            x += b.pixel_size.x();
            i += 1;
        }
        if x != w {
            return Err(BROKEN);
        }
        bands.push(Band {
            height,
            blocks: start..i,
        });
        y += height;
    }
    if y != h {
        return Err(BROKEN);
    }
    Ok(bands)
}

/// Indices into `list` of the channels read as `channels` image channels, matched on the last
/// dotted component of their names (`ViewLayer.Combined.R` works as well as `R`).
fn pick_channels(
    list: &[ChannelDescription],
    channels: usize,
) -> std::result::Result<Vec<usize>, String> {
    let short = |c: &ChannelDescription| -> String {
        let full = c.name.to_string();
        full.rsplit('.').next().unwrap_or(&full).to_string()
    };
    let find = |wanted: &[&str]| {
        wanted.iter().find_map(|want| {
            list.iter()
                .position(|c| short(c).eq_ignore_ascii_case(want))
        })
    };
    let names = || {
        list.iter()
            .map(|c| c.name.to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    if channels == 3 {
        match (find(&["R", "X"]), find(&["G", "Y"]), find(&["B", "Z"])) {
            (Some(r), Some(g), Some(b)) => Ok(vec![r, g, b]),
            _ if list.len() == 1 => Ok(vec![0; 3]),
            _ => Err(format!("has no R, G, B channels (found: {})", names())),
        }
    } else {
        match find(&["Y", "Z", "R"]) {
            Some(c) => Ok(vec![c]),
            None if list.len() == 1 => Ok(vec![0]),
            None => Err(format!("has no Y, Z or R channel (found: {})", names())),
        }
    }
}

/// How many channels the file's first part holds, from its header alone.
pub fn channel_count(path: &Path) -> Result<usize> {
    let meta = exr::meta::MetaData::read_from_file(path, false)
        .map_err(|e| Error::file(path, format!("not a readable EXR file ({e})")))?;
    Ok(meta.headers.first().map_or(0, |h| h.channels.list.len()))
}

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
    let layered = !frame.layers.is_empty();
    let names: Vec<String> = match c {
        3 if layered => frame.rgb.clone(),
        3 => ["R", "G", "B"].map(String::from).to_vec(),
        4 => ["R", "G", "B", "A"].map(String::from).to_vec(),
        _ => vec!["Y".to_string()],
    };
    let renamed_alpha;
    let mut planes: Vec<&Plane> = Vec::new();
    if let (3, Some(alpha)) = (c, &frame.alpha) {
        if layered {
            planes.push(alpha);
        } else {
            renamed_alpha = Plane {
                desc: ChannelDescription {
                    name: Text::from("A"),
                    ..alpha.desc.clone()
                },
                samples: alpha.samples.clone(),
            };
            planes.push(&renamed_alpha);
        }
    }
    planes.extend(&frame.layers);
    let sample_type = if encoding.half {
        SampleType::F16
    } else {
        SampleType::F32
    };
    let (header, sources) = header(
        image,
        &names,
        sample_type,
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
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .all_layers()
        .all_attributes()
        .from_file(path)
        .map_err(|e| Error::file(path, format!("not a readable EXR file ({e})")))?;
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
