//! Image quality scores by the project's protocol (docs/ALGORITHM.md §5).
//!
//! SSIM and PSNR are taken on the LDR view (clamp to [0, 1], then the sRGB curve); relMSE on linear
//! HDR. SSIM reproduces scikit-image's `structural_similarity(gaussian_weights=True, sigma=1.5,
//! use_sample_covariance=False, data_range=1.0, channel_axis=2)`: an 11-tap Gaussian window applied
//! with scipy's `reflect` border, K1 = 0.01, K2 = 0.03, a 5-pixel border cropped, the mean over pixels
//! and then channels. Everything is computed in f64.

use serde::Serialize;

use crate::error::{Error, Result};
use crate::image::Image;

/// The three scores of one image against a reference.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Scores {
    pub ssim: f64,
    pub psnr: f64,
    pub relmse: f64,
}

/// Scores `image` against `reference`; both must be 3-channel and the same size.
pub fn score(image: &Image, reference: &Image) -> Result<Scores> {
    check_pair(image, reference)?;
    let a = ldr_planes(image);
    let b = ldr_planes(reference);
    let (w, h) = image.dims();
    Ok(Scores {
        ssim: ssim_planes(&a, &b, w, h),
        psnr: psnr_planes(&a, &b),
        relmse: rel_mse(image, reference),
    })
}

fn check_pair(image: &Image, reference: &Image) -> Result<()> {
    if image.dims() != reference.dims() {
        return Err(Error::Usage(format!(
            "image is {}x{} but the reference is {}x{}",
            image.width(),
            image.height(),
            reference.width(),
            reference.height()
        )));
    }
    if image.channels() != 3 || reference.channels() != 3 {
        return Err(Error::Usage("scores need 3-channel (RGB) images".into()));
    }
    Ok(())
}

/// The sRGB encoding curve applied to linear light clamped to [0, 1].
pub fn srgb_encode(x: f64) -> f64 {
    let x = if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// One f64 plane per channel, each sample passed through `f`.
fn planes_with(img: &Image, f: impl Fn(f64) -> f64) -> Vec<Vec<f64>> {
    let c = img.channels();
    (0..c)
        .map(|k| {
            img.data()
                .iter()
                .skip(k)
                .step_by(c)
                .map(|&v| f(v as f64))
                .collect()
        })
        .collect()
}

/// The LDR view as one f64 plane per channel.
fn ldr_planes(img: &Image) -> Vec<Vec<f64>> {
    planes_with(img, srgb_encode)
}

/// Split planes of an already-LDR image (no curve applied): for comparisons on given data.
pub fn planes_of(img: &Image) -> Vec<Vec<f64>> {
    planes_with(img, |v| v)
}

/// SSIM of the LDR views of two linear images.
pub fn ssim(image: &Image, reference: &Image) -> Result<f64> {
    check_pair(image, reference)?;
    Ok(ssim_planes(
        &ldr_planes(image),
        &ldr_planes(reference),
        image.width(),
        image.height(),
    ))
}

/// PSNR (dB) of the LDR views; `inf` for identical views.
pub fn psnr(image: &Image, reference: &Image) -> Result<f64> {
    check_pair(image, reference)?;
    Ok(psnr_planes(&ldr_planes(image), &ldr_planes(reference)))
}

/// mean((x − r)² / (r² + 0.01)) over all linear samples.
pub fn rel_mse(image: &Image, reference: &Image) -> f64 {
    let n = image.data().len().max(1) as f64;
    image
        .data()
        .iter()
        .zip(reference.data())
        .map(|(&x, &r)| {
            let (x, r) = (x as f64, r as f64);
            (x - r) * (x - r) / (r * r + 0.01)
        })
        .sum::<f64>()
        / n
}

pub fn psnr_planes(a: &[Vec<f64>], b: &[Vec<f64>]) -> f64 {
    let mut sum = 0.0;
    let mut n = 0usize;
    for (pa, pb) in a.iter().zip(b) {
        for (x, y) in pa.iter().zip(pb) {
            sum += (x - y) * (x - y);
            n += 1;
        }
    }
    let mse = sum / n.max(1) as f64;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (1.0 / mse).log10()
    }
}

const SIGMA: f64 = 1.5;
const RADIUS: usize = 5; // int(3.5 * 1.5 + 0.5), scikit-image's truncate = 3.5

fn gaussian_taps() -> [f64; 2 * RADIUS + 1] {
    let mut taps = [0.0; 2 * RADIUS + 1];
    for (i, t) in taps.iter_mut().enumerate() {
        let x = i as f64 - RADIUS as f64;
        *t = (-0.5 * x * x / (SIGMA * SIGMA)).exp();
    }
    let sum: f64 = taps.iter().sum();
    taps.iter_mut().for_each(|t| *t /= sum);
    taps
}

/// scipy's `reflect` border (d c b a | a b c d), valid for any offset and any size ≥ 1.
fn reflect(i: isize, n: usize) -> usize {
    let period = 2 * n as isize;
    let m = i.rem_euclid(period);
    if m >= n as isize {
        (period - 1 - m) as usize
    } else {
        m as usize
    }
}

/// Separable Gaussian filter of one plane.
fn blur(src: &[f64], w: usize, h: usize, taps: &[f64]) -> Vec<f64> {
    let r = RADIUS as isize;
    let mut tmp = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for (t, &k) in taps.iter().enumerate() {
                s += k * src[y * w + reflect(x as isize + t as isize - r, w)];
            }
            tmp[y * w + x] = s;
        }
    }
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for (t, &k) in taps.iter().enumerate() {
                s += k * tmp[reflect(y as isize + t as isize - r, h) * w + x];
            }
            out[y * w + x] = s;
        }
    }
    out
}

/// Mean SSIM over channels of planar images of size w × h.
///
/// For images too small to crop a 5-pixel border from, the mean is taken over all pixels
/// (scikit-image refuses those sizes).
pub fn ssim_planes(a: &[Vec<f64>], b: &[Vec<f64>], w: usize, h: usize) -> f64 {
    const C1: f64 = 0.01 * 0.01;
    const C2: f64 = 0.03 * 0.03;
    let taps = gaussian_taps();
    let mut total = 0.0;
    for (pa, pb) in a.iter().zip(b) {
        let prod = |f: &dyn Fn(f64, f64) -> f64| -> Vec<f64> {
            pa.iter().zip(pb).map(|(&x, &y)| f(x, y)).collect()
        };
        let ux = blur(pa, w, h, &taps);
        let uy = blur(pb, w, h, &taps);
        let uxx = blur(&prod(&|x, _| x * x), w, h, &taps);
        let uyy = blur(&prod(&|_, y| y * y), w, h, &taps);
        let uxy = blur(&prod(&|x, y| x * y), w, h, &taps);
        let (x_range, y_range) = if w > 2 * RADIUS && h > 2 * RADIUS {
            (RADIUS..w - RADIUS, RADIUS..h - RADIUS)
        } else {
            (0..w, 0..h)
        };
        let mut sum = 0.0;
        let mut n = 0usize;
        for y in y_range {
            for x in x_range.clone() {
                let i = y * w + x;
                let vx = uxx[i] - ux[i] * ux[i];
                let vy = uyy[i] - uy[i] * uy[i];
                let vxy = uxy[i] - ux[i] * uy[i];
                let num = (2.0 * ux[i] * uy[i] + C1) * (2.0 * vxy + C2);
                let den = (ux[i] * ux[i] + uy[i] * uy[i] + C1) * (vx + vy + C2);
                sum += num / den;
                n += 1;
            }
        }
        total += sum / n.max(1) as f64;
    }
    total / a.len().max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_images_score_perfectly() {
        let img = Image::from_fn(13, 17, 3, |x, y, c| (x * 7 + y * 3 + c) as f32 / 60.0);
        let s = score(&img, &img).unwrap();
        assert!((s.ssim - 1.0).abs() < 1e-12);
        assert!(s.psnr.is_infinite());
        assert_eq!(s.relmse, 0.0);
    }

    #[test]
    fn tiny_images_are_scored_without_panicking() {
        let a = Image::filled(1, 1, 3, 0.2);
        let b = Image::filled(1, 1, 3, 0.3);
        let s = score(&a, &b).unwrap();
        assert!(s.ssim.is_finite() && s.ssim < 1.0);
    }

    #[test]
    fn reflect_matches_scipy() {
        let got: Vec<usize> = (-4..8).map(|i| reflect(i, 3)).collect();
        assert_eq!(got, vec![2, 2, 1, 0, 0, 1, 2, 2, 1, 0, 0, 1]);
    }
}
