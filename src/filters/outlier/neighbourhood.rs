//! A pixel's neighbourhood and the statistics the rules read of it: the window's pixels, their
//! luminance, median and quantile.

use rayon::prelude::*;

use crate::image::Image;

/// Rec. 709 luminance of linear RGB, summed in f64 so that f32::MAX input cannot overflow to ∞.
#[inline]
pub fn luminance(c: &[f32]) -> f32 {
    let l = 0.2126 * c[0] as f64 + 0.7152 * c[1] as f64 + 0.0722 * c[2] as f64;
    (l as f32).min(f32::MAX)
}

/// Luminance of every pixel of a 3-channel image.
pub fn luminance_image(color: &Image) -> Vec<f32> {
    color.data().par_chunks_exact(3).map(luminance).collect()
}

/// Median of `v` (reorders it); `v` must not be empty.
pub(super) fn median(v: &mut [f32]) -> f32 {
    let n = v.len();
    let (_, &mut hi, _) = v.select_nth_unstable_by(n / 2, f32::total_cmp);
    if n % 2 == 1 {
        hi
    } else {
        let lo = v[..n / 2].iter().copied().fold(f32::NEG_INFINITY, f32::max);
        0.5 * lo + 0.5 * hi
    }
}

/// The q-quantile of `v` with linear interpolation (numpy's default); sorts `v`; `v` not empty.
pub(super) fn quantile(v: &mut [f32], q: f32) -> f32 {
    v.sort_unstable_by(f32::total_cmp);
    let pos = q * (v.len() - 1) as f32;
    let lo = pos.floor() as usize;
    let hi = (lo + 1).min(v.len() - 1);
    let t = pos - lo as f32;
    v[lo] + t * (v[hi] - v[lo])
}

/// Indices of the pixels in the (2r+1)² window around (x, y), the centre excluded, clipped to the image.
#[inline]
pub(super) fn window(
    x: usize,
    y: usize,
    r: usize,
    w: usize,
    h: usize,
) -> impl Iterator<Item = usize> {
    let (x0, x1) = (x.saturating_sub(r), (x + r).min(w - 1));
    let (y0, y1) = (y.saturating_sub(r), (y + r).min(h - 1));
    (y0..=y1).flat_map(move |ny| {
        (x0..=x1)
            .filter(move |&nx| nx != x || ny != y)
            .map(move |nx| ny * w + nx)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_and_quantile_agree_with_hand_values() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
        assert_eq!(quantile(&mut [1.0, 2.0, 3.0, 4.0, 5.0], 0.75), 4.0);
        assert_eq!(quantile(&mut [0.0, 1.0], 0.75), 0.75);
        assert_eq!(quantile(&mut [7.0], 0.75), 7.0);
    }

    #[test]
    fn window_excludes_centre_and_clips() {
        let v: Vec<usize> = window(0, 0, 1, 3, 3).collect();
        assert_eq!(v, vec![1, 3, 4]);
        assert_eq!(window(1, 1, 1, 3, 3).count(), 8);
        assert_eq!(window(0, 0, 2, 1, 1).count(), 0);
    }

    #[test]
    fn luminance_is_finite_at_f32_max() {
        assert!(luminance(&[f32::MAX; 3]).is_finite());
        assert!((luminance(&[1.0, 1.0, 1.0]) - 1.0).abs() < 1e-6);
    }
}
