//! The colour the walks compare (`color_guide`): on a mirror, glass or chrome the albedo and normal
//! are smooth, so only the colour difference can keep a reflected or refracted edge, and one noisy
//! pixel against another cannot tell an edge from noise unless σ is so small that the noise stays.
//! A 3×3 patch compared in units of the noise can: the walks then compare the colour after an
//! NL-means pass whose patch distance counts in noise standard deviations (the prefilter's kernel,
//! Rousselle et al. 2012), and still average the unfiltered colour. Two patches that differ only by
//! noise weigh fully, a reflected edge the noise cannot explain weighs nothing, so the guide keeps
//! the edge and loses most of the noise.

use crate::filters::noise::measured::pixel_variance;
use crate::filters::prefilter::{filter_metered, Kind, Params};
use crate::image::Image;
use crate::meter::Meter;

/// Search radius (7×7) and patch radius (3×3) of the guide's NL-means: the prefilter's.
const RADIUS: usize = 3;
const PATCH: usize = 1;

/// `color` after an NL-means pass with per-pixel `variance` (3 channels, averaged) and strength
/// `k` (patches closer than about k noise standard deviations average); `None` when the variance
/// reads no noise anywhere (nothing to take out). The colour is first brought to units of its
/// median noise, so the kernel's fixed floor of the distance normalisation (set for albedo) stays
/// far below the noise at any exposure and sample count; the result is brought back.
pub fn color_guide(color: &Image, variance: &Image, k: f64, meter: &Meter) -> Option<Image> {
    let (w, h) = color.dims();
    let per_pixel: Vec<f64> = variance
        .data()
        .chunks_exact(3)
        .map(pixel_variance)
        .collect();
    let mut positive: Vec<f64> = per_pixel.iter().copied().filter(|&v| v > 0.0).collect();
    if positive.is_empty() {
        return None;
    }
    let mid = positive.len() / 2;
    let typical = *positive.select_nth_unstable_by(mid, f64::total_cmp).1;
    if !(typical.is_finite() && typical > 0.0) {
        return None;
    }
    let scale = typical.sqrt().recip();
    let scaled = Image::from_fn(w, h, 3, |x, y, c| {
        (color.pixel(y * w + x)[c] as f64 * scale) as f32
    });
    let var: Vec<f32> = per_pixel
        .iter()
        .map(|&v| (v / typical).min(f32::MAX as f64) as f32)
        .collect();
    let params = Params {
        strength: k,
        radius: RADIUS,
        patch: PATCH,
        keep: 0.65,
    };
    let filtered = filter_metered(&scaled, &var, Kind::Plain, &params, meter);
    Some(Image::from_fn(w, h, 3, |x, y, c| {
        (filtered.pixel(y * w + x)[c] as f64 * typical.sqrt()) as f32
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat-featured patch with a sharp edge of 3 noise σ and heavy-tailed noise: the guide keeps
    /// the edge (its two sides stay apart) and takes most of the noise out on either side.
    #[test]
    fn guide_keeps_an_edge_and_loses_the_noise() {
        let (w, h) = (32, 32);
        let sd = 0.02f32;
        let mut state = 12345u64;
        let mut noise = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let u = ((state >> 11) as f64 / (1u64 << 53) as f64) as f32;
            // Mostly Gaussian-like (sum of uniforms), one in 25 a bright path.
            let g = (u * 12.0).fract() * 2.0 - 1.0;
            if u < 0.04 {
                8.0 * sd
            } else {
                g * sd * 1.7
            }
        };
        let truth = |x: usize| if x < 16 { 0.1f32 } else { 0.1 + 3.0 * sd };
        let color = Image::from_fn(w, h, 3, |x, _, _| truth(x));
        let noisy =
            Image::from_vec(w, h, 3, color.data().iter().map(|&v| v + noise()).collect()).unwrap();
        let variance = Image::filled(w, h, 3, sd * sd);
        let g = color_guide(&noisy, &variance, 0.5, &Meter::default()).unwrap();
        let col_mean = |img: &Image, x: usize| {
            (4..h - 4).map(|y| img.pixel(y * w + x)[0]).sum::<f32>() / (h - 8) as f32
        };
        // The typical pixel's error (the median): the bright paths are the outlier stage's.
        let err = |img: &Image| {
            let mut e: Vec<f32> = (4..h - 4)
                .flat_map(|y| (4..12).chain(20..28).map(move |x| (x, y)))
                .map(|(x, y)| (img.pixel(y * w + x)[0] - truth(x)).abs())
                .collect();
            e.sort_by(f32::total_cmp);
            e[e.len() / 2]
        };
        let step = col_mean(&g, 17) - col_mean(&g, 14);
        assert!(step > 2.0 * sd, "edge kept: step {step}");
        assert!(
            err(&g) < 0.5 * err(&noisy),
            "{} vs {}",
            err(&g),
            err(&noisy)
        );
        // No noise read anywhere: no guide.
        assert!(color_guide(&noisy, &Image::new(w, h, 3), 0.25, &Meter::default()).is_none());
    }
}
