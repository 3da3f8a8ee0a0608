//! The `regress` stage (docs/ALGORITHM.md §9): both kernels and any thread count give the same
//! bits, a first-order fit takes out the bias an average leaves along an edge, a filter that is
//! right is left alone, hard inputs stay finite, the result follows the exposure, and bad keys
//! are one-line errors.

use crate::common::assert_set_refused;
use gsid::filters::regress::{refine_with, regress_with, Inputs, Params};
use gsid::kernels::simd::Kernel;
use gsid::Image;

fn bits(img: &Image) -> Vec<u32> {
    img.data().iter().map(|v| v.to_bits()).collect()
}

/// Gaussian noise from a fixed seed (xorshift and Box–Muller), one value per call.
fn gaussian(seed: u64) -> impl FnMut() -> f32 {
    let mut s = seed.max(1);
    let mut uniform = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        ((s >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    move || {
        let (u, v) = (uniform(), uniform());
        ((-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()) as f32
    }
}

/// Two walls meeting at column `w / 2` (normals +z and +x), each lit by a ramp that darkens
/// towards the corner: the truth, the noisy render (noise σ), its variance, the features.
struct Corner {
    w: usize,
    h: usize,
    truth: Image,
    noisy: Image,
    variance: Image,
    albedo: Image,
    normal: Image,
}

fn corner(w: usize, h: usize, sigma: f32, seed: u64) -> Corner {
    let edge = w / 2;
    // 0.005 a pixel over 12 pixels: a gentle darkening, a quarter of the noise a pixel.
    let light = |x: usize| {
        let d = if x < edge { edge - 1 - x } else { x - edge } as f32;
        0.1 + 0.005 * d.min(12.0)
    };
    let truth = Image::from_fn(w, h, 3, |x, _, _| light(x));
    let mut g = gaussian(seed);
    let noisy = Image::from_fn(w, h, 3, |x, _, _| light(x) + sigma * g());
    Corner {
        w,
        h,
        truth,
        noisy,
        variance: Image::filled(w, h, 3, sigma * sigma),
        albedo: Image::filled(w, h, 3, 0.7),
        normal: Image::from_fn(w, h, 3, |x, _, k| ((x < edge) == (k == 2)) as u8 as f32),
    }
}

impl Corner {
    /// What an average on each wall gives: the truth smoothed over ±`r` columns of its own wall,
    /// so it is flattened into the corner (and right elsewhere, where the light is linear).
    fn averaged(&self, r: usize) -> Image {
        let edge = self.w / 2;
        Image::from_fn(self.w, self.h, 3, |x, y, k| {
            let (lo, hi) = if x < edge { (0, edge) } else { (edge, self.w) };
            let cols = x.saturating_sub(r).max(lo)..(x + r + 1).min(hi);
            let n = cols.len() as f32;
            cols.map(|c| self.truth.at(c, y)[k]).sum::<f32>() / n
        })
    }

    fn inputs<'a>(&'a self, filtered: &'a Image) -> Inputs<'a> {
        Inputs {
            noisy: &self.noisy,
            filtered,
            variance: &self.variance,
            albedo: Some(&self.albedo),
            normal: Some(&self.normal),
        }
    }

    /// RMS error of `img` against the truth over columns `cols`.
    fn rms(&self, img: &Image, cols: impl Iterator<Item = usize> + Clone) -> f64 {
        let mut sum = 0.0f64;
        let mut n = 0.0;
        for y in 0..self.h {
            for x in cols.clone() {
                for k in 0..3 {
                    let d = (img.at(x, y)[k] - self.truth.at(x, y)[k]) as f64;
                    sum += d * d;
                    n += 1.0;
                }
            }
        }
        (sum / n).sqrt()
    }
}

#[test]
fn both_kernels_and_any_thread_count_give_the_same_bits() {
    for (w, h) in [(1, 1), (2, 3), (23, 17), (40, 9), (9, 40)] {
        let c = corner(w, h, 0.05, 7);
        let filtered = c.averaged(2);
        for features in [true, false] {
            let mut inputs = c.inputs(&filtered);
            if !features {
                (inputs.albedo, inputs.normal) = (None, None);
            }
            for radius in [1, 3, 6] {
                let p = Params {
                    radius,
                    ..Params::default()
                };
                let scalar = refine_with(Kernel::Scalar, inputs, &p);
                let fast = refine_with(Kernel::detect(), inputs, &p);
                // Every kernel this CPU runs: with AVX-512, the AVX2 copy too.
                for kernel in Kernel::ALL.into_iter().filter(|k| k.is_available()) {
                    let out = refine_with(kernel, inputs, &p);
                    assert_eq!(
                        bits(&scalar),
                        bits(&out),
                        "{w}x{h} radius {radius} {kernel:?}"
                    );
                }
                let one = rayon::ThreadPoolBuilder::new()
                    .num_threads(1)
                    .build()
                    .unwrap()
                    .install(|| refine_with(Kernel::detect(), inputs, &p));
                assert_eq!(bits(&one), bits(&fast), "{w}x{h}: 1 thread against all");
                assert!(fast.data().iter().all(|v| v.is_finite()));
            }
        }
    }
}

#[test]
fn the_bias_an_average_leaves_along_an_edge_is_taken_out() {
    // An average over ±6 columns of its wall reads the columns by the corner up to 0.015 too
    // bright (the light darkens into the corner); the noise is σ 0.02 per pixel.
    let c = corner(64, 48, 0.02, 11);
    let filtered = c.averaged(6);
    let out = refine_with(Kernel::detect(), c.inputs(&filtered), &Params::default());
    let band = c.w / 2 - 2..c.w / 2 + 2;
    let (before, after) = (c.rms(&filtered, band.clone()), c.rms(&out, band));
    assert!(
        after < 0.5 * before,
        "rms by the corner {before:.4} → {after:.4}"
    );
    // Away from the corner the average is right (the light is linear there) and stays so.
    let inside = 10..c.w / 2 - 10;
    let (before, after) = (c.rms(&filtered, inside.clone()), c.rms(&out, inside));
    assert!(
        after < before + 0.004,
        "rms inside {before:.4} → {after:.4}"
    );
}

#[test]
fn a_filter_that_is_right_is_left_nearly_alone() {
    // One wall lit by a linear ramp, so the fit has no bias, and a filtered image that is the
    // truth: the fit only adds its own noise. For Gaussian noise the mix keeps E[(1 − 3/X)₊² X/3]
    // of its squared error (X ~ χ²₃): an rms ratio of 0.41. Taking the fit whole would be 1.
    let (w, h) = (48, 40);
    let mut c = corner(w, h, 0.05, 3);
    c.truth = Image::from_fn(w, h, 3, |x, _, _| 0.1 + 0.004 * x as f32);
    let mut g = gaussian(17);
    c.noisy = Image::from_fn(w, h, 3, |x, y, k| c.truth.at(x, y)[k] + 0.05 * g());
    c.normal = Image::from_fn(w, h, 3, |_, _, k| (k == 2) as u8 as f32);
    let p = Params::default();
    let out = refine_with(Kernel::detect(), c.inputs(&c.truth), &p);
    let fit = regress_with(Kernel::detect(), c.inputs(&c.truth), &p).color;
    let all = 0..c.w;
    let (err, fit_err) = (c.rms(&out, all.clone()), c.rms(&fit, all));
    assert!(err < 0.6 * fit_err, "rms {err:.5} (the fit's {fit_err:.5})");
}

#[test]
fn hard_inputs_stay_finite() {
    let (w, h) = (13, 11);
    let c = corner(w, h, 0.05, 5);
    let filtered = c.averaged(2);
    let p = Params::default();
    let run = |noisy: &Image, filtered: &Image, variance: &Image| {
        let out = refine_with(
            Kernel::detect(),
            Inputs {
                noisy,
                filtered,
                variance,
                albedo: Some(&c.albedo),
                normal: Some(&c.normal),
            },
            &p,
        );
        assert!(out.data().iter().all(|v| v.is_finite()), "{:?}", out.data());
        out
    };
    // NaN, ±inf and a 1e6 firefly in the noisy colour; a NaN in the filtered one.
    let mut bad = c.noisy.clone();
    bad.pixel_mut(20).fill(f32::NAN);
    bad.pixel_mut(40).fill(f32::INFINITY);
    bad.pixel_mut(41).fill(f32::NEG_INFINITY);
    bad.pixel_mut(60).fill(1e6);
    let out = run(&bad, &filtered, &c.variance);
    // The firefly is held to 3σ of its neighbourhood's filtered value by the clip.
    assert!(
        out.pixel(60)[0] < filtered.pixel(60)[0] + 0.2,
        "{:?}",
        out.pixel(60)
    );
    // A NaN albedo (the stage's inputs are sanitised first, but the kernel is public).
    let mut bad_albedo = c.albedo.clone();
    bad_albedo.pixel_mut(30).fill(f32::NAN);
    let out = refine_with(
        Kernel::detect(),
        Inputs {
            albedo: Some(&bad_albedo),
            ..c.inputs(&filtered)
        },
        &p,
    );
    assert!(out.data().iter().all(|v| v.is_finite()));
    let mut bad_filtered = filtered.clone();
    bad_filtered.pixel_mut(5).fill(f32::NAN);
    run(&c.noisy, &bad_filtered, &c.variance);
    // A variance of zeros: no noise to take out, the filtered image comes back unchanged.
    let zeros = Image::filled(w, h, 3, 0.0);
    let out = run(&c.noisy, &filtered, &zeros);
    assert_eq!(bits(&out), bits(&filtered));
    // NaN, infinite and negative variances.
    let mut v = c.variance.clone();
    v.pixel_mut(3).fill(f32::NAN);
    v.pixel_mut(4).fill(f32::INFINITY);
    v.pixel_mut(5).fill(-1.0);
    run(&c.noisy, &filtered, &v);
    // Black and constant images; a tiny variance.
    let black = Image::filled(w, h, 3, 0.0);
    assert_eq!(bits(&run(&black, &black, &c.variance)), bits(&black));
    let grey = Image::filled(w, h, 3, 0.37);
    let out = run(&grey, &grey, &Image::filled(w, h, 3, 1e-30));
    assert_eq!(bits(&out), bits(&grey));
    // 1×1 and 2×1.
    for (w, h) in [(1, 1), (2, 1)] {
        let img = Image::filled(w, h, 3, 0.5);
        let out = refine_with(
            Kernel::detect(),
            Inputs {
                noisy: &img,
                filtered: &img,
                variance: &Image::filled(w, h, 3, 0.01),
                albedo: None,
                normal: None,
            },
            &p,
        );
        assert_eq!(bits(&out), bits(&img));
    }
}

#[test]
fn the_result_follows_the_exposure() {
    let c = corner(31, 23, 0.03, 9);
    let filtered = c.averaged(3);
    let base = refine_with(Kernel::detect(), c.inputs(&filtered), &Params::default());
    for scale in [1e-3f32, 1e4] {
        let s = |img: &Image, f: f32| Image::from_fn(c.w, c.h, 3, |x, y, k| img.at(x, y)[k] * f);
        let (noisy, filtered, variance) = (
            s(&c.noisy, scale),
            s(&filtered, scale),
            s(&c.variance, scale * scale),
        );
        let out = refine_with(
            Kernel::detect(),
            Inputs {
                noisy: &noisy,
                filtered: &filtered,
                variance: &variance,
                albedo: Some(&c.albedo),
                normal: Some(&c.normal),
            },
            &Params::default(),
        );
        for (a, b) in out.data().iter().zip(base.data()) {
            assert!(
                (a / scale - b).abs() <= 1e-4 * b.abs().max(1e-3),
                "×{scale}: {a} against {b}"
            );
        }
    }
}

#[test]
fn bad_regress_keys_are_one_line_errors() {
    for (key, culprit) in [
        ("regress.radius=0", "regress.radius"),
        ("regress.radius=17", "regress.radius"),
        ("regress.sigma=0", "regress.sigma"),
        ("regress.clip=nan", "regress.clip"),
        ("regress.normal_cos=2", "regress.normal_cos"),
        ("regress.albedo_sigma=-1", "regress.albedo_sigma"),
        ("regress.radios=3", "radios"),
    ] {
        assert_set_refused(key, culprit);
    }
}
