//! Per pixel, which cells of its (2r+1)² window pass a symmetric pairwise test ("on the same
//! surface"), one bit per cell in raster order: the noise estimate's and the blend's surface-mates,
//! the `feature` outlier rule's neighbours.
//!
//! The test is symmetric, so each pair is tested once: the forward half of every window (the cells
//! after the centre in raster order) over contiguous runs of pixels, cell by cell, which the test's
//! caller runs in vector lanes; the backward half is read from the neighbours' forward bits.

use std::ops::Range;

use rayon::prelude::*;

use crate::image::par_vec;
use crate::meter::Meter;

/// Largest radius whose window's cells fit the bits of a `u64` (7×7).
pub(crate) const MOST_RADIUS: usize = 3;

/// Rows per task of the forward half: each task builds what the test reads (`band`) for its own
/// rows and the window's reach below them, so no copy of the whole image's features is held.
const BAND_ROWS: usize = 16;

/// The pixel index offset of every bit's cell in a window of `radius` over an image `w` wide, bits
/// in raster order of the window: what a set bit of [`window_bits`] points at.
pub(crate) fn offsets(w: usize, radius: usize) -> Vec<isize> {
    let (r, side) = (radius as isize, 2 * radius + 1);
    (0..side * side)
        .map(|b| ((b / side) as isize - r) * w as isize + (b % side) as isize - r)
        .collect()
}

/// The bits of a `w`×`h` image's windows of `radius`. `band(rows)` gives what the test reads
/// for a range of rows; `forward(data, i0, j0, bit, out)` sets `bit` of `out[t]` where pixels
/// i0 + t and j0 + t pass the test (j0 the neighbour at that bit's cell), both indices counted
/// from the first of `data`'s rows; it must be symmetric to the bit. With `centre`, every
/// pixel's own bit is tested too (as the pair (i, i)). A cell outside the image is never set.
pub(crate) fn window_bits<T>(
    w: usize,
    h: usize,
    radius: usize,
    centre: bool,
    band: impl Fn(Range<usize>) -> T + Sync,
    forward: impl Fn(&T, usize, usize, u32, &mut [u64]) + Sync,
) -> Vec<u64> {
    window_bits_metered(w, h, radius, centre, band, forward, &Meter::default())
}

/// [`window_bits`] that skips its remaining bands and rows once `meter` is cancelled (the bits are
/// then unfinished, for the caller to throw away).
pub(crate) fn window_bits_metered<T>(
    w: usize,
    h: usize,
    radius: usize,
    centre: bool,
    band: impl Fn(Range<usize>) -> T + Sync,
    forward: impl Fn(&T, usize, usize, u32, &mut [u64]) + Sync,
    meter: &Meter,
) -> Vec<u64> {
    assert!(
        radius <= MOST_RADIUS,
        "a window of radius {radius} has more cells than a u64 has bits"
    );
    let (r, side) = (radius as isize, 2 * radius as isize + 1);
    let last = (side * side - 1) as u32;
    let cells = |ahead: bool| -> Vec<(u32, isize, isize)> {
        (0..side * side)
            .map(|b| (b as u32, b % side - r, b / side - r))
            .filter(|&(_, dx, dy)| (dx, dy) != (0, 0) || centre)
            .filter(|&(_, dx, dy)| (dy > 0 || (dy == 0 && dx >= 0)) == ahead)
            .collect()
    };
    let (ahead, behind) = (cells(true), cells(false));
    let row = w.max(1);
    let mut fwd = par_vec(0u64, w * h);
    meter.pass(h);
    fwd.par_chunks_mut(row * BAND_ROWS)
        .enumerate()
        .for_each(|(b, out)| {
            if meter.cancelled() {
                return;
            }
            let y0 = b * BAND_ROWS;
            let y1 = (y0 + BAND_ROWS).min(h);
            meter.rows(y1 - y0);
            // The forward half looks down by at most `radius` rows.
            let data = band(y0..(y1 + radius).min(h));
            let base = y0 * w;
            for (y, out) in (y0..y1).zip(out.chunks_mut(row)) {
                for &(bit, dx, dy) in &ahead {
                    if let Some((lo, hi, j0)) = run(w, h, y, dx, dy) {
                        forward(&data, y * w + lo - base, j0 - base, bit, &mut out[lo..hi]);
                    }
                }
            }
        });
    let mut bits = par_vec(0u64, w * h);
    meter.pass(h);
    bits.par_chunks_mut(row).enumerate().for_each(|(y, bits)| {
        if meter.cancelled() {
            return;
        }
        meter.rows(1);
        bits.copy_from_slice(&fwd[y * w..y * w + bits.len()]);
        for &(bit, dx, dy) in &behind {
            let Some((lo, hi, j0)) = run(w, h, y, dx, dy) else {
                continue;
            };
            for (b, &f) in bits[lo..hi].iter_mut().zip(&fwd[j0..j0 + hi - lo]) {
                *b |= (f >> (last - bit) & 1) << bit;
            }
        }
    });
    bits
}

/// For row `y` of a `w`×`h` image and cell (dx, dy): the columns whose neighbour is inside, and
/// that neighbour's index at the first of them.
fn run(w: usize, h: usize, y: usize, dx: isize, dy: isize) -> Option<(usize, usize, usize)> {
    let ny = y as isize + dy;
    let lo = (-dx).max(0) as usize;
    let hi = (w as isize - dx).clamp(0, w as isize) as usize;
    (ny >= 0 && (ny as usize) < h && lo < hi)
        .then(|| (lo, hi, (ny * w as isize + lo as isize + dx) as usize))
}
