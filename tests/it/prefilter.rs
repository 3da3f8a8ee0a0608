//! The feature prefilter (docs/ALGORITHM.md §8, "Noisy features"): it lowers the error of a noisy
//! albedo and normal against the clean ones, keeps a sharp edge and a checker texture when the
//! noise is low, stays finite on hard cases, and gives the same bits on 1 and 2 threads.

use gsid::filters::prefilter::{self, Estimate, Kind, Params, PrefilterParams};
use gsid::render_set::Feature;
use gsid::{Buffers, DenoiseOptions, Image, PipelineSpec, RenderSet};

/// The `prefilter` stage's defaults.
fn params() -> Params {
    PrefilterParams::default().kernel_params()
}

/// A reproducible uniform stream in [0, 1).
fn uniforms(seed: u64) -> impl FnMut() -> f32 {
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// The variance the `prefilter` stage reads by default.
fn variance(img: &Image, kind: Kind) -> Vec<f32> {
    match PrefilterParams::default().estimate {
        Estimate::Directional => prefilter::line_aware_variance(img, kind, params().keep),
        Estimate::Trimmed => prefilter::variance(img, kind, params().keep),
    }
}

fn filtered(img: &Image, kind: Kind) -> Image {
    prefilter::filter(img, &variance(img, kind), kind, &params())
}

fn rms(a: &Image, b: &Image) -> f64 {
    let n = a.data().len() as f64;
    let sum: f64 = a
        .data()
        .iter()
        .zip(b.data())
        .map(|(x, y)| (*x as f64 - *y as f64).powi(2))
        .sum();
    (sum / n).sqrt()
}

/// A clean albedo: two flat regions split by a vertical edge at x = 20.
fn two_regions(w: usize, h: usize) -> Image {
    Image::from_fn(
        w,
        h,
        3,
        |x, _, k| if x < 20 { 0.2 + 0.1 * k as f32 } else { 0.8 },
    )
}

/// A few-sample albedo: each pixel the mean of `spp` samples, each of which sees the pixel's own
/// surface or (with probability `p`) another one, as under a glossy reflection or depth of field.
fn few_sample(clean: &Image, spp: usize, p: f32, seed: u64) -> Image {
    let mut u = uniforms(seed);
    let mut out = clean.clone();
    for px in out.data_mut().chunks_exact_mut(3) {
        let mut acc = [0.0f32; 3];
        for _ in 0..spp {
            let other = u() < p;
            let stray = [u(), u(), u()];
            for k in 0..3 {
                acc[k] += if other { stray[k] } else { px[k] };
            }
        }
        for k in 0..3 {
            px[k] = acc[k] / spp as f32;
        }
    }
    out
}

#[test]
fn lowers_the_error_of_a_noisy_albedo() {
    let clean = two_regions(48, 40);
    // At 1 spp a stray sample is an impulse the window's other pixels outvote (read as structure,
    // and barely filtered); from 2 samples on the strays are spread over most pixels.
    for spp in [2, 4] {
        let noisy = few_sample(&clean, spp, 0.3, 11);
        let out = filtered(&noisy, Kind::Plain);
        let (before, after) = (rms(&noisy, &clean), rms(&out, &clean));
        assert!(
            after < 0.85 * before,
            "{spp} spp: rms {before:.4} → {after:.4}"
        );
        assert!(out.all_finite());
    }
}

/// Thin mortar lines across flat bricks, each line pixel's coverage sampled 4 times: the stage's
/// estimate finds the lines' noise along them and averages it out; the trimmed window alone takes
/// the lines for structure and leaves them.
#[test]
fn lowers_the_error_of_thin_lines_few_sample_coverage() {
    let (w, h) = (48, 36);
    let on_line = |y: usize| y % 6 == 3;
    let (brick, mortar) = (0.6f32, 0.95f32);
    let clean = Image::from_fn(w, h, 3, |_, y, _| {
        if on_line(y) {
            0.5 * (brick + mortar)
        } else {
            brick
        }
    });
    let mut u = uniforms(23);
    let mut noisy = clean.clone();
    for (i, px) in noisy.data_mut().chunks_exact_mut(3).enumerate() {
        if on_line(i / w) {
            let hits = (0..4).filter(|_| u() < 0.5).count() as f32;
            px.fill(brick + (mortar - brick) * hits / 4.0);
        }
    }
    let lines = |img: &Image| {
        let sum: f64 = (0..w * h)
            .filter(|&i| on_line(i / w))
            .map(|i| (img.pixel(i)[0] as f64 - clean.pixel(i)[0] as f64).powi(2))
            .sum();
        (sum / (w * h / 6) as f64).sqrt()
    };
    let before = lines(&noisy);
    let after = lines(&filtered(&noisy, Kind::Plain));
    let trimmed = prefilter::variance(&noisy, Kind::Plain, params().keep);
    let left = lines(&prefilter::filter(&noisy, &trimmed, Kind::Plain, &params()));
    assert!(
        after < 0.85 * before,
        "rms on the lines {before:.4} → {after:.4}"
    );
    assert!(
        left > 0.99 * before,
        "trimmed alone: {before:.4} → {left:.4}"
    );
}

#[test]
fn lowers_the_error_of_noisy_normals_and_keeps_them_unit() {
    let (w, h) = (40, 40);
    // A crease: two planes whose normals meet at x = 20, plus Gaussian-like jitter.
    let clean = Image::from_fn(w, h, 3, |x, _, k| {
        let n = if x < 20 {
            [0.6, 0.0, 0.8]
        } else {
            [-0.6, 0.0, 0.8]
        };
        n[k]
    });
    let mut u = uniforms(5);
    let mut noisy = clean.clone();
    for px in noisy.data_mut().chunks_exact_mut(3) {
        for v in px.iter_mut() {
            *v += 0.08 * ((0..4).map(|_| u()).sum::<f32>() - 2.0);
        }
        let len = px.iter().map(|v| v * v).sum::<f32>().sqrt();
        px.iter_mut().for_each(|v| *v /= len);
    }
    let out = filtered(&noisy, Kind::Normal);
    let (before, after) = (rms(&noisy, &clean), rms(&out, &clean));
    assert!(after < 0.7 * before, "rms {before:.4} → {after:.4}");
    for px in out.data().chunks_exact(3) {
        let len = px.iter().map(|v| v * v).sum::<f32>().sqrt();
        assert!((len - 1.0).abs() < 1e-5, "normal of length {len}");
    }
    // The crease stays: the columns beside it keep their own plane's normal.
    for y in 0..h {
        assert!(
            out.at(18, y)[0] > 0.45 && out.at(21, y)[0] < -0.45,
            "row {y}"
        );
    }
}

#[test]
fn keeps_a_sharp_edge_and_a_checker_at_low_noise() {
    let (w, h) = (48, 48);
    let checker = |x: usize, y: usize| ((x / 4 + y / 4) % 2) as f32;
    let clean = Image::from_fn(w, h, 3, |x, y, k| {
        if x < 24 {
            0.1 + 0.8 * checker(x, y)
        } else {
            [0.9, 0.5, 0.1][k]
        }
    });
    let mut u = uniforms(3);
    let noisy = Image::from_vec(
        w,
        h,
        3,
        clean
            .data()
            .iter()
            .map(|v| v + 0.01 * ((0..12).map(|_| u()).sum::<f32>() - 6.0))
            .collect(),
    )
    .unwrap();
    let out = filtered(&noisy, Kind::Plain);
    let worst = out
        .data()
        .iter()
        .zip(clean.data())
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(worst < 0.06, "texture or edge moved by {worst}");
    // Noise-free, nothing changes at all.
    assert_eq!(filtered(&clean, Kind::Plain), clean);
}

#[test]
fn hard_cases_stay_finite() {
    for (w, h) in [(1, 1), (1, 7), (2, 3), (5, 1), (17, 9)] {
        let mut u = uniforms((w * 31 + h) as u64);
        let noisy = Image::from_fn(w, h, 3, |_, _, _| u());
        for kind in [Kind::Plain, Kind::Normal] {
            let out = filtered(&noisy, kind);
            assert!(out.all_finite(), "{w}x{h} {kind:?}");
        }
        let depth = Image::from_fn(w, h, 1, |_, _, _| 1.0 + u());
        assert!(filtered(&depth, Kind::Depth).all_finite());
    }
    for value in [0.0, 0.5, 1e30] {
        let flat = Image::filled(9, 6, 3, value);
        assert_eq!(filtered(&flat, Kind::Plain), flat, "constant {value}");
    }
    // Unknown normals (all zero) stay unknown; known ones beside them stay finite and unit.
    let mut u = uniforms(9);
    let normals = Image::from_fn(12, 12, 3, |x, _, _| if x % 3 == 0 { 0.0 } else { u() });
    let out = filtered(&normals, Kind::Normal);
    for (i, px) in out.data().chunks_exact(3).enumerate() {
        if i % 3 == 0 {
            assert_eq!(px, [0.0; 3]);
        } else {
            assert!(px.iter().all(|v| v.is_finite()));
        }
    }
    // Through the stage, on a black frame with black features, and on a 1×1 frame.
    for (w, h) in [(8, 6), (1, 1)] {
        let black = || Image::new(w, h, 3);
        let set = RenderSet::new(black())
            .with(Feature::Albedo, black())
            .unwrap()
            .with(Feature::Normal, black())
            .unwrap();
        let out = run_full(&Buffers::from(set), 1);
        assert!(out.all_finite());
    }
}

/// A noisy render set: colour, and albedo and normal with few-sample noise.
fn noisy_set(w: usize, h: usize) -> Buffers {
    let albedo = few_sample(&two_regions(w, h), 2, 0.3, 17);
    let mut u = uniforms(23);
    let normal = Image::from_fn(w, h, 3, |_, _, k| if k == 2 { 1.0 } else { 0.2 * u() });
    let color = Image::from_fn(w, h, 3, |x, y, k| albedo.at(x, y)[k] * (0.5 + u()));
    let set = RenderSet::new(color)
        .with(Feature::Albedo, albedo)
        .unwrap()
        .with(Feature::Normal, normal)
        .unwrap();
    Buffers::from(set)
}

fn run_full(buffers: &Buffers, threads: usize) -> Image {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let spec = PipelineSpec::parse(
        "name = \"p\"\n[[stage]]\nkind = \"prefilter\"\n[[stage]]\nkind = \"gsid\"\nwalks = 2\n",
        "p.toml",
    )
    .unwrap();
    let pipeline = spec.build().unwrap();
    pool.install(|| {
        pipeline
            .run(&mut buffers.clone(), &DenoiseOptions::seeded(0))
            .unwrap()
            .0
    })
}

#[test]
fn same_bits_on_one_and_two_threads() {
    let buffers = noisy_set(37, 23);
    assert_eq!(run_full(&buffers, 1).data(), run_full(&buffers, 2).data());
    let albedo = buffers.features().get(Feature::Albedo).unwrap();
    let on = |threads| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| filtered(albedo, Kind::Plain))
    };
    let (one, two) = (on(1), on(2));
    assert_ne!(&one, albedo, "the noisy albedo was not filtered at all");
    assert_eq!(one.data(), two.data());
}

#[test]
fn bad_keys_are_named() {
    for (text, key) in [
        ("features = [\"colour\"]", "prefilter.features"),
        ("features = [\"albedo\", \"albedo\"]", "prefilter.features"),
        ("strength = 0.0", "prefilter.strength"),
        ("keep = 1.0", "prefilter.keep"),
        ("radius = 0", "prefilter.radius"),
        ("patch = 9", "prefilter.patch"),
        ("estimate = \"median\"", "estimate"),
        ("stregth = 1.0", "stregth"),
    ] {
        let file = format!("name = \"p\"\n[[stage]]\nkind = \"prefilter\"\n{text}\n");
        let err = PipelineSpec::parse(&file, "p.toml")
            .unwrap()
            .build()
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains(key), "{text}: {err}");
    }
}

#[test]
fn both_kernels_give_the_same_bits() {
    for (w, h) in [(1, 1), (2, 3), (5, 4), (23, 17), (41, 9)] {
        let albedo = few_sample(&two_regions(w, h), 2, 0.3, 5);
        let normal = Image::from_fn(w, h, 3, |x, y, k| {
            // Unknown (all-zero) normals on a diagonal, noisy unit normals elsewhere.
            if (x + y) % 5 == 0 {
                0.0
            } else {
                [0.1 * ((x * 7 + y) % 3) as f32, 0.2, 0.97][k]
            }
        });
        let depth = Image::from_fn(w, h, 1, |x, y, _| {
            1.0 + 0.01 * ((x * 13 + y * 7) % 5) as f32
        });
        for (img, kind) in [
            (&albedo, Kind::Plain),
            (&normal, Kind::Normal),
            (&depth, Kind::Depth),
        ] {
            for keep in [0.65, 0.3] {
                let scalar =
                    prefilter::variance_with(gsid::kernels::simd::Kernel::Scalar, img, kind, keep);
                let fast = prefilter::variance_with(
                    gsid::kernels::simd::Kernel::detect(),
                    img,
                    kind,
                    keep,
                );
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(
                    bits(&scalar),
                    bits(&fast),
                    "{w}x{h} {kind:?} keep {keep}: variance"
                );
                let p = Params { keep, ..params() };
                let a = prefilter::filter_with(
                    gsid::kernels::simd::Kernel::Scalar,
                    img,
                    &fast,
                    kind,
                    &p,
                );
                let b = prefilter::filter_with(
                    gsid::kernels::simd::Kernel::detect(),
                    img,
                    &fast,
                    kind,
                    &p,
                );
                assert_eq!(bits(a.data()), bits(b.data()), "{w}x{h} {kind:?}: filter");
                assert!(b.data().iter().all(|v| v.is_finite()));
            }
        }
    }
}

/// Depth's ε is relative to the pixel's depth (ε·z²), so filtering depth in metres or in
/// millimetres gives the same surface: the result scales with its input. With one ε for every
/// depth, noise far below it (here 0.003 around 1) would average freely in metres and by its own
/// variance in millimetres.
#[test]
fn depth_filters_the_same_in_any_unit() {
    let (w, h) = (24, 16);
    let mut u = uniforms(11);
    let metres = Image::from_fn(w, h, 1, |x, _, _| {
        let z = if x < w / 2 { 1.0 } else { 1.5 };
        z + 0.003 * (u() - 0.5)
    });
    let filtered = |img: &Image| {
        let v = prefilter::variance(img, Kind::Depth, params().keep);
        prefilter::filter(img, &v, Kind::Depth, &params())
    };
    let mut millimetres = metres.clone();
    millimetres.data_mut().iter_mut().for_each(|z| *z *= 1000.0);
    let (a, b) = (filtered(&metres), filtered(&millimetres));
    let worst = a
        .data()
        .iter()
        .zip(b.data())
        .map(|(&m, &mm)| ((mm / 1000.0 - m) / m).abs())
        .fold(0.0f32, f32::max);
    assert!(worst < 1e-5, "relative difference {worst}");
    assert_ne!(a.data(), metres.data(), "the noise was filtered");
}
