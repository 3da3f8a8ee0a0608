//! Named buffers: the blackboard that pipeline stages read from and write to.
//!
//! A pipeline file names the buffers its stages read and write (`color`, `out`, `outlier_mask`, …).
//! The render set's own buffers are held typed ([`RenderSet`]'s colour and [`FeatureSet`]), so
//! kernels take them without a name lookup; only the buffers stages create sit in a map. All
//! buffers share one width and height.

use std::collections::BTreeMap;

use crate::error::{Error, Result};
use crate::image::Image;
use crate::render_set::{Feature, FeatureSet, NoiseInputs, RenderSet};

/// The buffer holding the render set's colour (a stage may replace it, e.g. with outliers repaired).
pub const COLOR: &str = "color";

#[derive(Clone, Debug, Default)]
pub struct Buffers {
    color: Option<Image>,
    features: FeatureSet,
    /// Buffers created by stages, by name.
    created: BTreeMap<String, Image>,
}

impl From<RenderSet> for Buffers {
    fn from(set: RenderSet) -> Self {
        let NoiseInputs { variance, halves } = set.noise;
        let variance = variance.map(|v| (NoiseInputs::VARIANCE.to_string(), v));
        let halves = halves
            .into_iter()
            .flat_map(|h| NoiseInputs::HALVES.map(String::from).into_iter().zip(h));
        let created = variance.into_iter().chain(halves).collect();
        Buffers {
            color: Some(set.color),
            features: set.features,
            created,
        }
    }
}

impl Buffers {
    pub fn new() -> Self {
        Self::default()
    }

    /// The render set's feature buffers, typed.
    pub fn features(&self) -> &FeatureSet {
        &self.features
    }

    /// The render set's colour and features, for in-place input conditioning.
    pub fn inputs_mut(&mut self) -> (Option<&mut Image>, &mut FeatureSet) {
        (self.color.as_mut(), &mut self.features)
    }

    /// The render set's noise buffers present (`variance`, `color_a`, `color_b`), for in-place
    /// conditioning.
    pub fn noise_mut(&mut self) -> impl Iterator<Item = (&str, &mut Image)> {
        self.created
            .iter_mut()
            .filter(|(name, _)| {
                *name == NoiseInputs::VARIANCE || NoiseInputs::HALVES.contains(&name.as_str())
            })
            .map(|(name, img)| (name.as_str(), img))
    }

    /// Size shared by all buffers, if any are present.
    pub fn dims(&self) -> Option<(usize, usize)> {
        self.iter().next().map(|(_, img)| img.dims())
    }

    /// Adds or replaces a buffer; its size must match the others, and a feature buffer's channel
    /// count its feature's.
    pub fn insert(&mut self, name: impl Into<String>, image: Image) -> Result<()> {
        let name = name.into();
        if let Some((w, h)) = self.dims() {
            let only_self = self.len() == 1 && self.contains(&name);
            if image.dims() != (w, h) && !only_self {
                return Err(Error::buffer(
                    name,
                    format!(
                        "is {}x{} but the other buffers are {w}x{h}",
                        image.width(),
                        image.height()
                    ),
                ));
            }
        }
        match Feature::from_name(&name) {
            Some(f) => {
                self.features.set(f, image)?;
            }
            None if name == COLOR => self.color = Some(image),
            None => {
                self.created.insert(name, image);
            }
        }
        Ok(())
    }

    pub fn get(&self, name: &str) -> Option<&Image> {
        match Feature::from_name(name) {
            Some(f) => self.features.get(f),
            None if name == COLOR => self.color.as_ref(),
            None => self.created.get(name),
        }
    }

    pub fn get_mut(&mut self, name: &str) -> Option<&mut Image> {
        match Feature::from_name(name) {
            Some(f) => self.features.get_mut(f),
            None if name == COLOR => self.color.as_mut(),
            None => self.created.get_mut(name),
        }
    }

    /// The buffer, or an error naming it.
    pub fn require(&self, name: &str) -> Result<&Image> {
        self.get(name)
            .ok_or_else(|| Error::buffer(name, "is required but missing"))
    }

    /// The buffer if present with the expected channel count.
    pub fn get_channels(&self, name: &str, channels: usize) -> Result<Option<&Image>> {
        match self.get(name) {
            Some(img) if img.channels() != channels => Err(Error::buffer(
                name,
                format!("has {} channels, expected {channels}", img.channels()),
            )),
            other => Ok(other),
        }
    }

    /// The buffer if present with the expected channel count and the colour's size `dims`.
    pub fn get_sized(
        &self,
        name: &str,
        channels: usize,
        dims: (usize, usize),
    ) -> Result<Option<&Image>> {
        match self.get_channels(name, channels)? {
            Some(img) if img.dims() != dims => Err(Error::buffer(
                name,
                "does not match the colour buffer's size",
            )),
            other => Ok(other),
        }
    }

    /// The buffer, which must exist with the expected channel count.
    pub fn require_channels(&self, name: &str, channels: usize) -> Result<&Image> {
        self.require(name)?;
        Ok(self.get_channels(name, channels)?.expect("required above"))
    }

    pub fn remove(&mut self, name: &str) -> Option<Image> {
        match Feature::from_name(name) {
            Some(f) => self.features.take(f),
            None if name == COLOR => self.color.take(),
            None => self.created.remove(name),
        }
    }

    pub fn contains(&self, name: &str) -> bool {
        self.get(name).is_some()
    }

    /// Every buffer with its name: colour, the features, then the created ones by name.
    pub fn iter(&self) -> impl Iterator<Item = (&str, &Image)> {
        let color = self.color.as_ref().map(|c| (COLOR, c));
        let features = self.features.iter().map(|(f, img)| (f.name(), img));
        let created = self.created.iter().map(|(n, img)| (n.as_str(), img));
        color.into_iter().chain(features).chain(created)
    }

    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.iter().map(|(name, _)| name)
    }

    fn len(&self) -> usize {
        self.iter().count()
    }
}
