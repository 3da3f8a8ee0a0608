//! gsid: feature-guided stochastic image denoising for path-traced renders.
//!
//! See README.md for the module map. The maths is in ALGORITHM.md of the project's shared notes.

pub mod buffers;
pub mod cli;
pub mod error;
pub mod image;
pub mod io;
pub mod render;

pub use crate::buffers::Buffers;
pub use crate::error::{Error, Result};
pub use crate::image::Image;
