//! Per-pixel f64 planes with a margin on every side, so the pixels of a row read their windows
//! side by side as contiguous runs, without bounds checks or clamped coordinates: the noise
//! estimate's, the blend's and the feature prefilter's kernels read their inputs through it.

use rayon::prelude::*;

use crate::image::par_vec;

/// What a margin cell holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Margin {
    /// 0: for windows whose cells outside the image are masked out anyway.
    Zeros,
    /// The nearest edge pixel's value, as clamped coordinates would read it.
    Edge,
}

/// `src` into `line` with `margin` copies of its first and last values before and after it (as
/// `Margin::Edge` does for a whole plane), so each tap of a 1-D window along the row is one shifted
/// slice `line[d..d + src.len()]`. `line` is a reused buffer; `src` is not empty.
pub(crate) fn edge_padded_line<T: Copy>(line: &mut Vec<T>, src: &[T], margin: usize) {
    line.clear();
    line.extend(std::iter::repeat_n(src[0], margin));
    line.extend_from_slice(src);
    line.extend(std::iter::repeat_n(src[src.len() - 1], margin));
}

/// `planes` planes of a `w`×`h` image, each `(w + 2m) × (h + 2m)` for a margin m.
pub(crate) struct Padded {
    pub(crate) planes: Vec<Vec<f64>>,
    stride: usize,
    margin: usize,
}

impl Padded {
    /// Plane k of pixel i holds `value(i, k)`; the `margin` cells around the image hold `fill`.
    pub(crate) fn new(
        (w, h): (usize, usize),
        planes: usize,
        margin: usize,
        fill: Margin,
        value: impl Fn(usize, usize) -> f64 + Sync,
    ) -> Self {
        let m = margin as isize;
        let stride = w + 2 * margin;
        let (wi, hi) = (w as isize, h as isize);
        let planes = (0..planes)
            .map(|k| {
                let mut plane = par_vec(0.0, stride * (h + 2 * margin));
                plane
                    .par_chunks_mut(stride)
                    .enumerate()
                    .for_each(|(row, cells)| {
                        let y = row as isize - m;
                        let inside_row = (0..hi).contains(&y);
                        if fill == Margin::Zeros && !inside_row {
                            return;
                        }
                        // The image's own cells of the row first, with no test per cell; then
                        // the margin's, which `Edge` fills from the nearest pixel.
                        if inside_row {
                            let first = y as usize * w;
                            for (x, v) in cells[margin..margin + w].iter_mut().enumerate() {
                                *v = value(first + x, k);
                            }
                        }
                        if fill == Margin::Edge {
                            let y = y.clamp(0, hi - 1);
                            for (col, v) in cells.iter_mut().enumerate() {
                                let x = col as isize - m;
                                if !((0..wi).contains(&x) && inside_row) {
                                    *v = value((y * wi + x.clamp(0, wi - 1)) as usize, k);
                                }
                            }
                        }
                    });
                plane
            })
            .collect();
        Padded {
            planes,
            stride,
            margin,
        }
    }

    /// Index in a plane of pixel (x, y), −margin ≤ x < w + margin and y likewise.
    #[inline(always)]
    pub(crate) fn index(&self, x: isize, y: isize) -> usize {
        let m = self.margin as isize;
        ((y + m) * self.stride as isize + x + m) as usize
    }

    /// Index in a plane of the cell (dx, dy) from pixel (x, y), |dx|, |dy| ≤ the margin.
    #[inline(always)]
    pub(crate) fn at(&self, x: usize, y: usize, (dx, dy): (isize, isize)) -> usize {
        self.index(x as isize + dx, y as isize + dy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn margins_hold_zeros_or_the_nearest_edge_pixel() {
        let (w, h) = (3, 2);
        for fill in [Margin::Zeros, Margin::Edge] {
            let p = Padded::new((w, h), 2, 2, fill, |i, k| (10 * k + i + 1) as f64);
            for y in -2..h as isize + 2 {
                for x in -2..w as isize + 2 {
                    let inside = (0..w as isize).contains(&x) && (0..h as isize).contains(&y);
                    let (cx, cy) = (x.clamp(0, w as isize - 1), y.clamp(0, h as isize - 1));
                    for k in 0..2 {
                        let want = if inside || fill == Margin::Edge {
                            (10 * k as isize + cy * w as isize + cx + 1) as f64
                        } else {
                            0.0
                        };
                        assert_eq!(p.planes[k][p.index(x, y)], want, "{fill:?} ({x}, {y})");
                    }
                }
            }
        }
    }
}
