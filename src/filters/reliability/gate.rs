//! The reliability gate of one feature buffer: every pixel pulled towards its window's median in
//! proportion to how little of the window's variation its noise leaves to the surface.
//!
//! Per pixel, over a (2r+1)² window (edges replicated), summed over the channels:
//! - the noise variance `n²`: the window's mean squared second difference along the direction in
//!   which it is smallest, over 6 (a second difference of independent noise has variance 6σ²; along
//!   an edge, a line or a ramp it is zero, so a texture's or a slope's own change is not read as
//!   noise);
//! - the signal variance `s²`: the variance, over the window, of the buffer's 5-pixel median along
//!   the direction in which its 3×3 neighbourhood varies least (it keeps a line or an edge that runs
//!   that way, a brick wall's mortar in either direction, and drops isolated salt-and-pepper samples,
//!   so `s²` is the surface's own change);
//! - the reliability `ρ = s² / (s² + k·n²)`, k = 2 because a pair of pixels' difference carries the
//!   noise of both;
//! - the gated value `median + ρ·(value − median)`, the median being that directional one, or for a
//!   distance the separable 5×5 median (a surface's depth has no sub-pixel texture to keep, and a noisy depth
//!   is usually noisy in every direction).
//!
//! Before that, a distance of zero is read as "not recorded" (`median::fill_unrecorded`).
//!
//! A clean buffer (n² = 0) passes unchanged; one whose variation is all noise (fog's per-sample mix of
//! medium and surface, few-sample depth of field) becomes its median and guides nothing. Every sum
//! runs in f64 in a fixed order per pixel: the same bits on any thread count.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::mean::{pull_to_surface_mean, Reading};
use super::median::{fill_unrecorded, median_along, square_median, MEDIAN_RADIUS};
use super::variance::{noise_variance, signal_variance};
use crate::error::Result;
use crate::image::{par_vec, Image};
use crate::kernels::padded::{Margin, Padded};
use crate::meter::Meter;

/// Keeps 0/0 at a reliability of 1 (a flat, clean window).
const EPS: f64 = 1e-12;

/// How a buffer's values are read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Domain {
    /// As they are (albedo, material weights, shadow).
    Linear,
    /// Unit vectors: gated per channel, then renormalised; all-zero ("unknown") pixels stay zero.
    Normal,
    /// Distances, gated in log space (depth differences count relatively).
    Log,
}

/// What a noisy pixel is pulled towards.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Centre {
    /// The window's median (directional, or 5×5 for a distance): a two-valued mix becomes its
    /// majority.
    Median,
    /// The median first, then by the pixel's unreliability towards the mean of the raw samples of
    /// its own surface (`mean`): a two-valued mix becomes its proportion, the feature's reference.
    #[default]
    Mean,
}

/// Settings of the gate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Params {
    /// Window radius of the noise and signal variances.
    pub radius: usize,
    /// k: the noise's share in the reliability.
    pub pair_noise: f64,
    /// What a noisy pixel is pulled towards.
    pub centre: Centre,
}

/// The gated buffer and the reliability ρ of every pixel (one channel).
pub fn gate(img: &Image, domain: Domain, p: Params) -> (Image, Image) {
    gate_metered(img, domain, p, None, &Meter::default()).expect("a run without a cancel")
}

/// [`gate`] that ends with `Err(Cancelled)` between its passes once `meter` is cancelled, with
/// every pixel's reliability raised to at least `at_least`'s (one channel) when one is given.
pub fn gate_metered(
    img: &Image,
    domain: Domain,
    p: Params,
    at_least: Option<&Image>,
    meter: &Meter,
) -> Result<(Image, Image)> {
    let filled;
    let img = if domain == Domain::Log {
        filled = fill_unrecorded(img);
        &filled
    } else {
        img
    };
    let (w, h, c) = (img.width(), img.height(), img.channels());
    let floor = log_floor(img, domain);
    let src = Padded::new((w, h), c, MEDIAN_RADIUS, Margin::Edge, |i, k| {
        to_domain(img.data()[i * c + k], domain, floor)
    });
    meter.step()?;
    let (noise, along) = noise_variance(&src, (w, h), p.radius, meter)?;
    let squares: Vec<Vec<f64>> = src
        .planes
        .iter()
        .map(|plane| {
            meter.step()?;
            Ok(square_median(&src, plane, (w, h)))
        })
        .collect::<Result<_>>()?;
    let medians: Vec<Vec<f64>> = src
        .planes
        .iter()
        .zip(&squares)
        .map(|(plane, square)| {
            meter.step()?;
            Ok(median_along(&src, plane, &along, square, (w, h)))
        })
        .collect::<Result<_>>()?;
    let signal = signal_variance(&medians, (w, h), p.radius, meter)?;
    let centres = if domain == Domain::Log {
        &squares
    } else {
        &medians
    };
    meter.step()?;
    // Every pass below in parallel, each pixel's operations as one pass would do them.
    let rho: Vec<f64> = signal
        .par_iter()
        .zip(&noise)
        .map(|(&s, &n)| (s + EPS) / (s + p.pair_noise * n + EPS))
        .zip(0..w * h)
        .map(|(r, i)| at_least.map_or(r, |f| r.max(f.data()[i] as f64)))
        .collect();
    let mut out = Image::new(w, h, c);
    if p.centre == Centre::Mean {
        // The raw planes without their margins, copied a row at a time.
        let raw: Vec<Vec<f64>> = src
            .planes
            .iter()
            .map(|plane| {
                let mut v = par_vec(0.0, w * h);
                v.par_chunks_mut(w.max(1)).enumerate().for_each(|(y, row)| {
                    let at = src.index(0, y as isize);
                    row.copy_from_slice(&plane[at..at + w]);
                });
                v
            })
            .collect();
        let gated: Vec<Vec<f64>> = raw
            .iter()
            .zip(centres)
            .map(|(v, m)| {
                v.par_iter()
                    .zip(m)
                    .zip(&rho)
                    .map(|((&v, &m), &r)| pull(v, m, r))
                    .collect()
            })
            .collect();
        let reading = Reading {
            rho: &rho,
            along: &along,
        };
        let gated = pull_to_surface_mean(
            &raw,
            &gated,
            reading,
            (w, h),
            (p.radius, p.pair_noise),
            meter,
        )?;
        out.data_mut()
            .par_chunks_mut(c)
            .enumerate()
            .for_each(|(i, px)| write_pixel(px, |k| gated[k][i], domain, img.pixel(i)));
    } else {
        // Straight from the padded planes, a row at a time.
        out.data_mut()
            .par_chunks_mut(c * w.max(1))
            .enumerate()
            .for_each(|(y, row)| {
                let at = src.index(0, y as isize);
                for (x, px) in row.chunks_exact_mut(c).enumerate() {
                    let i = y * w + x;
                    let value = |k: usize| pull(src.planes[k][at + x], centres[k][i], rho[i]);
                    write_pixel(px, value, domain, img.pixel(i));
                }
            });
    }
    let rho = Image::from_vec(w, h, 1, rho.par_iter().map(|&r| r as f32).collect())
        .expect("one value a pixel");
    Ok((out, rho))
}

/// One output pixel: channel k's gated `value(k)` back from the domain, a normal renormalised
/// against its `input`.
#[inline(always)]
fn write_pixel(px: &mut [f32], value: impl Fn(usize) -> f64, domain: Domain, input: &[f32]) {
    for (k, v) in px.iter_mut().enumerate() {
        *v = from_domain(value(k), domain);
    }
    if domain == Domain::Normal {
        renormalise(px, input);
    }
}

/// A value `v` pulled towards its centre `m` by its unreliability: `m + ρ·(v − m)`.
#[inline(always)]
fn pull(v: f64, m: f64, rho: f64) -> f64 {
    m + rho * (v - m)
}

/// The smallest depth read in log space: relative to the farthest, so the unit of depth does not
/// matter; a zero depth ("nothing hit") becomes it.
fn log_floor(img: &Image, domain: Domain) -> f64 {
    if domain != Domain::Log {
        return 0.0;
    }
    let far = img.data().iter().fold(0.0f32, |a, &v| a.max(v)) as f64;
    (far * 1e-6).max(f64::MIN_POSITIVE)
}

fn to_domain(v: f32, domain: Domain, floor: f64) -> f64 {
    match domain {
        Domain::Log => (v as f64).max(floor).ln(),
        _ => v as f64,
    }
}

fn from_domain(v: f64, domain: Domain) -> f32 {
    match domain {
        Domain::Log => v.exp() as f32,
        _ => v as f32,
    }
}

/// A known normal back to unit length; an unknown one (all zero in the input) stays zero.
fn renormalise(px: &mut [f32], input: &[f32]) {
    if input.iter().all(|&v| v == 0.0) {
        px.fill(0.0);
        return;
    }
    let len = px
        .iter()
        .map(|&v| (v as f64) * (v as f64))
        .sum::<f64>()
        .sqrt();
    if len > 0.0 {
        for v in px.iter_mut() {
            *v = (*v as f64 / len) as f32;
        }
    } else {
        px.copy_from_slice(input);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    const P: Params = Params {
        radius: 3,
        pair_noise: 2.0,
        centre: Centre::Median,
    };

    #[test]
    fn a_clean_texture_passes_unchanged() {
        // A checker of 4-pixel squares (steps of 0.7) and a ramp: no noise. Only the checker's
        // corners, where every direction crosses an edge, read as a little noise.
        let img = Image::from_fn(24, 20, 3, |x, y, k| {
            let sq = ((x / 4 + y / 4) % 2) as f32;
            0.1 + 0.7 * sq + 0.01 * (x as f32) * (k as f32 + 1.0)
        });
        let (out, rho) = gate(&img, Domain::Linear, P);
        for (a, b) in out.data().iter().zip(img.data()) {
            assert!((a - b).abs() < 0.035, "{a} against {b}");
        }
        assert!(rho.data().iter().all(|r| (0.0..=1.0).contains(r)));
    }

    #[test]
    fn salt_and_pepper_loses_most_of_its_pattern() {
        // A flat albedo where every pixel is, at random, the surface's 0.2 or the medium's 0.9
        // (fog's per-sample mix).
        for density in [0.1, 0.2] {
            let mut rng = rand::rngs::Xoshiro256PlusPlus::seed_from_u64(7);
            let img = Image::from_fn(40, 40, 1, |_, _, _| {
                if rng.random::<f64>() < density {
                    0.9
                } else {
                    0.2
                }
            });
            let (out, rho) = gate(&img, Domain::Linear, P);
            let mean_rho = rho.data().iter().map(|&r| r as f64).sum::<f64>() / 1600.0;
            assert!(
                mean_rho < 0.2,
                "density {density}: mean reliability {mean_rho}"
            );
            let (before, after) = (spread(img.data()), spread(out.data()));
            assert!(
                after < 0.5 * before,
                "density {density}: {after} against {before}"
            );
        }
    }

    #[test]
    fn a_noisy_one_pixel_line_is_kept() {
        // Mortar or a wire: 1-pixel vertical lines every 4 pixels, with a little noise on top.
        let mut rng = rand::rngs::Xoshiro256PlusPlus::seed_from_u64(11);
        let img = Image::from_fn(32, 32, 1, |x, _, _| {
            let line = if x % 4 == 0 { 0.8 } else { 0.3 };
            line + 0.02 * (rng.random::<f32>() - 0.5)
        });
        let (out, _) = gate(&img, Domain::Linear, P);
        for y in 4..28 {
            for x in (4..28).step_by(4) {
                let contrast = out.at(x, y)[0] - 0.5 * (out.at(x - 1, y)[0] + out.at(x + 1, y)[0]);
                assert!(contrast > 0.45, "({x}, {y}): line contrast {contrast}");
            }
        }
    }

    #[test]
    fn unrecorded_depth_is_filled_and_the_sky_stays_empty() {
        // A floor receding from 2 to 2.4 with a third of its pixels unrecorded (0), under an empty sky.
        let mut rng = rand::rngs::Xoshiro256PlusPlus::seed_from_u64(13);
        let img = Image::from_fn(30, 30, 1, |_, y, _| {
            if y < 10 || rng.random::<f64>() < 0.33 {
                0.0
            } else {
                2.0 + 0.02 * (y - 10) as f32
            }
        });
        let (out, _) = gate(&img, Domain::Log, P);
        for y in 0..30 {
            for x in 0..30 {
                let v = out.at(x, y)[0];
                if y < 8 {
                    assert!(v < 1e-4, "sky ({x}, {y}) = {v}");
                } else if y >= 12 {
                    let want = 2.0 + 0.02 * (y - 10) as f32;
                    assert!(
                        (v - want).abs() < 0.03 * want,
                        "({x}, {y}) = {v}, want {want}"
                    );
                }
            }
        }
    }

    #[test]
    fn depth_is_gated_relatively_and_zero_depth_is_no_nan() {
        // The same scene in metres and in millimetres gives the same relative result.
        let mut rng = rand::rngs::Xoshiro256PlusPlus::seed_from_u64(3);
        let noise: Vec<f32> = (0..900).map(|_| rng.random::<f32>()).collect();
        let scene = |scale: f32| {
            Image::from_fn(30, 30, 1, |x, y, _| {
                let i = y * 30 + x;
                if i % 97 == 0 {
                    0.0
                } else {
                    scale * (2.0 + x as f32 * 0.1 + noise[i])
                }
            })
        };
        let (m, _) = gate(&scene(1.0), Domain::Log, P);
        let (mm, _) = gate(&scene(1000.0), Domain::Log, P);
        for (a, b) in m.data().iter().zip(mm.data()) {
            assert!(a.is_finite() && b.is_finite());
            assert!(
                (a * 1000.0 - b).abs() <= 1e-3 * b.abs().max(1e-3),
                "{a} {b}"
            );
        }
    }

    #[test]
    fn normals_stay_unit_and_unknown_normals_stay_zero() {
        let mut rng = rand::rngs::Xoshiro256PlusPlus::seed_from_u64(5);
        let img = Image::from_fn(16, 16, 3, |x, _, k| {
            if x < 3 {
                return 0.0;
            }
            let j: f32 = rng.random::<f32>() * 0.6 - 0.3;
            [j, 0.3, 0.95][k]
        });
        let (out, _) = gate(&img, Domain::Normal, P);
        for i in 0..256 {
            let px = out.pixel(i);
            if i % 16 < 3 {
                assert_eq!(px, &[0.0, 0.0, 0.0]);
            } else {
                let len: f32 = px.iter().map(|v| v * v).sum::<f32>().sqrt();
                assert!((len - 1.0).abs() < 1e-5, "{len}");
            }
        }
    }

    #[test]
    fn tiny_and_odd_images_are_finite() {
        for (w, h) in [(1, 1), (1, 7), (3, 2), (5, 5)] {
            let img = Image::from_fn(w, h, 3, |x, y, k| (x * 3 + y + k) as f32 * 0.1);
            let (out, rho) = gate(&img, Domain::Linear, P);
            assert!(out.all_finite() && rho.all_finite());
        }
    }

    fn spread(v: &[f32]) -> f64 {
        let n = v.len() as f64;
        let m = v.iter().map(|&x| x as f64).sum::<f64>() / n;
        (v.iter().map(|&x| (x as f64 - m).powi(2)).sum::<f64>() / n).sqrt()
    }
}
