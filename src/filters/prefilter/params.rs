//! How the prefilter treats a feature buffer and its settings, and which of its pixels take
//! part: shared by the noise estimates and the filter.

use crate::image::Image;

/// How the prefilter treats one feature buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// Values in absolute units (albedo, material weights, shadow).
    Plain,
    /// Unit vectors: all-zero ("unknown") pixels are left out and stay so; the result is renormalised.
    Normal,
    /// Distances: the floor of the distance normalisation is relative to the pixel's depth.
    Depth,
}

/// Settings of the NL-means prefilter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Params {
    /// k: patches closer than k noise standard deviations average.
    pub strength: f64,
    /// Search window radius.
    pub radius: usize,
    /// Patch radius.
    pub patch: usize,
    /// The share of a window's adjacent-pixel differences read as noise (the smallest ones); the
    /// rest is taken for structure.
    pub keep: f64,
}

/// Whether pixel `i` takes part (an unknown normal does not).
pub(super) fn known(img: &Image, kind: Kind, i: usize) -> bool {
    kind != Kind::Normal || img.pixel(i).iter().any(|&v| v != 0.0)
}
