//! The weighted per-pixel merge of the window (docs/ALGORITHM.md "Temporal merge"): each
//! neighbour's reprojected sample counts by how well its 3×3 neighbourhood agrees with the centre
//! frame's: colour patch by patch against the frame's estimated noise, albedo, normal and depth by
//! their 3×3 means against the windows' spread (so noise is accepted and a disocclusion, a moving
//! shadow or reflection is not). The centre frame
//! always counts fully, so a pixel no neighbour matches keeps its own value. Sums run in f64 in a
//! fixed order per pixel: the same bits on any thread count.

use rayon::prelude::*;

use super::reproject::{bilinear, nearest, window, MAX_CHANNELS};
use super::variance::{pooled, Spread, Sums};
use crate::image::Image;
use crate::render_set::{Feature, RenderSet};

/// A difference of 3×3 means below this many standard errors (squared) is taken for noise…
const ACCEPT: f64 = 4.0;
/// …and above this many it rejects the sample; weights fall linearly between.
const REJECT: f64 = 16.0;
/// Variance of a 3×3 mean relative to the window's spread: 1/9 for independent pixels, more
/// because a renderer's pixel filter correlates neighbours.
const MEAN_SPREAD: f64 = 2.0 / 9.0;

/// Differences every buffer tolerates beyond its noise (sub-pixel misalignment, slow change):
/// a fraction of the centre's level plus an absolute floor.
fn tolerance(buffer: Option<Feature>, level: f64) -> f64 {
    match buffer {
        None => 0.02 * level + 1e-6,
        Some(Feature::Albedo) => 0.03 + 0.05 * level,
        Some(Feature::Normal) => 0.1,
        Some(Feature::Depth) => 0.02 * level + 1e-6,
        Some(_) => 0.05 + 0.05 * level,
    }
}

/// Weight of a squared difference `r` in units of its noise: 1 up to `accept`, 0 from `reject`,
/// linear between.
fn ramp(r: f64, accept: f64, reject: f64) -> f64 {
    if r <= accept {
        1.0
    } else if r >= reject {
        0.0
    } else {
        (reject - r) / (reject - accept)
    }
}

/// 3×3 mean and spread per channel (`reproject::window`).
type Stats = ([f64; MAX_CHANNELS], [f64; MAX_CHANNELS]);

/// The agreement of a `c`-channel buffer between the centre pixel, whose 3×3 statistics are
/// `(m0, v0)`, and a neighbour's pixel `there`.
fn agreement(
    (m0, v0): &Stats,
    c: usize,
    other: &Image,
    there: (usize, usize),
    buffer: Option<Feature>,
) -> f64 {
    let (m1, v1) = window(other, there);
    let level = m0[..c].iter().fold(0.0f64, |a, v| a.max(v.abs()));
    let floor = tolerance(buffer, level);
    let (mut diff, mut noise) = (0.0, 0.0);
    for k in 0..c {
        diff += (m1[k] - m0[k]).powi(2);
        // The smaller spread: a window that straddles an edge or a highlight the other lacks
        // measures structure, not noise, and must not make a different surface look alike.
        noise += 2.0 * v0[k].min(v1[k]) * MEAN_SPREAD + floor * floor;
    }
    ramp(diff / noise, ACCEPT, REJECT)
}

/// Most a 3×3 colour patch may differ from the centre's, in units of its expected noise
/// (1 for pure noise), before its weight falls…
const PATCH_ACCEPT: f64 = 2.0;
/// …and where it reaches zero.
const PATCH_REJECT: f64 = 4.0;

/// Most pixels of a patch left out of the colour test where nothing moved: a spike from each of
/// the two frames compared.
const STILL_SPIKES: usize = 2;

/// One pixel of a patch comparison: its squared difference and what noise explains of it.
#[derive(Clone, Copy, Default)]
struct Cell {
    diff: f64,
    expected: f64,
}

/// Colour agreement of the 3×3 patches around the centre pixel `at` and the neighbour's `there`,
/// pixel by pixel against twice the centre's estimated noise (`noise`: the variance of one pixel,
/// from the image): a patch whose structure moved unlike its motion pass (a reflection, a shadow)
/// differs by more than noise even where the surface is textured. `still`: the neighbour's sample
/// is this pixel itself (nothing moved), and the patch's most different pixels are left out.
fn patch_agreement(
    centre: &Image,
    noise: &Image,
    (x, y): (usize, usize),
    other: &Image,
    (u, v): (usize, usize),
    still: bool,
) -> f64 {
    let (w, h) = centre.dims();
    let (ow, oh) = other.dims();
    let mut cells = [Cell::default(); 9];
    let mut n = 0;
    for dy in -1isize..=1 {
        for dx in -1isize..=1 {
            let (cx, cy) = (x as isize + dx, y as isize + dy);
            let (nx, ny) = (u as isize + dx, v as isize + dy);
            if cx < 0 || cy < 0 || nx < 0 || ny < 0 {
                continue;
            }
            let (cx, cy, nx, ny) = (cx as usize, cy as usize, nx as usize, ny as usize);
            if cx >= w || cy >= h || nx >= ow || ny >= oh {
                continue;
            }
            let a = centre.at(cx, cy);
            let b = other.at(nx, ny);
            let s = noise.at(cx, cy);
            let cell = &mut cells[n];
            for k in 0..3 {
                let floor = 0.02 * (a[k] as f64).abs() + 1e-6;
                cell.diff += (a[k] as f64 - b[k] as f64).powi(2);
                cell.expected += 2.0 * (s[k] as f64).max(0.0) + floor * floor;
            }
            n += 1;
        }
    }
    // Where nothing moved (the neighbour's sample is this very pixel), the patch's most different
    // pixels are left out, as long as five remain: a lone spike in either frame (a rare bright
    // path, the heavy tail of a glossy highlight's noise) is noise of one pixel, and the two frames
    // compared may each carry one; structure that changed spans more of the patch. Where the
    // surface moved, a one-pixel difference may be a highlight that moved unlike it.
    if still {
        let ratio = |c: &Cell| c.diff / c.expected.max(f64::MIN_POSITIVE);
        for _ in 0..STILL_SPIKES {
            if n < 5 {
                break;
            }
            let worst = (0..n)
                .max_by(|&a, &b| ratio(&cells[a]).total_cmp(&ratio(&cells[b])))
                .expect("cells");
            cells.swap(worst, n - 1);
            n -= 1;
        }
    }
    let (diff, expected) = cells[..n]
        .iter()
        .fold((0.0, 0.0), |(d, e), c| (d + c.diff, e + c.expected));
    if expected <= 0.0 {
        return 1.0;
    }
    ramp(diff / expected, PATCH_ACCEPT, PATCH_REJECT)
}

/// How far above the frame's typical noise (relative to brightness) a pixel's estimate may lie.
const NOISE_CAP: f64 = 16.0;

/// The variance of one pixel of `color`, from the image (the noise stage's estimate), capped at
/// [`NOISE_CAP`] times the frame's median noise relative to the local brightness. Why: the
/// estimate takes a mirror's sharp reflection for noise, and a reflection that moved unlike its
/// surface's motion pass would then pass for noise too (and, where no neighbour is taken, the
/// merged pixel's variance would claim noise that is not there).
fn capped_noise(color: &Image, features: &crate::render_set::FeatureSet) -> Image {
    let mut noise = crate::filters::noise::estimate(color, features);
    let (w, h) = color.dims();
    let levels: Vec<f64> = (0..w * h)
        .map(|i| {
            let (m, _) = window(color, (i % w, i / w));
            (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]) / 3.0 + 1e-4
        })
        .collect();
    let mut ratios: Vec<f64> = (0..w * h)
        .map(|i| {
            let s = noise.pixel(i);
            let v = (s[0] + s[1] + s[2]) as f64 / 3.0;
            v / levels[i]
        })
        .filter(|r| r.is_finite())
        .collect();
    if ratios.is_empty() {
        return noise;
    }
    ratios.sort_unstable_by(f64::total_cmp);
    let median = ratios[ratios.len() / 2];
    for (px, level) in noise.data_mut().chunks_exact_mut(3).zip(&levels) {
        let cap = (NOISE_CAP * median * level) as f32;
        px.iter_mut().for_each(|v| *v = v.min(cap));
    }
    noise
}

/// The merged frame: colour and features as weighted means over the window, and what each
/// frame contributed.
pub struct Merged {
    pub set: RenderSet,
    /// Mean weight of each window frame over the image (the centre's is 1, a missing frame's 0).
    pub weights: Vec<f64>,
}

/// Merges the window `frames` (in frame order, `None` where missing) at the centre frame's
/// pixels; `tracks` gives each frame's positions of those pixels (`None`: unreachable). The result
/// carries the variance of each pixel's merged mean, measured from the spread of the samples it and
/// its surface-mates took (`variance`; the centre's capped noise estimate where they took none).
pub fn merge(
    frames: &[Option<&RenderSet>],
    tracks: &[Option<Vec<[f32; 2]>>],
    centre: usize,
) -> Merged {
    let base = frames[centre].expect("the centre frame is present");
    let (w, h) = base.dims();
    // Buffers merged: colour, then the centre's features, each with its channel count.
    let features: Vec<(Feature, usize)> = base
        .features
        .iter()
        .map(|(f, img)| (f, img.channels()))
        .collect();
    // The weighted means (colour, features).
    let means = 3 + features.iter().map(|(_, c)| c).sum::<usize>();
    let width = means;
    let used: Vec<(usize, &RenderSet, &[[f32; 2]])> = frames
        .iter()
        .zip(tracks)
        .enumerate()
        .filter_map(|(j, (f, t))| Some((j, (*f)?, t.as_deref()?)))
        .collect();
    let noise = capped_noise(&base.color, &base.features);
    let mut out = vec![0.0f32; w * h * width];
    let mut spreads = vec![Spread::default(); w * h];
    let row_weights: Vec<Vec<f64>> = out
        .par_chunks_mut(w * width)
        .zip(spreads.par_chunks_mut(w))
        .enumerate()
        .map(|(y, (row, row_spreads))| {
            let mut totals = vec![0.0f64; frames.len()];
            let mut sums = vec![0.0f64; means];
            for x in 0..w {
                let px = &mut row[x * width..(x + 1) * width];
                row_spreads[x] = merge_pixel(
                    base,
                    &noise,
                    &features,
                    &used,
                    centre,
                    (x, y),
                    px,
                    &mut sums,
                    &mut totals,
                );
            }
            totals
        })
        .collect();
    let mut weights = vec![0.0f64; frames.len()];
    for row in &row_weights {
        for (t, r) in weights.iter_mut().zip(row) {
            *t += r;
        }
    }
    weights.iter_mut().for_each(|t| *t /= (w * h) as f64);
    let plane = |offset: usize, c: usize| {
        let data = out
            .chunks_exact(width)
            .flat_map(|px| px[offset..offset + c].iter().copied())
            .collect();
        Image::from_vec(w, h, c, data).expect("a plane of the merged frame")
    };
    let mut set = RenderSet::new(plane(0, 3));
    let mut offset = 3;
    for &(f, c) in &features {
        set.features
            .set(f, plane(offset, c))
            .expect("a feature keeps its channel count");
        offset += c;
    }
    set.noise.variance = Some(pooled(&spreads, &base.features, &noise));
    set.noise.from_stack = true;
    // Any neighbour read between pixels softens the merged edges (bilinear taps).
    set.noise.resampled = used.iter().any(|&(j, _, track)| {
        j != centre
            && track
                .iter()
                .any(|p| p.iter().all(|v| v.is_finite()) && p.iter().any(|v| v.fract() != 0.0))
    });
    Merged { set, weights }
}

/// One output pixel: the weighted means into `px`, each frame's weight added to `totals`, and the
/// spread of its colour samples returned; `sums` is the row's scratch, one slot a mean.
#[allow(clippy::too_many_arguments)]
fn merge_pixel(
    base: &RenderSet,
    noise: &Image,
    features: &[(Feature, usize)],
    used: &[(usize, &RenderSet, &[[f32; 2]])],
    centre: usize,
    (x, y): (usize, usize),
    px: &mut [f32],
    sums: &mut [f64],
    totals: &mut [f64],
) -> Spread {
    let w = base.dims().0;
    let i = y * w + x;
    sums.fill(0.0);
    // The centre's 3×3 statistics of each feature, read once for all neighbours.
    let centre_stats: Vec<Option<Stats>> = features
        .iter()
        .map(|&(f, _)| base.features.get(f).map(|a| window(a, (x, y))))
        .collect();
    let mut colour = Sums::default();
    let mut sample = [0.0f64; MAX_CHANNELS];
    for &(j, set, track) in used {
        let pos = track[i];
        let weight = if j == centre {
            1.0
        } else {
            let Some(there) = nearest(&set.color, pos) else {
                continue;
            };
            let still = pos == [x as f32, y as f32];
            let mut wt = patch_agreement(&base.color, noise, (x, y), &set.color, there, still);
            for (&(f, c), stats) in features.iter().zip(&centre_stats) {
                if wt <= 0.0 {
                    break;
                }
                if let (Some(stats), Some(b)) = (stats, set.features.get(f)) {
                    wt *= agreement(stats, c, b, there, Some(f));
                }
            }
            wt
        };
        if weight <= 0.0 {
            continue;
        }
        totals[j] += weight;
        let kept = bilinear(&set.color, pos, &mut sample);
        colour.add(weight, kept, &sample);
        for k in 0..3 {
            sums[k] += weight * sample[k];
        }
        let mut offset = 3;
        for &(f, c) in features {
            // A neighbour without the feature lends the centre's value, so the mean stays whole.
            let img = set
                .features
                .get(f)
                .or(base.features.get(f))
                .expect("present");
            let at = if set.features.contains(f) {
                pos
            } else {
                [x as f32, y as f32]
            };
            bilinear(img, at, &mut sample);
            for k in 0..c {
                sums[offset + k] += weight * sample[k];
            }
            offset += c;
        }
    }
    for (p, &sum) in px.iter_mut().zip(sums.iter()) {
        *p = (sum / colour.w) as f32;
    }
    colour.spread()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(value: impl Fn(usize, usize) -> f32, albedo: f32) -> RenderSet {
        RenderSet::new(Image::from_fn(8, 8, 3, |x, y, _| value(x, y)))
            .with(Feature::Albedo, Image::filled(8, 8, 3, albedo))
            .unwrap()
    }

    fn still(n: usize) -> Vec<Option<Vec<[f32; 2]>>> {
        let id: Vec<[f32; 2]> = (0..64).map(|i| [(i % 8) as f32, (i / 8) as f32]).collect();
        vec![Some(id); n]
    }

    #[test]
    fn agreeing_frames_average_and_a_different_surface_is_left_out() {
        let noisy = |k: usize| {
            move |x: usize, y: usize| 0.5 + 0.01 * (((x * 7 + y * 3 + k) % 5) as f32 - 2.0)
        };
        let (a, b, c) = (
            frame(noisy(0), 0.5),
            frame(noisy(1), 0.5),
            frame(noisy(2), 0.5),
        );
        let merged = merge(&[Some(&a), Some(&b), Some(&c)], &still(3), 1);
        assert!(
            merged.weights.iter().all(|&w| w > 0.99),
            "{:?}",
            merged.weights
        );
        let want = (a.color.at(3, 3)[0] + b.color.at(3, 3)[0] + c.color.at(3, 3)[0]) as f64 / 3.0;
        assert!((merged.set.color.at(3, 3)[0] as f64 - want).abs() < 1e-6);
        assert!(merged.set.noise.variance.unwrap().all_finite());
        let other = frame(noisy(1), 0.9);
        let merged = merge(&[Some(&a), Some(&other), Some(&c)], &still(3), 1);
        assert_eq!(merged.weights[0], 0.0);
        assert_eq!(merged.set.color, other.color);
    }

    /// `n` frames of one flat surface of albedo 0.5, `size`² pixels, each with its own uniform
    /// noise of half-width `h` per channel (variance h²/3) about `level(frame, x, y)`.
    fn noisy_stack(
        n: usize,
        size: usize,
        h: f64,
        level: impl Fn(usize, usize, usize) -> f64,
    ) -> Vec<RenderSet> {
        (0..n)
            .map(|k| {
                let noise = |x: usize, y: usize, c: usize| {
                    let key = (((k * size + y) * size + x) * 3 + c) as u64;
                    let u =
                        (crate::render::integrator::mix(key) >> 11) as f64 / (1u64 << 53) as f64;
                    (level(k, x, y) + h * (2.0 * u - 1.0)) as f32
                };
                RenderSet::new(Image::from_fn(size, size, 3, noise))
                    .with(Feature::Albedo, Image::filled(size, size, 3, 0.5))
                    .unwrap()
            })
            .collect()
    }

    fn merge_still(frames: &[RenderSet]) -> Merged {
        let refs: Vec<Option<&RenderSet>> = frames.iter().map(Some).collect();
        let (w, _) = frames[0].dims();
        let id: Vec<[f32; 2]> = (0..w * w)
            .map(|i| [(i % w) as f32, (i / w) as f32])
            .collect();
        merge(&refs, &vec![Some(id); frames.len()], frames.len() / 2)
    }

    /// Mean over the channels of the merged variance, per pixel.
    fn variances(merged: &Merged) -> Vec<f64> {
        let v = merged.set.noise.variance.as_ref().unwrap();
        let (w, h) = v.dims();
        (0..w * h)
            .map(|i| v.pixel(i).iter().map(|&v| v as f64).sum::<f64>() / 3.0)
            .collect()
    }

    #[test]
    fn a_stack_read_between_pixels_says_so_and_a_whole_pixel_one_does_not() {
        let frames = noisy_stack(3, 8, 0.1, |_, _, _| 0.5);
        assert!(!merge_still(&frames).set.noise.resampled);
        let refs: Vec<Option<&RenderSet>> = frames.iter().map(Some).collect();
        let moved = |dx: f32| -> Vec<[f32; 2]> {
            (0..64)
                .map(|i| [(i % 8) as f32 + dx, (i / 8) as f32])
                .collect()
        };
        let tracks = |dx| vec![Some(moved(dx)), Some(moved(0.0)), Some(moved(dx))];
        // One pixel over: whole-pixel reads, edges as sharp as the frame's own.
        assert!(!merge(&refs, &tracks(1.0), 1).set.noise.resampled);
        assert!(merge(&refs, &tracks(0.5), 1).set.noise.resampled);
    }

    #[test]
    fn a_static_stack_of_known_noise_has_that_noise_over_n_measured_over_the_surface() {
        // Five frames of one flat surface: the merged mean's variance is a fifth of h²/3.
        let (n, size, h) = (5usize, 32usize, 0.1f64);
        let want = h * h / 3.0 / n as f64;
        let merged = merge_still(&noisy_stack(n, size, h, |_, _, _| 0.5));
        assert!(
            merged.weights.iter().all(|&w| w > 0.95),
            "{:?}",
            merged.weights
        );
        let per_pixel = variances(&merged);
        let mean = per_pixel.iter().sum::<f64>() / per_pixel.len() as f64;
        assert!((mean / want - 1.0).abs() < 0.1, "mean {mean}, want {want}");
        // Pooled over the surface, not each pixel's own four degrees of freedom: nearly every
        // pixel is close to the truth.
        let close = per_pixel
            .iter()
            .filter(|&&v| (v / want - 1.0).abs() < 0.35)
            .count();
        assert!(
            close as f64 >= 0.95 * per_pixel.len() as f64,
            "{close} of {} pixels within 35 %",
            per_pixel.len()
        );
    }

    #[test]
    fn a_ghost_is_left_out_and_adds_nothing_to_the_measured_noise() {
        // A shadow over an 8×8 block of the same surface in every frame but the centre one.
        let (n, size, h) = (5usize, 32usize, 0.1f64);
        let shadow = |k: usize, x: usize, y: usize| {
            let inside = (12..20).contains(&x) && (12..20).contains(&y);
            if k != 2 && inside {
                0.1
            } else {
                0.5
            }
        };
        let frames = noisy_stack(n, size, h, shadow);
        let merged = merge_still(&frames);
        let centre = &frames[2].color;
        let per_pixel = variances(&merged);
        let one_frame = h * h / 3.0;
        for y in 14..18 {
            for x in 14..18 {
                assert_eq!(merged.set.color.at(x, y), centre.at(x, y), "({x}, {y})");
                // Its own value only: one frame's noise, not the shadow's depth.
                let v = per_pixel[y * size + x];
                assert!((v / one_frame - 1.0).abs() < 0.5, "({x}, {y}): {v}");
            }
        }
    }

    #[test]
    fn lone_spikes_in_a_still_stack_do_not_shut_out_the_other_frames() {
        // A rare bright path in the centre frame at (8, 8) and in the next frame at (9, 8), on a
        // flat surface: noise of one pixel each, so every frame still counts at both and around.
        let (n, size, h) = (5usize, 16usize, 0.02f64);
        let mut frames = noisy_stack(n, size, h, |_, _, _| 0.5);
        frames[2].color.pixel_mut(8 * size + 8).fill(5.0);
        frames[3].color.pixel_mut(8 * size + 9).fill(5.0);
        let merged = merge_still(&frames);
        // (8, 8): its own spike; (8, 9): both spikes in its patch against the next frame.
        for (x, y) in [(8, 8), (9, 8), (8, 9)] {
            let mean = frames
                .iter()
                .map(|f| f.color.at(x, y)[0] as f64)
                .sum::<f64>()
                / n as f64;
            let got = merged.set.color.at(x, y)[0] as f64;
            assert!(
                (got - mean).abs() < 1e-4,
                "({x}, {y}): {got}, the frames' mean {mean}"
            );
        }
    }

    #[test]
    fn a_lone_spike_where_the_surface_moved_still_keeps_its_own_frame() {
        // The same spike on a surface that moves a pixel a frame: there a one-pixel difference
        // may be a highlight that moved unlike its surface, so no neighbour is taken at it.
        let (n, size, h) = (5usize, 16usize, 0.02f64);
        let mut frames = noisy_stack(n, size, h, |_, _, _| 0.5);
        frames[2].color.pixel_mut(8 * size + 8).fill(5.0);
        let refs: Vec<Option<&RenderSet>> = frames.iter().map(Some).collect();
        let tracks: Vec<Option<Vec<[f32; 2]>>> = (0..n)
            .map(|k| {
                let shift = k as f32 - 2.0;
                let at = |i: usize| [(i % size) as f32 + shift, (i / size) as f32];
                Some((0..size * size).map(at).collect())
            })
            .collect();
        let merged = merge(&refs, &tracks, 2);
        assert_eq!(merged.set.color.at(8, 8), frames[2].color.at(8, 8));
    }

    #[test]
    fn a_missing_or_unreachable_frame_adds_nothing() {
        let a = frame(|_, _| 0.3, 0.5);
        let b = frame(|_, _| 0.7, 0.5);
        let mut tracks = still(3);
        tracks[2] = None;
        let merged = merge(&[None, Some(&a), Some(&b)], &tracks, 1);
        assert_eq!(merged.weights, [0.0, 1.0, 0.0]);
        assert_eq!(merged.set.color, a.color);
    }
}
