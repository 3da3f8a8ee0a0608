//! gsid: feature-guided stochastic image denoising for path-traced renders.
//!
//! See README.md for the module map; the maths is in docs/ALGORITHM.md, the formats and command
//! forms in docs/FORMATS.md.
//!
//! # Calling gsid from a renderer
//!
//! Build a [`RenderSet`] from the frame's buffers (row-major, interleaved `f32`, row 0 at the top),
//! pick a named pipeline, run it with a seed, and take the denoised colour back. Depend on the
//! crate with `default-features = false` to leave out the command line's dependencies (`cli`).
//!
//! ```
//! use gsid::{Buffers, DenoiseOptions, Feature, Image, PipelineSpec, RenderSet};
//!
//! # fn main() -> gsid::Result<()> {
//! let (w, h) = (32, 24);
//! // What the renderer wrote: noisy colour, albedo and shading normals.
//! let noisy: Vec<f32> = (0..w * h * 3)
//!     .map(|i| 0.2 + 0.1 * ((i * 7919 % 13) as f32 / 13.0))
//!     .collect();
//! let albedo = vec![0.8; w * h * 3];
//! let normal: Vec<f32> = (0..w * h).flat_map(|_| [0.0, 0.0, 1.0]).collect();
//!
//! let set = RenderSet::new(Image::from_vec(w, h, 3, noisy)?)
//!     .with(Feature::Albedo, Image::from_vec(w, h, 3, albedo)?)?
//!     .with(Feature::Normal, Image::from_vec(w, h, 3, normal)?)?;
//!
//! // A pipeline compiled into the crate (`gsid pipelines` lists them); no file is read.
//! let pipeline = PipelineSpec::builtin("full")?.build()?;
//! // The same set, pipeline and seed give the same bits on any number of threads. The options
//! // also take a thread count, a progress callback and a cancel token.
//! let options = DenoiseOptions::seeded(0);
//! let (denoised, report) = pipeline.run(&mut Buffers::from(set), &options)?;
//!
//! assert_eq!(denoised.dims(), (w, h));
//! assert!(denoised.data().iter().all(|v| v.is_finite()));
//! assert_eq!(report.pipeline, "full");
//! # Ok(())
//! # }
//! ```

pub mod buffers;
#[cfg(feature = "cli")]
pub mod cli;
pub mod condition;
pub mod embed;
pub mod error;
pub mod features;
pub mod filters;
pub mod image;
pub mod io;
pub mod kernels;
pub mod meter;
pub mod metrics;
pub mod options;
pub mod pipeline;
pub mod progress;
#[cfg(feature = "cli")]
pub mod render;
pub mod render_set;
pub mod run;
pub mod spec;
#[cfg(feature = "cli")]
pub mod study;
pub mod temporal;

pub use crate::buffers::Buffers;
pub use crate::embed::{ImageView, ImageViewMut, Inputs, Layout};
pub use crate::error::{Error, Result};
pub use crate::image::Image;
pub use crate::options::{CancelToken, DenoiseOptions, ProgressFn};
pub use crate::pipeline::{Pipeline, PipelineSpec, RunReport};
pub use crate::render_set::{Feature, FeatureSet, RenderSet};
