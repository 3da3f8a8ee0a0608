//! The colour-edge step on edges no feature shows: a light's rim of few samples, a clean edge, a
//! thin line, stripes, and the hard images.

use super::super::tests::{run_stage, stripe_contrast};
use super::along_colour_edges;
use crate::image::Image;
use crate::meter::Meter;

/// The light's level and the ceiling's, and the share of the rim row's area the light covers.
const LIGHT: f32 = 6.5;
const CEILING: f32 = 0.05;
const COVER: f64 = 0.28;

/// 24×24: ceiling above row 11, light below it; row 11 is the rim, each pixel the mean of four
/// samples that each land on the light with chance [`COVER`] (or, with `clean`, the exact mix).
fn rim(seed: u64, clean: bool) -> Image {
    let mut next = crate::kernels::trim::tests::xorshift(seed);
    let mut uniform = move || (next() >> 11) as f64 / (1u64 << 53) as f64;
    let row: Vec<f32> = (0..24)
        .map(|_| {
            if clean {
                return (COVER * LIGHT as f64 + (1.0 - COVER) * CEILING as f64) as f32;
            }
            let hits = (0..4).filter(|_| uniform() < COVER).count() as f32;
            (hits * LIGHT + (4.0 - hits) * CEILING) / 4.0
        })
        .collect();
    Image::from_fn(24, 24, 3, |x, y, _| match y {
        0..=10 => CEILING,
        11 => row[x],
        _ => LIGHT,
    })
}

fn run(color: &Image, noise: f32) -> Image {
    let (w, h) = color.dims();
    let variance = Image::filled(w, h, 3, noise);
    along_colour_edges(color, &variance, (1, 1.0), &Meter::default())
}

/// Squared error of the rim row against its exact mix, away from the image's sides.
fn rim_error(img: &Image) -> f64 {
    let mix = COVER * LIGHT as f64 + (1.0 - COVER) * CEILING as f64;
    (2..22)
        .map(|x| (img.pixel(11 * 24 + x)[0] as f64 - mix).powi(2))
        .sum()
}

#[test]
fn a_lights_rim_of_few_samples_moves_towards_its_mix_though_its_noise_reads_small() {
    // The image's noise estimate trims the rim's pairs as an edge's and reads the ceiling's small
    // noise there; only the colour's scatter along the rim says how far its pixels may move. As
    // for a feature edge, a quarter less error is what a working step must at least reach (the
    // noise's own gate moves these pixels by less than a thousandth).
    for seed in [3, 5, 8] {
        let color = rim(seed, false);
        let out = run(&color, 1e-4);
        let (before, after) = (rim_error(&color), rim_error(&out));
        assert!(
            after < 0.75 * before,
            "seed {seed}: error {before} → {after}"
        );
        for y in (0..9).chain(14..24) {
            for x in 0..24 {
                assert_eq!(out.pixel(y * 24 + x), color.pixel(y * 24 + x), "({x}, {y})");
            }
        }
    }
}

#[test]
fn a_clean_rim_passes_unchanged() {
    let color = rim(3, true);
    let out = run(&color, 1e-4);
    for (a, b) in out.data().iter().zip(color.data()) {
        assert!((a - b).abs() <= 1e-6 * b.abs().max(1.0), "{a} against {b}");
    }
}

#[test]
fn a_thin_line_and_stripes_pass_unchanged() {
    // A one-pixel line: both sides of it are the same ceiling, so it is no edge between two.
    let mut next = crate::kernels::trim::tests::xorshift(13);
    let line: Vec<f32> = (0..24).map(|_| (next() >> 62) as f32 * 2.0).collect();
    let color = Image::from_fn(24, 24, 3, |x, y, _| if y == 11 { line[x] } else { CEILING });
    assert_eq!(run(&color, 1e-4), color);
    // Two-pixel stripes whose boundary pixels show a random side: edges three pixels apart.
    let flips: Vec<bool> = (0..24 * 24).map(|_| next() >> 63 == 1).collect();
    let stripe =
        |x: usize, y: usize| ((x / 2) % 2 == 1) ^ (x.is_multiple_of(2) && flips[y * 24 + x]);
    let color = Image::from_fn(24, 24, 3, |x, y, _| if stripe(x, y) { 0.9 } else { 0.1 });
    let out = run(&color, 1e-4);
    let (before, after) = (
        stripe_contrast(&color, stripe),
        stripe_contrast(&out, stripe),
    );
    assert!(after > 0.97 * before, "stripe contrast {before} → {after}");
}

#[test]
fn the_same_bits_on_one_and_two_threads() {
    let color = rim(5, false);
    let on = |threads| {
        crate::options::thread_pool(threads)
            .unwrap()
            .install(|| run(&color, 1e-4))
    };
    assert_eq!(on(1), on(2));
}

#[test]
fn hard_images_stay_finite_and_non_negative() {
    for (w, h) in [(1, 1), (1, 5), (5, 1), (2, 2), (3, 7), (24, 24)] {
        for value in [0.0f32, 1.0, 1e6, f32::MAX] {
            let mut color = Image::filled(w, h, 3, value);
            color.pixel_mut(0).fill(if value > 0.0 { 0.0 } else { 1e6 });
            for noise in [0.0, 1e-30, 1e3] {
                let out = run(&color, noise);
                assert!(
                    out.data().iter().all(|v| v.is_finite() && *v >= 0.0),
                    "{w}×{h} at {value}, noise {noise}: {:?}",
                    &out.data()[..out.data().len().min(12)]
                );
            }
        }
    }
}

#[test]
fn a_pattern_along_an_edge_that_is_no_mix_of_its_sides_passes_unchanged() {
    // Red spots along the boundary of a grey ceiling and a white light: their mean along the edge
    // lies off the line between the two sides, so they are the edge's own structure, not pixels
    // each some share of the two sides.
    let mut next = crate::kernels::trim::tests::xorshift(21);
    let spots: Vec<bool> = (0..24).map(|_| next() >> 63 == 1).collect();
    let color = Image::from_fn(24, 24, 3, |x, y, c| match y {
        0..=10 => 0.2,
        11 if spots[x] => [2.0, 0.0, 0.0][c],
        11 => 0.6,
        _ => 1.0,
    });
    // The rows beside it may follow the wobble of the edge's direction near a spot (and at the
    // image's border) by a hair.
    let out = run(&color, 1e-4);
    for i in 0..24 * 24 {
        let (a, b) = (out.pixel(i), color.pixel(i));
        if i / 24 == 11 {
            assert_eq!(a, b, "({}, 11)", i % 24);
        }
        for (a, b) in a.iter().zip(b) {
            assert!(
                (a - b).abs() <= 1e-2,
                "({}, {}): {a} against {b}",
                i % 24,
                i / 24
            );
        }
    }
}

/// The `coverage` stage (keys `table`, no features) on the rim of few samples, alone or as a
/// `--temporal` frame whose variance was measured from the shot.
fn staged(table: &str, from_stack: bool) -> Image {
    let mut set = crate::render_set::RenderSet::new(rim(5, false));
    set.noise.variance = Some(Image::filled(24, 24, 3, 1e-4));
    set.noise.from_stack = from_stack;
    run_stage(table, set)
}

#[test]
fn a_temporal_frame_skips_the_colour_step_unless_asked() {
    let single = staged("", false);
    assert_ne!(single, rim(5, false), "the case must show the colour step");
    // A `--temporal` frame: its merged colour holds the shot's samples.
    assert_eq!(staged("", true), rim(5, false));
    assert_eq!(staged("stack_colour = true", true), single);
}

#[test]
fn a_dark_pixel_beside_a_reflected_highlight_is_not_lit() {
    // `cycles-studio` at 16 spp, the filtered colour around a light reflected in the chrome bowl
    // (luminance, rows 61-69, columns 28-36): the dark pixel right of the highlight's core (row 4,
    // column 4, reference 0.028) was lit to 0.28 when some line through it ran between the
    // highlight's levels: the mean along it was a mix of its two sides, but neither side is one
    // level along it, so it is no edge whose pixels show one side or the other.
    #[rustfmt::skip]
    const PATCH: [[f32; 9]; 9] = [
        [0.035, 0.03, 0.026, 0.029, 0.026, 0.026, 0.027, 0.05, 0.2],
        [0.158, 0.138, 0.118, 0.072, 0.074, 0.072, 0.075, 0.074, 0.106],
        [0.062, 0.058, 0.054, 0.051, 0.04, 0.038, 0.05, 0.071, 0.083],
        [0.02, 1.572, 0.796, 0.62, 0.026, 0.024, 0.021, 0.027, 0.051],
        [1.774, 7.665, 6.74, 1.719, 0.024, 0.024, 0.024, 0.024, 0.024],
        [0.023, 1.553, 0.816, 0.665, 1.198, 0.024, 0.024, 0.024, 0.024],
        [0.087, 1.039, 0.589, 0.569, 0.542, 1.092, 1.049, 0.561, 0.045],
        [0.072, 0.145, 0.121, 0.119, 0.023, 0.02, 0.591, 0.043, 0.108],
        [0.205, 0.198, 0.164, 0.053, 0.034, 0.035, 0.044, 0.044, 0.045],
    ];
    let color = Image::from_fn(9, 9, 3, |x, y, _| PATCH[y][x]);
    // A noise of 3 % of each pixel's level: σ under 0.001 on the dark pixels, as the image's
    // estimate read them.
    let variance = Image::from_fn(9, 9, 3, |x, y, _| (0.03 * PATCH[y][x]).powi(2));
    let out = along_colour_edges(&color, &variance, (1, 1.0), &Meter::default());
    let dark = out.pixel(4 * 9 + 4)[0];
    assert!(
        (dark - 0.024).abs() < 0.005,
        "the dark pixel went 0.024 → {dark}"
    );
}
