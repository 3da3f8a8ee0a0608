//! The fast walk kernel equals the plain reference, on any thread count, for any input.

use crate::common::{default_features, synthetic_set};
use gsid::features::{Features, Tone, Weights};
use gsid::filters::gsid::walk::{
    self, Engine, FeatureSource, Kernel, WalkJob, WalkParams, WalkStats,
};
use gsid::Image;
use proptest::prelude::*;

/// A rayon pool of `threads` threads.
fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
}

fn bits(img: &Image) -> Vec<u32> {
    img.data().iter().map(|v| v.to_bits()).collect()
}

/// A job on whole-image `features` with `engine`.
fn job<'a>(
    color: &'a Image,
    features: &'a Features,
    params: &'a WalkParams,
    engine: Engine,
) -> WalkJob<'a> {
    WalkJob {
        engine,
        ..WalkJob::new(color, FeatureSource::Whole(features), params)
    }
}

fn run(job: &WalkJob) -> (Image, WalkStats) {
    walk::run(job).expect("whole-image features")
}

fn run_both(
    color: &Image,
    features: &Features,
    mask: Option<&[bool]>,
    params: &WalkParams,
) -> (Image, Image) {
    let fast_job = WalkJob {
        mask,
        seed: 3,
        level: 1,
        ..job(color, features, params, Engine::default())
    };
    let (fast, fast_stats) = run(&fast_job);
    let (slow, slow_stats) = run(&WalkJob {
        engine: Engine::Reference,
        ..fast_job
    });
    assert_eq!(
        fast_stats, slow_stats,
        "both kernels take the same steps: {params:?}"
    );
    (fast, slow)
}

#[test]
fn fast_kernel_equals_reference_bit_for_bit() {
    let set = synthetic_set(23, 17);
    let color = set.get("color").unwrap();
    let features = default_features(color, &set);
    let mask: Vec<bool> = (0..23 * 17).map(|i| i % 11 == 0).collect();
    // 1, 3 and 6 walks batch 8, 3 and 2 start pixels into the AVX2 kernel's slots (23 columns
    // leave a partial batch at the end of every row); 20 walks run one pixel at a time.
    for walks in [1, 3, 6, 20] {
        for window in [Some(1), Some(4), None] {
            for m in [None, Some(mask.as_slice())] {
                let params = WalkParams {
                    sigma: 0.7,
                    walks,
                    window,
                    self_weight: 0.5,
                    ..WalkParams::default()
                };
                let (fast, slow) = run_both(color, &features, m, &params);
                assert_eq!(
                    bits(&fast),
                    bits(&slow),
                    "walks {walks}, window {window:?}, mask {}",
                    m.is_some()
                );
            }
        }
    }
}

#[test]
fn output_is_identical_on_one_and_two_threads() {
    let set = synthetic_set(31, 9);
    let color = set.get("color").unwrap();
    let features = default_features(color, &set);
    let params = WalkParams::default();
    let input = WalkJob {
        seed: 11,
        ..job(color, &features, &params, Engine::default())
    };
    let on = |threads| pool(threads).install(|| run(&input).0);
    assert_eq!(bits(&on(1)), bits(&on(2)));
}

#[test]
fn levels_and_seeds_draw_different_walks() {
    let set = synthetic_set(12, 12);
    let color = set.get("color").unwrap();
    let (features, _) = Features::build(
        color,
        set.features(),
        &Weights::color_only(),
        Tone::Reinhard,
        1.0,
    )
    .unwrap();
    let params = WalkParams {
        sigma: 2.0,
        ..WalkParams::default()
    };
    let out = |seed, level| {
        run(&WalkJob {
            seed,
            level,
            ..job(color, &features, &params, Engine::default())
        })
        .0
    };
    assert_ne!(bits(&out(1, 0)), bits(&out(2, 0)));
    assert_ne!(bits(&out(1, 0)), bits(&out(1, 1)));
}

fn any_value() -> impl Strategy<Value = f32> {
    prop_oneof![
        4 => 0.0f32..2.0,
        1 => Just(f32::NAN),
        1 => Just(f32::INFINITY),
        1 => Just(1e6f32),
        1 => Just(-3.0f32),
        1 => Just(0.0f32),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Any size from 1×1, any mix of NaN/Inf/huge/negative colour, σ across twelve decades:
    /// the kernels agree bit for bit and every output sample is finite.
    #[test]
    fn kernels_agree_and_stay_finite(
        w in 1usize..7,
        h in 1usize..7,
        values in proptest::collection::vec(any_value(), 36 * 3),
        log_sigma in -6.0f32..6.0,
        window in prop_oneof![Just(0u32), 1u32..5],
        walks in 1u32..6,
    ) {
        let mut color = Image::from_fn(w, h, 3, |x, y, c| values[(y * w + x) * 3 + c]);
        let mut features = gsid::FeatureSet::default();
        gsid::condition::sanitize(Some(&mut color), &mut features);
        let color = &color;
        let (features, _) = Features::build(color, &features, &Weights::color_only(), Tone::Reinhard, 1.0).unwrap();
        let params = WalkParams {
            sigma: 10f32.powf(log_sigma),
            walks,
            window: (window > 0).then_some(window),
            ..WalkParams::default()
        };
        let (fast, slow) = run_both(color, &features, None, &params);
        prop_assert_eq!(bits(&fast), bits(&slow));
        prop_assert!(fast.all_finite());
    }
}

/// The portable and the AVX2 step (where the CPU has it) give the reference's bits, also when tiny
/// σ sends every step through the log-domain fallback, when a large σ never does, and when the
/// step cap ends walks.
#[test]
fn every_kernel_equals_the_reference() {
    let set = synthetic_set(29, 13);
    let color = set.get("color").unwrap();
    let features = default_features(color, &set);
    let mask: Vec<bool> = (0..29 * 13).map(|i| i % 7 == 3).collect();
    for (sigma, max_steps) in [(1e-3, 64), (0.05, 64), (1.0, 64), (50.0, 64), (50.0, 3)] {
        for window in [Some(2), Some(5)] {
            let params = WalkParams {
                sigma,
                walks: 7,
                window,
                max_steps,
                ..WalkParams::default()
            };
            let input = WalkJob {
                mask: Some(&mask),
                seed: 11,
                ..job(color, &features, &params, Engine::Reference)
            };
            let (want, want_stats) = run(&input);
            for kernel in Kernel::ALL.into_iter().filter(|k| k.is_available()) {
                let (got, stats) = run(&WalkJob {
                    engine: Engine::Fast(kernel),
                    ..input
                });
                let case = format!("{kernel:?} σ {sigma} cap {max_steps} window {window:?}");
                assert_eq!(stats, want_stats, "{case}");
                assert_eq!(bits(&got), bits(&want), "{case}");
            }
        }
    }
}

/// Walks long enough that the vector kernel weighs their steps in several chunks: each pixel's only
/// neighbour of weight above 0 is its twin (pairs of equal colour, σ tiny), so every step has
/// probability 1 and every walk runs to `max_steps`, far beyond one chunk of records. Every kernel
/// still equals the reference.
#[test]
fn walks_weighed_in_many_chunks_equal_the_reference() {
    let (w, h) = (4, 2);
    let color = Image::from_fn(w, h, 3, |x, y, _| 10.0 * (2 * y + x / 2) as f32 + 1.0);
    let mut set = gsid::Buffers::new();
    set.insert("color", color.clone()).unwrap();
    let features = default_features(&color, &set);
    let params = WalkParams {
        sigma: 1e-3,
        walks: 16,
        window: Some(1),
        max_steps: 5000,
        ..WalkParams::default()
    };
    let input = job(&color, &features, &params, Engine::Reference);
    let (want, want_stats) = run(&input);
    assert_eq!(
        want_stats.steps,
        (w * h) as u64 * 16 * 5000,
        "every walk ran to the cap"
    );
    for kernel in Kernel::ALL.into_iter().filter(|k| k.is_available()) {
        let (got, stats) = run(&WalkJob {
            engine: Engine::Fast(kernel),
            ..input
        });
        assert_eq!(stats, want_stats, "{kernel:?}");
        assert_eq!(bits(&got), bits(&want), "{kernel:?}");
    }
}

/// Denoising strip by strip (features built per strip plus the window's halo) gives the bits of one
/// whole-image run, for strips shorter and longer than the window, with a mask, and without a window.
#[test]
fn strips_equal_one_whole_image_run() {
    let (w, h) = (19, 41);
    let set = synthetic_set(w, h);
    let color = set.get("color").unwrap();
    let weights = Weights::default();
    let (features, _) =
        Features::build(color, set.features(), &weights, Tone::Reinhard, 1.0).unwrap();
    let features_for = |rows: std::ops::Range<usize>| {
        Features::build_rows(color, set.features(), &weights, Tone::Reinhard, 1.0, rows)
            .map(|(f, _)| f)
    };
    let mask: Vec<bool> = (0..w * h).map(|i| i % 13 == 5).collect();
    for window in [Some(1), Some(4), None] {
        for m in [None, Some(mask.as_slice())] {
            let params = WalkParams {
                walks: 5,
                window,
                ..WalkParams::default()
            };
            let whole = WalkJob {
                mask: m,
                seed: 3,
                level: 1,
                ..job(color, &features, &params, Engine::default())
            };
            let (want, want_stats) = run(&whole);
            for (strip_rows, threads) in [(1, 2), (3, 1), (8, 3), (40, 2), (100, 2)] {
                let strips = WalkJob {
                    features: FeatureSource::Strips {
                        build: &features_for,
                        rows: Some(strip_rows),
                    },
                    ..whole
                };
                let (got, stats) = pool(threads).install(|| walk::run(&strips)).unwrap();
                let case = format!(
                    "window {window:?}, strips of {strip_rows}, {threads} threads, mask {}",
                    m.is_some()
                );
                assert_eq!(bits(&got), bits(&want), "{case}");
                // Walks start from each strip's own rows only: the work is one run's, no more.
                assert_eq!(stats, want_stats, "{case}");
            }
        }
    }
}

/// A strip whose features cannot be built fails the run with that error, on any thread count,
/// without waiting forever on the strip.
#[test]
fn a_failed_strip_is_an_error_not_a_hang() {
    let (w, h) = (9, 30);
    let set = synthetic_set(w, h);
    let color = set.get("color").unwrap();
    let weights = Weights::default();
    let features_for = |rows: std::ops::Range<usize>| {
        if rows.contains(&15) {
            return Err(gsid::Error::buffer("albedo", "broken for this test"));
        }
        Features::build_rows(color, set.features(), &weights, Tone::Reinhard, 1.0, rows)
            .map(|(f, _)| f)
    };
    let params = WalkParams {
        walks: 2,
        window: Some(2),
        ..WalkParams::default()
    };
    let features = FeatureSource::Strips {
        build: &features_for,
        rows: Some(4),
    };
    let job = WalkJob {
        seed: 1,
        ..WalkJob::new(color, features, &params)
    };
    for threads in [1, 2, 4] {
        let result = pool(threads).install(|| walk::run(&job));
        let err = result.expect_err("the broken strip fails the run");
        assert!(err.to_string().contains("broken for this test"), "{err}");
    }
}
