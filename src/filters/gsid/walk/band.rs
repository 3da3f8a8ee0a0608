//! A band of start rows: its tables built once ([`Near`], [`Pairs`], from one set of feature
//! planes), then every start pixel's walks, with the portable or the AVX2 kernel.

use std::ops::Range;
use std::sync::atomic::{AtomicU64, Ordering};

use rayon::prelude::*;

#[cfg(target_arch = "x86_64")]
use super::avx2;
use super::params::{inv_two_sigma2, WalkInput, WalkParams, WalkStats};
use super::scalar::{walk_unbounded, walk_windowed};
use super::step::Accum;
use super::tables::{Near, Pairs, Window, RUN_PAD};
use crate::image::Image;
use crate::kernels::simd::Kernel;

/// Start-pixel rows per parallel task: the band's neighbour terms (with a window-radius halo) stay
/// in cache and never exist for the whole image at once.
pub(super) const BAND_ROWS: usize = 16;

/// Window grid cells a batch of start pixels may take: large windows walk fewer start pixels per
/// batch (each walk's sums are its own, so the batch size does not change the result).
const BATCH_CELLS: usize = 1 << 18;

thread_local! {
    /// Each worker thread's scratch space. Thread-local rather than rayon's `for_each_init`, which
    /// makes a fresh one per work split: the band tables would be allocated (and page-faulted in)
    /// again for every band.
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// Per-thread scratch space, reused across start pixels, bands and runs.
#[derive(Default)]
struct Scratch {
    /// Window grids of a batch of start pixels, one after the other.
    grid: Vec<f32>,
    egrid: Vec<f32>,
    /// Per batch pixel: (grid cell of its centre, pixel index).
    starts: Vec<(usize, usize)>,
    /// Per pixel results of a batch.
    accs: Vec<Accum>,
    /// The AVX2 kernel's per-walk tables.
    #[cfg(target_arch = "x86_64")]
    walks: avx2::Walks,
    near: Near,
    pairs: Pairs,
}

/// The fast kernels on a whole image: parallel over bands of [`BAND_ROWS`] rows, neighbour terms
/// precomputed per band, window terms per start pixel. `on_row(n)` is told of every finished row (n = 1) and
/// asked before a band starts (n = 0); when it returns false (the run was cancelled) the remaining
/// rows are skipped.
pub(super) fn denoise(
    kernel: Kernel,
    input: &WalkInput,
    params: &WalkParams,
    on_row: &(dyn Fn(usize) -> bool + Sync),
) -> (Image, WalkStats) {
    let (w, h) = input.color.dims();
    let steps = AtomicU64::new(0);
    let mut out = Image::new(w, h, 3);
    // Unbounded walks may reach any row, so they share one whole-image table.
    let global = params.radius().is_none().then(|| {
        let mut near = Near::default();
        let planes = input.features.planes(0..h, RUN_PAD);
        near.compute(kernel, input, inv_two_sigma2(params.sigma), 0..h, &planes);
        near
    });
    let band = Band::new(kernel, params, global.as_ref());
    out.data_mut()
        .par_chunks_mut(3 * w.max(1) * BAND_ROWS)
        .enumerate()
        .for_each(|(b, rows)| {
            let y_begin = b * BAND_ROWS;
            let y_end = (y_begin + BAND_ROWS).min(h);
            let n = band.run(input, params, y_begin..y_end, rows, on_row);
            steps.fetch_add(n, Ordering::Relaxed);
        });
    let stats = WalkStats {
        walks: (w * h) as u64 * params.walks as u64,
        steps: steps.into_inner(),
    };
    (out, stats)
}

/// What every band of one kernel run shares.
pub(super) struct Band<'a> {
    kernel: Kernel,
    inv: f32,
    /// Window radius clipped to the step cap; `None` for unbounded walks.
    radius: Option<usize>,
    /// The whole-image neighbour table of unbounded walks.
    global: Option<&'a Near>,
}

impl<'a> Band<'a> {
    /// What the bands of one run with `params` share; `global` is the whole-image neighbour table,
    /// which unbounded walks need.
    pub(super) fn new(kernel: Kernel, params: &WalkParams, global: Option<&'a Near>) -> Self {
        Band {
            kernel,
            inv: inv_two_sigma2(params.sigma),
            radius: params.radius(),
            global,
        }
    }

    /// Denoises the start pixels of image rows `ys` into `rows` (3 floats a pixel, row `ys.start`
    /// first), with this thread's scratch tables; returns the steps taken.
    pub(super) fn run(
        &self,
        input: &WalkInput,
        params: &WalkParams,
        ys: Range<usize>,
        rows: &mut [f32],
        on_row: &(dyn Fn(usize) -> bool + Sync),
    ) -> u64 {
        let Band {
            kernel,
            inv,
            radius,
            global,
        } = *self;
        let (w, h) = input.color.dims();
        let (y_begin, y_end) = (ys.start, ys.end);
        if !on_row(0) {
            return 0;
        }
        SCRATCH.with_borrow_mut(|scratch| {
            let (near, pairs) = match radius {
                Some(r) => {
                    // The rows a walk from this band can reach.
                    let halo = y_begin.saturating_sub(r)..(y_end + r).min(h);
                    let with_pairs = Pairs::fits(w, r, y_begin..y_end);
                    // One transposition of the band's features serves both tables: the halo and
                    // the row above it (where `Near`'s backward pairs start), padded for `Pairs`.
                    let pad = if with_pairs { r + RUN_PAD } else { RUN_PAD };
                    let planes = input
                        .features
                        .planes(halo.start.saturating_sub(1)..halo.end, pad);
                    scratch.near.compute(kernel, input, inv, halo, &planes);
                    if with_pairs {
                        let band = y_begin..y_end;
                        scratch.pairs.compute(kernel, input, inv, r, band, &planes);
                    }
                    (&scratch.near, with_pairs.then_some(&scratch.pairs))
                }
                None => (
                    global.expect("built by `denoise` when there is no window"),
                    None,
                ),
            };
            let mut band_steps = 0u64;
            // The AVX2 kernel runs windowed walks on bands its 32-bit indices cover.
            #[cfg(target_arch = "x86_64")]
            let vector = kernel.avx2() && radius.is_some() && avx2::fits(near);
            #[cfg(not(target_arch = "x86_64"))]
            let vector = false;
            // Whether the AVX2 kernel weighs its steps in AVX-512 registers.
            #[cfg(target_arch = "x86_64")]
            let wide = kernel.or_portable() == Kernel::Avx512;
            // Start pixels whose walks share the AVX2 kernel's lanes.
            let cells = radius.map_or(0, |r| (2 * r + 3) * (2 * r + 3));
            let batch = match vector {
                #[cfg(target_arch = "x86_64")]
                true => avx2::batch(params.walks).min((BATCH_CELLS / cells).max(1)),
                _ => 1,
            };
            // Every grid's outer ring is −∞ / 0 from here on: no fill writes a ring cell.
            scratch.grid.clear();
            scratch.grid.resize(batch * cells, f32::NEG_INFINITY);
            scratch.egrid.clear();
            scratch.egrid.resize(batch * cells, 0.0);
            scratch.accs.resize(batch, Accum::default());
            for y0 in y_begin..y_end {
                let row = &mut rows[3 * w * (y0 - y_begin)..3 * w * (y0 - y_begin + 1)];
                for x_begin in (0..w).step_by(batch) {
                    let xs = x_begin..(x_begin + batch).min(w);
                    let n = match radius {
                        Some(r) => {
                            scratch.starts.clear();
                            Window::fill_run(
                                input,
                                inv,
                                &mut scratch.grid,
                                &mut scratch.egrid,
                                pairs,
                                r,
                                (xs.clone(), y0),
                                &mut scratch.starts,
                            );
                            match vector {
                                #[cfg(target_arch = "x86_64")]
                                // SAFETY: `vector` holds only if the CPU reported AVX2 above
                                // and `fits` holds for `near`; `wide` only if it reported
                                // AVX-512 (`or_portable`).
                                true => unsafe {
                                    avx2::walk_batch(
                                        input,
                                        params,
                                        near,
                                        avx2::Batch {
                                            grid: &scratch.grid,
                                            egrid: &scratch.egrid,
                                            side: 2 * r + 3,
                                            starts: &scratch.starts,
                                        },
                                        wide,
                                        &mut scratch.walks,
                                        &mut scratch.accs,
                                    )
                                },
                                _ => {
                                    let win = Window {
                                        grid: &scratch.grid[..cells],
                                        egrid: &scratch.egrid[..cells],
                                        side: 2 * r + 3,
                                        i0: y0 * w + xs.start,
                                    };
                                    let (acc, n) = walk_windowed(input, params, near, &win);
                                    scratch.accs[0] = acc;
                                    n
                                }
                            }
                        }
                        None => {
                            let (acc, n) = walk_unbounded(input, params, near, inv, xs.start, y0);
                            scratch.accs[0] = acc;
                            n
                        }
                    };
                    band_steps += n;
                    for (b, x0) in xs.enumerate() {
                        let i0 = y0 * w + x0;
                        scratch.accs[b].write(input.color.pixel(i0), &mut row[3 * x0..3 * x0 + 3]);
                    }
                }
                if !on_row(1) {
                    break;
                }
            }
            band_steps
        })
    }
}
