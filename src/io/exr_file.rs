//! EXR files decoded and encoded block by block on the caller's thread pool.
//!
//! The exr crate's image-level API compresses on a pool of its own (one per file, every core,
//! whatever `--threads` says) and moves samples through per-line generic readers, leaving the
//! channel interleave serial. Here the file's chunks are read in order (cheap), then decompressed
//! and converted to interleaved f32, or built and compressed, in parallel on the pool the caller
//! runs in. Headers are the ones the image-level API writes, so files are byte-identical (tested).

use std::io::{BufReader, Seek, Write};
use std::path::Path;

use exr::block::{self, chunk::Chunk, writer::ChunksWriter, BlockIndex, UncompressedBlock};
use exr::meta::attribute::{ChannelDescription, IntegerBounds, SampleType};
use exr::meta::header::{Header, ImageAttributes, LayerAttributes};
use exr::meta::BlockDescription;
use exr::prelude::{f16, LineOrder, SmallVec, Vec2};
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::image::Image;

pub use exr::prelude::Compression;

/// Most pixels [`read`] accepts (2^28, a 16384² image): it allocates 4 bytes per pixel per channel
/// asked for (12 for colour) whatever the file's sample types, so a header may not declare more
/// than this, however small its samples.
pub const MAX_PIXELS: u64 = 1 << 28;

/// Reads the first non-deep layer of an EXR file at its full resolution as `channels` channels.
pub fn read(path: &Path, channels: usize) -> Result<Image> {
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
    if let Some(c) = picked.iter().find(|&&c| list[c].sampling != Vec2(1, 1)) {
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
    let mut data = vec![0.0f32; w * h * channels];
    let mut rest = data.as_mut_slice();
    let mut rows = Vec::with_capacity(bands.len());
    for band in &bands {
        let (head, tail) = rest.split_at_mut(band.height * w * channels);
        rows.push(head);
        rest = tail;
    }
    rows.into_par_iter()
        .zip(bands.par_iter())
        .try_for_each(|(rows, band)| {
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
                }
            }
            Ok(())
        })?;
    Image::from_vec(w, h, channels, data).map_err(|e| Error::file(path, e))
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

/// The header the exr crate's image-level API writes for one scan-line layer of f32 channels.
fn header(w: usize, h: usize, names: &[&str], compression: Compression) -> Header {
    let mut list: SmallVec<[ChannelDescription; 5]> = names
        .iter()
        .map(|name| ChannelDescription::named(*name, SampleType::F32))
        .collect();
    list.sort_unstable_by_key(|c| c.name.clone());
    let mut header = Header::new("".into(), (w, h), list).with_encoding(
        compression,
        BlockDescription::ScanLines,
        LineOrder::Increasing,
    );
    header.own_attributes = LayerAttributes::default();
    header.shared_attributes = ImageAttributes::new(IntegerBounds::from_dimensions((w, h)));
    header
}

/// Compressed blocks held at once while writing: bounds the extra memory to a slice of the image.
const BLOCKS_IN_FLIGHT: usize = 256;

/// Writes `image` (channels named `names`) as one scan-line layer of f32 samples.
pub fn write(
    out: impl Write + Seek + Send,
    image: &Image,
    names: &[&str],
    compression: Compression,
) -> exr::error::UnitResult {
    let (w, h, c) = (image.width(), image.height(), image.channels());
    let header = header(w, h, names, compression);
    // Block lines hold each channel's samples in turn, in the header's (sorted) channel order.
    let order: Vec<usize> = header
        .channels
        .list
        .iter()
        .map(|d| {
            names
                .iter()
                .position(|n| d.name == **n)
                .expect("a named channel")
        })
        .collect();
    let headers: exr::meta::Headers = SmallVec::from_elem(header, 1);
    block::write(out, headers, true, |meta, writer| {
        let indices: Vec<_> =
            block::enumerate_ordered_header_block_indices(&meta.headers).collect();
        let compress = |group: &[(usize, BlockIndex)]| -> exr::error::Result<Vec<Chunk>> {
            group
                .par_iter()
                .map(|(_, index)| {
                    let (y0, lines) = (index.pixel_position.y(), index.pixel_size.y());
                    let mut data = Vec::with_capacity(lines * w * c * 4);
                    for row in image.data()[y0 * w * c..(y0 + lines) * w * c].chunks_exact(w * c) {
                        for &ch in &order {
                            for px in row.chunks_exact(c) {
                                data.extend_from_slice(&px[ch].to_le_bytes());
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
    })
}

/// Named channels of one size: width, height, and `(name, samples)` per channel.
pub type Channels = (usize, usize, Vec<(String, Vec<f32>)>);

/// Every channel of every non-deep part of an EXR file, as `(name, samples)`: a part's name (if it
/// has one) is prefixed to its channels' names, so multi-part and multilayer files name alike.
pub fn read_all_channels(path: &Path) -> Result<Channels> {
    use exr::prelude::{FlatSamples, ReadChannels, ReadLayers};
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .all_layers()
        .all_attributes()
        .from_file(path)
        .map_err(|e| Error::file(path, format!("not a readable EXR file ({e})")))?;
    let size = image
        .layer_data
        .first()
        .map(|l| l.size)
        .unwrap_or(Vec2(0, 0));
    let mut channels = Vec::new();
    for layer in &image.layer_data {
        let part = layer.attributes.layer_name.as_ref().map(|n| n.to_string());
        for c in &layer.channel_data.list {
            let name = match &part {
                Some(p) => format!("{p}.{}", c.name),
                None => c.name.to_string(),
            };
            if layer.size != size || c.sampling != Vec2(1, 1) {
                return Err(Error::file(
                    path,
                    format!(
                        "channel {name} is not at the image's full size, which is not supported"
                    ),
                ));
            }
            let samples = match &c.sample_data {
                FlatSamples::F16(v) => v.iter().map(|s| s.to_f32()).collect(),
                FlatSamples::F32(v) => v.clone(),
                FlatSamples::U32(v) => v.iter().map(|&s| s as f32).collect(),
            };
            channels.push((name, samples));
        }
    }
    Ok((size.x(), size.y(), channels))
}
