//! The settings of d: the eight feature weights W1..W8 with their checks, the feature buffer each
//! weight needs, and the tone curve T of the colour feature.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::render_set::Feature;

/// The eight feature weights W1..W8 (docs/ALGORITHM.md §2). Zero switches a feature off (and skips its buffer).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Weights {
    /// F1: noisy colour, through the tone curve.
    pub color: f32,
    /// F2: true colour (albedo).
    pub albedo: f32,
    /// F3: shading normal.
    pub normal: f32,
    /// F4: diffuse material weight.
    pub diffuse: f32,
    /// F5: reflective material weight.
    pub reflective: f32,
    /// F6: refractive material weight.
    pub refractive: f32,
    /// F7: shadow (light exposure).
    pub shadow: f32,
    /// F8: relative depth.
    pub depth: f32,
}

impl Default for Weights {
    /// The 2019 report's weights.
    fn default() -> Self {
        Weights {
            color: 2.0,
            albedo: 2.0,
            normal: 3.0,
            diffuse: 1.0,
            reflective: 2.0,
            refractive: 1.0,
            shadow: 0.5,
            depth: 2.0,
        }
    }
}

impl Weights {
    /// SID: colour only.
    pub fn color_only() -> Self {
        Weights {
            color: 1.0,
            albedo: 0.0,
            normal: 0.0,
            diffuse: 0.0,
            reflective: 0.0,
            refractive: 0.0,
            shadow: 0.0,
            depth: 0.0,
        }
    }

    pub fn as_array(&self) -> [f32; 8] {
        [
            self.color,
            self.albedo,
            self.normal,
            self.diffuse,
            self.reflective,
            self.refractive,
            self.shadow,
            self.depth,
        ]
    }

    pub const NAMES: [&'static str; 8] = [
        "color",
        "albedo",
        "normal",
        "diffuse",
        "reflective",
        "refractive",
        "shadow",
        "depth",
    ];

    /// Sets weight `index` (0..8, in `NAMES` order).
    pub fn set(&mut self, index: usize, value: f32) {
        let slot = match index {
            0 => &mut self.color,
            1 => &mut self.albedo,
            2 => &mut self.normal,
            3 => &mut self.diffuse,
            4 => &mut self.reflective,
            5 => &mut self.refractive,
            6 => &mut self.shadow,
            _ => &mut self.depth,
        };
        *slot = value;
    }

    pub fn validate(&self) -> Result<()> {
        for (name, w) in Self::NAMES.iter().zip(self.as_array()) {
            if !(0.0..=1000.0).contains(&w) {
                return Err(Error::config(
                    format!("weights.{name}"),
                    format!("is {w}, allowed range is 0 to 1000"),
                ));
            }
        }
        Ok(())
    }
}

/// The feature buffer each weight needs (colour, weight 0, is always there).
pub(super) const WEIGHT_BUFFER: [Option<Feature>; 8] = [
    None,
    Some(Feature::Albedo),
    Some(Feature::Normal),
    Some(Feature::Material),
    Some(Feature::Material),
    Some(Feature::Material),
    Some(Feature::Shadow),
    Some(Feature::Depth),
];

/// The robust tone curve T of feature F1 (averaging always uses linear colour).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Tone {
    /// x / (1 + x): bounded, compresses highlights and fireflies.
    Reinhard,
    /// ln(1 + x): unbounded but slow-growing.
    Log1p,
    /// x itself: only for LDR input.
    Linear,
}

impl Tone {
    #[inline]
    pub fn apply(self, x: f32) -> f32 {
        match self {
            Tone::Reinhard => x / (1.0 + x),
            Tone::Log1p => x.ln_1p(),
            Tone::Linear => x,
        }
    }
}
