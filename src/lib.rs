//! gsid: feature-guided stochastic image denoising for path-traced renders.
//!
//! See README.md for the module map; the maths is in docs/ALGORITHM.md, the formats and command
//! forms in docs/FORMATS.md.

pub mod atrous;
pub mod buffers;
pub mod cli;
pub mod condition;
pub mod error;
pub mod fastmath;
pub mod features;
pub mod image;
pub mod io;
pub mod metrics;
pub mod noise;
pub mod outlier;
pub mod pipeline;
pub mod progress;
pub mod pyramid;
pub mod render;
pub mod render_set;
pub mod run;
pub mod simd;
pub mod spec;
pub mod stages;
pub mod study;
pub mod walk;

pub use crate::buffers::Buffers;
pub use crate::error::{Error, Result};
pub use crate::image::Image;
pub use crate::render_set::{Feature, FeatureSet, RenderSet};
