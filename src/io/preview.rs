//! 8-bit previews of a float image (`-o x.png`, `-o x.jpg`): ×2^exposure, clamp to [0, 1], the sRGB
//! transfer curve, round. Alpha is coverage, not light: it is clamped and rounded, never curved or
//! exposed. PNG keeps it; JPEG has none and drops it.

use image::codecs::jpeg::JpegEncoder;
use image::codecs::png::PngEncoder;
use image::{ExtendedColorType, ImageEncoder};
use rayon::prelude::*;

use crate::image::Image;

/// The two preview encoders.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Preview {
    Png,
    Jpeg,
}

/// JPEG quality: high enough that a preview shows the denoiser's residue, not the codec's blocks.
const JPEG_QUALITY: u8 = 92;

/// The sRGB encoding curve (linear light to display values), the inverse of
/// [`super::read::srgb_to_linear`].
pub fn linear_to_srgb(v: f32) -> f32 {
    if v <= 0.003_130_8 {
        v * 12.92
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// `v` clamped to [0, 1], NaN to 0, as an 8-bit value of `curve(v)`.
fn quantise(v: f32, curve: impl Fn(f32) -> f32) -> u8 {
    let v = if v > 0.0 { v.min(1.0) } else { 0.0 };
    (curve(v) * 255.0).round() as u8
}

/// Encodes `image` (1, 3 or 4 channels) as an 8-bit preview, `exposure` in stops.
pub fn encode(image: &Image, kind: Preview, exposure: f32) -> std::result::Result<Vec<u8>, String> {
    let (w, h, c) = (image.width(), image.height(), image.channels());
    let (kept, color) = match (c, kind) {
        (1, _) => (1, ExtendedColorType::L8),
        (3, _) | (4, Preview::Jpeg) => (3, ExtendedColorType::Rgb8),
        (4, Preview::Png) => (4, ExtendedColorType::Rgba8),
        _ => return Err(format!("cannot write a {c}-channel image as {kind:?}")),
    };
    let gain = exposure.exp2();
    let mut samples = vec![0u8; w * h * kept];
    if w > 0 {
        samples
            .par_chunks_mut(w * kept)
            .zip(image.data().par_chunks(w * c))
            .for_each(|(dst, src)| {
                for (d, px) in dst.chunks_exact_mut(kept).zip(src.chunks_exact(c)) {
                    for (k, out) in d.iter_mut().enumerate() {
                        *out = if k == 3 {
                            quantise(px[3], |a| a)
                        } else {
                            quantise(px[k] * gain, linear_to_srgb)
                        };
                    }
                }
            });
    }
    let (w, h) = (
        u32::try_from(w).map_err(|_| "is too wide")?,
        u32::try_from(h).map_err(|_| "is too tall")?,
    );
    let mut bytes = Vec::new();
    match kind {
        Preview::Png => PngEncoder::new(&mut bytes).write_image(&samples, w, h, color),
        Preview::Jpeg => JpegEncoder::new_with_quality(&mut bytes, JPEG_QUALITY)
            .write_image(&samples, w, h, color),
    }
    .map_err(|e| format!("cannot encode the {kind:?} preview ({e})"))?;
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_curve_inverts_the_decoding_curve() {
        for i in 0..=255 {
            let v = i as f32 / 255.0;
            let back = linear_to_srgb(crate::io::read::srgb_to_linear(v));
            assert!((back - v).abs() < 1e-5, "{v}: {back}");
        }
    }

    #[test]
    fn samples_are_exposed_clamped_and_curved() {
        let img = Image::from_vec(5, 1, 1, vec![-1.0, f32::NAN, 0.25, 0.5, f32::INFINITY]).unwrap();
        let png = encode(&img, Preview::Png, 1.0).unwrap();
        let back = image::load_from_memory(&png).unwrap().to_luma8();
        // 0.25 and 0.5 exposed one stop: 0.5 (sRGB 188) and 1.0.
        assert_eq!(back.as_raw(), &[0, 0, 188, 255, 255]);
    }

    #[test]
    fn png_keeps_alpha_linear() {
        let img = Image::from_vec(1, 1, 4, vec![0.0, 0.0, 0.0, 0.5]).unwrap();
        let png = encode(&img, Preview::Png, 3.0).unwrap();
        let back = image::load_from_memory(&png).unwrap().to_rgba8();
        assert_eq!(back.as_raw(), &[0, 0, 0, 128]);
    }
}
