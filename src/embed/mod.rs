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
use crate::image::Image;
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
    halves: [Option<ImageView<'a>>; 2],
}

impl<'a> Inputs<'a> {
    pub fn new(color: ImageView<'a>) -> Self {
        Inputs {
            color,
            features: Vec::new(),
            variance: None,
            halves: [None, None],
        }
    }

    /// Adds (or replaces) the buffer the command line reads under `name`: a feature (`albedo`,
    /// `normal`, `depth`, `material`, `shadow`), `variance`, or a half-sample colour (`color_a`,
    /// `color_b`, which come together). An unknown name is an error naming it.
    pub fn with_named(self, name: &str, view: ImageView<'a>) -> Result<Self> {
        if let Some(feature) = Feature::from_name(name) {
            return Ok(self.with(feature, view));
        }
        if name == NoiseInputs::VARIANCE {
            return Ok(self.with_variance(view));
        }
        match NoiseInputs::HALVES.iter().position(|&h| h == name) {
            Some(k) => {
                let mut inputs = self;
                inputs.halves[k] = Some(view);
                Ok(inputs)
            }
            None => Err(Error::buffer(
                name,
                "is not a buffer gsid reads (albedo, normal, depth, material, shadow, variance, color_a, color_b)",
            )),
        }
    }

    /// Adds the colour of two independent halves of the samples (3 channels each), from which
    /// the noise is measured.
    pub fn with_halves(mut self, a: ImageView<'a>, b: ImageView<'a>) -> Self {
        self.halves = [Some(a), Some(b)];
        self
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
        let dims = set.dims();
        if let Some(view) = &self.variance {
            set.noise.variance = Some(noise_image(NoiseInputs::VARIANCE, view, dims)?);
        }
        let [name_a, name_b] = NoiseInputs::HALVES;
        set.noise.halves = match &self.halves {
            [Some(a), Some(b)] => {
                Some([noise_image(name_a, a, dims)?, noise_image(name_b, b, dims)?])
            }
            [None, None] => None,
            [a, _] => {
                let (missing, have) = if a.is_some() {
                    (name_b, name_a)
                } else {
                    (name_a, name_b)
                };
                return Err(Error::buffer(
                    missing,
                    format!("is required with {have}: the two half-sample colours come together"),
                ));
            }
        };
        Ok(set)
    }
}

/// A noise buffer (`variance`, a half) copied from its view: 3 channels of the colour's size.
fn noise_image(name: &str, view: &ImageView, (w, h): (usize, usize)) -> Result<Image> {
    let img = view.to_image(name)?;
    if img.dims() != (w, h) || img.channels() != 3 {
        return Err(Error::buffer(
            name,
            format!(
                "is {}x{} with {} channels, expected {w}x{h} with 3",
                img.width(),
                img.height(),
                img.channels()
            ),
        ));
    }
    Ok(img)
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
