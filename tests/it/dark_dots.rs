//! Dark dots (issue 41): a pixel whose few samples returned almost nothing on a lit surface is
//! averaged away by the presets (the outlier stage's `two_sided` rule raises it before the walks
//! and the blend see it); dark detail the features show stays dark.

use gsid::pipeline::PipelineSpec;
use gsid::{Buffers, DenoiseOptions, Image};
use rand::rngs::Xoshiro256PlusPlus;
use rand::{Rng, SeedableRng};

const PRESETS: [&str; 4] = ["fast", "balanced", "full", "quality"];
const SD: f32 = 0.05;

fn uniform(rng: &mut Xoshiro256PlusPlus) -> f64 {
    (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// A flat grey surface at 0.5 with noise of std `SD`, one value for the three channels.
fn surface(w: usize, h: usize, rng: &mut Xoshiro256PlusPlus) -> Image {
    let mut color = Image::filled(w, h, 3, 0.0);
    for i in 0..w * h {
        let n = (0..4).map(|_| uniform(rng) as f32 - 0.5).sum::<f32>() * SD * 3f32.sqrt();
        color.pixel_mut(i).fill(0.5 + n);
    }
    color
}

/// `n` isolated pixels (no two within 2 of each other), away from the border.
fn isolated(w: usize, h: usize, n: usize, rng: &mut Xoshiro256PlusPlus) -> Vec<usize> {
    let mut picked: Vec<usize> = Vec::new();
    while picked.len() < n {
        let x = 8 + (uniform(rng) * (w - 16) as f64) as usize;
        let y = 8 + (uniform(rng) * (h - 16) as f64) as usize;
        let near = |j: &usize| (j % w).abs_diff(x) < 3 && (j / w).abs_diff(y) < 3;
        if !picked.iter().any(near) {
            picked.push(y * w + x);
        }
    }
    picked
}

fn buffers(color: &Image, albedo: Image) -> Buffers {
    let (w, h) = color.dims();
    let mut b = Buffers::new();
    b.insert("color", color.clone()).unwrap();
    b.insert("albedo", albedo).unwrap();
    b.insert(
        "normal",
        Image::from_fn(w, h, 3, |_, _, c| if c == 2 { 1.0 } else { 0.0 }),
    )
    .unwrap();
    b
}

/// `preset` on `b` on `threads` workers, with the outlier stage's `two_sided` as given.
fn run(preset: &str, b: &Buffers, threads: usize, two_sided: bool) -> Image {
    let mut spec = PipelineSpec::builtin(preset).unwrap();
    spec.set("outlier.two_sided", two_sided.into()).unwrap();
    let pipeline = spec.build().unwrap();
    let mut options = DenoiseOptions::seeded(1);
    options.threads = Some(threads);
    pipeline.run(&mut b.clone(), &options).unwrap().0
}

/// A dotted surface: 40 isolated black pixels on the noisy grey one.
fn dotted() -> (Image, Vec<usize>) {
    let (w, h) = (64, 64);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(6);
    let mut color = surface(w, h, &mut rng);
    let dots = isolated(w, h, 40, &mut rng);
    for &i in &dots {
        color.pixel_mut(i).fill(0.0);
    }
    (color, dots)
}

/// On a flat surface, a black pixel among lit ones is raised and averaged: with the two-sided rule
/// every dot comes out brighter than with the one-sided one (where the walks never leave it and the
/// blend gives it back) and the dots' mean more than doubles, in every preset, and the image's mean stays within 1 % of the input's. (How
/// far it is raised depends on the surface's brightness against the image's: the rule's std floor
/// is in tone-mapped units, so on a surface of the image's typical brightness the lower limit is a
/// small fraction of it; docs/RESULTS.md, "Dark dots".)
#[test]
fn dark_dots_on_a_flat_surface_are_raised_and_averaged() {
    let (color, dots) = dotted();
    let b = buffers(&color, Image::filled(64, 64, 3, 0.5));
    let mean =
        |img: &Image| img.data().iter().map(|&v| v as f64).sum::<f64>() / img.data().len() as f64;
    for preset in PRESETS {
        let on = run(preset, &b, 1, true);
        let off = run(preset, &b, 1, false);
        let (mut sum_on, mut sum_off) = (0.0, 0.0);
        for &i in &dots {
            let (a, o) = (on.pixel(i)[0], off.pixel(i)[0]);
            assert!(
                a > o,
                "{preset}: the dot at ({}, {}) came out at {a} ({o} one-sided)",
                i % 64,
                i / 64
            );
            (sum_on, sum_off) = (sum_on + a, sum_off + o);
        }
        assert!(
            sum_on > 2.0 * sum_off,
            "{preset}: the dots' mean {} two-sided, {} one-sided",
            sum_on / 40.0,
            sum_off / 40.0
        );
        let kept = mean(&on) / mean(&color) - 1.0;
        assert!(kept.abs() < 0.01, "{preset}: mean {:+.2} %", 100.0 * kept);
    }
}

/// A thin dark outline and a dark texel of one pixel that the albedo shows are detail, not dots:
/// they come out dark in every preset (docs/ALGORITHM.md §4, "Dark dots").
#[test]
fn dark_detail_the_albedo_shows_stays() {
    let (w, h) = (48, 48);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
    let mut color = surface(w, h, &mut rng);
    // A closed outline (a line's end, also where it meets the image's border, has one dark
    // neighbour and is not told apart from a dot beside a second dot).
    let dark = |x: usize, y: usize| {
        let on = |v: usize| (10..=30).contains(&v);
        ((x == 10 || x == 30) && on(y)) || ((y == 10 || y == 30) && on(x)) || (x, y) == (38, 38)
    };
    let albedo = Image::from_fn(w, h, 3, |x, y, _| if dark(x, y) { 0.05 } else { 0.5 });
    for y in 0..h {
        for x in 0..w {
            if dark(x, y) {
                color.pixel_mut(y * w + x).fill(0.05);
            }
        }
    }
    let b = buffers(&color, albedo);
    for preset in PRESETS {
        let out = run(preset, &b, 1, true);
        for y in 0..h {
            for x in (0..w).filter(|&x| dark(x, y)) {
                let v = out.pixel(y * w + x)[0];
                assert!(
                    v < 0.1,
                    "{preset}: dark detail at ({x}, {y}) came out at {v}"
                );
            }
        }
    }
}

/// Dots, fireflies and a black frame stay finite, and give the same bits on 1 and 2 threads.
#[test]
fn dark_dots_stay_finite_and_the_same_bits_on_one_and_two_threads() {
    let (mut color, dots) = dotted();
    for &i in dots.iter().step_by(4) {
        // Some of them fireflies instead.
        color.pixel_mut(i + 1).fill(1e6);
    }
    let b = buffers(&color, Image::filled(64, 64, 3, 0.5));
    let one = run("full", &b, 1, true);
    assert!(one.data().iter().all(|v| v.is_finite()));
    assert_eq!(one.data(), run("full", &b, 2, true).data());
    let black = buffers(
        &Image::filled(16, 16, 3, 0.0),
        Image::filled(16, 16, 3, 0.5),
    );
    assert!(run("full", &black, 2, true)
        .data()
        .iter()
        .all(|v| v.is_finite()));
}
