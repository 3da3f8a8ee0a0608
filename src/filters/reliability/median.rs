//! The robust centres the gate pulls a pixel towards, and the filling of distances a renderer did
//! not record.

use rayon::prelude::*;

use super::variance::{DIRECTIONS, NO_DIRECTION};
use crate::image::{par_vec, Image};
use crate::kernels::padded::Padded;
use crate::kernels::simd::{row_kernel, Kernel};

/// Radius of the medians: 5 pixels along a direction, or a 5×5 square (the five-value network
/// below is written for it).
pub const MEDIAN_RADIUS: usize = 2;

/// The median of the 2·MEDIAN_RADIUS + 1 pixels of `plane` through every pixel along its direction
/// `along`: it drops isolated samples and keeps a line or an edge that runs that way, which a
/// square median would erase. A pixel with no direction takes its `square` median.
pub(super) fn median_along(
    src: &Padded,
    plane: &[f64],
    along: &[u8],
    square: &[f64],
    (w, h): (usize, usize),
) -> Vec<f64> {
    let r = MEDIAN_RADIUS as isize;
    let mut out = par_vec(0.0, w * h);
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let i = y * w + x;
            let d = along[i];
            if d == NO_DIRECTION {
                *o = square[i];
                continue;
            }
            let (dx, dy) = DIRECTIONS[d as usize];
            let mut win = [0.0f64; 5];
            for (t, slot) in (-r..=r).zip(win.iter_mut()) {
                *slot = plane[src.at(x, y, (t * dx, t * dy))];
            }
            *o = median5(win);
        }
    });
    out
}

/// The 5×5 median of every pixel, taken separably: the median of the five row medians of its
/// window. Not the exact median of 25, but as sure to drop a scatter of outliers (a row median
/// drops up to two in its row, the column median up to two bad rows) at a fifth of the cost.
pub(super) fn square_median(src: &Padded, plane: &[f64], (w, h): (usize, usize)) -> Vec<f64> {
    let mut out = par_vec(0.0, w * h);
    out.par_chunks_mut(BAND * w.max(1))
        .enumerate()
        .for_each(|(band, out)| {
            let (kernel, y0) = (Kernel::detect(), band * BAND);
            row_kernel!(kernel, square_band(src: &Padded, plane: &[f64], w: usize, y0: usize, out: &mut [f64]));
        });
    out
}

/// Rows a task of [`square_median`] takes: its row medians stay in cache for the column pass.
const BAND: usize = 32;

/// [`square_median`] of the rows from `y0` on that `out` holds: the row medians of its rows and
/// MEDIAN_RADIUS either side (the padded plane's margin), then the column medians.
#[inline(always)]
fn square_band(src: &Padded, plane: &[f64], w: usize, y0: usize, out: &mut [f64]) {
    let r = MEDIAN_RADIUS as isize;
    let rows = out.len() / w;
    let span = rows + 2 * MEDIAN_RADIUS;
    let mut row_med = vec![0.0f64; span * w];
    for (j, med) in row_med.chunks_exact_mut(w).enumerate() {
        let at = src.index(0, y0 as isize + j as isize - r);
        let p = &plane[at - 2..at + w + 2];
        for (x, o) in med.iter_mut().enumerate() {
            *o = median5([p[x], p[x + 1], p[x + 2], p[x + 3], p[x + 4]]);
        }
    }
    for (t, out) in out.chunks_exact_mut(w).enumerate() {
        let m = |k: usize| &row_med[(t + k) * w..(t + k + 1) * w];
        let (m0, m1, m2, m3, m4) = (m(0), m(1), m(2), m(3), m(4));
        for (x, o) in out.iter_mut().enumerate() {
            *o = median5([m0[x], m1[x], m2[x], m3[x], m4[x]]);
        }
    }
}

/// The median of five values: a sorting network, no branches.
#[inline(always)]
fn median5(mut v: [f64; 5]) -> f64 {
    let mut cx = |a: usize, b: usize| {
        let (lo, hi) = (v[a].min(v[b]), v[a].max(v[b]));
        v[a] = lo;
        v[b] = hi;
    };
    cx(0, 1);
    cx(3, 4);
    cx(2, 4);
    cx(2, 3);
    cx(0, 3);
    cx(0, 2);
    cx(1, 4);
    cx(1, 3);
    cx(1, 2);
    v[2]
}

/// A zero distance is one the renderer did not record (Blender's `Denoising Depth` is 0 where the
/// pixel's one sample scattered inside a medium): each becomes the median of the recorded distances
/// of its (2·MEDIAN_RADIUS + 1)² window when they are most of it, so it no longer looks like a
/// surface at another depth. A region with mostly nothing recorded (the sky) stays zero. Two
/// passes: the second fills a hole whose window the first made mostly recorded (a cluster of
/// unrecorded samples), and a straight edge of the sky is no nearer a majority after the first.
pub(super) fn fill_unrecorded(img: &Image) -> Image {
    fill_pass(&fill_pass(img))
}

fn fill_pass(img: &Image) -> Image {
    const N: usize = (2 * MEDIAN_RADIUS + 1) * (2 * MEDIAN_RADIUS + 1);
    let (w, h, c) = (img.width(), img.height(), img.channels());
    let r = MEDIAN_RADIUS as isize;
    let mut out = img.clone();
    out.data_mut()
        .par_chunks_mut(w * c)
        .enumerate()
        .for_each(|(y, row)| {
            for x in 0..w {
                for k in 0..c {
                    if row[x * c + k] > 0.0 {
                        continue;
                    }
                    let mut known = [0.0f32; N];
                    let mut n = 0;
                    for dy in -r..=r {
                        let yy = (y as isize + dy).clamp(0, h as isize - 1) as usize;
                        for dx in -r..=r {
                            let xx = (x as isize + dx).clamp(0, w as isize - 1) as usize;
                            let v = img.data()[(yy * w + xx) * c + k];
                            if v > 0.0 {
                                known[n] = v;
                                n += 1;
                            }
                        }
                    }
                    if 2 * n > N {
                        let (_, m, _) = known[..n].select_nth_unstable_by(n / 2, f32::total_cmp);
                        row[x * c + k] = *m;
                    }
                }
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::padded::Margin;

    #[test]
    fn the_banded_square_median_is_the_median_of_the_row_medians_of_every_window() {
        // Heights across several bands, widths down to one pixel; edges replicated.
        for (w, h) in [(1, 1), (3, 2), (7, 70), (1, 33), (12, 65)] {
            let value = |i: usize, _k: usize| ((i * 7919 + 13) % 101) as f64 / 10.0 - 3.0;
            let src = Padded::new((w, h), 1, MEDIAN_RADIUS, Margin::Edge, value);
            let got = square_median(&src, &src.planes[0], (w, h));
            let at = |x: isize, y: isize| {
                let (x, y) = (x.clamp(0, w as isize - 1), y.clamp(0, h as isize - 1));
                value(y as usize * w + x as usize, 0)
            };
            for y in 0..h as isize {
                for x in 0..w as isize {
                    let row = |dy: isize| {
                        median5(std::array::from_fn(|k| at(x + k as isize - 2, y + dy)))
                    };
                    let want = median5(std::array::from_fn(|k| row(k as isize - 2)));
                    assert_eq!(got[y as usize * w + x as usize], want, "{w}x{h} ({x}, {y})");
                }
            }
        }
    }

    #[test]
    fn median5_is_the_middle_of_every_order() {
        // All 120 orders of five distinct values, and ties.
        let base = [1.0, 2.0, 3.0, 4.0, 5.0];
        let mut idx = [0usize, 1, 2, 3, 4];
        let mut count = 0;
        permute(&mut idx, 0, &mut |p| {
            assert_eq!(median5(p.map(|i| base[i])), 3.0, "{p:?}");
            count += 1;
        });
        assert_eq!(count, 120);
        assert_eq!(median5([2.0, 2.0, 1.0, 2.0, 9.0]), 2.0);
    }

    fn permute(v: &mut [usize; 5], k: usize, f: &mut impl FnMut([usize; 5])) {
        if k == 5 {
            return f(*v);
        }
        for i in k..5 {
            v.swap(k, i);
            permute(v, k + 1, f);
            v.swap(k, i);
        }
    }
}
