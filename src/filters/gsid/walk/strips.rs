//! Denoising a strip of rows at a time, so that only two or three strips' features exist at once:
//! one queue of tasks (build a strip's features, denoise a band) that every pool thread takes from.

use std::ops::Range;
use std::sync::atomic::{AtomicU64, Ordering};

use super::band::{self, Band, BAND_ROWS};
use super::job::{FeatureBuilder, WalkJob};
use super::params::{WalkInput, WalkParams, WalkStats};
use crate::error::Result;
use crate::features::Features;
use crate::image::Image;
use crate::kernels::simd::Kernel;

/// Pixels per strip of [`denoise`]: their features take 8 MB, and two or three strips
/// are alive at a time. A budget in pixels, not rows, so that the memory is the same at every
/// width. (At 4 MP, strips of 16 MB made `full`'s peak 664–700 MB, of 8 MB 662–665 MB.)
const STRIP_PIXELS: usize = 1 << 17;

/// Rows per strip of [`denoise`] for an image `width` pixels wide.
pub(super) fn strip_rows(width: usize) -> usize {
    (STRIP_PIXELS / width.max(1)).max(1)
}

/// The strips of [`denoise`] for an image `h` rows high: (rows kept, rows computed).
fn strips(h: usize, params: &WalkParams, strip_rows: usize) -> Vec<(Range<usize>, Range<usize>)> {
    let Some(reach) = params.radius() else {
        return vec![(0..h, 0..h)];
    };
    (0..h)
        .step_by(strip_rows.max(1))
        .map(|y0| {
            let y1 = (y0 + strip_rows.max(1)).min(h);
            (y0..y1, y0.saturating_sub(reach)..(y1 + reach).min(h))
        })
        .collect()
}

/// The fast kernels a strip of `strip_rows` rows at a time, with features built per strip by
/// `features_for(rows)` (a [`Features`] whose row 0 is image row `rows.start`).
///
/// Why: features take 64 bytes a pixel, the largest per-pixel table of a run (268 MB at 4 MP).
/// Windowed walks reach at most the window radius from their start row, so each strip needs only
/// its rows' features plus that halo; walks start from the strip's own rows only. Keys use
/// whole-image pixel indices and nothing a walk can reach differs, so the result and the step
/// count are those of one whole-image run, bit for bit. Unbounded walks may reach any row: one
/// strip.
///
/// Strips do not end in a barrier: every thread takes the next task of one queue (build strip
/// s + 1's features, placed [`LOOKAHEAD`] bands into strip s, or denoise a band), so while one
/// thread builds the next strip the others finish this one. A strip's features are dropped when
/// its last band is done: two strips' features are alive at a time (more only if a band of an
/// older strip is still running when a build starts).
pub(super) fn denoise(
    job: &WalkJob,
    kernel: Kernel,
    features_for: &FeatureBuilder,
    strip_rows: usize,
) -> Result<(Image, WalkStats)> {
    let WalkJob {
        color,
        mask,
        seed,
        level,
        params,
        on_row,
        ..
    } = *job;
    let (w, h) = color.dims();
    let mut out = Image::new(w, h, 3);
    let strips = strips(h, params, strip_rows);
    let band = Band::new(kernel, params, None);
    if params.radius().is_none() || strips.len() <= 1 {
        // One strip (unbounded walks share one whole-image table): the plain parallel run.
        let features = features_for(0..h)?;
        let input = WalkInput {
            color,
            features: &features,
            mask,
            seed,
            level,
            origin: 0,
        };
        return Ok(band::denoise(kernel, &input, params, on_row));
    }

    // The queue: build strip 0, then each strip's bands with the next strip's build among them.
    let mut tasks = vec![Task::Build(0)];
    for (s, (kept, _)) in strips.iter().enumerate() {
        let ys: Vec<_> = kept.clone().step_by(BAND_ROWS).collect();
        for (b, &y) in ys.iter().enumerate() {
            if s + 1 < strips.len() && b == LOOKAHEAD.min(ys.len() - 1) {
                tasks.push(Task::Build(s + 1));
            }
            tasks.push(Task::Band(s, y..(y + BAND_ROWS).min(kept.end)));
        }
    }
    // Each band's output rows, by task index, handed to whichever thread takes the band.
    let mut rest = out.data_mut();
    let outputs: Vec<_> = tasks
        .iter()
        .map(|task| {
            let rows = match task {
                Task::Band(_, ys) => {
                    let (head, tail) = std::mem::take(&mut rest).split_at_mut(3 * w * ys.len());
                    rest = tail;
                    Some(head)
                }
                Task::Build(_) => None,
            };
            std::sync::Mutex::new(rows)
        })
        .collect();
    let slots: Vec<Slot> = strips
        .iter()
        .map(|(kept, _)| Slot {
            state: std::sync::Mutex::new(StripState::Pending),
            ready: std::sync::Condvar::new(),
            bands_left: std::sync::atomic::AtomicUsize::new(kept.len().div_ceil(BAND_ROWS)),
        })
        .collect();
    let next = std::sync::atomic::AtomicUsize::new(0);
    let steps = AtomicU64::new(0);
    let error = std::sync::Mutex::new(None);
    // One worker per pool thread. Broadcast jobs cannot be stolen, so a thread waiting inside a
    // build's parallel loop never starts a second worker that would wait on that same build.
    rayon::broadcast(|_| loop {
        let t = next.fetch_add(1, Ordering::Relaxed);
        let Some(task) = tasks.get(t) else { break };
        match task {
            Task::Build(s) => {
                let rows = strips[*s].1.clone();
                let state = match features_for(rows.clone()) {
                    Ok(features) => {
                        let color = Image::from_vec(
                            w,
                            rows.len(),
                            3,
                            color.data()[3 * w * rows.start..3 * w * rows.end].to_vec(),
                        )
                        .expect("a strip of a 3-channel image");
                        StripState::Ready(std::sync::Arc::new(StripData { features, color }))
                    }
                    Err(e) => {
                        error.lock().expect("no panic holding it").get_or_insert(e);
                        StripState::Gone
                    }
                };
                *slots[*s].state.lock().expect("no panic holding it") = state;
                slots[*s].ready.notify_all();
            }
            Task::Band(s, ys) => {
                let slot = &slots[*s];
                let data = {
                    let mut state = slot.state.lock().expect("no panic holding it");
                    loop {
                        match &*state {
                            StripState::Pending => {
                                state = slot.ready.wait(state).expect("no panic holding it")
                            }
                            StripState::Ready(data) => break Some(data.clone()),
                            StripState::Gone => break None,
                        }
                    }
                };
                let Some(data) = data else { continue };
                let rows = strips[*s].1.clone();
                let input = WalkInput {
                    color: &data.color,
                    features: &data.features,
                    mask: mask.map(|m| &m[w * rows.start..w * rows.end]),
                    seed,
                    level,
                    origin: w * rows.start,
                };
                let dest = outputs[t]
                    .lock()
                    .expect("no panic holding it")
                    .take()
                    .expect("each band is taken once");
                let local = ys.start - rows.start..ys.end - rows.start;
                let n = band.run(&input, params, local, dest, on_row);
                steps.fetch_add(n, Ordering::Relaxed);
                drop(data);
                if slot.bands_left.fetch_sub(1, Ordering::AcqRel) == 1 {
                    *slot.state.lock().expect("no panic holding it") = StripState::Gone;
                }
            }
        }
    });
    if let Some(e) = error.into_inner().expect("no panic holding it") {
        return Err(e);
    }
    let stats = WalkStats {
        walks: (w * h) as u64 * params.walks as u64,
        steps: steps.into_inner(),
    };
    Ok((out, stats))
}

/// Bands of a strip denoised before the next strip's features start building: time for older
/// strips' last bands to finish, so their features are gone before new ones are made.
const LOOKAHEAD: usize = 2;

/// A step of [`denoise`]'s queue.
enum Task {
    /// Build strip s's features.
    Build(usize),
    /// Denoise the start pixels of these image rows of strip s.
    Band(usize, Range<usize>),
}

/// What the bands of one strip read.
struct StripData {
    features: Features,
    color: Image,
}

/// Where a strip's features stand; bands of the strip wait on [`Slot::ready`] while `Pending`.
enum StripState {
    Pending,
    Ready(std::sync::Arc<StripData>),
    /// The build failed, or every band is done (the features are dropped).
    Gone,
}

/// One strip's shared state in [`denoise`]'s queue.
struct Slot {
    state: std::sync::Mutex<StripState>,
    ready: std::sync::Condvar,
    bands_left: std::sync::atomic::AtomicUsize,
}
