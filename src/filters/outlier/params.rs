//! What detection and repair are told and what detection gives: the rule, the action, their
//! settings, the feature guides (and when two pixels share a surface), the flags and limits.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::image::Image;

/// Which test decides that a pixel is an outlier.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Rule {
    /// One-sided robust z-score of log luminance against the neighbourhood's median and MAD.
    Zscore,
    /// Tone-mapped luminance against the mean and std of neighbours sharing albedo and normal.
    Feature,
    /// Cycles-style: luminance above `threshold` × the 75th percentile of the neighbourhood.
    Percentile,
}

impl Rule {
    pub fn name(self) -> &'static str {
        match self {
            Rule::Zscore => "zscore",
            Rule::Feature => "feature",
            Rule::Percentile => "percentile",
        }
    }

    /// The rule's customary threshold: 3.5 robust σ, 3 σ, twice the 75th percentile.
    pub fn default_threshold(self) -> f32 {
        match self {
            Rule::Zscore => 3.5,
            Rule::Feature => 3.0,
            Rule::Percentile => 2.0,
        }
    }

    /// Neighbourhood radius: 5×5 for the order statistics (a 3×3 median of 8 values is too noisy
    /// at low spp), 3×3 for the feature test as the report describes it.
    pub fn default_radius(self) -> usize {
        match self {
            Rule::Zscore | Rule::Percentile => 2,
            Rule::Feature => 1,
        }
    }
}

/// What happens to a flagged pixel's colour.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Action {
    /// Replace with the colour of the feature-weighted median (by luminance) of non-outlier neighbours.
    Median,
    /// Scale the colour down so its luminance equals the detection limit: keeps hue, bounds energy.
    Clamp,
    /// Leave the colour unchanged; only the mask marks the pixel (the walks then avoid it).
    Mask,
}

impl Action {
    pub fn name(self) -> &'static str {
        match self {
            Action::Median => "median",
            Action::Clamp => "clamp",
            Action::Mask => "mask",
        }
    }
}

/// Settings of the detection kernel (already validated by the stage).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DetectParams {
    pub rule: Rule,
    pub threshold: f32,
    /// Neighbourhood radius r: the (2r+1)² window around the pixel, the pixel itself excluded.
    pub radius: usize,
    /// Smallest MAD of log luminance used by `zscore` (log units, i.e. relative to the median):
    /// a flat neighbourhood has MAD 0, which would flag any pixel slightly above it.
    pub mad_floor: f32,
    /// Smallest std of tone-mapped luminance used by `feature`, for the same reason.
    pub std_floor: f32,
    /// Neighbours whose albedo differs by at most this (Euclidean, RGB) count as the same surface.
    pub albedo_tol: f32,
    /// Neighbours whose normal difference (1 − n·n′)/2 is at most this count as the same surface.
    pub normal_tol: f32,
    /// `feature` only: also flag dark dots, pixels below what their surface's spread explains
    /// and darker than all their neighbours but one.
    pub two_sided: bool,
}

/// Optional feature buffers that gate the `feature` rule and weight the `median` repair.
#[derive(Clone, Copy, Default)]
pub struct Guides<'a> {
    /// 3-channel albedo.
    pub albedo: Option<&'a Image>,
    /// 3-channel unit normals; zero-length normals are "unknown" and match anything.
    pub normal: Option<&'a Image>,
}

impl Guides<'_> {
    /// Feature distances (albedo, normal) of pixels i and j, each 0 when its buffer is missing.
    #[inline]
    pub(super) fn distances(&self, i: usize, j: usize) -> (f32, f32) {
        let (da2, dn) = self.squared_distances(i, j);
        (da2.sqrt(), dn)
    }

    /// [`Guides::distances`] with the albedo's distance squared, for a caller that squares it.
    #[inline]
    pub(super) fn squared_distances(&self, i: usize, j: usize) -> (f32, f32) {
        let da2 = self.albedo.map_or(0.0, |a| {
            let (p, q) = (a.pixel(i), a.pixel(j));
            (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)
        });
        let dn = self.normal.map_or(0.0, |n| {
            let (p, q) = (n.pixel(i), n.pixel(j));
            let dot = p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
            let known = p.iter().any(|&v| v != 0.0) && q.iter().any(|&v| v != 0.0);
            if known {
                ((1.0 - dot) * 0.5).clamp(0.0, 1.0)
            } else {
                0.0
            }
        });
        (da2, dn)
    }

    pub(super) fn any(&self) -> bool {
        self.albedo.is_some() || self.normal.is_some()
    }
}

/// The result of detection.
#[derive(Clone, Debug, PartialEq)]
pub struct Detection {
    /// One flag per pixel (row-major): true = outlier.
    pub mask: Vec<bool>,
    /// Per pixel, the luminance above which it is flagged (+∞ where it cannot be flagged).
    pub limit: Vec<f32>,
    /// Per pixel, the luminance below which it is flagged as a dark dot (−∞ where it cannot be:
    /// everywhere unless the rule is two-sided).
    pub low: Vec<f32>,
}

impl Detection {
    pub fn count(&self) -> usize {
        self.mask.iter().filter(|&&m| m).count()
    }

    /// The mask as a 1-channel image (1.0 = outlier), the form the walk stage reads.
    pub fn mask_image(&self, width: usize, height: usize) -> Image {
        let data = self
            .mask
            .par_iter()
            .map(|&m| if m { 1.0 } else { 0.0 })
            .collect();
        Image::from_vec(width, height, 1, data).expect("mask has one value per pixel")
    }
}

/// Settings and rules the unit tests of detection and repair share.
#[cfg(test)]
pub(crate) mod fixtures {
    use super::*;

    pub(crate) fn params(rule: Rule) -> DetectParams {
        DetectParams {
            rule,
            threshold: rule.default_threshold(),
            radius: rule.default_radius(),
            mad_floor: 0.25,
            std_floor: 0.02,
            albedo_tol: 0.1,
            normal_tol: 0.05,
            two_sided: false,
        }
    }

    /// The guides with both buffers, with the albedo only and with the normal only.
    pub(crate) fn guide_sets<'a>(albedo: &'a Image, normal: &'a Image) -> [Guides<'a>; 3] {
        [
            Guides {
                albedo: Some(albedo),
                normal: Some(normal),
            },
            Guides {
                albedo: Some(albedo),
                normal: None,
            },
            Guides {
                albedo: None,
                normal: Some(normal),
            },
        ]
    }

    pub(crate) const RULES: [Rule; 3] = [Rule::Zscore, Rule::Feature, Rule::Percentile];
}
