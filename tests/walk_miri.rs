//! Miri-sized walk kernel tests: tiny images, two short walks, so `scripts/miri.sh` can interpret
//! every kernel's loads (the AVX2 kernel's raw-pointer ones above all) and check they stay in
//! bounds. They also run natively with the rest of the suite, where they are cheap.
//!
//! Each case runs the reference, the scalar and (where it runs) the AVX2 kernel and wants the
//! reference's bits, so a kernel that reads a wrong cell fails here even when Miri is not looking.

#[path = "it/common.rs"]
mod common;

use common::synthetic_set;
use gsid::features::{Features, Tone, Weights};
use gsid::filters::gsid::walk::{self, Engine, FeatureSource, Kernel, WalkJob, WalkParams};
use gsid::{FeatureSet, Image};

fn bits(img: &Image) -> Vec<u32> {
    img.data().iter().map(|v| v.to_bits()).collect()
}

/// The kernels under test: the AVX2 one only where it runs (under Miri, only when the build
/// enables the `avx2` target feature, as `scripts/miri.sh` does), announced when it is skipped.
fn fast_kernels() -> Vec<Kernel> {
    if Kernel::Avx2.is_available() {
        vec![Kernel::Scalar, Kernel::Avx2]
    } else {
        eprintln!("walk_miri: AVX2 not available, checking the scalar kernel only");
        vec![Kernel::Scalar]
    }
}

/// Runs every kernel on `color` and wants the reference's bits and steps, and finite output.
fn check(color: &Image, features: &Features, mask: Option<&[bool]>, params: &WalkParams) {
    let reference = WalkJob {
        mask,
        seed: 5,
        level: 1,
        engine: Engine::Reference,
        ..WalkJob::new(color, FeatureSource::Whole(features), params)
    };
    let (want, want_stats) = walk::run(&reference).unwrap();
    assert!(want.all_finite(), "reference {params:?}");
    for kernel in fast_kernels() {
        let (got, stats) = walk::run(&WalkJob {
            engine: Engine::Fast(kernel),
            ..reference
        })
        .unwrap();
        let case = format!("{kernel:?} {params:?} mask {}", mask.is_some());
        assert_eq!(stats, want_stats, "{case}");
        assert_eq!(bits(&got), bits(&want), "{case}");
    }
}

/// Two walks of at most `max_steps` steps.
fn params(sigma: f32, window: Option<u32>, max_steps: u32) -> WalkParams {
    WalkParams {
        sigma,
        walks: 2,
        max_steps,
        window,
        self_weight: 0.5,
        ..WalkParams::default()
    }
}

fn features_of(color: &Image, set: &FeatureSet, weights: &Weights) -> Features {
    Features::build(color, set, weights, Tone::Reinhard, 1.0)
        .unwrap()
        .0
}

/// All eight features on 5×4 and 3×3: every window touches the image edge, with and without a
/// mask, and with a σ so small that every step takes the log-domain fallback.
#[test]
fn kernels_agree_on_tiny_images_with_edges_and_masks() {
    for (w, h) in [(5, 4), (3, 3)] {
        let set = synthetic_set(w, h);
        let color = set.get("color").unwrap();
        let features = features_of(color, set.features(), &Weights::default());
        let mask: Vec<bool> = (0..w * h).map(|i| i % 4 == 1).collect();
        for m in [None, Some(mask.as_slice())] {
            for (sigma, window) in [(0.7, Some(1)), (0.7, Some(2)), (1e-3, Some(1))] {
                check(color, &features, m, &params(sigma, window, 4));
            }
        }
        // Unbounded walks (the AVX2 kernel leaves them to the scalar one).
        check(color, &features, Some(&mask), &params(0.7, None, 4));
    }
}

/// Flat colour, so all open neighbours weigh the same and the prefix sums tie, with a mask that
/// blocks exactly lanes 3 and 7 (the ends of the two prefix-sum halves) of every pixel with
/// x − 2y ≡ 1 (mod 5): a walk there must never pick a blocked lane, whatever its uniform.
#[test]
fn flat_colour_with_lanes_3_and_7_blocked() {
    let (w, h) = (5, 4);
    let color = Image::from_fn(w, h, 3, |_, _, _| 0.5);
    let features = features_of(&color, &FeatureSet::default(), &Weights::color_only());
    let blocked = |x: usize, y: usize| (x + 10 - 2 * y).is_multiple_of(5);
    let mask: Vec<bool> = (0..w * h).map(|i| blocked(i % w, i / w)).collect();
    // The mask does what the test claims: at (3, 1), lanes 3 (−1, 0) and 7 (+1, +1) only.
    let open: Vec<bool> = walk::OFFSETS
        .iter()
        .map(|&(dx, dy)| !blocked((3 + dx) as usize, (1 + dy) as usize))
        .collect();
    assert_eq!(
        open,
        [true, true, true, false, true, true, true, false],
        "mask"
    );
    for window in [Some(1), Some(2), None] {
        check(&color, &features, Some(&mask), &params(1.0, window, 6));
    }
}
