//! The coverage stage on edges built to show each case: a staircase of few samples, a clean
//! anti-aliased edge, stripes, no noise, and the hard images.

use super::{along_edges, normals, Gate, Guide};
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
    along_edges(
        color,
        &variance,
        &guide,
        &dirs,
        (1, 1.0, Gate::Noise),
        &Meter::default(),
    )
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
    let (before, after) = (
        stripe_contrast(&color, stripe),
        stripe_contrast(&out, stripe),
    );
    assert!(after > 0.97 * before, "stripe contrast {before} → {after}");
}

/// What blurring stripes costs: the contrast between a 24×24 image's bright pixels (`stripe`
/// true) and its dark ones.
pub(super) fn stripe_contrast(img: &Image, stripe: impl Fn(usize, usize) -> bool) -> f64 {
    let (mut s, mut n) = ([0.0f64; 2], [0usize; 2]);
    for i in 0..24 * 24 {
        let k = stripe(i % 24, i / 24) as usize;
        s[k] += img.pixel(i)[0] as f64;
        n[k] += 1;
    }
    s[1] / n[1] as f64 - s[0] / n[0] as f64
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
            let along = run(&color, &set, 1e3);
            let guide = Guide::new(&set, (w, h)).expect("an albedo");
            let dirs = normals(&guide);
            let variance = Image::filled(w, h, 3, 1e3);
            let spread = super::spread(&guide, &dirs);
            assert!(spread.tail.is_finite(), "{w}×{h}: {spread:?}");
            // The largest share the stage can take, on every edge pixel the hard image has.
            let out = super::across_edges(
                &along,
                &variance,
                &guide,
                &dirs,
                (0.25, 1.0),
                &Meter::default(),
            );
            assert!(
                out.data().iter().all(|v| v.is_finite() && *v >= 0.0),
                "{w}×{h} at {value}: {:?}",
                out.data()
            );
        }
    }
}

/// Vertical edges at x = 10.3, 26.3, 42.3 and 58.3 between albedo 0.2 and 0.8 (alternating),
/// 64×64, each pixel's `n` samples placed by `place` (the sample's x offset from the pixel's centre
/// for a uniform draw `u` in [0, 1) and a normal draw `g`): the albedo and colour (0.1 and 0.9) of
/// the sides the samples landed on, averaged.
fn edges(n: usize, seed: u64, place: impl Fn(f64, f64) -> f64) -> (Image, FeatureSet) {
    let mut next = crate::kernels::trim::tests::xorshift(seed);
    let mut uniform = move || (next() >> 11) as f64 / (1u64 << 53) as f64;
    let side = |x: f64| {
        let k = [10.3, 26.3, 42.3, 58.3].iter().filter(|&&e| x >= e).count();
        (k % 2) as f32
    };
    let (w, h) = (64, 64);
    let mut share = vec![0.0f32; w * h];
    for (i, s) in share.iter_mut().enumerate() {
        for _ in 0..n {
            let (u, v) = (uniform(), uniform());
            // Box–Muller: one normal draw from two uniform ones.
            let g = (-2.0 * (1.0 - u).ln()).sqrt() * (std::f64::consts::TAU * v).cos();
            *s += side((i % w) as f64 + place(u, g)) / n as f32;
        }
    }
    let color = Image::from_fn(w, h, 3, |x, y, _| 0.1 + 0.8 * share[y * w + x]);
    let mut set = FeatureSet::default();
    set.set(
        Feature::Albedo,
        Image::from_fn(w, h, 3, |x, y, _| 0.2 + 0.6 * share[y * w + x]),
    )
    .unwrap();
    (color, set)
}

/// A box pixel filter: samples uniform over the pixel.
fn boxed(u: f64, _: f64) -> f64 {
    u - 0.5
}

/// A wide pixel filter, importance-sampled: offsets of a Gaussian of σ 1 pixel (the three Cycles
/// fixtures' features read a tail of 0.30 to 0.50, as this filter's do).
fn wide(_: f64, g: f64) -> f64 {
    g
}

fn spread_of(set: &FeatureSet) -> super::Spread {
    let guide = Guide::new(set, (64, 64)).expect("an albedo");
    super::spread(&guide, &normals(&guide))
}

#[test]
fn the_spread_tells_a_box_filter_from_a_wide_one() {
    // At one sample a pixel and at many: the estimate reads where the samples land on average,
    // not how many there are.
    for n in [64, 16, 4, 1] {
        let (b, w) = (
            spread_of(&edges(n, 3, boxed).1),
            spread_of(&edges(n, 3, wide).1),
        );
        assert!(b.edges >= super::across::MIN_EDGES, "box at {n}: {b:?}");
        assert!(w.edges >= super::across::MIN_EDGES, "wide at {n}: {w:?}");
        assert!(b.tail < 0.02 && b.share() < 0.005, "box at {n}: {b:?}");
        assert!(w.tail > 0.15 && w.share() > 0.04, "wide at {n}: {w:?}");
    }
    // No straight edge to read (flat features): no spread.
    let mut set = FeatureSet::default();
    set.set(Feature::Albedo, Image::filled(64, 64, 3, 0.5))
        .unwrap();
    let flat = spread_of(&set);
    assert_eq!((flat.edges, flat.share()), (0, 0.0));
}

fn across(color: &Image, set: &FeatureSet, noise: f32) -> Image {
    let guide = Guide::new(set, color.dims()).expect("an albedo");
    let dirs = normals(&guide);
    let share = super::spread(&guide, &dirs).share();
    let variance = Image::filled(color.dims().0, color.dims().1, 3, noise);
    super::across_edges(
        color,
        &variance,
        &guide,
        &dirs,
        (share, 1.0),
        &Meter::default(),
    )
}

/// The squared error of the columns beside the edges (the pixel each edge crosses and one each
/// side) against the many-sample render of the same filter.
fn edge_error(img: &Image, truth: &Image) -> f64 {
    let mut e = 0.0;
    for y in 4..60 {
        for x in [9, 10, 11, 25, 26, 27, 41, 42, 43] {
            e += (img.pixel(y * 64 + x)[0] as f64 - truth.pixel(y * 64 + x)[0] as f64).powi(2);
        }
    }
    e
}

#[test]
fn a_wide_filters_edges_of_one_sample_move_towards_its_mix() {
    let (color, set) = edges(1, 5, wide);
    let truth = edges(4096, 9, wide).0;
    let out = across(&color, &set, 0.2);
    let (before, after) = (edge_error(&color, &truth), edge_error(&out, &truth));
    assert!(after < 0.9 * before, "error {before} → {after}");
}

#[test]
fn a_box_filters_sharp_edges_pass_unchanged() {
    let (color, set) = edges(1, 5, boxed);
    assert_eq!(across(&color, &set, 0.2), color);
    let (color, set) = edges(64, 5, boxed);
    assert_eq!(across(&color, &set, 0.2), color);
}

#[test]
fn across_without_noise_nothing_moves() {
    let (color, set) = edges(1, 5, wide);
    assert_eq!(across(&color, &set, 0.0), color);
}

#[test]
fn across_gives_the_same_bits_on_one_and_two_threads() {
    let (color, set) = edges(1, 5, wide);
    let on = |threads| {
        crate::options::thread_pool(threads)
            .unwrap()
            .install(|| (across(&color, &set, 0.2), spread_of(&set)))
    };
    assert_eq!(on(1), on(2));
}

/// The `coverage` stage (keys `table`) on `set`'s colour as the filtered image, its variance as
/// the noise.
pub(super) fn run_stage(table: &str, set: crate::render_set::RenderSet) -> Image {
    use crate::buffers::Buffers;
    use crate::filters::stage::{Context, Stage, StageIo};
    let color = set.color.clone();
    let mut buffers = Buffers::from(set);
    buffers.insert("out", color).unwrap();
    buffers.insert_same("noise", "variance").unwrap();
    let io = StageIo {
        input: "out".into(),
        output: "out".into(),
    };
    let stage =
        super::CoverageStage::from_table("coverage", io, toml::from_str(table).unwrap()).unwrap();
    stage
        .execute(&mut buffers, &mut Context::new(0, false))
        .unwrap();
    buffers.get("out").unwrap().clone()
}

/// The `coverage` stage (keys `table`) on one-sample edges of a wide filter, alone or as a
/// `--temporal` frame merged from neighbours resampled between pixels.
fn staged(table: &str, resampled: bool) -> Image {
    let (color, features) = edges(1, 5, wide);
    let (w, h) = color.dims();
    let mut set = crate::render_set::RenderSet::new(color);
    set.features = features;
    set.noise.variance = Some(Image::filled(w, h, 3, 0.2));
    set.noise.from_stack = resampled;
    set.noise.resampled = resampled;
    run_stage(table, set)
}

#[test]
fn a_resampled_temporal_frame_skips_the_across_spread_unless_asked() {
    // The colour-edge step off throughout: a `--temporal` frame skips it too (colour_tests).
    let renderer = staged("colour = false", false);
    let along_only = staged("colour = false\nacross = false", false);
    assert_ne!(renderer, along_only, "the case must show the across spread");
    // A `--temporal` frame whose neighbours moved: its edges already carry the resampling's spread.
    assert_eq!(staged("colour = false", true), along_only);
    assert_eq!(
        staged("colour = false\nstack_across = true", true),
        renderer
    );
}
