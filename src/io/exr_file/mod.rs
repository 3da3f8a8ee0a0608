//! EXR files decoded and encoded block by block on the caller's thread pool.
//!
//! The exr crate's image-level API compresses on a pool of its own (one per file, every core,
//! whatever `--threads` says) and moves samples through per-line generic readers, leaving the
//! channel interleave serial. Here the file's chunks are read in order (cheap), then decompressed
//! and converted to interleaved f32, or built and compressed, in parallel on the pool the caller
//! runs in. Headers are the ones the image-level API writes, so files are byte-identical (tested).

mod declared;
mod frame;
mod read;
mod write;

pub use declared::MAX_PIXELS;
pub use frame::{read_all_channels, Frame, Plane};
pub use read::{channel_count, declared_layout, declared_size, is_multilayer, read};
pub use write::{check, write, Compression, Encoding};
