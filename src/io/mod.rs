//! Reading and writing images and render sets (FORMATS.md).
//!
//! EXR goes through the `exr` crate (any channel names, f16/f32/u32 samples); PFM is read and written
//! as Open Image Denoise does (`pfm.rs`); 8-bit PNG/JPEG colour through `image`, decoded from sRGB to
//! linear. An output's extension picks its format (`format.rs`). Writes go to a temporary file in the target folder
//! that is renamed into place, so a failed run never leaves a half-written image.
//!
//! `read`: one image file; `load`: render sets (a folder, a multilayer file, named buffers) into a
//! [`LoadedSet`] (`loaded_set`, with the checks every loader applies); `output`: outputs reserved and
//! committed whole; `format`: the format an output is written in; `footprint`: the memory a read takes, from the header; `compression`: the EXR methods;
//! `exr_file`, [`pfm`], `preview`: the codecs; [`passes`]: multilayer pass names.

mod compression;
mod exr_file;
mod footprint;
mod format;
mod load;
mod loaded_set;
mod output;
pub mod passes;
pub mod pfm;
mod preview;
mod read;
mod stale;

pub use compression::Compression;
pub use exr_file::{Frame, Plane};
pub use footprint::read_bytes;
pub use format::{check_output, write_image, Encoding, ImageFormat};
pub use load::{
    colour_dims, is_layered_file, is_render_set, load_input, load_input_from, load_input_with,
    load_named, load_render_set, split_layer,
};
pub use loaded_set::{find_reference, LoadedSet};
pub use output::{
    remove_pending_outputs, remove_stale_beside, write_exr, NewFolder, PendingFolder,
    PendingOutput, STDOUT,
};
pub use read::{is_ldr, read_color, read_image, read_text, srgb_to_linear};
