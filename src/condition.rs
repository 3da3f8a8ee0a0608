//! Input conditioning, in one place: everything done to a render set before the first stage and
//! undone after the last.
//!
//! 1. Sanitising (docs/ALGORITHM.md §1): every buffer finite and in range before any maths, with a
//!    count of what changed so the run can report it. A reference is sanitised the same way.
//! 2. Brightness: colour is scaled into the range the stages' parameters were calibrated in, and
//!    the result scaled back.

use rayon::prelude::*;
use serde::Serialize;

use crate::buffers::{Buffers, COLOR};
use crate::error::{Error, Result};
use crate::image::Image;
use crate::render_set::{Feature, FeatureSet, NoiseInputs};

/// How many samples or pixels sanitisation changed, per kind of fix.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct SanitizeReport {
    /// Colour samples that were NaN or ±Inf, set to 0.
    pub color_nonfinite: usize,
    /// Colour samples below 0, set to 0.
    pub color_negative: usize,
    /// Normals that were NaN or (near) zero length, set to the "unknown" zero vector.
    pub normal_unknown: usize,
    /// Depth values that were infinite, NaN or negative, set to the background depth.
    pub depth_background: usize,
    /// Albedo, material or shadow samples that were non-finite or outside [0, 1], clamped (the
    /// three below together).
    pub feature_clamped: usize,
    /// Of those, the albedo's.
    pub albedo_clamped: usize,
    /// Of those, the material weights'.
    pub material_clamped: usize,
    /// Of those, the shadow's.
    pub shadow_clamped: usize,
    /// Variance samples that were non-finite or negative, set to 0 (the two half-sample colours
    /// are counted with colour).
    pub variance_invalid: usize,
}

impl SanitizeReport {
    pub fn total(&self) -> usize {
        self.color_nonfinite
            + self.color_negative
            + self.normal_unknown
            + self.depth_background
            + self.feature_clamped
            + self.variance_invalid
    }

    /// One line for the user, or `None` when nothing changed.
    pub fn summary(&self) -> Option<String> {
        if self.total() == 0 {
            return None;
        }
        let parts: Vec<String> = [
            (self.color_nonfinite, "non-finite colour samples → 0"),
            (self.color_negative, "negative colour samples → 0"),
            (self.normal_unknown, "invalid normals → unknown"),
            (
                self.depth_background,
                "infinite/invalid depths → background",
            ),
            (self.albedo_clamped, "albedo samples clamped to [0, 1]"),
            (self.material_clamped, "material samples clamped to [0, 1]"),
            (self.shadow_clamped, "shadow samples clamped to [0, 1]"),
            (self.variance_invalid, "invalid variance samples → 0"),
        ]
        .iter()
        .filter(|(n, _)| *n > 0)
        .map(|(n, what)| format!("{n} {what}"))
        .collect();
        Some(format!("sanitised input: {}", parts.join(", ")))
    }
}

/// Applies `fix` to every value, in parallel chunks; `fix` reports which of N kinds of change it
/// made, and the result counts each kind.
fn fix_each<const N: usize>(
    data: &mut [f32],
    fix: impl Fn(&mut f32) -> [bool; N] + Sync,
) -> [usize; N] {
    let add = |mut a: [usize; N], b: [usize; N]| {
        for (x, y) in a.iter_mut().zip(b) {
            *x += y;
        }
        a
    };
    data.par_chunks_mut(1 << 16)
        .map(|chunk| {
            chunk
                .iter_mut()
                .fold([0; N], |acc, v| add(acc, fix(v).map(usize::from)))
        })
        .reduce(|| [0; N], add)
}

/// Sets NaN/±Inf and negative radiance samples to 0; returns (non-finite, negative) counts.
fn sanitize_radiance(img: &mut Image) -> (usize, usize) {
    let [nonfinite, negative] = fix_each(img.data_mut(), |v| {
        let kinds = [!v.is_finite(), v.is_finite() && *v < 0.0];
        if kinds.contains(&true) {
            *v = 0.0;
        }
        kinds
    });
    (nonfinite, negative)
}

/// Sanitises the noise buffers in place: a variance that is NaN, ±Inf or negative says nothing, so
/// it becomes 0; the half-sample colours are radiance like colour and are counted with it.
pub fn sanitize_noise<'a>(
    noise: impl Iterator<Item = (&'a str, &'a mut Image)>,
    report: &mut SanitizeReport,
) {
    for (name, img) in noise {
        if name == NoiseInputs::VARIANCE {
            let [invalid] = fix_each(img.data_mut(), |v| {
                let bad = !(v.is_finite() && *v >= 0.0);
                if bad {
                    *v = 0.0;
                }
                [bad]
            });
            report.variance_invalid += invalid;
        } else {
            let (nonfinite, negative) = sanitize_radiance(img);
            report.color_nonfinite += nonfinite;
            report.color_negative += negative;
        }
    }
}

/// Sanitises a reference image as input colour is sanitised, so a score never meets a NaN.
pub fn sanitize_reference(reference: &mut Image) -> SanitizeReport {
    let (color_nonfinite, color_negative) = sanitize_radiance(reference);
    SanitizeReport {
        color_nonfinite,
        color_negative,
        ..SanitizeReport::default()
    }
}

/// Refuses a colour or feature buffer none of whose samples is a number: a pass the renderer
/// never wrote (or a crashed render), which sanitising would silently turn into black or
/// "unknown". A buffer with some NaNs among numbers is sanitised as usual; infinite depths (the
/// sky) are numbers; a variance of nothing but NaN says nothing and is sanitised to 0, as before.
pub fn check_recorded(buffers: &Buffers) -> Result<()> {
    let recorded = |name: &str| name == COLOR || Feature::from_name(name).is_some();
    for (name, img) in buffers.iter().filter(|(name, _)| recorded(name)) {
        let data = img.data();
        if !data.is_empty() && data.par_iter().all(|v| v.is_nan()) {
            return Err(Error::buffer(
                name,
                "every sample is NaN (the pass holds no values)",
            ));
        }
    }
    Ok(())
}

/// Squared length below which a normal is unknown: the pixel's samples hit no surface.
const NO_NORMAL: f32 = 1e-12;
/// Squared lengths of a normal averaged over samples of which some missed (a silhouette's pixel).
const SHORT: std::ops::Range<f32> = 0.02 * 0.02..0.9 * 0.9;
/// Normals count as averaged over samples when at least one pixel in this many is short.
const SHORT_SHARE: usize = 1000;
/// Largest albedo kept for a pixel that hit no surface: far above any light a render is exposed for.
const MAX_SEEN: f32 = 1e6;

/// A normal's squared length.
fn length2(n: &[f32]) -> f32 {
    n[0] * n[0] + n[1] * n[1] + n[2] * n[2]
}

/// Whether a normal of squared length `len2` (raw, before sanitising) says its pixel's samples hit
/// no surface.
fn no_surface(len2: f32) -> bool {
    !len2.is_finite() || len2 < NO_NORMAL
}

/// What pixels that hit no surface saw, where the renderer wrote it as their albedo (before the
/// clamp to [0, 1]), zero elsewhere; `None` when no pixel has one or when the normals are not averaged
/// over samples. Blender writes a light or the sky a pixel saw, directly or in a mirror, as that pixel's
/// albedo, and its colour is that albedo times about one: the noise estimate demodulates such pixels
/// by it, so a light reflected in chrome reads as flat as texture does (docs/ALGORITHM.md §8).
/// Averaged over several samples a normal is shorter than 1 where only some samples hit, so a zero
/// normal there means every sample missed; where no normal is short (one sample a pixel, or a renderer
/// that normalises), a zero normal may be one sample's miss beside an edge, whose colour is no mean of
/// what the pixel sees, and nothing is taken.
fn seen_albedo(features: &FeatureSet) -> Option<Image> {
    let (albedo, normal) = (
        features.get(Feature::Albedo)?,
        features.get(Feature::Normal)?,
    );
    if albedo.dims() != normal.dims() {
        return None;
    }
    let (w, h) = albedo.dims();
    let short = normal
        .data()
        .chunks_exact(3)
        .filter(|n| SHORT.contains(&length2(n)))
        .count();
    if short * SHORT_SHARE < w * h {
        return None;
    }
    let mut seen = Image::new(w, h, 3);
    let mut any = false;
    for ((out, a), n) in seen
        .data_mut()
        .chunks_exact_mut(3)
        .zip(albedo.data().chunks_exact(3))
        .zip(normal.data().chunks_exact(3))
    {
        if no_surface(length2(n)) && a.iter().all(|v| v.is_finite()) && a.iter().any(|&v| v > 0.0) {
            for (o, &v) in out.iter_mut().zip(a) {
                *o = v.clamp(0.0, MAX_SEEN);
            }
            any = true;
        }
    }
    any.then_some(seen)
}

/// Sanitises the colour and every feature buffer in place.
pub fn sanitize(color: Option<&mut Image>, features: &mut FeatureSet) -> SanitizeReport {
    let mut report = SanitizeReport::default();
    if let Some(img) = color {
        (report.color_nonfinite, report.color_negative) = sanitize_radiance(img);
    }
    // Read before the albedo is clamped and the normals renormalised.
    let seen = seen_albedo(features);
    features.set_seen(seen);
    for feature in [Feature::Albedo, Feature::Material, Feature::Shadow] {
        if let Some(img) = features.get_mut(feature) {
            let [clamped] = fix_each(img.data_mut(), |v| {
                let clean = if v.is_finite() {
                    v.clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let changed = clean != *v;
                *v = clean;
                [changed]
            });
            report.feature_clamped += clamped;
            *match feature {
                Feature::Albedo => &mut report.albedo_clamped,
                Feature::Material => &mut report.material_clamped,
                _ => &mut report.shadow_clamped,
            } += clamped;
        }
    }
    if let Some(img) = features.get_mut(Feature::Normal) {
        report.normal_unknown += img
            .data_mut()
            .par_chunks_mut(3 << 14)
            .map(|chunk| {
                let mut unknown = 0;
                for n in chunk.chunks_exact_mut(3) {
                    let len2 = length2(n);
                    if no_surface(len2) {
                        if n.iter().any(|v| *v != 0.0) || !len2.is_finite() {
                            unknown += 1;
                        }
                        n.fill(0.0);
                    } else {
                        // Averaged normals at an edge are shorter than 1; renormalising keeps F3 on
                        // its scale.
                        let inv = 1.0 / len2.sqrt();
                        n.iter_mut().for_each(|v| *v *= inv);
                    }
                }
                unknown
            })
            .sum::<usize>();
    }
    if let Some(img) = features.get_mut(Feature::Depth) {
        let max_finite = img
            .data()
            .par_iter()
            .copied()
            .filter(|v| v.is_finite() && *v >= 0.0)
            .reduce(|| 0.0f32, f32::max);
        // Larger than every finite depth, so misses differ from every surface.
        let background = if max_finite > 0.0 {
            max_finite * 2.0
        } else {
            1.0
        };
        let [misses] = fix_each(img.data_mut(), |v| {
            let miss = !v.is_finite() || *v < 0.0;
            if miss {
                *v = background;
            }
            [miss]
        });
        report.depth_background += misses;
    }
    report
}

/// The robust brightness every render is filtered at. The tone curve, σ, the outlier floors and the
/// pyramid's log offset all read colour on an absolute scale; bringing every render to one brightness
/// first makes the result independent of the renderer's exposure (up to rounding). The value is the
/// robust brightness of the Mitsuba box (fixtures/mitsuba-cornell), the scene the spec's calibration
/// table (docs/ALGORITHM.md §3) was measured on, so plain SID and GSID still reproduce that table.
pub const UNIT_BRIGHTNESS: f64 = 0.072;

/// The factor that brings `color`'s robust brightness (mean luminance of the pixels at or below the
/// 99th percentile, so lights and fireflies do not count) to [`UNIT_BRIGHTNESS`]; 1 for a black image.
pub fn exposure_scale(color: &Image) -> f32 {
    let mean = robust_brightness(color);
    if mean.is_finite() && mean > 0.0 {
        let scale = (UNIT_BRIGHTNESS / mean) as f32;
        if scale.is_finite() && scale > 0.0 {
            return scale;
        }
    }
    1.0
}

/// Mean luminance of the pixels at or below the 99th percentile (lights and fireflies left out);
/// 0 for an empty or black image. It scales with the exposure, so measures divided by it do not.
pub fn robust_brightness(color: &Image) -> f64 {
    let mut lum: Vec<f64> = color
        .data()
        .par_chunks_exact(3)
        .map(|p| 0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64)
        .collect();
    if lum.is_empty() {
        return 0.0;
    }
    let k = ((lum.len() - 1) as f64 * 0.99) as usize;
    let (_, &mut p99, _) = lum.select_nth_unstable_by(k, f64::total_cmp);
    // One sequential sum: its order (and so its rounding) does not depend on the thread count.
    let (sum, kept) = lum
        .iter()
        .filter(|&&l| l <= p99)
        .fold((0.0f64, 0usize), |(s, n), &l| (s + l, n + 1));
    sum / kept.max(1) as f64
}

/// What conditioning did to a run's inputs, and what must be undone on its result.
#[derive(Clone, Debug)]
pub struct Conditioning {
    pub sanitized: SanitizeReport,
    /// The factor colour was filtered at (1: as given).
    pub scale: f32,
}

impl Conditioning {
    /// Sanitises the render set's buffers and brings colour to the unit brightness.
    pub fn apply(buffers: &mut Buffers) -> Conditioning {
        let (color, features) = buffers.inputs_mut();
        let mut color = color;
        let mut sanitized = sanitize(color.as_deref_mut(), features);
        let scale = color.as_deref().map_or(1.0, exposure_scale);
        if let Some(img) = color {
            scale_image(img, scale);
        }
        sanitize_noise(buffers.noise_mut(), &mut sanitized);
        // The noise stays on the colour's scale: the halves scale with it, a variance with its square.
        for (name, img) in buffers.noise_mut() {
            let factor = if name == NoiseInputs::VARIANCE {
                scale * scale
            } else {
                scale
            };
            scale_image(img, factor);
        }
        Conditioning { sanitized, scale }
    }

    /// The user's notes for what was changed, in order.
    pub fn notes(&self) -> Vec<String> {
        self.sanitized.summary().into_iter().collect()
    }

    /// Brings a radiance buffer filtered at [`Conditioning::scale`] back to the input's scale.
    pub fn undo(&self, img: &mut Image) {
        let inverse = 1.0 / self.scale;
        if inverse.is_finite() {
            scale_image(img, inverse);
        } else {
            // A scale below 1/f32::MAX (a render near f32's top, brightness ~3e37) has no f32
            // inverse: multiply in f64, where it has one, and round once.
            scale_image_f64(img, 1.0 / self.scale as f64);
        }
    }
}

/// Every value times `factor` in f64, rounded once: for factors (or their products) that f32 cannot
/// hold.
pub(crate) fn scale_image_f64(img: &mut Image, factor: f64) {
    img.data_mut()
        .par_iter_mut()
        .for_each(|v| *v = (*v as f64 * factor) as f32);
}

fn scale_image(img: &mut Image, factor: f32) {
    if factor != 1.0 {
        img.data_mut().par_iter_mut().for_each(|v| *v *= factor);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What a pixel that hit no surface saw is kept for the noise estimate, above 1 too, where the
    /// normals are averaged over samples (some are short); with one sample a pixel (every normal
    /// unit or zero) a zero normal may be one miss beside an edge, and nothing is kept.
    #[test]
    fn what_a_pixel_without_surface_saw_is_kept_where_normals_are_averaged() {
        let albedo =
            Image::from_vec(3, 1, 3, vec![0.5, 0.5, 0.5, 7.0, 6.0, 5.0, 0.2, 0.2, 0.2]).unwrap();
        for (short, kept) in [(0.5, true), (1.0, false)] {
            let normal =
                Image::from_vec(3, 1, 3, vec![0.0, 0.0, short, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
            let mut set = FeatureSet::default();
            set.set(Feature::Albedo, albedo.clone()).unwrap();
            set.set(Feature::Normal, normal.unwrap()).unwrap();
            sanitize(None, &mut set);
            assert_eq!(set.get(Feature::Albedo).unwrap().pixel(1), &[1.0, 1.0, 1.0]);
            match set.seen() {
                Some(seen) if kept => {
                    assert_eq!(seen.pixel(1), &[7.0, 6.0, 5.0]);
                    assert_eq!(seen.pixel(0), &[0.0; 3]);
                    assert_eq!(seen.pixel(2), &[0.0; 3]);
                }
                None if !kept => {}
                other => panic!(
                    "short normal {short}: {:?}",
                    other.map(|s| s.data().to_vec())
                ),
            }
        }
    }

    #[test]
    fn counts_and_fixes_bad_samples() {
        let mut b = Buffers::new();
        let color =
            Image::from_vec(2, 1, 3, vec![f32::NAN, -1.0, 0.5, f32::INFINITY, 1.0, 2.0]).unwrap();
        b.insert("color", color).unwrap();
        let normal = Image::from_vec(2, 1, 3, vec![0.0, 0.0, 0.0, 0.0, 2.0, 0.0]).unwrap();
        b.insert("normal", normal).unwrap();
        let depth = Image::from_vec(2, 1, 1, vec![f32::INFINITY, 3.0]).unwrap();
        b.insert("depth", depth).unwrap();
        let (color, features) = b.inputs_mut();
        let r = sanitize(color, features);
        assert_eq!(r.color_nonfinite, 2);
        assert_eq!(r.color_negative, 1);
        assert_eq!(r.depth_background, 1);
        assert_eq!(
            b.get("color").unwrap().data(),
            &[0.0, 0.0, 0.5, 0.0, 1.0, 2.0]
        );
        assert_eq!(
            b.get("normal").unwrap().data(),
            &[0.0, 0.0, 0.0, 0.0, 1.0, 0.0]
        );
        assert_eq!(b.get("depth").unwrap().data(), &[6.0, 3.0]);
        assert!(r.summary().unwrap().contains("2 non-finite colour"));
    }

    #[test]
    fn invalid_variance_becomes_zero_and_halves_are_sanitised_like_colour() {
        let mut b = Buffers::new();
        b.insert("color", Image::new(2, 1, 3)).unwrap();
        let variance = vec![f32::NAN, -1.0, 0.5, f32::INFINITY, 0.0, f32::NEG_INFINITY];
        b.insert("variance", Image::from_vec(2, 1, 3, variance).unwrap())
            .unwrap();
        let half = vec![f32::NAN, -1.0, 0.5, 1.0, 1.0, 1.0];
        b.insert("color_a", Image::from_vec(2, 1, 3, half).unwrap())
            .unwrap();
        b.insert("color_b", Image::new(2, 1, 3)).unwrap();
        let c = Conditioning::apply(&mut b);
        assert_eq!(c.sanitized.variance_invalid, 4);
        assert_eq!(
            (c.sanitized.color_nonfinite, c.sanitized.color_negative),
            (1, 1)
        );
        assert_eq!(
            b.get("variance").unwrap().data(),
            &[0.0, 0.0, 0.5, 0.0, 0.0, 0.0]
        );
        assert_eq!(
            b.get("color_a").unwrap().data(),
            &[0.0, 0.0, 0.5, 1.0, 1.0, 1.0]
        );
        assert!(c
            .sanitized
            .summary()
            .unwrap()
            .contains("4 invalid variance samples → 0"));
    }

    #[test]
    fn noise_buffers_follow_the_brightness_scale() {
        let mut b = Buffers::new();
        b.insert("color", Image::from_fn(4, 4, 3, |_, _, _| 10.0))
            .unwrap();
        b.insert("variance", Image::from_fn(4, 4, 3, |_, _, _| 4.0))
            .unwrap();
        b.insert("color_a", Image::from_fn(4, 4, 3, |_, _, _| 10.0))
            .unwrap();
        let c = Conditioning::apply(&mut b);
        assert!(c.scale < 1.0);
        let s = c.scale;
        assert_eq!(b.get("color_a").unwrap().data()[0], 10.0 * s);
        assert_eq!(b.get("variance").unwrap().data()[0], 4.0 * (s * s));
    }
}
