//! Highlights the clamp took (issue 41, "never worse than the 64 spp input"): on a clean render a
//! smooth bright highlight two pixels wide keeps its peak through `full` (the `spread` stage's
//! `highlights` test gives the clamp's light back in place), while a lone firefly is still clamped.
//! On a `--temporal` frame (a variance measured from the stack) the test is `stack_highlights`'s,
//! off unless set: a pair passed on one frame and clamped on the next flickers.

use gsid::pipeline::PipelineSpec;
use gsid::{Buffers, DenoiseOptions, Feature, Image, RenderSet};
use rand::rngs::Xoshiro256PlusPlus;
use rand::{Rng, SeedableRng};

const SD: f32 = 0.01;
const W: usize = 64;
const H: usize = 64;
/// The highlight's centre and the firefly's pixel, far apart on one surface.
const PEAK: (usize, usize) = (20, 20);
const FIREFLY: (usize, usize) = (45, 40);

/// A flat grey surface at 0.5 with little noise (many samples a pixel), a smooth highlight two
/// pixels wide (a Gaussian of height 7.5, σ 0.8 along x and 0.6 across, centred between `PEAK` and
/// its right neighbour, as a reflected light on a curved mirror), and one pixel at 20 at `FIREFLY`;
/// uniform albedo and normal.
fn scene() -> Buffers {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
    let mut color = Image::filled(W, H, 3, 0.0);
    for y in 0..H {
        for x in 0..W {
            let (dx, dy) = (x as f32 - PEAK.0 as f32 - 0.5, y as f32 - PEAK.1 as f32);
            let bump = 7.5 * (-0.5 * ((dx / 0.8).powi(2) + (dy / 0.6).powi(2))).exp();
            let n = (rng.next_u64() >> 40) as f32 / (1u64 << 24) as f32 - 0.5;
            color
                .pixel_mut(y * W + x)
                .fill(0.5 + bump + n * SD * 12f32.sqrt());
        }
    }
    color.pixel_mut(FIREFLY.1 * W + FIREFLY.0).fill(20.0);
    let mut b = Buffers::new();
    b.insert("color", color).unwrap();
    b.insert("albedo", Image::filled(W, H, 3, 0.6)).unwrap();
    b.insert(
        "normal",
        Image::from_fn(W, H, 3, |_, _, c| if c == 2 { 1.0 } else { 0.0 }),
    )
    .unwrap();
    b
}

/// `full` on `b` on `threads` workers with `spread.highlights` at `alpha`.
fn run(b: &Buffers, alpha: f64, threads: usize) -> Image {
    run_with(b, &[("spread.highlights", alpha)], threads)
}

/// `full` on `b` on `threads` workers with the keys set as given.
fn run_with(b: &Buffers, keys: &[(&str, f64)], threads: usize) -> Image {
    let mut spec = PipelineSpec::builtin("full").unwrap();
    for &(key, value) in keys {
        spec.set(key, value.into()).unwrap();
    }
    let mut options = DenoiseOptions::seeded(1);
    options.threads = Some(threads);
    spec.build()
        .unwrap()
        .run(&mut b.clone(), &options)
        .unwrap()
        .0
}

fn at(img: &Image, (x, y): (usize, usize)) -> f32 {
    img.pixel(y * W + x)[0]
}

#[test]
fn a_smooth_highlight_keeps_its_peak_and_a_lone_firefly_is_still_clamped() {
    let b = scene();
    let input = b.get("color").unwrap().clone();
    let peak_in = at(&input, PEAK);
    let kept = run(&b, 0.01, 2);
    // The peak within 10 % of the input's; the firefly brought to its surface's level.
    assert!(
        (at(&kept, PEAK) / peak_in - 1.0).abs() < 0.1,
        "peak {} against the input's {peak_in}",
        at(&kept, PEAK)
    );
    assert!(at(&kept, FIREFLY) < 1.0, "firefly {}", at(&kept, FIREFLY));
    // Without the test the clamp flattens the highlight: what the test is for.
    let clamped = run(&b, 0.0, 2);
    assert!(
        at(&clamped, PEAK) < 0.7 * peak_in,
        "peak without the test {}",
        at(&clamped, PEAK)
    );
    // The same bits on one thread.
    assert_eq!(run(&b, 0.01, 1).data(), kept.data());
}

/// `scene()` as a `--temporal` frame: its variance (the noise's, SD²) measured from the stack.
fn stacked() -> Buffers {
    let b = scene();
    let color = b.get("color").unwrap().clone();
    let mut set = RenderSet::new(color)
        .with(Feature::Albedo, b.get("albedo").unwrap().clone())
        .unwrap()
        .with(Feature::Normal, b.get("normal").unwrap().clone())
        .unwrap();
    set.noise.variance = Some(Image::filled(W, H, 3, SD * SD));
    set.noise.from_stack = true;
    Buffers::from(set)
}

#[test]
fn a_stacked_frame_takes_the_stack_key_and_keeps_nothing_unless_it_is_set() {
    let b = stacked();
    let peak_in = at(b.get("color").unwrap(), PEAK);
    // `full`'s own keys: `highlights` 0.01, `stack_highlights` unset (off) — the peak is clamped.
    let preset = run_with(&b, &[], 2);
    assert!(
        at(&preset, PEAK) < 0.7 * peak_in,
        "peak on a stacked frame {} against the input's {peak_in}",
        at(&preset, PEAK)
    );
    // The stack's own key turned on gives it back, as `highlights` does on a single frame.
    let kept = run_with(&b, &[("spread.stack_highlights", 0.01)], 2);
    assert!(
        (at(&kept, PEAK) / peak_in - 1.0).abs() < 0.1,
        "peak with stack_highlights {} against the input's {peak_in}",
        at(&kept, PEAK)
    );
}
