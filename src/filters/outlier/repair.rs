//! What is done to the flagged pixels: the colour of a same-surface neighbour's weighted median,
//! a clamp to the detection limit, or nothing (the mask only).

use rayon::prelude::*;

use super::neighbourhood::{luminance_image, window};
use super::params::{Action, DetectParams, Detection, Guides};
use crate::image::Image;

/// Repairs the flagged pixels of `color` by `action`; returns the new colour image.
///
/// `median` takes the colour of the neighbour (radius `radius`, at least 1) whose luminance is the
/// weighted median of the non-outlier neighbours, each weighted by feature similarity
/// exp(−½(Δalbedo/albedo_tol)² − ½(Δnormal/normal_tol)²): a real pixel's colour, from the same
/// surface when there is one. Without non-outlier neighbours it falls back to `clamp`.
pub fn repair(
    color: &Image,
    detection: &Detection,
    guides: &Guides,
    params: &DetectParams,
    action: Action,
) -> Image {
    let mut out = color.par_clone();
    if action == Action::Mask {
        return out;
    }
    let (w, h) = color.dims();
    let r = params.radius.max(1);
    let lum = luminance_image(color);
    let src = color.data();
    out.data_mut()
        .par_chunks_mut(3 * w.max(1))
        .enumerate()
        .for_each_init(Vec::new, |cand: &mut Vec<(f32, f32, usize)>, (y, row)| {
            for (x, px) in row.chunks_exact_mut(3).enumerate() {
                let i = y * w + x;
                if !detection.mask[i] {
                    continue;
                }
                if action == Action::Median {
                    cand.clear();
                    cand.extend(
                        window(x, y, r, w, h)
                            .filter(|&j| !detection.mask[j])
                            .map(|j| (lum[j], likeness(guides, params, i, j), j)),
                    );
                    if !cand.is_empty() {
                        cand.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.2.cmp(&b.2)));
                        let half = 0.5 * cand.iter().map(|c| c.1).sum::<f32>();
                        let mut acc = 0.0;
                        let mut pick = cand[cand.len() - 1].2;
                        for c in cand.iter() {
                            acc += c.1;
                            if acc >= half {
                                pick = c.2;
                                break;
                            }
                        }
                        px.copy_from_slice(&src[3 * pick..3 * pick + 3]);
                        continue;
                    }
                }
                let l = lum[i];
                if l < detection.low[i] {
                    raise(
                        px,
                        l,
                        detection.low[i],
                        i,
                        (x, y),
                        (w, h),
                        src,
                        &lum,
                        detection,
                        guides,
                        params,
                    );
                    continue;
                }
                let scale = if l > 0.0 {
                    (detection.limit[i] / l).clamp(0.0, 1.0)
                } else {
                    1.0
                };
                for v in px.iter_mut() {
                    *v *= scale;
                }
            }
        });
    out
}

/// How much neighbour j shares pixel i's surface: exp(−½(Δalbedo/albedo_tol)² −
/// ½(Δnormal/normal_tol)²), floored so a pixel on its own surface still reads its neighbours.
fn likeness(guides: &Guides, params: &DetectParams, i: usize, j: usize) -> f32 {
    let (da, dn) = guides.distances(i, j);
    let za = da / params.albedo_tol.max(1e-6);
    let zn = dn / params.normal_tol.max(1e-6);
    (-0.5 * (za * za + zn * zn)).exp().max(1e-6)
}

/// Raises a dark dot `px` (pixel i at (x, y), luminance `l`) to luminance `low` by adding a share
/// of its unflagged neighbours' colour, each weighted by feature similarity as the median's: a
/// black pixel has no hue of its own to scale, and its surface's is the one it lacks.
#[allow(clippy::too_many_arguments)]
fn raise(
    px: &mut [f32],
    l: f32,
    low: f32,
    i: usize,
    (x, y): (usize, usize),
    (w, h): (usize, usize),
    src: &[f32],
    lum: &[f32],
    detection: &Detection,
    guides: &Guides,
    params: &DetectParams,
) {
    let (mut sum, mut total) = ([0.0f64; 3], 0.0f64);
    for j in window(x, y, params.radius.max(1), w, h).filter(|&j| !detection.mask[j]) {
        let wt = likeness(guides, params, i, j) as f64;
        if !wt.is_finite() || !lum[j].is_finite() {
            continue;
        }
        for k in 0..3 {
            sum[k] += wt * src[3 * j + k] as f64;
        }
        total += wt;
    }
    if total <= 0.0 {
        return;
    }
    let mean = sum.map(|v| v / total);
    let lm = 0.2126 * mean[0] + 0.7152 * mean[1] + 0.0722 * mean[2];
    let need = low as f64 - l as f64;
    if !(lm > 0.0 && need > 0.0) {
        return;
    }
    let s = need / lm;
    for (v, m) in px.iter_mut().zip(mean) {
        *v = (*v as f64 + s * m).min(f32::MAX as f64) as f32;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filters::outlier::detect::detect;
    use crate::filters::outlier::neighbourhood::luminance;
    use crate::filters::outlier::params::fixtures::{params, RULES};
    use crate::filters::outlier::params::Rule;

    #[test]
    fn clamp_keeps_hue_and_hits_the_limit() {
        let mut img = Image::filled(5, 5, 3, 0.2);
        img.pixel_mut(12).copy_from_slice(&[1e5, 2e5, 3e5]);
        for rule in RULES {
            let p = params(rule);
            let d = detect(&img, &Guides::default(), &p);
            let out = repair(&img, &d, &Guides::default(), &p, Action::Clamp);
            let c = out.pixel(12);
            assert!((luminance(c) / d.limit[12] - 1.0).abs() < 1e-4, "{rule:?}");
            assert!((c[1] / c[0] - 2.0).abs() < 1e-4 && (c[2] / c[0] - 3.0).abs() < 1e-4);
        }
    }

    #[test]
    fn median_prefers_neighbours_on_the_same_surface() {
        // Left half dark surface A, right half bright surface B; a firefly on A next to the edge.
        let (w, h) = (6, 5);
        let img = Image::from_fn(w, h, 3, |x, y, _| match (x, y) {
            (2, 2) => 1e4,
            (x, _) if x < 3 => 0.1,
            _ => 0.9,
        });
        let albedo = Image::from_fn(w, h, 3, |x, _, _| if x < 3 { 0.2 } else { 0.8 });
        let guides = Guides {
            albedo: Some(&albedo),
            normal: None,
        };
        let p = params(Rule::Zscore);
        let d = detect(&img, &guides, &p);
        assert!(d.mask[2 * w + 2]);
        let out = repair(&img, &d, &guides, &p, Action::Median);
        assert_eq!(out.pixel(2 * w + 2), &[0.1, 0.1, 0.1]);
    }

    #[test]
    fn detection_is_identical_on_one_and_two_threads() {
        let img = Image::from_fn(31, 17, 3, |x, y, c| {
            let v = ((x * 7919 + y * 104729 + c * 31) % 97) as f32 / 97.0;
            if (x * 13 + y * 7) % 41 == 0 {
                1e3 * v
            } else {
                v
            }
        });
        for rule in RULES {
            let p = params(rule);
            let run = |threads| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap()
                    .install(|| {
                        let d = detect(&img, &Guides::default(), &p);
                        let o = repair(&img, &d, &Guides::default(), &p, Action::Median);
                        (d, o)
                    })
            };
            assert_eq!(run(1), run(2), "{rule:?}");
        }
    }

    fn two_sided() -> DetectParams {
        DetectParams {
            two_sided: true,
            ..params(Rule::Feature)
        }
    }

    /// A bright, slightly uneven, warm surface (R:G:B = 1.5 : 1.25 : 1).
    fn surface(w: usize, h: usize) -> Image {
        Image::from_fn(w, h, 3, |x, y, c| {
            [0.6, 0.5, 0.4][c] * (1.0 + 0.02 * ((x * 7 + y * 3) % 5) as f32)
        })
    }

    #[test]
    fn a_dark_dot_on_a_flat_surface_is_raised_with_the_surfaces_hue() {
        let (w, h) = (9, 7);
        let mut img = surface(w, h);
        let dot = 3 * w + 4;
        img.pixel_mut(dot).copy_from_slice(&[0.0, 0.0, 0.0]);
        // The one-sided rule leaves it.
        let one = detect(&img, &Guides::default(), &params(Rule::Feature));
        assert_eq!(one.count(), 0);
        let p = two_sided();
        let d = detect(&img, &Guides::default(), &p);
        assert_eq!(d.count(), 1);
        assert!(d.mask[dot]);
        let out = repair(&img, &d, &Guides::default(), &p, Action::Clamp);
        let c = out.pixel(dot);
        assert!((luminance(c) / d.low[dot] - 1.0).abs() < 1e-4, "{c:?}");
        assert!(luminance(c) > 0.2, "raised only to {c:?}");
        assert!((c[0] / c[2] - 1.5).abs() < 0.01 && (c[1] / c[2] - 1.25).abs() < 0.01);
        // Raised no higher than its second-darkest neighbour, and nothing else touched.
        let mut around: Vec<f32> = window(4, 3, 1, w, h)
            .map(|j| luminance(img.pixel(j)))
            .collect();
        around.sort_by(f32::total_cmp);
        assert!(luminance(c) <= around[1] * (1.0 + 1e-5), "{c:?} {around:?}");
        for i in (0..w * h).filter(|&i| i != dot) {
            assert_eq!(out.pixel(i), img.pixel(i));
        }
    }

    #[test]
    fn thin_dark_lines_and_a_dark_texel_stay() {
        let (w, h) = (9, 9);
        // A dark outline one pixel wide, slightly uneven, that no feature shows (a thin shadow):
        // each of its pixels has two dark neighbours along it.
        let ring = |x: usize, y: usize| {
            ((x == 2 || x == 6) && (2..=6).contains(&y))
                || ((y == 2 || y == 6) && (2..=6).contains(&x))
        };
        let mut img = surface(w, h);
        for y in 0..h {
            for x in (0..w).filter(|&x| ring(x, y)) {
                let v = 0.02 + 0.01 * ((x + y) % 3) as f32;
                img.pixel_mut(y * w + x).copy_from_slice(&[v, v, v]);
            }
        }
        let p = two_sided();
        let d = detect(&img, &Guides::default(), &p);
        let out = repair(&img, &d, &Guides::default(), &p, Action::Clamp);
        assert_eq!(d.count(), 0);
        assert_eq!(out, img);
        // The same outline, shown by the albedo: its pixels share their surface.
        let albedo = Image::from_fn(w, h, 3, |x, y, _| if ring(x, y) { 0.02 } else { 0.8 });
        let guides = Guides {
            albedo: Some(&albedo),
            normal: None,
        };
        assert_eq!(detect(&img, &guides, &p).count(), 0);
        // A dark texel the albedo shows: no neighbour shares its surface.
        let mut img = surface(w, h);
        img.pixel_mut(4 * w + 4)
            .copy_from_slice(&[0.01, 0.01, 0.01]);
        let albedo = Image::from_fn(w, h, 3, |x, y, _| if (x, y) == (4, 4) { 0.02 } else { 0.8 });
        let guides = Guides {
            albedo: Some(&albedo),
            normal: None,
        };
        let d = detect(&img, &guides, &p);
        assert_eq!(d.count(), 0);
    }

    #[test]
    fn hard_cases_stay_finite_and_black_stays_black() {
        let black = Image::filled(6, 5, 3, 0.0);
        let p = two_sided();
        let d = detect(&black, &Guides::default(), &p);
        assert_eq!(d.count(), 0);
        let img = Image::from_fn(11, 9, 3, |x, y, c| match (x * 5 + y * 3 + c) % 4 {
            0 => 0.0,
            1 => f32::MAX,
            2 => 1e-30,
            _ => 0.5,
        });
        for action in [Action::Clamp, Action::Median] {
            let d = detect(&img, &Guides::default(), &p);
            let out = repair(&img, &d, &Guides::default(), &p, action);
            assert!(out.data().iter().all(|v| v.is_finite()), "{action:?}");
        }
        let one = Image::filled(1, 1, 3, 0.0);
        assert_eq!(detect(&one, &Guides::default(), &p).count(), 0);
    }

    #[test]
    fn dark_dots_the_same_bits_on_one_and_two_threads() {
        let (w, h) = (37, 29);
        let img = Image::from_fn(w, h, 3, |x, y, c| {
            if (x * 31 + y * 17) % 13 == 0 {
                0.0
            } else {
                0.3 + 0.1 * ((x * 7 + y * 13 + c) % 5) as f32
            }
        });
        let albedo = Image::from_fn(
            w,
            h,
            3,
            |x, y, _| if (x / 5 + y / 7) % 2 == 0 { 0.3 } else { 0.6 },
        );
        let p = two_sided();
        let run = |threads| {
            crate::options::thread_pool(threads).unwrap().install(|| {
                let guides = Guides {
                    albedo: Some(&albedo),
                    normal: None,
                };
                let d = detect(&img, &guides, &p);
                (d.count(), repair(&img, &d, &guides, &p, Action::Clamp))
            })
        };
        let (n, one) = run(1);
        assert!(n > 10, "{n} flagged");
        assert_eq!((n, one), run(2));
    }
}
