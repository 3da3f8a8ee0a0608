//! The step's transition frequencies against its probabilities exp(a_k) / Σ exp(a), by a
//! chi-square test. The bit-for-bit tests compare the kernels with the reference, so a bias they
//! all share (a skewed uniform, a pick off by a lane, a wrong log-domain normaliser) passes them;
//! this compares the scalar step and the AVX2 step with the distribution itself.

use super::rng::{pixel_key, uniform, walk_key};
use super::step::{choose, prefix8, LINEAR_MIN};
use crate::kernels::fastmath::exp_neg;

/// Picks per state and kernel.
const DRAWS: usize = 1 << 20;

/// Uniforms drawn from each walk's stream, as a walk of this many steps draws them.
const STEPS: u32 = 64;

/// Chi-square at p = 1e-4 for 1 to 7 degrees of freedom: a larger statistic fails. A correct step
/// fails a state with probability 1e-4; the keys are fixed, so the test cannot flake.
const CRITICAL: [f64; 7] = [15.137, 18.421, 21.108, 23.513, 25.745, 27.856, 29.878];

/// The fixed states: each neighbour's log-weight a (−∞: outside the window, the image or the mask).
fn states() -> [(&'static str, [f32; 8]); 5] {
    let z = f32::NEG_INFINITY;
    [
        ("spread", [-0.1, -0.5, -1.0, -2.0, -0.3, -0.7, -1.5, -0.2]),
        // Lanes 3 and 7 end the prefix sum's two halves.
        ("zeros", [z, -0.4, -1.2, z, -0.1, -2.5, -0.6, z]),
        // Σ exp(a) below LINEAR_MIN (the log domain), with weights still above 0 in f32 ...
        (
            "near underflow",
            [-75.0, -76.0, -77.5, z, -75.2, -80.0, -76.0, z],
        ),
        // ... and with every weight 0 in f32.
        (
            "underflowed",
            [-200.0, -201.0, z, -203.0, -200.5, z, -202.0, -200.0],
        ),
        // One likely neighbour; six of probability 1.2e-4 and one of 2.5e-3.
        ("peaked", [-9.0, 0.0, -9.0, -9.0, -6.0, -9.0, -9.0, -9.0]),
    ]
}

/// The keys of the walks the uniforms come from: walks 0 to 15 of start pixels 0, 1, ...
fn keys() -> impl Iterator<Item = u64> {
    (0..)
        .flat_map(|pixel| (0..16).map(move |walk| walk_key(pixel_key(1, 0, pixel), walk)))
        .take(DRAWS / STEPS as usize)
}

/// Fails `case` if a neighbour of weight 0 was picked, or if Pearson's statistic of `counts`
/// against the probabilities exp(a_k) / Σ exp(a) (in f64) exceeds [`CRITICAL`].
fn check(counts: &[u64; 8], a: &[f32; 8], case: &str) {
    let top = a.iter().fold(f64::NEG_INFINITY, |m, &v| m.max(v as f64));
    let p = a.map(|v| (v as f64 - top).exp());
    let sum: f64 = p.iter().sum();
    let n = counts.iter().sum::<u64>() as f64;
    let (mut stat, mut bins) = (0.0, 0);
    for k in 0..8 {
        if p[k] == 0.0 {
            assert_eq!(counts[k], 0, "{case}: picked lane {k} of weight 0");
            continue;
        }
        let expected = n * p[k] / sum;
        stat += (counts[k] as f64 - expected).powi(2) / expected;
        bins += 1;
    }
    let limit = CRITICAL[bins - 2];
    assert!(
        stat <= limit,
        "{case}: chi-square {stat:.1} > {limit} ({} degrees of freedom), counts {counts:?}",
        bins - 1
    );
}

#[test]
fn the_states_take_both_paths_of_the_step() {
    for (name, a) in states() {
        let linear = prefix8(&a.map(exp_neg))[7] >= LINEAR_MIN;
        assert_eq!(linear, !name.contains("underflow"), "{name}");
    }
}

#[test]
fn the_scalar_step_picks_with_the_probabilities_of_the_weights() {
    for (name, a) in states() {
        let l = a.map(exp_neg);
        let mut counts = [0u64; 8];
        for key in keys() {
            for step in 1..=STEPS {
                let (k, _) = choose(&a, &l, uniform(key, step)).expect("a neighbour is allowed");
                counts[k] += 1;
            }
        }
        check(&counts, &a, &format!("scalar, {name}"));
    }
}

/// The AVX2 step with its own uniforms: eight walks in the same state, one per lane.
#[cfg(target_arch = "x86_64")]
#[test]
fn the_avx2_step_picks_with_the_probabilities_of_the_weights() {
    use std::arch::x86_64::*;

    use super::avx2_step::{choose8, uniform8};
    use super::rng::GAMMA;
    if !std::arch::is_x86_feature_detected!("avx2") {
        return;
    }
    let keys: Vec<u64> = keys().collect();
    for (name, a) in states() {
        let l = a.map(exp_neg);
        let mut counts = [0u64; 8];
        for walks in keys.chunks_exact(8) {
            for step in 1..=STEPS {
                // The kernel's counters: a walk's key plus (step + 1)·GAMMA.
                let ctr: [u64; 8] = std::array::from_fn(|s| {
                    walks[s].wrapping_add((step as u64 + 1).wrapping_mul(GAMMA))
                });
                let (mut ks, mut us) = ([0i32; 8], [0f32; 8]);
                // SAFETY: AVX2 is present (checked above); loads and stores use local arrays.
                let picked = unsafe {
                    let u = uniform8([
                        _mm256_loadu_si256(ctr.as_ptr().cast()),
                        _mm256_loadu_si256(ctr[4..].as_ptr().cast()),
                    ]);
                    // Register k holds neighbour k of every walk.
                    let lv = l.map(|v| _mm256_set1_ps(v));
                    let logs = [_mm256_loadu_ps(a.as_ptr()); 8];
                    let (k, _, picked) = choose8(&lv, &logs, u, 0xff, |_| a);
                    _mm256_storeu_si256(ks.as_mut_ptr().cast(), k);
                    _mm256_storeu_ps(us.as_mut_ptr(), u);
                    picked
                };
                assert_eq!(picked, 0xff, "{name}: every walk picks");
                for s in 0..8 {
                    let want = uniform(walks[s], step);
                    assert_eq!(us[s].to_bits(), want.to_bits(), "the kernel's uniforms");
                    counts[ks[s] as usize] += 1;
                }
            }
        }
        check(&counts, &a, &format!("AVX2, {name}"));
    }
}
