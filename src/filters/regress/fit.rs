//! The fit at every pixel: bands of rows in parallel, each copied into planes, swept in tiles
//! of groups of pixels whose window sums are formed together and then solved.

use rayon::prelude::*;

use super::params::{Fit, Inputs, Params};
use super::planes::{Planes, GROUP, LANES, WIDE_GROUP};
use super::window_sums::{window_sums_with, GroupSums, Taps};
use crate::image::{par_vec, Image};
use crate::kernels::simd::Kernel;
use crate::meter::Meter;

/// Output rows per parallel task; each task copies its rows plus the window's reach into planes.
const BAND_ROWS: usize = 32;

/// Columns of a band swept row by row before the next: the window's rows of every lane stay in
/// the core's cache from one output row to the next.
const TILE_COLUMNS: usize = 64;
const _: () = assert!(
    TILE_COLUMNS.is_multiple_of(WIDE_GROUP) && WIDE_GROUP.is_multiple_of(GROUP),
    "a tile holds whole groups"
);

/// The fit of the noisy colour at every pixel, with its variance.
pub fn regress_with(kernel: Kernel, inputs: Inputs, p: &Params) -> Fit {
    regress_in(kernel, inputs, p, &Meter::default())
}

/// [`regress_with`] in a run: its bands tell `meter` as they finish and are skipped once it is
/// cancelled (the fit is then unfinished, for the caller to throw away).
pub fn regress_in(kernel: Kernel, inputs: Inputs, p: &Params, meter: &Meter) -> Fit {
    let kernel = kernel.or_portable();
    let (w, h) = inputs.noisy.dims();
    let mut color = Image::new(w, h, 3);
    let mut variance = par_vec(0.0f32, w * h);
    if w == 0 || h == 0 {
        return Fit { color, variance };
    }
    match kernel {
        Kernel::Avx512 => {
            fit_bands::<WIDE_GROUP>(kernel, inputs, p, (&mut color, &mut variance), meter)
        }
        _ => fit_bands::<GROUP>(kernel, inputs, p, (&mut color, &mut variance), meter),
    }
    Fit { color, variance }
}

/// The fit of every band of rows into `color` and `variance`, G pixels of a row at a time.
fn fit_bands<const G: usize>(
    kernel: Kernel,
    inputs: Inputs,
    p: &Params,
    (color, variance): (&mut Image, &mut [f32]),
    meter: &Meter,
) {
    let (w, h) = inputs.noisy.dims();
    meter.pass(h);
    let (r, cos) = (p.radius, p.normal_cos);
    let inv_albedo = 1.0 / (2.0 * p.albedo_sigma * p.albedo_sigma);
    color
        .data_mut()
        .par_chunks_mut(3 * w * BAND_ROWS)
        .zip(variance.par_chunks_mut(w * BAND_ROWS))
        .enumerate()
        .for_each(|(band, (out, out_var))| {
            if meter.cancelled() {
                return;
            }
            let y0 = band * BAND_ROWS;
            let y1 = (y0 + BAND_ROWS).min(h);
            let planes = Planes::build(inputs, p, y0, y1);
            let lanes: [&[f32]; LANES] = std::array::from_fn(|l| planes.lanes[l].as_slice());
            let taps = Taps {
                lanes: &lanes,
                stride: planes.stride,
                r,
                inv_albedo,
                cos,
            };
            let mut sums = GroupSums::<G>::new();
            for tile in (0..w).step_by(TILE_COLUMNS) {
                for y in y0..y1 {
                    let at = y - y0;
                    for x0 in (tile..(tile + TILE_COLUMNS).min(w)).step_by(G) {
                        let center = planes.offset(0, at, 0) + x0;
                        window_sums_with(kernel, &taps, center, &mut sums);
                        sums.solve(
                            p,
                            &planes,
                            inputs,
                            (x0, y),
                            G.min(w - x0),
                            &mut out[3 * w * at..3 * w * (at + 1)],
                            &mut out_var[w * at..w * (at + 1)],
                        );
                    }
                }
            }
            meter.rows(y1 - y0);
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(w: usize, h: usize, f: impl Fn(usize, usize) -> f32) -> Image {
        Image::from_fn(w, h, 3, |x, y, _| f(x, y))
    }

    /// The fit of `img` (noisy and filtered alike) with a uniform variance `v`, no features, no
    /// demodulation and no ridge, with weights that ignore colour (σ 1e3).
    fn plain_fit(img: &Image, v: f32, radius: usize) -> Fit {
        let (w, h) = img.dims();
        let p = Params {
            demodulate: false,
            sigma: 1e3,
            ridge: 0.0,
            radius,
            ..Params::default()
        };
        let inputs = Inputs {
            noisy: img,
            filtered: img,
            variance: &Image::filled(w, h, 3, v),
            albedo: None,
            normal: None,
        };
        regress_with(Kernel::Scalar, inputs, &p)
    }

    #[test]
    fn a_linear_ramp_is_fitted_exactly_up_to_the_edge() {
        // A ramp with no noise: the fit recovers it at every pixel, including the borders, where
        // the window is one-sided.
        let ramp = plane(20, 13, |x, y| 0.1 + 0.01 * x as f32 + 0.02 * y as f32);
        let fit = plain_fit(&ramp, 1e-4, Params::default().radius);
        for (g, t) in fit.color.data().iter().zip(ramp.data()) {
            assert!((g - t).abs() < 1e-5, "{g} vs {t}");
        }
    }

    #[test]
    fn the_fits_variance_is_the_mean_over_its_window_in_the_middle() {
        // In the middle of the image the intercept of a symmetric window with flat weights is the
        // plain mean, variance v / n.
        let w = 21;
        let fit = plain_fit(&Image::filled(w, w, 3, 0.5), 0.01, 3);
        let v = fit.variance[10 * w + 10];
        assert!((v - 0.01 / 49.0).abs() < 1e-7, "{v}");
        // At a corner only a quarter of the window is there and the fit extrapolates: more.
        assert!(fit.variance[0] > 4.0 * v, "{}", fit.variance[0]);
    }
}

#[cfg(test)]
mod reference_tests {
    use super::*;
    use crate::filters::regress::params::{DEMODULATION_EPS, MAX_RADIUS};
    use crate::filters::regress::solve::first_column_of_inverse;

    /// A direct per-pixel solve in f64 of what `regress_with` computes.
    fn direct(inputs: Inputs, p: &Params) -> (Vec<[f64; 3]>, Vec<f64>) {
        let (w, h) = inputs.noisy.dims();
        let r = p.radius as isize;
        let scale = |i: usize, k: usize| match inputs.albedo {
            Some(a) if p.demodulate => (a.pixel(i)[k].max(0.0) + DEMODULATION_EPS) as f64,
            _ => 1.0,
        };
        let clipped = |i: usize, k: usize| {
            let (c, f, v) = (
                inputs.noisy.pixel(i)[k] as f64,
                inputs.filtered.pixel(i)[k] as f64,
                inputs.variance.pixel(i)[k].max(0.0) as f64,
            );
            let lim = p.clip as f64 * v.sqrt();
            (f + (c - f).clamp(-lim, lim)) / scale(i, k)
        };
        let vbar = |i: usize| {
            (0..3)
                .map(|k| inputs.variance.pixel(i)[k].max(0.0) as f64 / scale(i, k).powi(2))
                .sum::<f64>()
                / 3.0
        };
        let mut out = vec![];
        let mut var = vec![];
        for y in 0..h as isize {
            for x in 0..w as isize {
                let i = (y * w as isize + x) as usize;
                let mut a = [[0.0f64; 3]; 3];
                let mut m = [[0.0f64; 3]; 3];
                let mut b = [[0.0f64; 3]; 3];
                for dy in -r..=r {
                    for dx in -r..=r {
                        let (nx, ny) = (x + dx, y + dy);
                        if nx < 0 || ny < 0 || nx >= w as isize || ny >= h as isize {
                            continue;
                        }
                        let j = (ny * w as isize + nx) as usize;
                        let mut f2 = 0.0;
                        let mut a2 = 0.0;
                        for k in 0..3 {
                            let d = inputs.filtered.pixel(i)[k] as f64 / scale(i, k)
                                - inputs.filtered.pixel(j)[k] as f64 / scale(j, k);
                            f2 += d * d;
                            if let Some(al) = inputs.albedo {
                                let d = (al.pixel(i)[k] - al.pixel(j)[k]) as f64;
                                a2 += d * d;
                            }
                        }
                        let inv = 1.0 / (2.0 * (p.sigma as f64).powi(2) * vbar(i) + 1e-12);
                        let x = f2 * inv + a2 / (2.0 * (p.albedo_sigma as f64).powi(2));
                        let mut wgt = (1.0 - x / 8.0).max(0.0).powi(8);
                        if let Some(n) = inputs.normal {
                            let (ni, nj) = (n.pixel(i), n.pixel(j));
                            let dot: f32 = (0..3).map(|k| ni[k] * nj[k]).sum();
                            if dot < p.normal_cos {
                                wgt = 0.0;
                            }
                        }
                        let xr = [1.0, dx as f64 / r as f64, dy as f64 / r as f64];
                        for s in 0..3 {
                            for t in 0..3 {
                                a[s][t] += wgt * xr[s] * xr[t];
                                m[s][t] += wgt * wgt * vbar(j) * xr[s] * xr[t];
                            }
                            for (k, b) in b[s].iter_mut().enumerate() {
                                *b += wgt * xr[s] * clipped(j, k);
                            }
                        }
                    }
                }
                let u = first_column_of_inverse(
                    [a[0][0], a[0][1], a[0][2], a[1][1], a[1][2], a[2][2]],
                    p.ridge,
                );
                out.push(std::array::from_fn(|k| {
                    (0..3).map(|s| u[s] * b[s][k]).sum::<f64>() * scale(i, k)
                }));
                let q: f64 = (0..3)
                    .flat_map(|s| (0..3).map(move |t| (s, t)))
                    .map(|(s, t)| u[s] * m[s][t] * u[t])
                    .sum();
                var.push(q * (0..3).map(|k| scale(i, k).powi(2)).sum::<f64>() / 3.0);
            }
        }
        (out, var)
    }

    #[test]
    fn matches_a_direct_solve() {
        let (w, h) = (19, 14);
        let mut s = 12345u64;
        let mut rnd = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        let noisy = Image::from_fn(w, h, 3, |x, _, _| 0.2 + 0.01 * x as f32 + 0.1 * rnd());
        let filtered = Image::from_fn(w, h, 3, |x, y, _| 0.25 + 0.01 * x as f32 + 0.001 * y as f32);
        let variance = Image::from_fn(w, h, 3, |_, _, _| 0.002 + 0.001 * rnd());
        let albedo = Image::from_fn(
            w,
            h,
            3,
            |x, _, k| if x < 9 { 0.5 } else { 0.2 + 0.1 * k as f32 },
        );
        let normal = Image::from_fn(w, h, 3, |_, y, k| match (y < 7, k) {
            (true, 2) | (false, 1) => 1.0,
            _ => 0.0,
        });
        let inputs = Inputs {
            noisy: &noisy,
            filtered: &filtered,
            variance: &variance,
            albedo: Some(&albedo),
            normal: Some(&normal),
        };
        // Radius 3, and the largest, whose window is wider than the image: every window row's
        // reads then run to the end of the band's padded planes.
        for radius in [3, MAX_RADIUS] {
            for kernel in Kernel::ALL.into_iter().filter(|k| k.is_available()) {
                check_against_direct(inputs, radius, kernel);
            }
        }
    }

    fn check_against_direct(inputs: Inputs, radius: usize, kernel: Kernel) {
        let p = Params {
            radius,
            ..Params::default()
        };
        let fit = regress_with(kernel, inputs, &p);
        let (want, want_var) = direct(inputs, &p);
        for (i, want) in want.iter().enumerate() {
            for (k, &t) in want.iter().enumerate() {
                let g = fit.color.pixel(i)[k] as f64;
                assert!(
                    (g - t).abs() < 1e-4 * t.abs().max(1.0),
                    "pixel {i} channel {k}: {g} vs {t}"
                );
            }
            let (v, t) = (fit.variance[i] as f64, want_var[i]);
            assert!((v - t).abs() < 1e-3 * t, "pixel {i} variance: {v} vs {t}");
        }
    }
}
