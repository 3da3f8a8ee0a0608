//! Reading a neighbour's buffers at a centre pixel's tracked position: the value (bilinear, so a
//! sub-pixel motion is followed; exact at whole-pixel positions) and the 3×3 mean and spread around
//! the nearest pixel, which the agreement tests compare (a single noisy pixel says too little).

use crate::image::Image;

/// Most channels a buffer read here has (colour, albedo, normal).
pub const MAX_CHANNELS: usize = 3;

/// The nearest pixel of a position, if it lies in the image (half a pixel of margin).
pub fn nearest(img: &Image, [x, y]: [f32; 2]) -> Option<(usize, usize)> {
    let (w, h) = img.dims();
    let (xi, yi) = (x.round(), y.round());
    (xi >= 0.0 && yi >= 0.0 && (xi as usize) < w && (yi as usize) < h)
        .then_some((xi as usize, yi as usize))
}

/// Bilinear value of `img` at a position inside it (edge pixels repeated), into `out`; returns the
/// sum of the squared tap weights, the share of one pixel's noise variance the value keeps (1 at a
/// whole pixel, 1/4 halfway between four).
pub fn bilinear(img: &Image, [x, y]: [f32; 2], out: &mut [f64; MAX_CHANNELS]) -> f64 {
    let (w, h) = img.dims();
    let c = img.channels();
    let x = x.clamp(0.0, (w - 1) as f32);
    let y = y.clamp(0.0, (h - 1) as f32);
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = ((x - x0 as f32) as f64, (y - y0 as f32) as f64);
    let taps = [
        (x0, y0, (1.0 - fx) * (1.0 - fy)),
        (x1, y0, fx * (1.0 - fy)),
        (x0, y1, (1.0 - fx) * fy),
        (x1, y1, fx * fy),
    ];
    out[..c].iter_mut().for_each(|v| *v = 0.0);
    let mut kept = 0.0;
    for (tx, ty, wt) in taps {
        if wt == 0.0 {
            continue;
        }
        kept += wt * wt;
        for (o, &v) in out[..c].iter_mut().zip(img.at(tx, ty)) {
            *o += wt * v as f64;
        }
    }
    kept
}

/// Mean and variance per channel over the 3×3 window around (x, y) (clipped at the border).
pub fn window(img: &Image, (x, y): (usize, usize)) -> ([f64; MAX_CHANNELS], [f64; MAX_CHANNELS]) {
    let (w, h) = img.dims();
    let c = img.channels();
    let (mut sum, mut sq) = ([0.0f64; MAX_CHANNELS], [0.0f64; MAX_CHANNELS]);
    let mut n = 0.0f64;
    for yy in y.saturating_sub(1)..=(y + 1).min(h - 1) {
        for xx in x.saturating_sub(1)..=(x + 1).min(w - 1) {
            for (k, &v) in img.at(xx, yy).iter().enumerate().take(c) {
                let v = v as f64;
                sum[k] += v;
                sq[k] += v * v;
            }
            n += 1.0;
        }
    }
    let mut var = [0.0; MAX_CHANNELS];
    for k in 0..c {
        sum[k] /= n;
        var[k] = (sq[k] / n - sum[k] * sum[k]).max(0.0);
    }
    (sum, var)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_is_exact_at_pixels_and_halfway_between() {
        let img = Image::from_fn(4, 3, 1, |x, y, _| (x + 10 * y) as f32);
        let mut out = [0.0; MAX_CHANNELS];
        bilinear(&img, [2.0, 1.0], &mut out);
        assert_eq!(out[0], 12.0);
        assert_eq!(bilinear(&img, [1.5, 0.5], &mut out), 0.25);
        assert_eq!(out[0], 6.5);
        assert_eq!(nearest(&img, [3.4, 2.4]), Some((3, 2)));
        assert_eq!(nearest(&img, [-0.6, 0.0]), None);
        assert_eq!(nearest(&img, [f32::NAN, 0.0]), None);
    }

    #[test]
    fn window_statistics_of_a_flat_image_have_no_spread() {
        let img = Image::filled(5, 5, 3, 0.25);
        let (mean, var) = window(&img, (0, 4));
        assert_eq!(mean, [0.25; 3]);
        assert_eq!(var, [0.0; 3]);
    }
}
