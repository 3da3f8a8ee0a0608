//! gsid inside another program: a frame's buffers as borrowed, strided views ([`Inputs`]), the
//! result written into the caller's buffer ([`Pipeline::denoise_into`]), and the run watched from
//! the caller's thread ([`watch`]) for the Python and C bindings.
//!
//! The views are copied into the render set the pipeline runs on (every stage reads the buffers
//! many times, in its own layout); the caller's output is written once, after the last stage, so a
//! failed or cancelled run leaves it as it was.

pub mod view;
pub mod watch;

use crate::buffers::Buffers;
use crate::error::{Error, Result};
use crate::options::DenoiseOptions;
use crate::pipeline::{Pipeline, RunReport};
use crate::render_set::{Feature, NoiseInputs, RenderSet};
pub use view::{ImageView, ImageViewMut, Layout};

/// One frame's buffers as the renderer holds them: colour (3 channels) and any features, each a
/// borrowed view of its own layout. Checked (every sample inside its slice, channel counts, one
/// size) when the run starts, errors naming the buffer as the command line names it.
#[derive(Clone, Debug)]
pub struct Inputs<'a> {
    color: ImageView<'a>,
    features: Vec<(Feature, ImageView<'a>)>,
    variance: Option<ImageView<'a>>,
}

impl<'a> Inputs<'a> {
    pub fn new(color: ImageView<'a>) -> Self {
        Inputs {
            color,
            features: Vec::new(),
            variance: None,
        }
    }

    /// Adds (or replaces) a feature buffer: 3 channels, or 1 for depth and shadow.
    pub fn with(mut self, feature: Feature, view: ImageView<'a>) -> Self {
        self.features.retain(|(f, _)| *f != feature);
        self.features.push((feature, view));
        self
    }

    /// Adds the renderer's variance of the pixel mean (3 channels), which spares the estimate.
    pub fn with_variance(mut self, view: ImageView<'a>) -> Self {
        self.variance = Some(view);
        self
    }

    /// The colour's width and height.
    pub fn dims(&self) -> (usize, usize) {
        self.color.dims()
    }

    /// A render set copied from the views, each checked.
    pub fn to_render_set(&self) -> Result<RenderSet> {
        let color = self.color.to_image("color")?;
        if color.channels() != 3 {
            return Err(Error::buffer(
                "color",
                format!("has {} channels, expected 3", color.channels()),
            ));
        }
        let mut set = RenderSet::new(color);
        for (feature, view) in &self.features {
            set = set.with(*feature, view.to_image(feature.name())?)?;
        }
        if let Some(view) = &self.variance {
            let variance = view.to_image(NoiseInputs::VARIANCE)?;
            let (w, h) = set.dims();
            if variance.dims() != (w, h) || variance.channels() != 3 {
                return Err(Error::buffer(
                    NoiseInputs::VARIANCE,
                    format!(
                        "is {}x{} with {} channels, expected {w}x{h} with 3",
                        variance.width(),
                        variance.height(),
                        variance.channels()
                    ),
                ));
            }
            set.noise.variance = Some(variance);
        }
        Ok(set)
    }
}

impl Pipeline {
    /// Denoises `inputs` into `out` (3 channels of the colour's size, any strides): the call a
    /// renderer makes. The same run as [`Pipeline::run`] on the copied render set, so the same bits;
    /// `out` is checked before any work and written only when the run succeeded.
    pub fn denoise_into(
        &self,
        inputs: &Inputs,
        out: &mut ImageViewMut,
        options: &DenoiseOptions,
    ) -> Result<RunReport> {
        let (w, h) = inputs.dims();
        out.check("out", w, h, 3)?;
        let set = inputs.to_render_set()?;
        let (image, report) = self.run(&mut Buffers::from(set), options)?;
        out.write("out", &image)?;
        Ok(report)
    }
}
