//! Numerically hard inputs through whole pipelines: every output finite and sensible.

use crate::common::synthetic_set;
use gsid::pipeline::PipelineSpec;
use gsid::{Buffers, DenoiseOptions, Image};

fn run(pipeline: &str, sets: &[&str], buffers: &mut Buffers) -> Image {
    let mut spec = PipelineSpec::resolve(pipeline).unwrap();
    for s in sets {
        spec.apply_set(s).unwrap();
    }
    let (out, _) = spec
        .build()
        .unwrap()
        .run(buffers, &DenoiseOptions::seeded(5))
        .unwrap();
    out
}

fn assert_finite(img: &Image, what: &str) {
    assert!(img.all_finite(), "{what}: non-finite output");
    assert!(
        img.data().iter().all(|&v| v >= 0.0),
        "{what}: negative output"
    );
}

/// Every named pipeline, presets included.
const PIPELINES: [&str; 8] = [
    "gsid",
    "sid",
    "gsid-outlier",
    "pyramid",
    "full",
    "fast",
    "balanced",
    "quality",
];

#[test]
fn tiny_and_huge_sigma_stay_finite() {
    for p in PIPELINES {
        for sigma in ["1e-4", "1e4", "1e-6", "1e6"] {
            let mut b = synthetic_set(16, 12);
            let input = b.get("color").unwrap().clone();
            let key = if p != "gsid" && p != "sid" && p != "gsid-outlier" {
                "pyramid.gsid.sigma"
            } else {
                "gsid.sigma"
            };
            let out = run(p, &[&format!("{key}={sigma}")], &mut b);
            assert_finite(&out, &format!("{p} sigma {sigma}"));
            let mean_in = input.channel_means().iter().sum::<f64>();
            let mean_out = out.channel_means().iter().sum::<f64>();
            assert!(
                (mean_in - mean_out).abs() < 0.25 * mean_in,
                "{p} sigma {sigma}: mean {mean_in} → {mean_out}"
            );
        }
    }
}

#[test]
fn fireflies_of_a_million_stay_finite_and_local() {
    for p in PIPELINES {
        let mut b = synthetic_set(24, 24);
        let c = b.get_mut("color").unwrap();
        for i in [30usize, 200, 401] {
            c.pixel_mut(i).copy_from_slice(&[1e6, 1e6, 1e6]);
        }
        let out = run(p, &[], &mut b);
        assert_finite(&out, p);
        // A firefly may spread, but not to the far corner of the image.
        assert!(
            out.pixel(24 * 24 - 1)[0] < 1e3,
            "{p}: firefly reached the far corner"
        );
    }
}

/// A frame of nothing but fireflies (every pixel black or 1e6, at random), with features that are
/// salt and pepper too and a depth that is mostly unrecorded (0): what the reliability gate, the
/// outlier test and the noise estimate see at their worst.
#[test]
fn a_frame_of_nothing_but_fireflies_stays_finite() {
    for p in PIPELINES {
        let mut b = synthetic_set(20, 17);
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut coin = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state.is_multiple_of(3)
        };
        for i in 0..20 * 17 {
            let v = if coin() { 1e6 } else { 0.0 };
            b.get_mut("color").unwrap().pixel_mut(i).fill(v);
            let a = if coin() { 0.9 } else { 0.1 };
            b.get_mut("albedo").unwrap().pixel_mut(i).fill(a);
            if coin() || coin() {
                b.get_mut("depth").unwrap().pixel_mut(i)[0] = 0.0;
            }
        }
        let out = run(p, &[], &mut b);
        assert_finite(&out, p);
    }
}

#[test]
fn nan_and_inf_pixels_are_sanitised() {
    for p in PIPELINES {
        let mut b = synthetic_set(10, 10);
        let c = b.get_mut("color").unwrap();
        c.pixel_mut(3)
            .copy_from_slice(&[f32::NAN, f32::INFINITY, f32::NEG_INFINITY]);
        c.pixel_mut(57).copy_from_slice(&[f32::NAN; 3]);
        b.get_mut("normal")
            .unwrap()
            .pixel_mut(4)
            .copy_from_slice(&[f32::NAN; 3]);
        b.get_mut("depth").unwrap().pixel_mut(5)[0] = f32::INFINITY;
        b.get_mut("albedo").unwrap().pixel_mut(6)[0] = f32::NAN;
        let out = run(p, &[], &mut b);
        assert_finite(&out, p);
    }
}

#[test]
fn black_and_constant_images_come_back_unchanged() {
    for p in PIPELINES {
        // 3e37: a scale to unit brightness below 1/f32::MAX, whose f32 inverse is infinite (it came
        // back +inf); 1e-30: one near f32's bottom.
        for value in [0.0f32, 0.37, 1e5, 3e37, 1e-30] {
            let mut b = synthetic_set(9, 7);
            b.insert("color", Image::filled(9, 7, 3, value)).unwrap();
            let out = run(p, &[], &mut b);
            assert!(
                out.data()
                    .iter()
                    .all(|&v| (v - value).abs() <= value * 1e-6),
                "{p}: constant {value} changed"
            );
        }
    }
}

#[test]
fn degenerate_sizes_work() {
    for p in PIPELINES {
        for (w, h) in [(1, 1), (1, 9), (9, 1), (3, 5), (2, 2)] {
            let mut b = synthetic_set(w, h);
            let out = run(p, &[], &mut b);
            assert_eq!(out.dims(), (w, h));
            assert_finite(&out, &format!("{p} {w}x{h}"));
        }
    }
}

#[test]
fn a_single_pixel_comes_back_as_itself() {
    let mut b = Buffers::new();
    b.insert(
        "color",
        Image::from_vec(1, 1, 3, vec![0.1, 0.2, 0.3]).unwrap(),
    )
    .unwrap();
    for p in PIPELINES {
        let out = run(p, &[], &mut b.clone());
        let close = out
            .data()
            .iter()
            .zip([0.1f32, 0.2, 0.3])
            .all(|(a, b)| (a - b).abs() <= 1e-6);
        assert!(close, "{p}: {:?}", out.data());
    }
}

#[test]
fn full_pipeline_is_identical_on_one_and_two_threads() {
    let spec = PipelineSpec::resolve("full").unwrap();
    let pipeline = spec.build().unwrap();
    let run_on = |threads| {
        let mut b = synthetic_set(40, 29);
        b.get_mut("color")
            .unwrap()
            .pixel_mut(100)
            .copy_from_slice(&[1e6; 3]);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let out = pool.install(|| pipeline.run(&mut b, &DenoiseOptions::seeded(9)).unwrap().0);
        out.data().iter().map(|v| v.to_bits()).collect::<Vec<_>>()
    };
    assert_eq!(run_on(1), run_on(2));
}

/// `out / k`: a result brought back to the ×1 render's scale.
fn at_unit_scale(out: &Image, k: f32) -> Image {
    Image::from_fn(out.width(), out.height(), 3, |x, y, c| out.at(x, y)[c] / k)
}

/// The render set with every radiance buffer scaled by `k` (a variance by k²), as a renderer with a
/// different exposure would write it.
fn exposed(set: &gsid::RenderSet, k: f32, with_noise: bool) -> Buffers {
    let mut b = Buffers::from(set.clone());
    for name in ["color", "color_a", "color_b", "variance"] {
        let present = b.get(name).is_some();
        if !present {
            continue;
        }
        if !with_noise && name != "color" {
            b.remove(name);
            continue;
        }
        let factor = if name == "variance" { k * k } else { k };
        b.get_mut(name)
            .unwrap()
            .data_mut()
            .iter_mut()
            .for_each(|v| *v *= factor);
    }
    b
}

#[test]
fn results_follow_the_render_s_brightness_scale() {
    // textured carries gsid render's variance and half buffers: both ways of knowing the noise.
    let set = gsid::io::load_render_set(std::path::Path::new("fixtures/textured/spp4")).unwrap();
    let reference = gsid::io::read_image(set.reference.as_ref().unwrap(), 3).unwrap();
    assert!(set.set.noise.variance.is_some());
    for with_noise in [false, true] {
        let out =
            |k: f32| at_unit_scale(&run("full", &[], &mut exposed(&set.set, k, with_noise)), k);
        let unit = out(1.0);
        // The filter itself is good at ×1, so "the same output up to scale" is a meaningful claim.
        assert!(gsid::metrics::rel_mse(&unit, &reference) < 0.02);
        for k in [1e-3f32, 1e4] {
            let e = gsid::metrics::rel_mse(&out(k), &unit);
            assert!(
                e <= 1e-3,
                "brightness ×{k} (noise buffers: {with_noise}): relMSE {e:.2e} against the ×1 output"
            );
        }
    }
}

#[test]
fn every_render_is_filtered_at_the_unit_brightness() {
    let unit = gsid::condition::UNIT_BRIGHTNESS;
    let mut images: Vec<Image> = [
        "mitsuba-cornell",
        "cornell",
        "caustics",
        "textured",
        "detail",
    ]
    .iter()
    .map(|name| {
        gsid::io::read_image(
            std::path::Path::new(&format!("fixtures/{name}/spp1/color.exr")),
            3,
        )
        .unwrap()
    })
    .collect();
    images.push(Image::filled(4, 4, 3, 100.0));
    images.push(Image::filled(4, 4, 3, 1e-30));
    for img in images {
        let k = gsid::condition::exposure_scale(&img);
        let scaled = Image::from_fn(img.width(), img.height(), 3, |x, y, c| img.at(x, y)[c] * k);
        let b = gsid::condition::robust_brightness(&scaled);
        assert!((b / unit - 1.0).abs() < 1e-5, "brightness {b} after ×{k}");
    }
    assert_eq!(gsid::condition::exposure_scale(&Image::new(4, 4, 3)), 1.0);
}

#[test]
fn hard_cases_cover_every_named_pipeline() {
    let mut named: Vec<&str> = gsid::pipeline::BUILTIN.iter().map(|(n, _)| *n).collect();
    let mut covered = PIPELINES.to_vec();
    named.sort_unstable();
    covered.sort_unstable();
    assert_eq!(covered, named);
}

/// Outputs are finite and non-negative wherever the input colour was, on the inputs where they
/// were not: `full` on the Mitsuba box at 1 spp (24 negative pixels, down to −0.012: the
/// first-order fit extrapolated below 0), a variance buffer of 1e38 (hundreds, every preset), and
/// half the colour NaN (`fast`).
#[test]
fn outputs_are_finite_and_non_negative_on_the_reported_inputs() {
    let set = gsid::io::load_render_set(std::path::Path::new("fixtures/mitsuba-cornell/spp1"))
        .unwrap()
        .set;
    let (w, h) = set.color.dims();
    for p in PIPELINES {
        let out = run(p, &[], &mut Buffers::from(set.clone()));
        assert_finite(&out, &format!("{p}, Mitsuba box 1 spp"));
        let mut b = Buffers::from(set.clone());
        b.insert("variance", Image::filled(w, h, 3, 1e38)).unwrap();
        let out = run(p, &[], &mut b);
        assert_finite(&out, &format!("{p}, variance 1e38"));
        let mut b = Buffers::from(set.clone());
        let c = b.get_mut("color").unwrap();
        for i in (0..w * h).step_by(2) {
            c.pixel_mut(i).copy_from_slice(&[f32::NAN; 3]);
        }
        let out = run(p, &[], &mut b);
        assert_finite(&out, &format!("{p}, half the colour NaN"));
    }
}

/// Fog at one sample a pixel: each pixel's sample saw, at random, the medium (bright, albedo 0.9)
/// or the surface behind it (dark, albedo 0.2), so the colour and the albedo are the same salt and
/// pepper, whose reference is flat (the mix). With `blender`, a medium sample writes what Blender
/// writes for it, a camera-facing normal and depth 0; without, the geometry is the surface's alone.
/// How much of the pattern the output keeps: the mean output of the medium's pixels minus that of
/// the surface's, away from the border (the input's is 0.7).
fn fog_contrast(sets: &[&str], blender: bool) -> f64 {
    let (w, h) = (40, 40);
    let mut b = synthetic_set(w, h);
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let medium: Vec<bool> = (0..w * h)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state % 10 < 3
        })
        .collect();
    let mix = Image::from_fn(w, h, 3, |x, y, _| if medium[y * w + x] { 0.9 } else { 0.2 });
    b.insert("color", mix.clone()).unwrap();
    b.insert("albedo", mix).unwrap();
    let scattered = |x: usize, y: usize| blender && medium[y * w + x];
    // The surface a floor (normal +y); a sample that scattered faces the camera (+z).
    let normal = Image::from_fn(w, h, 3, |x, y, c| {
        let axis = if scattered(x, y) { 2 } else { 1 };
        (c == axis) as u8 as f32
    });
    b.insert("normal", normal).unwrap();
    let depth = Image::from_fn(w, h, 1, |x, y, _| if scattered(x, y) { 0.0 } else { 2.0 });
    b.insert("depth", depth).unwrap();
    b.remove("material");
    b.remove("shadow");
    let out = run("full", sets, &mut b);
    let (mut sums, mut counts) = ([0.0f64; 2], [0.0f64; 2]);
    for y in 4..h - 4 {
        for x in 4..w - 4 {
            let k = medium[y * w + x] as usize;
            sums[k] += out.at(x, y)[1] as f64;
            counts[k] += 1.0;
        }
    }
    sums[1] / counts[1] - sums[0] / counts[0]
}

#[test]
fn a_salt_and_pepper_albedo_guides_little() {
    // The output keeps less than a tenth of the input's pattern (it kept a sixth when the gate
    // pulled the albedo to its median, whose blotches guided the walks and the demodulation).
    // `full` trusts the albedo as far as the geometry (`albedo_by_geometry`), and Blender's
    // geometry in fog is as noisy as its albedo.
    let kept = fog_contrast(&[], true);
    assert!(kept.abs() < 0.07, "kept {kept} of the input's 0.7");
    // The gate alone, on geometry that shows only the surface.
    let floor_off = "reliability.albedo_by_geometry=false";
    let gate = fog_contrast(&[floor_off], false);
    assert!(
        gate.abs() < 0.07,
        "the gate alone kept {gate} of the input's 0.7"
    );
    // The median centre, still selectable, keeps more of it.
    let median = fog_contrast(&[floor_off, "reliability.centre=median"], false);
    assert!(gate < median, "mean {gate} against median {median}");
}
