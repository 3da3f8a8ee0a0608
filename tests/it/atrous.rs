//! The à-trous stage: both kernels give the same bits, it keeps what it should keep, masked pixels
//! give no weight, hard inputs stay finite, and bad keys are one-line errors.

use crate::common::{assert_set_refused, default_features, synthetic_set};
use gsid::features::{FeaturePlanes, Features, Recipe, Tone, Weights};
use gsid::filters::atrous::pass::pass_with;
use gsid::kernels::simd::Kernel;
use gsid::{Buffers, DenoiseOptions, Image};

fn bits(img: &Image) -> Vec<u32> {
    img.data().iter().map(|v| v.to_bits()).collect()
}

/// The features of any band of rows, as the stage hands them to a pass.
fn features<'a>(
    color: &'a Image,
    set: &'a Buffers,
) -> impl Fn(std::ops::Range<usize>, usize) -> (FeaturePlanes, f32) + Sync + 'a {
    let recipe = Recipe::new(
        color,
        set.features(),
        &Weights::default(),
        Tone::Reinhard,
        1.0,
        None,
    )
    .unwrap();
    move |rows, pad| recipe.planes(rows, pad)
}

/// Makes every feature but albedo and colour uniform: one flat plane facing +z, fully lit, depth 1.
fn flat_plane(set: &mut Buffers) {
    let (w, h) = set.dims().unwrap();
    set.insert(
        "normal",
        Image::from_fn(w, h, 3, |_, _, c| (c == 2) as u8 as f32),
    )
    .unwrap();
    set.insert("depth", Image::from_fn(w, h, 1, |_, _, _| 1.0))
        .unwrap();
    set.insert("shadow", Image::from_fn(w, h, 1, |_, _, _| 1.0))
        .unwrap();
}

/// Also against the pass written out pixel by pixel: taps before the centre reuse the weights of
/// their mirrored taps, computed rows earlier, so heights past one band (32 rows) and every step
/// check that the reuse reads the right rows.
#[test]
fn both_kernels_any_thread_count_and_the_textbook_sum_give_the_same_bits() {
    for (w, h) in [(1, 1), (2, 3), (23, 17), (40, 9), (29, 37), (70, 41)] {
        let set = synthetic_set(w, h);
        let color = set.get("color").unwrap();
        let f = features(color, &set);
        // The records, which the textbook pass reads: the fast pass's planes are built without
        // them and must hold the same bits.
        let whole = default_features(color, &set);
        let mask: Vec<bool> = (0..w * h).map(|i| i % 7 == 3).collect();
        for m in [None, Some(mask.as_slice())] {
            for step in [1, 2, 4, 8] {
                for sigma in [1e-3, 0.2, 5.0] {
                    let scalar = pass_with(Kernel::Scalar, color, &f, m, step, sigma);
                    let fast = pass_with(Kernel::detect(), color, &f, m, step, sigma);
                    for kernel in Kernel::ALL.into_iter().filter(|k| k.is_available()) {
                        let out = pass_with(kernel, color, &f, m, step, sigma);
                        assert_eq!(
                            bits(&scalar),
                            bits(&out),
                            "{w}x{h} step {step} σ {sigma} {kernel:?}"
                        );
                    }
                    let want = textbook_pass(color, &whole, m, step, sigma);
                    assert_eq!(
                        bits(&fast),
                        bits(&want),
                        "{w}x{h} step {step} σ {sigma}: textbook"
                    );
                    let one = rayon::ThreadPoolBuilder::new()
                        .num_threads(1)
                        .build()
                        .unwrap()
                        .install(|| pass_with(Kernel::detect(), color, &f, m, step, sigma));
                    assert_eq!(bits(&one), bits(&fast), "{w}x{h}: 1 thread against all");
                    assert!(fast.data().iter().all(|v| v.is_finite()));
                }
            }
        }
    }
}

/// The pass written out pixel by pixel: every tap in raster order, its weight from
/// `Features::distance` of the two pixels and `exp_neg`, summed in f64.
fn textbook_pass(
    color: &Image,
    f: &Features,
    mask: Option<&[bool]>,
    step: usize,
    sigma: f32,
) -> Image {
    use gsid::filters::atrous::pass::TAPS;
    let (w, h) = color.dims();
    let inv = 1.0 / (2.0 * sigma * sigma);
    let keep = |i: usize| if mask.is_some_and(|m| m[i]) { 0.0 } else { 1.0 };
    Image::from_fn(w, h, 3, |x, y, k| {
        let (mut sum, mut weight) = (0.0f64, 0.0f64);
        for (a, &ha) in TAPS.iter().enumerate() {
            for (b, &hb) in TAPS.iter().enumerate() {
                let nx = x as isize + (b as isize - 2) * step as isize;
                let ny = y as isize + (a as isize - 2) * step as isize;
                if nx < 0 || ny < 0 || nx >= w as isize || ny >= h as isize {
                    continue;
                }
                let (i, j) = (y * w + x, ny as usize * w + nx as usize);
                let d = f.distance(i, j);
                let e = gsid::kernels::fastmath::exp_neg(-(d * d) * inv);
                let wgt = (ha * hb * e * keep(j) * keep(i)) as f64;
                sum += wgt * color.pixel(j)[k] as f64;
                weight += wgt;
            }
        }
        if weight > 0.0 && weight.is_finite() {
            (sum / weight) as f32
        } else {
            color.pixel(y * w + x)[k]
        }
    })
}

#[test]
fn a_constant_image_stays_constant() {
    let (w, h) = (19, 11);
    let mut set = synthetic_set(w, h);
    let color = Image::from_vec(w, h, 3, vec![0.37; w * h * 3]).unwrap();
    set.insert("color", color.clone()).unwrap();
    let f = features(&color, &set);
    let out = pass_with(Kernel::detect(), &color, &f, None, 2, 0.2);
    for &v in out.data() {
        assert!((v - 0.37).abs() < 1e-6, "{v}");
    }
}

#[test]
fn averaging_stops_at_an_albedo_edge_and_smooths_within_a_surface() {
    // Left half dark red surface, right half bright grey; the colour carries noise.
    let (w, h) = (24, 16);
    let mut set = synthetic_set(w, h);
    let mut albedo = vec![0.0f32; w * h * 3];
    let mut color = vec![0.0f32; w * h * 3];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let noise = if (x * 7 + y * 13) % 5 < 2 { 0.1 } else { -0.05 };
            let (a, c) = if x < w / 2 {
                ([0.8, 0.1, 0.1], 0.2)
            } else {
                ([0.7, 0.7, 0.7], 0.9)
            };
            albedo[3 * i..3 * i + 3].copy_from_slice(&a);
            for k in 0..3 {
                color[3 * i + k] = c + noise;
            }
        }
    }
    set.insert("albedo", Image::from_vec(w, h, 3, albedo).unwrap())
        .unwrap();
    // One flat, fully lit plane: only the albedo has an edge.
    flat_plane(&mut set);
    let color = Image::from_vec(w, h, 3, color).unwrap();
    set.insert("color", color.clone()).unwrap();
    let f = features(&color, &set);
    // σ = 1: this colour is raw noise, not a GSID result.
    let out = pass_with(Kernel::detect(), &color, &f, None, 1, 1.0);
    let spread = |img: &Image, xs: std::ops::Range<usize>| {
        let v: Vec<f32> = (0..h)
            .flat_map(|y| xs.clone().map(move |x| (x, y)))
            .map(|(x, y)| img.pixel(y * w + x)[0])
            .collect();
        let mean = v.iter().sum::<f32>() / v.len() as f32;
        (
            mean,
            v.iter().map(|a| (a - mean).abs()).fold(0.0f32, f32::max),
        )
    };
    let (left_in, left_in_spread) = spread(&color, 0..w / 2);
    let (left_out, left_out_spread) = spread(&out, 0..w / 2);
    let (right_in, _) = spread(&color, w / 2..w);
    let (right_out, _) = spread(&out, w / 2..w);
    assert!(
        left_out_spread < 0.5 * left_in_spread,
        "noise is smoothed: std {left_in_spread} → {left_out_spread}"
    );
    assert!(
        (left_out - left_in).abs() < 0.02,
        "no light leaks across the edge"
    );
    assert!((right_out - right_in).abs() < 0.02);
    // The columns next to the edge keep their side's level.
    for y in 0..h {
        assert!(out.pixel(y * w + w / 2 - 1)[0] < 0.45);
        assert!(out.pixel(y * w + w / 2)[0] > 0.65);
    }
}

#[test]
fn masked_pixels_give_no_weight_and_fireflies_stay_finite() {
    let (w, h) = (15, 13);
    let set = synthetic_set(w, h);
    let base = set.get("color").unwrap().clone();
    let firefly = 7 * w + 7;
    let mut mask = vec![false; w * h];
    mask[firefly] = true;
    let mut outs = Vec::new();
    for value in [0.0f32, 1e6] {
        let mut color = base.clone();
        color.pixel_mut(firefly).fill(value);
        let f = features(&color, &set);
        let out = pass_with(Kernel::detect(), &color, &f, Some(&mask), 1, 0.2);
        assert!(out.data().iter().all(|v| v.is_finite()));
        // Unmasked, the 1e6 firefly is still finite and stays bright where it is.
        let open = pass_with(Kernel::detect(), &color, &f, None, 1, 0.2);
        assert!(open.data().iter().all(|v| v.is_finite()));
        outs.push(out);
    }
    for i in (0..w * h).filter(|&i| i != firefly) {
        assert_eq!(
            outs[0].pixel(i),
            outs[1].pixel(i),
            "pixel {i} saw the masked firefly"
        );
    }
}

#[test]
fn bad_atrous_keys_are_one_line_errors() {
    for (key, culprit) in [
        ("atrous.iterations=0", "iterations"),
        ("atrous.iterations=13", "iterations"),
        ("atrous.sigma=-1", "sigma"),
        ("atrous.sigmaa=1", "sigmaa"),
        ("atrous.weights.albedo=-2", "albedo"),
    ] {
        assert_set_refused(key, culprit);
    }
}

#[test]
fn demodulation_keeps_texture_out_of_the_average() {
    use gsid::pipeline::PipelineSpec;
    // A flat, evenly lit plane with a 2×2-pixel checker albedo and noisy lighting.
    let (w, h) = (32, 32);
    let mut set = synthetic_set(w, h);
    let check = |x: usize, y: usize| {
        if (x / 2 + y / 2).is_multiple_of(2) {
            0.2
        } else {
            0.8
        }
    };
    let noise =
        |x: usize, y: usize| 1.0 + 0.3 * (((x * 7919 + y * 104_729) % 97) as f32 / 97.0 - 0.5);
    set.insert("albedo", Image::from_fn(w, h, 3, |x, y, _| check(x, y)))
        .unwrap();
    flat_plane(&mut set);
    set.insert(
        "color",
        Image::from_fn(w, h, 3, |x, y, _| 0.5 * check(x, y) * noise(x, y)),
    )
    .unwrap();
    let reference = Image::from_fn(w, h, 3, |x, y, _| 0.5 * check(x, y));
    let err = |demodulate: bool| {
        let text = format!(
            "name = \"t\"\ndescription = \"t\"\n[[stage]]\nkind = \"atrous\"\nsigma = 1.0\ndemodulate = {demodulate}\n"
        );
        let mut b = set.clone();
        let (out, _) = PipelineSpec::parse(&text, "t.toml")
            .unwrap()
            .build()
            .unwrap()
            .run(&mut b, &DenoiseOptions::seeded(0))
            .unwrap();
        gsid::metrics::score(&out, &reference).unwrap().relmse
    };
    let (plain, demodulated) = (err(false), err(true));
    assert!(
        demodulated < 0.5 * plain,
        "relMSE demodulated {demodulated} against plain {plain}"
    );
}

/// An emitter (albedo 0) above a wall, one of its pixels given some albedo (as a prefiltered or
/// gated albedo can have): its neighbours' light, divided by their 0 + 0.01 and multiplied back by
/// its own 0.08, came out above anything in the input (11.5 against 10 here, 8× on `textured` at
/// 1 spp). The output stays within its input's range.
#[test]
fn a_demodulated_pass_does_not_multiply_an_emitters_light() {
    use gsid::pipeline::PipelineSpec;
    let (w, h) = (24, 24);
    let mut set = synthetic_set(w, h);
    flat_plane(&mut set);
    let emitter = |x: usize, y: usize| (6..18).contains(&x) && y < 8;
    set.insert(
        "albedo",
        Image::from_fn(w, h, 3, |x, y, _| match (x, y) {
            (12, 4) => 0.07,
            _ if emitter(x, y) => 0.0,
            _ => 0.8,
        }),
    )
    .unwrap();
    set.insert(
        "color",
        Image::from_fn(w, h, 3, |x, y, _| if emitter(x, y) { 10.0 } else { 0.1 }),
    )
    .unwrap();
    let text =
        "name = \"t\"\ndescription = \"t\"\n[[stage]]\nkind = \"atrous\"\ndemodulate = true\n";
    let (out, _) = PipelineSpec::parse(text, "t.toml")
        .unwrap()
        .build()
        .unwrap()
        .run(&mut set.clone(), &DenoiseOptions::seeded(0))
        .unwrap();
    let brightest = out.data().iter().fold(0.0f32, |m, &v| m.max(v));
    assert!(
        brightest <= 10.0 * (1.0 + 1e-5),
        "the emitter's pixel (12, 4) is {:?}; the input is at most 10",
        out.pixel(4 * w + 12)
    );
    // The rest of the emitter and the wall stay what they were.
    assert!((out.pixel(2 * w + 8)[0] - 10.0).abs() < 1e-3);
    assert!((out.pixel(20 * w + 12)[0] - 0.1).abs() < 1e-3);
}
