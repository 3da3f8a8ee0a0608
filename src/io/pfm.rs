//! Portable float maps, read and written as Open Image Denoise's `oidnDenoise` does.
//!
//! `PF` (RGB) or `Pf` (one channel), the width, the height and a scale whose sign is the byte order
//! (negative: little endian), separated by whitespace, with one whitespace byte before the raster of
//! f32 samples, rows bottom-up. Samples are multiplied by |scale| as `oidnDenoise` does, except at
//! 1, so a file gsid wrote (little endian, scale -1.0) reads back bit for bit, NaN payloads included.
//! PFM has no alpha: a 4-channel image is written as its RGB.

use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

use rayon::prelude::*;

use super::exr_file::MAX_PIXELS;
use crate::error::{Error, Result};
use crate::image::Image;

/// Longest header read: the four fields and any sane whitespace fit many times over, and a
/// damaged file is not scanned further.
const HEADER_MAX: usize = 256;

/// What a PFM header declares.
#[derive(Debug)]
struct Header {
    width: usize,
    height: usize,
    channels: usize,
    little_endian: bool,
    scale: f32,
    /// Bytes before the raster.
    len: usize,
}

impl Header {
    fn raster_bytes(&self) -> u64 {
        (self.width * self.height * self.channels * 4) as u64
    }
}

/// C's `isspace`, which the `>>` reads of `oidnDenoise` skip.
fn is_space(b: u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\n' | b'\r' | 0x0b | 0x0c)
}

/// The width and height a PFM file's header declares, reading only the header.
pub(super) fn dims(path: &Path) -> Option<(usize, usize)> {
    use std::io::Read;
    let mut bytes = Vec::new();
    std::fs::File::open(path)
        .ok()?
        .take(HEADER_MAX as u64)
        .read_to_end(&mut bytes)
        .ok()?;
    let header = parse_header(&bytes).ok()?;
    Some((header.width, header.height))
}

/// Parses the header at the start of `bytes` (at most [`HEADER_MAX`] of them are looked at).
fn parse_header(bytes: &[u8]) -> std::result::Result<Header, String> {
    let bytes = &bytes[..bytes.len().min(HEADER_MAX)];
    let channels = match bytes.get(..2) {
        Some(b"PF") => 3,
        Some(b"Pf") => 1,
        _ => return Err("not a PFM file (it does not start with PF or Pf)".into()),
    };
    let mut pos = 2;
    // Each field follows whitespace and is followed by whitespace.
    let mut field = |what: &str| -> std::result::Result<&str, String> {
        let start = pos;
        while pos < bytes.len() && is_space(bytes[pos]) {
            pos += 1;
        }
        if pos == start && pos < bytes.len() {
            return Err(format!("no whitespace before its {what}"));
        }
        let begin = pos;
        while pos < bytes.len() && !is_space(bytes[pos]) {
            pos += 1;
        }
        if pos == bytes.len() {
            return Err(format!("its header is cut off at its {what}"));
        }
        std::str::from_utf8(&bytes[begin..pos]).map_err(|_| format!("its {what} is not a number"))
    };
    let size = |text: &str, what: &str| -> std::result::Result<u64, String> {
        match text.parse::<u64>() {
            Ok(n) if n > 0 && text.bytes().all(|b| b.is_ascii_digit()) => Ok(n),
            _ => Err(format!(
                "its {what} `{}` is not a positive whole number",
                text.escape_debug()
            )),
        }
    };
    let width = size(field("width")?, "width")?;
    let height = size(field("height")?, "height")?;
    let scale_text = field("scale")?;
    let scale = match scale_text.parse::<f32>() {
        Ok(s) if s.is_finite() && s != 0.0 => s,
        _ => {
            return Err(format!(
                "its scale `{}` is not a non-zero number (its sign gives the byte order)",
                scale_text.escape_debug()
            ))
        }
    };
    let pixels = width as u128 * height as u128;
    if pixels > MAX_PIXELS as u128 {
        return Err(format!(
            "its header declares {width}x{height} pixels, more than the {MAX_PIXELS} this program reads"
        ));
    }
    Ok(Header {
        width: width as usize,
        height: height as usize,
        channels,
        little_endian: scale < 0.0,
        scale: scale.abs(),
        // The one whitespace byte after the scale (the field loop stopped on it).
        len: pos + 1,
    })
}

/// The raster after the header must be exactly the declared size.
fn check_length(header: &Header, file_len: u64) -> std::result::Result<(), String> {
    let want = header.raster_bytes();
    let have = file_len - header.len as u64;
    let declared = format!(
        "{}x{}x{} samples ({want} bytes)",
        header.width, header.height, header.channels
    );
    if have < want {
        Err(format!(
            "is truncated: its header declares {declared} but {have} bytes follow it"
        ))
    } else if have > want {
        Err(format!(
            "has {} bytes after the {declared} its header declares",
            have - want
        ))
    } else {
        Ok(())
    }
}

/// The raster as a top-down image of `channels` channels: a one-channel file fills all three of
/// colour, an RGB file read as one channel gives its R (as EXR files are read).
fn decode_raster(header: &Header, raster: &[u8], channels: usize) -> Image {
    let (w, h, c) = (header.width, header.height, header.channels);
    let row_bytes = w * c * 4;
    let mut data = vec![0.0f32; w * h * channels];
    data.par_chunks_mut(w * channels)
        .enumerate()
        .for_each(|(y, row)| {
            let src = &raster[(h - 1 - y) * row_bytes..(h - y) * row_bytes];
            for (px, s) in row.chunks_exact_mut(channels).zip(src.chunks_exact(c * 4)) {
                for (k, out) in px.iter_mut().enumerate() {
                    let i = if c == channels { k } else { 0 };
                    let b = [s[4 * i], s[4 * i + 1], s[4 * i + 2], s[4 * i + 3]];
                    let v = if header.little_endian {
                        f32::from_le_bytes(b)
                    } else {
                        f32::from_be_bytes(b)
                    };
                    *out = if header.scale == 1.0 {
                        v
                    } else {
                        v * header.scale
                    };
                }
            }
        });
    Image::from_vec(w, h, channels, data).expect("the raster's shape")
}

/// Decodes a whole PFM file held in memory as `channels` channels (1 or 3).
pub fn decode(bytes: &[u8], channels: usize) -> std::result::Result<Image, String> {
    let header = parse_header(bytes)?;
    check_length(&header, bytes.len() as u64)?;
    Ok(decode_raster(&header, &bytes[header.len..], channels))
}

/// Reads a PFM file as `channels` channels (1 or 3). The header is checked against the file's
/// length before the raster is read, so a damaged header never allocates more than the file holds.
pub fn read(path: &Path, channels: usize) -> Result<Image> {
    let io_err = |e: std::io::Error| match e.kind() {
        std::io::ErrorKind::NotFound => Error::file(path, "file not found"),
        _ => Error::file(path, e),
    };
    let mut file = std::fs::File::open(path).map_err(io_err)?;
    let file_len = file.metadata().map_err(io_err)?.len();
    let mut head = Vec::with_capacity(HEADER_MAX);
    (&mut file)
        .take(HEADER_MAX as u64)
        .read_to_end(&mut head)
        .map_err(io_err)?;
    let bad = |m: String| Error::file(path, format!("not a readable PFM file: {m}"));
    let header = parse_header(&head).map_err(bad)?;
    check_length(&header, file_len).map_err(bad)?;
    let mut raster = vec![0u8; header.raster_bytes() as usize];
    file.seek(SeekFrom::Start(header.len as u64))
        .and_then(|_| file.read_exact(&mut raster))
        .map_err(io_err)?;
    Ok(decode_raster(&header, &raster, channels))
}

/// Encodes an image as `oidnDenoise` writes PFM: little endian, scale -1.0, rows bottom-up.
/// One channel gives `Pf`, three `PF`; of four, alpha is dropped.
pub fn encode(image: &Image) -> std::result::Result<Vec<u8>, String> {
    let (w, h, c) = (image.width(), image.height(), image.channels());
    let (magic, kept) = match c {
        1 => ("Pf", 1),
        3 | 4 => ("PF", 3),
        _ => return Err(format!("cannot write a {c}-channel image as PFM")),
    };
    let header = format!("{magic}\n{w} {h}\n-1.0\n");
    let mut bytes = vec![0u8; header.len() + w * h * kept * 4];
    let (head, raster) = bytes.split_at_mut(header.len());
    head.copy_from_slice(header.as_bytes());
    if w > 0 {
        raster
            .par_chunks_mut(w * kept * 4)
            .zip(image.data().par_chunks(w * c).rev())
            .for_each(|(dst, src)| {
                for (d, px) in dst.chunks_exact_mut(kept * 4).zip(src.chunks_exact(c)) {
                    for (k, &v) in px[..kept].iter().enumerate() {
                        d[4 * k..4 * k + 4].copy_from_slice(&v.to_le_bytes());
                    }
                }
            });
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pfm(header: &str, samples: &[u8]) -> Vec<u8> {
        let mut v = header.as_bytes().to_vec();
        v.extend_from_slice(samples);
        v
    }

    #[test]
    fn a_header_with_odd_whitespace_is_read() {
        let bytes = pfm("Pf \t2\r\n\n1 -1 ", &[0, 0, 128, 63, 0, 0, 0, 64]);
        let img = decode(&bytes, 1).unwrap();
        assert_eq!(img.dims(), (2, 1));
        assert_eq!(img.data(), &[1.0, 2.0]);
    }

    #[test]
    fn the_scale_multiplies_samples() {
        let bytes = pfm("Pf\n1 1\n-0.5\n", &4.0f32.to_le_bytes());
        assert_eq!(decode(&bytes, 1).unwrap().data(), &[2.0]);
    }

    #[test]
    fn bad_headers_are_named() {
        let cases: [(&[u8], &str); 9] = [
            (b"P6\n1 1\n-1\n", "does not start with PF"),
            (b"PF\n0 1\n-1\n", "width `0`"),
            (b"PF\n1 x\n-1\n", "height `x`"),
            (b"PF\n-1 1\n-1\n", "width `-1`"),
            (b"PF\n1 1\nnan\n", "scale `nan`"),
            (b"PF\n1 1\n0.0\n", "scale `0.0`"),
            (b"PF\n1 1\n-1", "cut off at its scale"),
            (b"PF1 1\n-1\n", "no whitespace"),
            (b"PF\n99999 99999\n-1\n", "more than the"),
        ];
        for (bytes, want) in cases {
            let err = decode(bytes, 3).unwrap_err();
            assert!(err.contains(want), "{err:?} lacks {want:?}");
        }
    }

    #[test]
    fn the_raster_must_have_the_declared_length() {
        let short = pfm("Pf\n2 1\n-1\n", &[0; 7]);
        assert!(decode(&short, 1).unwrap_err().contains("truncated"));
        let long = pfm("Pf\n2 1\n-1\n", &[0; 9]);
        assert!(decode(&long, 1).unwrap_err().contains("1 bytes after"));
    }

    #[test]
    fn channels_are_broadcast_or_taken_from_red() {
        let grey = pfm("Pf\n1 1\n-1\n", &3.0f32.to_le_bytes());
        assert_eq!(decode(&grey, 3).unwrap().data(), &[3.0, 3.0, 3.0]);
        let rgb: Vec<u8> = [5.0f32, 6.0, 7.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        assert_eq!(
            decode(&pfm("PF\n1 1\n-1\n", &rgb), 1).unwrap().data(),
            &[5.0]
        );
    }

    #[test]
    fn alpha_is_dropped_and_rows_are_stored_bottom_up() {
        let img = Image::from_fn(1, 2, 4, |_, y, c| (10 * y + c) as f32);
        let bytes = encode(&img).unwrap();
        let back = decode(&bytes, 3).unwrap();
        assert_eq!(back.data(), &[0.0, 1.0, 2.0, 10.0, 11.0, 12.0]);
        let raster = bytes.len() - 2 * 3 * 4;
        let first = f32::from_le_bytes(bytes[raster..raster + 4].try_into().unwrap());
        assert_eq!(
            first, 10.0,
            "the file's first row is the image's bottom row"
        );
    }
}
