//! Each pixel's neighbourhood peak, as a bound on a demodulated pass.
//!
//! Why: a pass over the colour divided by the albedo averages illumination and multiplies the
//! pixel's own albedo back. Where a pixel's albedo is above its neighbours' near zero (an emitter,
//! whose albedo is 0, beside a pixel the earlier stages gave some albedo), that product is their
//! light times (a + ε) / ε: above anything around it. An average of the neighbourhood cannot be
//! brighter than its brightest pixel, so the pass's output is held below that. Luminance only, one
//! plane: the bound is for this failure, and it costs little beside the pass.

use rayon::prelude::*;

use crate::filters::outlier::luminance_image;
use crate::image::Image;

/// The largest luminance of the RGB `input` over the (2r + 1)² window around each pixel (clipped
/// at the image's border): along each row first, then down the columns of those.
pub fn peaks(input: &Image, r: usize) -> Vec<f32> {
    let (w, h) = input.dims();
    assert_eq!(input.channels(), 3, "an RGB image");
    let lum = luminance_image(input);
    let mut rows = vec![0.0f32; w * h];
    rows.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            let lum = &lum[y * w..(y + 1) * w];
            for (x, p) in row.iter_mut().enumerate() {
                let (x0, x1) = (x.saturating_sub(r), (x + r).min(w - 1));
                *p = lum[x0..=x1]
                    .iter()
                    .fold(f32::NEG_INFINITY, |m, &v| m.max(v));
            }
        });
    let mut out = vec![0.0f32; w * h];
    out.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            let (y0, y1) = (y.saturating_sub(r), (y + r).min(h - 1));
            for (x, p) in row.iter_mut().enumerate() {
                *p = (y0..=y1).fold(f32::NEG_INFINITY, |m, ny| m.max(rows[ny * w + x]));
            }
        });
    out
}

/// Scales down, keeping its hue, every pixel of the RGB `out` whose luminance is above its
/// `peak` (one per pixel, from [`peaks`] of the image the pass read).
pub fn hold_below(out: &mut Image, peak: &[f32]) {
    assert_eq!(out.channels(), 3, "an RGB image");
    assert_eq!(peak.len(), out.dims().0 * out.dims().1, "a peak a pixel");
    let w = out.dims().0.max(1);
    out.data_mut()
        .par_chunks_mut(3 * w)
        .zip(peak.par_chunks(w))
        .for_each(|(row, peak)| {
            for (px, &top) in row.chunks_exact_mut(3).zip(peak) {
                // In f64, unrounded: the scale is a ratio of two luminances near each other.
                let l = 0.2126 * px[0] as f64 + 0.7152 * px[1] as f64 + 0.0722 * px[2] as f64;
                let top = top as f64;
                // Only a finite excess over a non-negative peak is scaled: nothing else divides.
                if l > top && top >= 0.0 && l.is_finite() {
                    let s = (top / l) as f32;
                    px.iter_mut().for_each(|v| *v *= s);
                }
            }
        });
}

/// [`peaks`] of `input` then [`hold_below`] on `out`.
#[cfg(test)]
fn hold_below_peak(out: &mut Image, input: &Image, r: usize) {
    let peak = peaks(input, r);
    hold_below(out, &peak);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filters::outlier::luminance;

    #[test]
    fn a_pixel_above_its_windows_peak_is_scaled_to_it_and_the_rest_passes() {
        // Grey pixels of luminance x + 10 y.
        let input = Image::from_fn(5, 4, 3, |x, y, _| (x + 10 * y) as f32);
        let mut out = input.clone();
        out.data_mut()[..3].copy_from_slice(&[400.0, 200.0, 100.0]);
        let last = 3 * (3 * 5 + 4);
        out.data_mut()[last..last + 3].copy_from_slice(&[-5.0, -5.0, -5.0]);
        hold_below_peak(&mut out, &input, 1);
        // (0, 0): its window is x 0..=1, y 0..=1, peak 11; the hue is kept.
        let p = out.pixel(0);
        assert!((luminance(p) - 11.0).abs() < 1e-4, "{p:?}");
        assert!((p[0] / p[1] - 2.0).abs() < 1e-5 && (p[1] / p[2] - 2.0).abs() < 1e-5);
        // Below the peak (even negative) passes, as does every other pixel.
        assert_eq!(out.pixel(19), &[-5.0, -5.0, -5.0]);
        for i in 1..19 {
            assert_eq!(out.pixel(i), input.pixel(i));
        }
    }

    #[test]
    fn one_pixel_and_empty_images_pass() {
        let input = Image::filled(1, 1, 3, 2.0);
        let mut out = Image::filled(1, 1, 3, 5.0);
        hold_below_peak(&mut out, &input, 2);
        assert!((luminance(out.pixel(0)) - 2.0).abs() < 1e-5);
        let mut empty = Image::new(0, 3, 3);
        hold_below_peak(&mut empty, &Image::new(0, 3, 3), 2);
    }
}
