//! Named buffers: the blackboard that pipeline stages read from and write to.
//!
//! A render set loads as `color` plus whichever of `albedo`, `normal`, `material`, `shadow`, `depth`
//! exist; stages add their own (`out`, `outlier_mask`, ...). All buffers share one width and height.

use std::collections::BTreeMap;

use crate::error::{Error, Result};
use crate::image::Image;

/// The feature buffers a renderer may write, with their channel counts (ALGORITHM.md §1).
pub const FEATURE_BUFFERS: [(&str, usize); 5] = [
    ("albedo", 3),
    ("normal", 3),
    ("material", 3),
    ("shadow", 1),
    ("depth", 1),
];

#[derive(Clone, Debug, Default)]
pub struct Buffers {
    map: BTreeMap<String, Image>,
}

impl Buffers {
    pub fn new() -> Self {
        Self::default()
    }

    /// Size shared by all buffers, if any are present.
    pub fn dims(&self) -> Option<(usize, usize)> {
        self.map.values().next().map(Image::dims)
    }

    /// Adds or replaces a buffer; its size must match the others.
    pub fn insert(&mut self, name: impl Into<String>, image: Image) -> Result<()> {
        let name = name.into();
        if let Some((w, h)) = self.dims() {
            let only_self = self.map.len() == 1 && self.map.contains_key(&name);
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
        self.map.insert(name, image);
        Ok(())
    }

    pub fn get(&self, name: &str) -> Option<&Image> {
        self.map.get(name)
    }

    pub fn get_mut(&mut self, name: &str) -> Option<&mut Image> {
        self.map.get_mut(name)
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

    pub fn remove(&mut self, name: &str) -> Option<Image> {
        self.map.remove(name)
    }

    pub fn contains(&self, name: &str) -> bool {
        self.map.contains_key(name)
    }

    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.map.keys().map(String::as_str)
    }
}
