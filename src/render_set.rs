//! The buffers a renderer writes, typed (docs/ALGORITHM.md §1): colour and each known feature.
//!
//! Names are resolved once, where files are read (`io`) or a pipeline file names a buffer
//! (`buffers`); kernels (features, REDUCE, sanitising) take these typed views. OIDN keeps typed
//! colour/albedo/normal members the same way and uses names only at its API edge.

use crate::error::{Error, Result};
use crate::image::Image;

/// A feature buffer a renderer may write beside colour.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Feature {
    /// Surface colour without lighting, RGB in [0, 1].
    Albedo,
    /// Shading normal of the first hit, unit xyz.
    Normal,
    /// Diffuse, reflective and refractive weights of the first-hit surface.
    Material,
    /// Fraction of light samples from the first hit that reach a light.
    Shadow,
    /// Distance from the camera to the first hit.
    Depth,
}

impl Feature {
    /// Every feature, in the order files are looked for and reported.
    pub const ALL: [Feature; 5] = [
        Feature::Albedo,
        Feature::Normal,
        Feature::Material,
        Feature::Shadow,
        Feature::Depth,
    ];

    /// The buffer's name in render-set folders and pipeline files.
    pub const fn name(self) -> &'static str {
        match self {
            Feature::Albedo => "albedo",
            Feature::Normal => "normal",
            Feature::Material => "material",
            Feature::Shadow => "shadow",
            Feature::Depth => "depth",
        }
    }

    pub const fn channels(self) -> usize {
        match self {
            Feature::Albedo | Feature::Normal | Feature::Material => 3,
            Feature::Shadow | Feature::Depth => 1,
        }
    }

    pub fn from_name(name: &str) -> Option<Feature> {
        Feature::ALL.into_iter().find(|f| f.name() == name)
    }
}

/// The feature buffers of one frame; each may be missing (its features are then off).
#[derive(Clone, Debug, Default)]
pub struct FeatureSet {
    albedo: Option<Image>,
    normal: Option<Image>,
    material: Option<Image>,
    shadow: Option<Image>,
    depth: Option<Image>,
    /// Where no surface was hit (no normal) and the renderer wrote an albedo, that albedo unclamped:
    /// what the pixel saw, a light or the sky (Blender writes it there); kept only where the normals
    /// are averaged over samples (`condition::sanitize`). Every stage sees the albedo clamped to
    /// [0, 1]; only the noise estimate reads this, to demodulate such pixels.
    seen: Option<Image>,
}

impl FeatureSet {
    /// What the pixels that hit no surface saw (see the field), if any pixel has it.
    pub fn seen(&self) -> Option<&Image> {
        self.seen.as_ref()
    }

    pub(crate) fn set_seen(&mut self, image: Option<Image>) {
        self.seen = image;
    }

    pub fn get(&self, feature: Feature) -> Option<&Image> {
        self.slot(feature).as_ref()
    }

    pub fn get_mut(&mut self, feature: Feature) -> Option<&mut Image> {
        self.slot_mut(feature).as_mut()
    }

    pub fn contains(&self, feature: Feature) -> bool {
        self.get(feature).is_some()
    }

    /// Sets a feature buffer, checking its channel count (its size is the caller's to check).
    pub fn set(&mut self, feature: Feature, image: Image) -> Result<Option<Image>> {
        if image.channels() != feature.channels() {
            return Err(Error::buffer(
                feature.name(),
                format!(
                    "has {} channels, expected {}",
                    image.channels(),
                    feature.channels()
                ),
            ));
        }
        Ok(self.slot_mut(feature).replace(image))
    }

    pub fn take(&mut self, feature: Feature) -> Option<Image> {
        self.slot_mut(feature).take()
    }

    /// The features present, in [`Feature::ALL`] order.
    pub fn iter(&self) -> impl Iterator<Item = (Feature, &Image)> {
        Feature::ALL
            .into_iter()
            .filter_map(|f| self.get(f).map(|img| (f, img)))
    }

    /// The features absent, in [`Feature::ALL`] order.
    pub fn missing(&self) -> Vec<Feature> {
        Feature::ALL
            .into_iter()
            .filter(|&f| !self.contains(f))
            .collect()
    }

    /// Applies `f` to every present buffer, giving a new set.
    pub fn try_map(&self, mut f: impl FnMut(Feature, &Image) -> Result<Image>) -> Result<Self> {
        let mut out = FeatureSet::default();
        for (feature, img) in self.iter() {
            *out.slot_mut(feature) = Some(f(feature, img)?);
        }
        Ok(out)
    }

    fn slot(&self, feature: Feature) -> &Option<Image> {
        match feature {
            Feature::Albedo => &self.albedo,
            Feature::Normal => &self.normal,
            Feature::Material => &self.material,
            Feature::Shadow => &self.shadow,
            Feature::Depth => &self.depth,
        }
    }

    fn slot_mut(&mut self, feature: Feature) -> &mut Option<Image> {
        match feature {
            Feature::Albedo => &mut self.albedo,
            Feature::Normal => &mut self.normal,
            Feature::Material => &mut self.material,
            Feature::Shadow => &mut self.shadow,
            Feature::Depth => &mut self.depth,
        }
    }
}

/// One noisy frame and the feature buffers its renderer wrote, all of one size.
#[derive(Clone, Debug)]
pub struct RenderSet {
    pub color: Image,
    pub features: FeatureSet,
    /// What the renderer measured of the colour's noise, when it wrote it.
    pub noise: NoiseInputs,
}

/// Buffers that measure the colour's noise (docs/ALGORITHM.md §8). Renderers that write them
/// (Arnold, RenderMan, Mitsuba's moment integrator, `gsid render`) spare the estimate from the image.
#[derive(Clone, Debug, Default)]
pub struct NoiseInputs {
    /// Variance of the pixel mean, per RGB channel (buffer `variance`).
    pub variance: Option<Image>,
    /// Colour from two independent halves of the samples (buffers `color_a`, `color_b`).
    pub halves: Option<[Image; 2]>,
    /// `variance` was measured from a shot's frames (`--temporal`), pooled over their samples and
    /// same-surface neighbours, not written by a renderer from each pixel's own few samples.
    pub from_stack: bool,
    /// The colour was merged from neighbours resampled between pixels (a `--temporal` frame whose
    /// neighbours moved): its edges already carry the resampling's spread.
    pub resampled: bool,
}

impl NoiseInputs {
    pub const VARIANCE: &'static str = "variance";
    pub const HALVES: [&'static str; 2] = ["color_a", "color_b"];

    /// The buffers present, by their file names.
    pub fn buffers(&self) -> impl Iterator<Item = (&'static str, &Image)> {
        let variance = self.variance.iter().map(|v| (Self::VARIANCE, v));
        let halves = self
            .halves
            .iter()
            .flat_map(|[a, b]| [(Self::HALVES[0], a), (Self::HALVES[1], b)]);
        variance.chain(halves)
    }
}

impl RenderSet {
    pub fn new(color: Image) -> Self {
        RenderSet {
            color,
            features: FeatureSet::default(),
            noise: NoiseInputs::default(),
        }
    }

    /// Adds a feature buffer, checking its channel count and that its size is the colour's.
    pub fn with(mut self, feature: Feature, image: Image) -> Result<Self> {
        if image.dims() != self.color.dims() {
            return Err(Error::buffer(
                feature.name(),
                format!(
                    "is {}x{} but colour is {}x{}",
                    image.width(),
                    image.height(),
                    self.color.width(),
                    self.color.height()
                ),
            ));
        }
        self.features.set(feature, image)?;
        Ok(self)
    }

    pub fn dims(&self) -> (usize, usize) {
        self.color.dims()
    }

    /// Colour and the features present, by their file names.
    pub fn buffers(&self) -> impl Iterator<Item = (&'static str, &Image)> {
        let features = self.features.iter().map(|(f, img)| (f.name(), img));
        std::iter::once(("color", &self.color)).chain(features)
    }
}
