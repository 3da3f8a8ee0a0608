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
                            .map(|j| {
                                let (da, dn) = guides.distances(i, j);
                                let za = da / params.albedo_tol.max(1e-6);
                                let zn = dn / params.normal_tol.max(1e-6);
                                // Floor so a pixel on its own surface still gets its neighbours' median.
                                let wt = (-0.5 * (za * za + zn * zn)).exp().max(1e-6);
                                (lum[j], wt, j)
                            }),
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
}
