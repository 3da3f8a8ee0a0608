//! The coverage stage on edges built to show each case: a staircase of few samples, a clean
//! anti-aliased edge, stripes, no noise, and the hard images.

use super::{along_edges, normals, Guide};
use crate::image::Image;
use crate::meter::Meter;
use crate::render_set::{Feature, FeatureSet};

/// Side A (albedo 0.2, colour 0.1) left of column 11, side B (0.8, 0.9) right of column 12; the
/// two columns between are the edge: `edge(x, y)` says which side, or a mix, each pixel shows.
fn render((w, h): (usize, usize), edge: impl Fn(usize, usize) -> f32) -> (Image, FeatureSet) {
    let side = |x: usize, y: usize| match x {
        0..=10 => 0.0,
        11 | 12 => edge(x, y),
        _ => 1.0,
    };
    let color = Image::from_fn(w, h, 3, |x, y, _| 0.1 + 0.8 * side(x, y));
    let mut set = FeatureSet::default();
    set.set(
        Feature::Albedo,
        Image::from_fn(w, h, 3, |x, y, _| 0.2 + 0.6 * side(x, y)),
    )
    .unwrap();
    (color, set)
}

fn run(color: &Image, set: &FeatureSet, noise: f32) -> Image {
    let guide = Guide::new(set, color.dims()).expect("an albedo");
    let dirs = normals(&guide);
    let variance = Image::filled(color.dims().0, color.dims().1, 3, noise);
    along_edges(color, &variance, &guide, &dirs, (1, 1.0), &Meter::default())
}

/// A pixel of the edge columns shows one side at random (one sample a pixel, half the pixel's area
/// on each side).
fn staircase() -> (Image, FeatureSet) {
    let mut next = crate::kernels::trim::tests::xorshift(7);
    let flips: Vec<bool> = (0..2 * 24).map(|_| next() >> 63 == 1).collect();
    render((24, 24), |x, y| flips[2 * y + (x - 11)] as u8 as f32)
}

#[test]
fn a_staircase_of_few_samples_moves_towards_its_mix() {
    let (color, set) = staircase();
    let out = run(&color, &set, 0.2);
    // Expected colour of an edge pixel: half of each side, 0.5.
    let err = |img: &Image| -> f64 {
        (2..22)
            .flat_map(|y| [11, 12].map(|x| (img.pixel(y * 24 + x)[0] as f64 - 0.5).powi(2)))
            .sum()
    };
    // The mean of three random sides has a third of one side's variance: with the share and the
    // noise weight below 1, a quarter less error is what a working stage must at least reach.
    let (before, after) = (err(&color), err(&out));
    assert!(after < 0.75 * before, "error {before} → {after}");
    for y in 0..24 {
        for x in (0..8).chain(16..24) {
            assert_eq!(
                out.pixel(y * 24 + x),
                color.pixel(y * 24 + x),
                "flat ({x}, {y})"
            );
        }
    }
}

#[test]
fn without_noise_nothing_moves() {
    let (color, set) = staircase();
    assert_eq!(run(&color, &set, 0.0), color);
}

#[test]
fn a_clean_anti_aliased_edge_passes_unchanged() {
    let (color, set) = render((24, 24), |x, _| if x == 11 { 0.3 } else { 0.7 });
    assert_eq!(run(&color, &set, 0.2), color);
}

#[test]
fn stripes_pass_unchanged() {
    // Two-pixel stripes whose pixels next to a boundary show a random side: edges three pixels
    // apart, whose direction is not one line's.
    let mut next = crate::kernels::trim::tests::xorshift(11);
    let flips: Vec<bool> = (0..24 * 24).map(|_| next() >> 63 == 1).collect();
    let stripe = |x: usize, y: usize| {
        let base = (x / 2) % 2 == 1;
        if x.is_multiple_of(2) && flips[y * 24 + x] {
            !base
        } else {
            base
        }
    };
    let color = Image::from_fn(24, 24, 3, |x, y, _| if stripe(x, y) { 0.9 } else { 0.1 });
    let mut set = FeatureSet::default();
    set.set(
        Feature::Albedo,
        Image::from_fn(24, 24, 3, |x, y, _| if stripe(x, y) { 0.8 } else { 0.2 }),
    )
    .unwrap();
    let out = run(&color, &set, 0.2);
    // What blurring stripes costs: the contrast between their bright and dark pixels.
    let contrast = |img: &Image| {
        let (mut s, mut n) = ([0.0f64; 2], [0usize; 2]);
        for i in 0..24 * 24 {
            let k = stripe(i % 24, i / 24) as usize;
            s[k] += img.pixel(i)[0] as f64;
            n[k] += 1;
        }
        s[1] / n[1] as f64 - s[0] / n[0] as f64
    };
    let (before, after) = (contrast(&color), contrast(&out));
    assert!(after > 0.97 * before, "stripe contrast {before} → {after}");
}

#[test]
fn the_same_bits_on_one_and_two_threads() {
    let (color, set) = staircase();
    let on = |threads| {
        crate::options::thread_pool(threads)
            .unwrap()
            .install(|| run(&color, &set, 0.2))
    };
    assert_eq!(on(1), on(2));
}

#[test]
fn hard_images_stay_finite_and_non_negative() {
    for (w, h) in [(1, 1), (1, 5), (5, 1), (2, 2), (3, 7)] {
        for value in [0.0f32, 1.0, 1e6] {
            let mut color = Image::filled(w, h, 3, value);
            color.pixel_mut(0).fill(if value > 0.0 { 0.0 } else { 1e6 });
            let mut set = FeatureSet::default();
            let albedo = Image::from_fn(
                w,
                h,
                3,
                |x, y, _| if (x + y) % 2 == 0 { f32::NAN } else { 0.5 },
            );
            set.set(Feature::Albedo, albedo).unwrap();
            let out = run(&color, &set, 1e3);
            assert!(
                out.data().iter().all(|v| v.is_finite() && *v >= 0.0),
                "{w}×{h} at {value}: {:?}",
                out.data()
            );
        }
    }
}
