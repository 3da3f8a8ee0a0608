//! Averaging raw per-pixel noise estimates over the same surface, weighted by their degrees of
//! freedom, and bringing the result to each pixel's albedo.

use rayon::prelude::*;

use super::surface::{window, Mates, Surface};
use crate::image::Image;
use crate::meter::Meter;

/// Radius of the window the raw estimates are averaged over (7×7).
pub(super) const SMOOTH_RADIUS: isize = 3;

/// Sample variance (per channel) of the colours of `members`, and its degrees of freedom
/// (members − 1).
fn spread(color: &[f32], members: &[usize]) -> ([f64; 3], usize) {
    let mut n = 0usize;
    let mut sum = [0.0f64; 3];
    let mut sum2 = [0.0f64; 3];
    for &j in members {
        for k in 0..3 {
            let v = color[3 * j + k] as f64;
            sum[k] += v;
            sum2[k] += v * v;
        }
        n += 1;
    }
    if n < 2 {
        return ([0.0; 3], 0);
    }
    let nf = n as f64;
    let var = std::array::from_fn(|k| ((sum2[k] - sum[k] * sum[k] / nf) / (nf - 1.0)).max(0.0));
    (var, n - 1)
}

/// The plain 3×3 spread of the colours around pixel `i`: the variance of a pixel with no
/// surface-mate when nothing better is known.
pub(super) fn plain_spread(color: &Image, i: usize) -> [f64; 3] {
    let (w, h) = color.dims();
    let (x, y) = (i % w, i / w);
    let mut near = [0usize; 9];
    let mut n = 0;
    for j in window(x, y, w, h, 1) {
        near[n] = j;
        n += 1;
    }
    spread(color.data(), &near[..n]).0
}

/// Averages raw per-pixel estimates (demodulated variance, degrees of freedom; 0 = none) over the
/// same surface, and brings the result to each pixel's albedo; a pixel none of whose mates has a
/// raw estimate takes `lone`'s variance.
pub(super) fn smooth(
    color: &Image,
    surface: &Surface,
    mates: &Mates,
    raw: impl Fn(usize) -> ([f64; 3], usize) + Sync,
    lone: impl Fn(usize) -> [f64; 3] + Sync,
    meter: &Meter,
) -> Image {
    let (w, h) = color.dims();
    let mut out = Image::new(w, h, 3);
    out.data_mut()
        .par_chunks_mut(3)
        .enumerate()
        .for_each(|(i, px)| {
            // A cancelled run's pixels are left unset: its result is thrown away.
            if meter.cancelled() {
                return;
            }
            let mut acc = [0.0f64; 3];
            let mut dof = 0usize;
            for j in mates.of(i) {
                let (v, d) = raw(j);
                if d == 0 {
                    continue;
                }
                for k in 0..3 {
                    acc[k] += d as f64 * v[k];
                }
                dof += d;
            }
            let var = if dof > 0 {
                let s = surface.scale(i);
                std::array::from_fn(|k| acc[k] / dof as f64 * s[k] * s[k])
            } else {
                lone(i)
            };
            for k in 0..3 {
                px[k] = var[k] as f32;
            }
        });
    out
}
