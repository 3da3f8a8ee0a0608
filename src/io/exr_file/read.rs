//! Reading one EXR layer as interleaved f32: the header's checks (channels, subsampling, sizes a
//! file can hold), the blocks decompressed on the caller's pool, and the check that they tile the image.

use std::io::BufReader;
use std::path::Path;

use exr::block::{self, chunk::Chunk, UncompressedBlock};
use exr::meta::attribute::{ChannelDescription, SampleType};
use exr::prelude::{f16, FlatSamples, Vec2};
use rayon::prelude::*;

use super::declared::check_declared;
use super::frame::{Frame, Plane};
use crate::error::{Error, Result};
use crate::image::{par_vec, Image};

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
    check_declared(path, header, file_len)?;
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

/// Whether the file holds named layers (a channel name with a dot, `ViewLayer.Combined.R`) or
/// several parts, from its headers alone: then which channels are a buffer is the pass table's
/// choice, not the first R, G, B that sorts first.
pub fn is_multilayer(path: &Path) -> Result<bool> {
    let meta = exr::meta::MetaData::read_from_file(path, false)
        .map_err(|e| Error::file(path, format!("not a readable EXR file ({e})")))?;
    let named = |h: &exr::meta::header::Header| {
        h.channels
            .list
            .iter()
            .any(|c| c.name.to_string().contains('.'))
    };
    Ok(meta.headers.len() > 1 || meta.headers.iter().any(named))
}

/// The size of the file's first part's data window, from its header alone.
pub fn declared_size(path: &Path) -> Option<(usize, usize)> {
    let meta = exr::meta::MetaData::read_from_file(path, false).ok()?;
    let size = meta.headers.first()?.layer_size;
    Some((size.width(), size.height()))
}

/// The first non-deep part's pixel count and bytes of samples per pixel (every channel, at its
/// stored type), from the header alone: what [`read`] decompresses.
pub fn declared_layout(path: &Path) -> Option<(u64, u64)> {
    let meta = exr::meta::MetaData::read_from_file(path, false).ok()?;
    let header = meta.headers.iter().find(|h| !h.deep)?;
    let size = header.layer_size;
    Some((
        size.width() as u64 * size.height() as u64,
        header.channels.bytes_per_pixel as u64,
    ))
}

/// How many channels the file's first part holds, from its header alone.
pub fn channel_count(path: &Path) -> Result<usize> {
    let meta = exr::meta::MetaData::read_from_file(path, false)
        .map_err(|e| Error::file(path, format!("not a readable EXR file ({e})")))?;
    Ok(meta.headers.first().map_or(0, |h| h.channels.list.len()))
}
