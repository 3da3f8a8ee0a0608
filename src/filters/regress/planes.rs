//! A band's inputs copied into padded f32 planes, one lane per quantity the window sums read, so
//! every tap of a window row reads one contiguous run with no bounds or validity test.

use super::params::{Inputs, Params, DEMODULATION_EPS, MAX_RADIUS};
use crate::image::Image;

/// Pixels of a row whose window sums are formed together, side by side: one AVX2 register of f32.
pub(super) const GROUP: usize = 8;

/// The group with AVX-512: one 512-bit register (the f64 sums are two, as AVX2's f32 group's are).
pub(super) const WIDE_GROUP: usize = 16;

/// Cells a window row's taps read for a group, at the largest radius and group: each lane's row
/// is taken as one array of this length, so no tap's load needs its own bounds check.
pub(super) const ROW: usize = 2 * MAX_RADIUS + WIDE_GROUP;

/// Floor under a pixel's noise variance in the weight's denominator, so a pixel read as
/// noise-free weighs only neighbours whose filtered colour equals its own (and never divides by 0).
const VARIANCE_FLOOR: f32 = 1e-12;

/// Lanes of a band's planes.
pub(super) const C: usize = 0; // clipped noisy colour, demodulated (3)
pub(super) const F: usize = 3; // filtered colour, demodulated (3)
pub(super) const V: usize = 6; // noise variance, demodulated, mean over channels
pub(super) const INV: usize = 7; // 1 / (2σ² v + floor)
pub(super) const A: usize = 8; // albedo (3)
pub(super) const N: usize = 11; // normal (3); NaN where VALID is 0
pub(super) const KNOWN: usize = 14; // 1 where the normal is known (non-zero), 0 where not; NaN where VALID is 0
pub(super) const VALID: usize = 15; // 1 inside the image with finite inputs, 0 in the margin
pub(super) const LANES: usize = 16;

/// A band's inputs as padded f32 planes: rows y0 − r .. y1 + r, columns −r .. w + r, zeros (and
/// VALID 0) outside the image, so every tap of a row reads one contiguous run.
pub(super) struct Planes {
    pub(super) lanes: Vec<Vec<f32>>,
    pub(super) stride: usize,
    radius: usize,
    /// The band's first output row (the planes' row `radius`).
    pub(super) first_row: usize,
}

impl Planes {
    /// Lanes of `rows` rows for an image `w` wide and a window of radius `r`, every cell as the
    /// margin's (zeros, NaN normals), and their stride.
    fn blank(w: usize, r: usize, rows: usize) -> (Vec<Vec<f32>>, usize) {
        let stride = w + 2 * r + 8;
        // Past the last row, room for a whole `ROW` read from any window row's first cell.
        let mut lanes = vec![vec![0.0f32; stride * rows + ROW]; LANES];
        // A cell that takes no part matches no pixel's normal: its NaNs fail both tests of
        // `window_sums`, so the kernel needs no VALID factor.
        for lane in &mut lanes[N..=KNOWN] {
            lane.fill(f32::NAN);
        }
        (lanes, stride)
    }

    pub(super) fn build(inputs: Inputs, p: &Params, y0: usize, y1: usize) -> Planes {
        let (w, h) = inputs.noisy.dims();
        let r = p.radius;
        let rows = y1 - y0 + 2 * r;
        let (mut lanes, stride) = Planes::blank(w, r, rows);
        let inv_scale = 2.0 * p.sigma * p.sigma;
        let demodulate = p.demodulate && inputs.albedo.is_some();
        // A missing albedo or normal reads as zeros: finite, so it passes the finiteness test as
        // when it is not tested, and a zero normal is unknown.
        let zeros = vec![0.0f32; 3 * w];
        fn row_of(img: &Image, i0: usize, w: usize) -> &[f32] {
            &img.data()[3 * i0..3 * (i0 + w)]
        }
        for row in 0..rows {
            let y = (y0 + row) as isize - r as isize;
            if y < 0 || y >= h as isize {
                continue;
            }
            let i0 = y as usize * w;
            let px = |img| row_of(img, i0, w);
            let (noisy, filtered, var) =
                (px(inputs.noisy), px(inputs.filtered), px(inputs.variance));
            let albedo = inputs.albedo.map_or(zeros.as_slice(), px);
            let normal = inputs.normal.map_or(zeros.as_slice(), px);
            let at = row * stride + r;
            let mut rows_out = lanes.iter_mut().map(|l| &mut l[at..at + w]);
            let out: [&mut [f32]; LANES] =
                std::array::from_fn(|_| rows_out.next().expect("LANES lanes"));
            // Every value is computed and then chosen by `finite`, with no branch: a pixel with
            // non-finite inputs keeps the margin's cell (zeros, NaN normals).
            for x in 0..w {
                let at3 = |s: &[f32]| -> [f32; 3] { [s[3 * x], s[3 * x + 1], s[3 * x + 2]] };
                let (nz, fl, vr, al, nm) = (
                    at3(noisy),
                    at3(filtered),
                    at3(var),
                    at3(albedo),
                    at3(normal),
                );
                let finite = nz
                    .iter()
                    .chain(&fl)
                    .chain(&vr)
                    .chain(&al)
                    .all(|v| v.is_finite());
                let pick = |v: f32| if finite { v } else { 0.0 };
                let mut v_mean = 0.0f32;
                for k in 0..3 {
                    let scale = if demodulate {
                        al[k].max(0.0) + DEMODULATION_EPS
                    } else {
                        1.0
                    };
                    let v = vr[k].max(0.0);
                    let limit = p.clip * v.sqrt();
                    // `clamp`'s own choices, written as selects.
                    let d = nz[k] - fl[k];
                    let d = if d < -limit { -limit } else { d };
                    let d = if d > limit { limit } else { d };
                    out[C + k][x] = pick((fl[k] + d) / scale);
                    out[F + k][x] = pick(fl[k] / scale);
                    out[A + k][x] = pick(al[k]);
                    v_mean += v / (scale * scale);
                }
                v_mean /= 3.0;
                let known = nm.iter().all(|v| v.is_finite()) & nm.iter().any(|&v| v != 0.0);
                out[V][x] = pick(v_mean);
                out[INV][x] = pick(1.0 / (inv_scale * v_mean + VARIANCE_FLOOR));
                for k in 0..3 {
                    let n = if known { nm[k] } else { 0.0 };
                    out[N + k][x] = if finite { n } else { f32::NAN };
                }
                let k = if known { 1.0 } else { 0.0 };
                out[KNOWN][x] = if finite { k } else { f32::NAN };
                out[VALID][x] = pick(1.0);
            }
        }
        Planes {
            lanes,
            stride,
            radius: r,
            first_row: y0,
        }
    }

    /// Index of the cell (dx, dy) from the band's row `row`, column 0.
    pub(super) fn offset(&self, dx: isize, row: usize, dy: isize) -> usize {
        let r = self.radius as isize;
        ((row as isize + r + dy) * self.stride as isize + r + dx) as usize
    }

    pub(super) fn lane(&self, lane: usize, offset: usize, n: usize) -> &[f32] {
        &self.lanes[lane][offset..offset + n]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A band's planes as the textbook builds them, pixel by pixel with branches: the cell of a
    /// pixel with a non-finite input is left as the margin's.
    fn textbook_planes(inputs: Inputs, p: &Params, y0: usize, y1: usize) -> Vec<Vec<f32>> {
        let (w, h) = inputs.noisy.dims();
        let r = p.radius;
        let rows = y1 - y0 + 2 * r;
        let (mut lanes, stride) = Planes::blank(w, r, rows);
        for row in 0..rows {
            let y = (y0 + row) as isize - r as isize;
            if y < 0 || y >= h as isize {
                continue;
            }
            for x in 0..w {
                let (i, cell) = (y as usize * w + x, row * stride + x + r);
                let (noisy, filtered) = (inputs.noisy.pixel(i), inputs.filtered.pixel(i));
                let var = inputs.variance.pixel(i);
                let albedo = inputs.albedo.map(|a| a.pixel(i));
                let all = noisy.iter().chain(filtered).chain(var);
                if !all.chain(albedo.unwrap_or_default()).all(|v| v.is_finite()) {
                    continue;
                }
                let mut v_mean = 0.0f32;
                for k in 0..3 {
                    let scale = match albedo {
                        Some(a) if p.demodulate => a[k].max(0.0) + DEMODULATION_EPS,
                        _ => 1.0,
                    };
                    let v = var[k].max(0.0);
                    let limit = p.clip * v.sqrt();
                    let clipped = filtered[k] + (noisy[k] - filtered[k]).clamp(-limit, limit);
                    lanes[C + k][cell] = clipped / scale;
                    lanes[F + k][cell] = filtered[k] / scale;
                    v_mean += v / (scale * scale);
                    lanes[A + k][cell] = albedo.map_or(0.0, |a| a[k]);
                }
                v_mean /= 3.0;
                lanes[V][cell] = v_mean;
                lanes[INV][cell] = 1.0 / (2.0 * p.sigma * p.sigma * v_mean + VARIANCE_FLOOR);
                let normal = inputs
                    .normal
                    .map(|n| n.pixel(i))
                    .filter(|n| n.iter().all(|v| v.is_finite()) && n.iter().any(|&v| v != 0.0));
                for k in 0..3 {
                    lanes[N + k][cell] = normal.map_or(0.0, |n| n[k]);
                }
                lanes[KNOWN][cell] = if normal.is_some() { 1.0 } else { 0.0 };
                lanes[VALID][cell] = 1.0;
            }
        }
        lanes
    }

    #[test]
    fn planes_are_the_textbook_cells_bit_for_bit_with_bad_inputs() {
        // Random inputs with NaN, ±∞, negative variances, zero normals and black albedo in every
        // buffer; with and without albedo and normals, demodulated or not; bands at both edges.
        let mut next = crate::kernels::trim::tests::xorshift(7);
        let (w, h) = (23, 29);
        let mut value = |scale: f32| {
            let r = next();
            match r % 23 {
                0 => f32::NAN,
                1 => f32::INFINITY,
                2 => f32::NEG_INFINITY,
                3 => 0.0,
                4 => -scale * (r >> 40) as f32 / (1u64 << 24) as f32,
                _ => scale * (r >> 40) as f32 / (1u64 << 24) as f32,
            }
        };
        let mut image = |scale: f32| Image::from_fn(w, h, 3, |_, _, _| value(scale));
        let (noisy, filtered, variance) = (image(2.0), image(2.0), image(0.1));
        let (albedo, normal) = (image(1.0), image(1.0));
        for (with_features, demodulate, (y0, y1)) in [
            (true, true, (0, 8)),
            (true, false, (8, 16)),
            (false, true, (21, 29)),
            (false, false, (0, 29)),
        ] {
            let inputs = Inputs {
                noisy: &noisy,
                filtered: &filtered,
                variance: &variance,
                albedo: with_features.then_some(&albedo),
                normal: with_features.then_some(&normal),
            };
            let p = Params {
                demodulate,
                radius: 3,
                ..Params::default()
            };
            let planes = Planes::build(inputs, &p, y0, y1);
            let textbook = textbook_planes(inputs, &p, y0, y1);
            for (l, (got, want)) in planes.lanes.iter().zip(&textbook).enumerate() {
                for (cell, (g, t)) in got.iter().zip(want).enumerate() {
                    assert_eq!(
                        g.to_bits(),
                        t.to_bits(),
                        "lane {l}, cell {cell}: {g} vs {t}"
                    );
                }
            }
        }
    }
}
