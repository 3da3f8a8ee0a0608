//! The EXR compression methods an output can be written with, by their `--compression` names.

use super::exr_file;

/// How an EXR's pixels are compressed: every method the exr crate writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Compression {
    /// Deflate, 16 lines a block: what Blender writes, and outputs' default when the colour was not
    /// an EXR (an EXR colour's own method is followed).
    Zip,
    /// Run-length: almost free to write, but it barely compresses float colour.
    Rle,
    None,
    /// Deflate, one scan line per block.
    Zips,
    Piz,
    /// Lossy for f32 (rounded to 24 bits), lossless for f16.
    Pxr24,
    /// Lossy for f16, which it alone compresses.
    B44,
    /// B44 that also packs flat blocks (lossy for f16).
    B44a,
    /// Lossy (DCT) for colour channels, 32 lines per block.
    Dwaa,
    /// Lossy (DCT) for colour channels, 256 lines per block.
    Dwab,
}

impl Compression {
    /// The `--compression` names, in the order they are listed.
    pub const NAMES: [(&'static str, Compression); 10] = [
        ("none", Compression::None),
        ("rle", Compression::Rle),
        ("zips", Compression::Zips),
        ("zip", Compression::Zip),
        ("piz", Compression::Piz),
        ("pxr24", Compression::Pxr24),
        ("b44", Compression::B44),
        ("b44a", Compression::B44a),
        ("dwaa", Compression::Dwaa),
        ("dwab", Compression::Dwab),
    ];

    pub fn name(self) -> &'static str {
        Self::NAMES
            .iter()
            .find(|(_, c)| *c == self)
            .map_or("", |(n, _)| n)
    }

    pub fn from_name(name: &str) -> Option<Compression> {
        Self::NAMES
            .iter()
            .find(|(n, _)| n.eq_ignore_ascii_case(name))
            .map(|&(_, c)| c)
    }

    /// Whether the method can change samples: then copied channels are no longer bit-exact.
    pub fn is_lossy(self) -> bool {
        self.exr().may_loose_data()
    }

    /// The method an EXR was written with (a DWA level is not kept).
    pub fn of_exr(c: exr_file::Compression) -> Compression {
        use exr_file::Compression as C;
        match c {
            C::ZIP16 => Compression::Zip,
            C::RLE => Compression::Rle,
            C::Uncompressed => Compression::None,
            C::ZIP1 => Compression::Zips,
            C::PIZ => Compression::Piz,
            C::PXR24 => Compression::Pxr24,
            C::B44 => Compression::B44,
            C::B44A => Compression::B44a,
            C::DWAA(_) => Compression::Dwaa,
            C::DWAB(_) => Compression::Dwab,
            #[allow(unreachable_patterns)]
            _ => Compression::Zip,
        }
    }

    pub(super) fn exr(self) -> exr_file::Compression {
        use exr_file::Compression as C;
        match self {
            Compression::Zip => C::ZIP16,
            Compression::Rle => C::RLE,
            Compression::None => C::Uncompressed,
            Compression::Zips => C::ZIP1,
            Compression::Piz => C::PIZ,
            Compression::Pxr24 => C::PXR24,
            Compression::B44 => C::B44,
            Compression::B44a => C::B44A,
            Compression::Dwaa => C::DWAA(None),
            Compression::Dwab => C::DWAB(None),
        }
    }
}
