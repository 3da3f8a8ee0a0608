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
    /// Names that read a created buffer (name → its target) until either is written: a stage that
    /// passes a buffer on unchanged (the `noise` stage's `reuse`) costs no copy.
    shared: BTreeMap<String, String>,
    /// The render set's `variance` was measured from a shot's frames (`NoiseInputs::from_stack`).
    variance_from_stack: bool,
    /// The colour was merged from neighbours resampled between pixels (`NoiseInputs::resampled`).
    resampled: bool,
}

impl From<RenderSet> for Buffers {
    fn from(set: RenderSet) -> Self {
        let NoiseInputs {
            variance,
            halves,
            from_stack,
            resampled,
        } = set.noise;
        let from_stack = from_stack && variance.is_some();
        let variance = variance.map(|v| (NoiseInputs::VARIANCE.to_string(), v));
        let halves = halves
            .into_iter()
            .flat_map(|h| NoiseInputs::HALVES.map(String::from).into_iter().zip(h));
        let created = variance.into_iter().chain(halves).collect();
        Buffers {
            color: Some(set.color),
            features: set.features,
            created,
            shared: BTreeMap::new(),
            variance_from_stack: from_stack,
            resampled,
        }
    }
}

impl Buffers {
    pub fn new() -> Self {
        Self::default()
    }

    /// Takes `from`'s account of where its variance and colour came from (a coarser level of it
    /// derives from the same shot's frames).
    pub(crate) fn inherit_origin(&mut self, from: &Buffers) {
        self.variance_from_stack = from.variance_from_stack;
        self.resampled = from.resampled;
    }

    /// Whether the render set's `variance` was measured from a shot's frames (`--temporal`).
    pub fn variance_from_stack(&self) -> bool {
        self.variance_from_stack
    }

    /// Whether the colour was merged from neighbours resampled between pixels (`--temporal` on a
    /// shot that moved).
    pub fn resampled(&self) -> bool {
        self.resampled
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
        self.unshare(&name);
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

    /// Makes `name` hold what `source` holds: the same memory while neither is written or
    /// removed (each keeps its own value after), or a copy when either is the colour or a feature.
    /// Errors if `source` is missing.
    pub fn insert_same(&mut self, name: impl Into<String>, source: &str) -> Result<()> {
        let name = name.into();
        let source = self
            .shared
            .get(source)
            .cloned()
            .unwrap_or_else(|| source.to_string());
        let image = self.require(&source)?;
        if name == source {
            return Ok(());
        }
        let created = |n: &str| Feature::from_name(n).is_none() && n != COLOR;
        if !(created(&name) && created(&source)) {
            let copy = image.par_clone();
            return self.insert(name, copy);
        }
        self.unshare(&name);
        self.created.remove(&name);
        self.shared.insert(name, source);
        Ok(())
    }

    /// Before `name` is written or removed: if it reads another buffer it stops doing so, and the
    /// names that read it get their own copy of its value.
    fn unshare(&mut self, name: &str) {
        self.shared.remove(name);
        let readers: Vec<String> = self
            .shared
            .iter()
            .filter(|(_, target)| *target == name)
            .map(|(reader, _)| reader.clone())
            .collect();
        for reader in readers {
            self.shared.remove(&reader);
            if let Some(img) = self.created.get(name) {
                let copy = img.par_clone();
                self.created.insert(reader, copy);
            }
        }
    }

    pub fn get(&self, name: &str) -> Option<&Image> {
        if let Some(target) = self.shared.get(name) {
            return self.created.get(target);
        }
        match Feature::from_name(name) {
            Some(f) => self.features.get(f),
            None if name == COLOR => self.color.as_ref(),
            None => self.created.get(name),
        }
    }

    pub fn get_mut(&mut self, name: &str) -> Option<&mut Image> {
        if let Some(target) = self.shared.remove(name) {
            let copy = self.created.get(&target)?.par_clone();
            self.created.insert(name.to_string(), copy);
        }
        self.unshare(name);
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
        if let Some(target) = self.shared.remove(name) {
            return self.created.get(&target).map(Image::par_clone);
        }
        self.unshare(name);
        match Feature::from_name(name) {
            Some(f) => self.features.take(f),
            None if name == COLOR => self.color.take(),
            None => self.created.remove(name),
        }
    }

    pub fn contains(&self, name: &str) -> bool {
        self.get(name).is_some()
    }

    /// Every buffer with its name: colour, the features, the created ones by name, then the names
    /// that share a created one's memory.
    pub fn iter(&self) -> impl Iterator<Item = (&str, &Image)> {
        let color = self.color.as_ref().map(|c| (COLOR, c));
        let features = self.features.iter().map(|(f, img)| (f.name(), img));
        let created = self.created.iter().map(|(n, img)| (n.as_str(), img));
        let shared = self
            .shared
            .iter()
            .filter_map(|(n, target)| Some((n.as_str(), self.created.get(target)?)));
        color
            .into_iter()
            .chain(features)
            .chain(created)
            .chain(shared)
    }

    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.iter().map(|(name, _)| name)
    }

    fn len(&self) -> usize {
        self.iter().count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn filled(v: f32) -> Image {
        Image::filled(4, 3, 3, v)
    }

    fn value(b: &Buffers, name: &str) -> Option<f32> {
        b.get(name).map(|img| img.data()[0])
    }

    #[test]
    fn a_shared_name_reads_its_source_and_keeps_its_value_when_either_is_written() {
        let mut b = Buffers::new();
        b.insert("noise", filled(1.0)).unwrap();
        b.insert_same("level", "noise").unwrap();
        assert_eq!(value(&b, "level"), Some(1.0));
        assert!(std::ptr::eq(
            b.get("level").unwrap(),
            b.get("noise").unwrap()
        ));
        assert_eq!(b.names().filter(|n| *n == "level").count(), 1);

        // The source replaced: the shared name keeps the old value.
        b.insert("noise", filled(2.0)).unwrap();
        assert_eq!(
            (value(&b, "noise"), value(&b, "level")),
            (Some(2.0), Some(1.0))
        );

        // The shared name written in place: the source does not change.
        b.insert_same("other", "noise").unwrap();
        b.get_mut("other").unwrap().data_mut()[0] = 5.0;
        assert_eq!(
            (value(&b, "noise"), value(&b, "other")),
            (Some(2.0), Some(5.0))
        );

        // The source written in place: the shared name does not change.
        b.insert_same("third", "noise").unwrap();
        b.get_mut("noise").unwrap().data_mut()[0] = 7.0;
        assert_eq!(
            (value(&b, "noise"), value(&b, "third")),
            (Some(7.0), Some(2.0))
        );

        // Removing either leaves the other.
        b.insert_same("fourth", "noise").unwrap();
        assert_eq!(b.remove("noise").map(|i| i.data()[0]), Some(7.0));
        assert_eq!((value(&b, "noise"), value(&b, "fourth")), (None, Some(7.0)));
        b.insert_same("fifth", "fourth").unwrap();
        assert_eq!(b.remove("fifth").map(|i| i.data()[0]), Some(7.0));
        assert_eq!((value(&b, "fourth"), value(&b, "fifth")), (Some(7.0), None));
    }

    #[test]
    fn sharing_the_colour_or_a_missing_buffer() {
        let mut b = Buffers::new();
        b.insert(COLOR, filled(3.0)).unwrap();
        // The colour is conditioned in place, so a name that takes it gets a copy.
        b.insert_same("copy", COLOR).unwrap();
        b.inputs_mut().0.unwrap().data_mut()[0] = 4.0;
        assert_eq!(value(&b, "copy"), Some(3.0));
        assert!(b.insert_same("x", "missing").is_err());
        // A name shared with itself, or with a name that shares it, stays as it is.
        b.insert_same("copy", "copy").unwrap();
        b.insert_same("back", "copy").unwrap();
        b.insert_same("copy", "back").unwrap();
        assert_eq!(
            (value(&b, "copy"), value(&b, "back")),
            (Some(3.0), Some(3.0))
        );
    }
}
