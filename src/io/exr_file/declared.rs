//! What an EXR header may declare, checked before anything is decoded: a damaged header can claim
//! gigapixels in a small file, and the crate allocates every block at its declared size.

use std::path::Path;

use crate::error::{Error, Result};

/// Most pixels the reader accepts (2^28, a 16384² image): it allocates 4 bytes per pixel per channel
/// asked for (12 for colour) whatever the file's sample types, so a header may not declare more
/// than this, however small its samples.
pub const MAX_PIXELS: u64 = 1 << 28;

/// Refuses, before anything is decoded, a part whose header declares more pixels than this
/// program reads ([`MAX_PIXELS`]) or more samples than the file's `file_len` bytes can hold with
/// its compression method: a damaged header can declare gigapixels in a small file, and every
/// block is allocated at its declared size before its data is checked.
pub(super) fn check_declared(
    path: &Path,
    header: &exr::meta::header::Header,
    file_len: u64,
) -> Result<()> {
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
    let declared = pixels as u128 * header.channels.bytes_per_pixel as u128;
    let holds = (file_len as u128)
        .saturating_mul(max_ratio(header.compression))
        .saturating_add(HEADER_SLACK);
    if declared > holds {
        return Err(Error::file(
            path,
            format!(
                "not a readable EXR file (its header declares {size} pixels, more than a {file_len}-byte file can hold with {:?} compression)",
                header.compression
            ),
        ));
    }
    Ok(())
}

/// Bytes of samples a file may declare beyond what its compression can pack into its length:
/// headers, offset tables and chunk framing of small images.
const HEADER_SLACK: u128 = 1 << 20;

/// The most bytes of samples one byte of a chunk can hold with `compression`: stored samples
/// one; run-length 64 (a two-byte run repeats at most 128 bytes); deflate about 1032 (its
/// limit), 1376 for PXR24's 24-bit floats; B44 packs a flat 4×4 block of halves into 3 bytes.
/// PIZ's Huffman runs are bounded by 4096, well above their limit. The DWA codecs store a flat
/// channel in a few bytes, whatever its size: no bound (the memory estimate still applies).
fn max_ratio(compression: exr::compression::Compression) -> u128 {
    use exr::compression::Compression as C;
    match compression {
        C::Uncompressed => 1,
        C::RLE => 64,
        C::ZIP1 | C::ZIP16 => 1032,
        C::PXR24 => 1376,
        C::B44 | C::B44A => 11,
        C::DWAA(_) | C::DWAB(_) => u128::MAX,
        _ => 4096,
    }
}
