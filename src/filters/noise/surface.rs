//! Which pixels lie on one surface (same albedo, normal and depth): the features that decide it,
//! each pixel's surface-mates in its window, and the albedo that demodulates a pixel's colour.

use std::ops::Range;

use crate::image::Image;
use crate::kernels::simd::{row_kernel, Kernel};
use crate::kernels::window_bits;
use crate::meter::Meter;
use crate::render_set::{Feature, FeatureSet};

/// Features compared per pixel by `same_key`.
const KEYS: usize = 8;
/// Keeps remodulation finite on black albedo.
const ALBEDO_EPS: f32 = 0.02;
/// The same guard for what a pixel without surface saw (`FeatureSet::seen`): its colour is that
/// times about one, so any floor on the order of its values (the dark sky beside a light, 0.02)
/// makes demodulated neighbours differ by the light's shape; this one only keeps the ratio finite.
const SEEN_EPS: f32 = 1e-4;

/// When two pixels are taken to lie on one surface. Loose enough for the few-sample features of
/// a 1 spp render, tight enough to keep texture, creases and silhouettes apart.
const ALBEDO_TOLERANCE: f32 = 0.1;
const NORMAL_COS: f32 = 0.9;
const DEPTH_TOLERANCE: f32 = 0.05;

/// The features that decide "same surface".
pub(crate) struct Surface<'a> {
    albedo: Option<&'a [f32]>,
    normal: Option<&'a [f32]>,
    depth: Option<&'a [f32]>,
    /// What pixels that hit no surface saw, their raw albedo (`FeatureSet::seen`); 0 elsewhere.
    seen: Option<&'a [f32]>,
}

impl<'a> Surface<'a> {
    pub(crate) fn new(features: &'a FeatureSet, dims: (usize, usize)) -> Self {
        let get = |f: Feature| {
            features
                .get(f)
                .filter(|img| img.dims() == dims)
                .map(Image::data)
        };
        Surface {
            albedo: get(Feature::Albedo),
            normal: get(Feature::Normal),
            depth: get(Feature::Depth),
            seen: features
                .seen()
                .filter(|img| img.dims() == dims)
                .map(Image::data),
        }
    }

    /// The features `same_key` compares for the `w`-pixel rows `rows`, one plane each: albedo (3),
    /// normal (3), depth, normal known (1/0). A missing feature is zeros, which every pair passes,
    /// as when it is not compared.
    fn planes(&self, rows: Range<usize>, w: usize) -> [Vec<f32>; KEYS] {
        let (first, n) = (rows.start * w, rows.len() * w);
        let plane = |src: Option<&[f32]>, stride: usize, k: usize| match src {
            Some(v) => v[stride * first..stride * (first + n)]
                .chunks_exact(stride)
                .map(|px| px[k])
                .collect(),
            None => vec![0.0; n],
        };
        let (a, nrm, z) = (self.albedo, self.normal, self.depth);
        let mut planes: [Vec<f32>; KEYS] = [
            plane(a, 3, 0),
            plane(a, 3, 1),
            plane(a, 3, 2),
            plane(nrm, 3, 0),
            plane(nrm, 3, 1),
            plane(nrm, 3, 2),
            plane(z, 1, 0),
            Vec::new(),
        ];
        planes[7] = (0..n)
            .map(|i| {
                let known = planes[3][i] != 0.0 || planes[4][i] != 0.0 || planes[5][i] != 0.0;
                if known {
                    1.0
                } else {
                    0.0
                }
            })
            .collect();
        planes
    }

    /// For every pixel, which pixels of its window of `radius` (at most 3) lie on its surface:
    /// `same_key` over runs of pixels, each pair once (`window_bits`).
    pub(crate) fn mates(&self, w: usize, h: usize, radius: usize) -> Mates {
        self.mates_metered(w, h, radius, &Meter::default())
    }

    /// [`Surface::mates`] that stops between rows once `meter` is cancelled (unfinished then).
    pub(crate) fn mates_metered(&self, w: usize, h: usize, radius: usize, meter: &Meter) -> Mates {
        let mut mates = Mates::new(w, radius);
        let kernel = Kernel::detect();
        mates.bits = window_bits::window_bits_metered(
            w,
            h,
            radius,
            true,
            |rows| self.planes(rows, w),
            |planes, i0, j0, bit, out| row_kernel!(kernel, same_key_run(planes: &[Vec<f32>; KEYS], i0: usize, j0: usize, bit: u32, out: &mut [u64])),
            meter,
        );
        mates
    }

    /// Pixel i's albedo + ε per channel (1 without albedo): colour divided by it is demodulated.
    #[inline]
    pub(crate) fn scale(&self, i: usize) -> [f64; 3] {
        if let Some(s) = self.seen_at(i) {
            return std::array::from_fn(|k| (s[k] + SEEN_EPS) as f64);
        }
        match self.albedo {
            Some(a) => std::array::from_fn(|k| (a[3 * i + k].max(0.0) + ALBEDO_EPS) as f64),
            None => [1.0; 3],
        }
    }

    /// Whether pixel i hit no surface and the renderer recorded what it saw (`FeatureSet::seen`).
    pub(crate) fn seen(&self, i: usize) -> bool {
        self.seen_at(i).is_some()
    }

    /// What pixel i saw, where it hit no surface and the renderer recorded it.
    #[inline]
    fn seen_at(&self, i: usize) -> Option<&'a [f32]> {
        self.seen
            .map(|s| &s[3 * i..3 * i + 3])
            .filter(|s| s.iter().any(|&v| v > 0.0))
    }

    /// Whether pixel i's samples hit a surface: a normal is known there (true without normals).
    pub(crate) fn hit(&self, i: usize) -> bool {
        self.normal
            .is_none_or(|n| n[3 * i..3 * i + 3].iter().any(|&v| v != 0.0))
    }

    /// A variance of pixel i's colour, demodulated.
    pub(crate) fn demodulate_variance(&self, i: usize, v: impl Iterator<Item = f64>) -> [f64; 3] {
        let s = self.scale(i);
        let mut out = [0.0; 3];
        for (k, v) in v.take(3).enumerate() {
            out[k] = v / (s[k] * s[k]);
        }
        out
    }
}

/// Sets `bit` of `out[t]` where pixels i0 + t and j0 + t lie on one surface (`same_key`), over
/// a run of pixels, so the tests run in vector lanes.
#[inline(always)]
fn same_key_run(planes: &[Vec<f32>; KEYS], i0: usize, j0: usize, bit: u32, out: &mut [u64]) {
    let n = out.len();
    let p: [&[f32]; KEYS] = std::array::from_fn(|k| &planes[k][i0..i0 + n]);
    let q: [&[f32]; KEYS] = std::array::from_fn(|k| &planes[k][j0..j0 + n]);
    for (x, b) in out.iter_mut().enumerate() {
        let mut a = [0.0f32; KEYS];
        let mut c = [0.0f32; KEYS];
        for k in 0..KEYS {
            a[k] = p[k][x];
            c[k] = q[k][x];
        }
        *b |= (same_key(&a, &c) as u64) << bit;
    }
}

/// Whether two pixels lie on one surface (their `Surface::planes`): albedo within
/// `ALBEDO_TOLERANCE` per channel, normals both unknown or both known and within `NORMAL_COS`,
/// depth within `DEPTH_TOLERANCE` of the larger. Symmetric in its arguments.
#[inline(always)]
fn same_key(p: &[f32; KEYS], q: &[f32; KEYS]) -> bool {
    // `|` and `&`, not `||` and `&&`: no branches, so runs of pixels are tested in vector lanes.
    let albedo = ((p[0] - q[0]).abs() > ALBEDO_TOLERANCE)
        | ((p[1] - q[1]).abs() > ALBEDO_TOLERANCE)
        | ((p[2] - q[2]).abs() > ALBEDO_TOLERANCE);
    let dot = p[3] * q[3] + p[4] * q[4] + p[5] * q[5];
    let known = p[7] != 0.0;
    // Two unknown normals (misses, or renderers without a normal) match.
    let normal = (known != (q[7] != 0.0)) | (known & (dot < NORMAL_COS));
    let (zi, zj) = (p[6], q[6]);
    let scale = zi.max(zj);
    let depth = (scale > 0.0) & ((zi - zj).abs() > DEPTH_TOLERANCE * scale);
    !(albedo | normal | depth)
}

/// Per pixel, a bit per cell of its (2·radius + 1)² window, in raster order: set when that pixel
/// is inside the image and on the same surface. Computed once, read by every window loop.
pub(crate) struct Mates {
    pub(crate) bits: Vec<u64>,
    pub(crate) side: usize,
    /// Pixel index offset of every bit's cell.
    offset: Vec<isize>,
}

impl Mates {
    fn new(w: usize, radius: usize) -> Self {
        Mates {
            bits: Vec::new(),
            side: 2 * radius + 1,
            offset: window_bits::offsets(w, radius),
        }
    }

    /// Pixel i's surface-mates, in raster order of its window.
    #[inline]
    pub(crate) fn of(&self, i: usize) -> impl Iterator<Item = usize> + '_ {
        let mut m = self.bits[i];
        std::iter::from_fn(move || {
            (m != 0).then(|| {
                let b = m.trailing_zeros();
                m &= m - 1;
                (i as isize + self.offset[b as usize]) as usize
            })
        })
    }
}

/// Neighbours of pixel (x, y) within `radius`, inside a `w`×`h` image, in raster order.
pub(super) fn window(
    x: usize,
    y: usize,
    w: usize,
    h: usize,
    radius: isize,
) -> impl Iterator<Item = usize> {
    let (x, y) = (x as isize, y as isize);
    let rows = (y - radius).max(0)..=(y + radius).min(h as isize - 1);
    rows.flat_map(move |ny| {
        let cols = (x - radius).max(0)..=(x + radius).min(w as isize - 1);
        cols.map(move |nx| ny as usize * w + nx as usize)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mates_are_the_pairwise_test_in_window_order() {
        // Taller than `window_bits`' bands of rows, so windows cross from one band to the next.
        let (w, h) = (13, 37);
        let mut set = FeatureSet::default();
        let albedo = Image::from_fn(
            w,
            h,
            3,
            |x, y, k| {
                if (x + 2 * y + k) % 5 < 2 {
                    0.8
                } else {
                    0.3
                }
            },
        );
        // Some unknown normals, and some too short to match themselves.
        let normal = Image::from_fn(w, h, 3, |x, y, k| match ((x * y) % 7, k) {
            (0, _) => 0.0,
            (3, 2) => 0.5,
            (_, 2) => 1.0,
            _ => 0.0,
        });
        let depth = Image::from_fn(w, h, 1, |x, _, _| 1.0 + (x / 4) as f32 * 0.2);
        set.set(Feature::Albedo, albedo).unwrap();
        set.set(Feature::Normal, normal).unwrap();
        set.set(Feature::Depth, depth).unwrap();
        let surface = Surface::new(&set, (w, h));
        let planes = surface.planes(0..h, w);
        let key = |i: usize| std::array::from_fn(|k| planes[k][i]);
        for radius in [1, 2, 3] {
            let mates = surface.mates(w, h, radius);
            for i in 0..w * h {
                let expected: Vec<usize> = window(i % w, i / w, w, h, radius as isize)
                    .filter(|&j| same_key(&key(i), &key(j)))
                    .collect();
                assert_eq!(
                    mates.of(i).collect::<Vec<_>>(),
                    expected,
                    "pixel {i}, radius {radius}"
                );
            }
        }
    }
}
