//! The step specification (docs/ALGORITHM.md §3): how a walk picks its next neighbour from the 8
//! weights, the weight of the pixel it reaches, and the f64 colour sums. Every kernel runs these
//! operations in this order, so all of them give the same bits.

use super::params::{WalkInput, WalkParams};
use crate::kernels::fastmath::{exp_neg, ln_normal};

/// Below this Σ exp(a) a step samples in the max-subtracted log domain instead: the linear
/// weights are then too close to f32 underflow to be trusted.
pub(super) const LINEAR_MIN: f32 = 1e-30;

/// Inclusive prefix sums of 8 lanes, added in the order of the AVX2 kernel's in-register scan
/// (pairs, then quads, then the low half's total carried into the high half), so both versions
/// round identically.
#[inline]
pub(super) fn prefix8(e: &[f32; 8]) -> [f32; 8] {
    let c3 = (e[3] + e[2]) + (e[1] + e[0]);
    let h7 = (e[7] + e[6]) + (e[5] + e[4]);
    [
        e[0],
        e[1] + e[0],
        (e[2] + e[1]) + e[0],
        c3,
        e[4] + c3,
        (e[5] + e[4]) + c3,
        ((e[6] + e[5]) + e[4]) + c3,
        h7 + c3,
    ]
}

/// The first lane of weight > 0 whose cumulative weight exceeds `target`; if rounding put
/// `target` above every such lane, the most likely lane (docs/ALGORITHM.md §3).
///
/// The weight test is what keeps walks inside their window and the image: [`prefix8`]'s sums are
/// not monotone to the last ulp (c[3] = (e3 + e2) + (e1 + e0) may exceed c[2] = (e2 + e1) + e0 with
/// e3 = 0), so "a cumulative sum exceeds the target" alone can pick a lane of weight 0, and such
/// lanes are the neighbours outside the window, the image or the mask. Callers guarantee some
/// lane has weight > 0 (Σ ≥ [`LINEAR_MIN`], or the max-subtracted lane's exp(0) = 1).
#[inline]
pub(super) fn pick(c: &[f32; 8], e: &[f32; 8], target: f32) -> usize {
    (0..8)
        .find(|&k| e[k] > 0.0 && target < c[k])
        .unwrap_or_else(|| most_likely(e))
}

/// The first lane of the largest weight > 0 (lane 0 if none is: callers rule that out).
#[inline]
fn most_likely(e: &[f32; 8]) -> usize {
    let mut best = 0;
    let mut top = 0.0f32;
    for k in 0..8 {
        if e[k] > top {
            (best, top) = (k, e[k]);
        }
    }
    best
}

/// Picks a neighbour with the uniform draw `u`, from log-weights `a` (−∞ = not allowed) and their
/// exponentials `l` (each the product of the two precomputed factors).
///
/// Returns the lane and its log-probability, or `None` when no neighbour is allowed. This is the
/// specification the AVX2 kernel reproduces bit for bit.
#[inline]
pub(super) fn choose(a: &[f32; 8], l: &[f32; 8], u: f32) -> Option<(usize, f32)> {
    choose_parts(a, l, u).map(|(k, x, sum)| (k, x - ln_normal(sum)))
}

/// [`choose`] before its last operation: the lane k, and x and sum with log-probability
/// x − ln(sum) (the AVX2 kernel takes that ln for several walks at once).
#[inline]
fn choose_parts(a: &[f32; 8], l: &[f32; 8], u: f32) -> Option<(usize, f32, f32)> {
    let c = prefix8(l);
    let sum = c[7];
    if sum >= LINEAR_MIN {
        let k = pick(&c, l, u * sum);
        return Some((k, a[k], sum));
    }
    choose_log(a, u)
}

/// [`choose_parts`] for weights near underflow: subtract the largest log-weight m before exp, so
/// the normaliser lies in [1, 8] for every σ; x is then a_k − m.
#[inline]
pub(super) fn choose_log(a: &[f32; 8], u: f32) -> Option<(usize, f32, f32)> {
    let m = a.iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v));
    if m == f32::NEG_INFINITY {
        return None;
    }
    let z = a.map(|v| v - m);
    let e = z.map(exp_neg);
    let c = prefix8(&e);
    let sum = c[7];
    let k = pick(&c, &e, u * sum);
    Some((k, z[k], sum))
}

/// The weight of the pixel reached at step `step` with log-probability `log_p`: the geometric mean
/// of the step probabilities, exp(log_p / step).
#[inline]
pub(super) fn step_weight(log_p: f64, step: u32) -> f64 {
    exp_neg((log_p / step as f64) as f32) as f64
}

/// Accumulates weighted colour in f64: one per walk, then merged into the start pixel's in walk
/// order, so walks may run interleaved and still give the same bits.
#[derive(Clone, Copy, Default)]
pub(super) struct Accum {
    pub(super) sum: [f64; 3],
    pub(super) weight: f64,
}

impl Accum {
    pub(super) fn new(input: &WalkInput, x0: usize, params: &WalkParams) -> Self {
        let mut acc = Accum {
            sum: [0.0; 3],
            weight: 0.0,
        };
        if params.self_weight > 0.0 {
            acc.add(
                input.color.pixel(x0),
                params.self_weight as f64 * params.walks as f64,
            );
        }
        acc
    }

    #[inline]
    pub(super) fn add(&mut self, c: &[f32], w: f64) {
        self.sum[0] += w * c[0] as f64;
        self.sum[1] += w * c[1] as f64;
        self.sum[2] += w * c[2] as f64;
        self.weight += w;
    }

    #[inline]
    pub(super) fn merge(&mut self, walk: &Accum) {
        for k in 0..3 {
            self.sum[k] += walk.sum[k];
        }
        self.weight += walk.weight;
    }

    pub(super) fn write(&self, fallback: &[f32], out: &mut [f32]) {
        if self.weight > 0.0 && self.weight.is_finite() {
            for k in 0..3 {
                out[k] = (self.sum[k] / self.weight) as f32;
            }
        } else {
            out.copy_from_slice(&fallback[..3]);
        }
    }
}

#[cfg(test)]
pub(super) mod tests {
    //! The pick against adversarial weights: lanes 3 and 7 (the ends of the prefix sum's two
    //! halves) of weight 0, and targets on every cumulative sum, one ulp either side of it, and
    //! at the top of the distribution (u = 1 − 2⁻²⁴), through the scalar pick (and,
    //! in `super::avx2_step`, the AVX2 pick).
    use super::*;
    use crate::filters::gsid::walk::rng::splitmix;

    /// Weight vectors whose lanes 3 or 7 are 0, with cases where [`prefix8`] is not monotone.
    pub(crate) fn adversarial() -> Vec<[f32; 8]> {
        let mut key = 7u64;
        let mut next = || {
            key = splitmix(key);
            (key >> 40) as f32 / 16_777_216.0
        };
        (0..20_000)
            .map(|n| {
                let mut e: [f32; 8] = std::array::from_fn(|_| next());
                e[3] = 0.0;
                if n % 2 == 0 {
                    e[7] = 0.0;
                }
                if n % 5 == 0 {
                    e[0] = 0.0;
                }
                e
            })
            .collect()
    }

    /// Targets at every cumulative sum and one ulp either side, and at the top.
    pub(crate) fn targets(c: &[f32; 8]) -> Vec<f32> {
        let mut t = vec![c[7] * (1.0 - 1.0 / 16_777_216.0), c[7], 0.0];
        for &ck in c {
            t.extend([
                ck,
                f32::from_bits(ck.to_bits().saturating_sub(1)),
                f32::from_bits(ck.to_bits() + 1),
            ]);
        }
        t
    }

    #[test]
    fn a_lane_of_weight_zero_is_never_picked() {
        let mut gaps = 0;
        for e in adversarial() {
            let c = prefix8(&e);
            gaps += usize::from(c[3] > c[2]) + usize::from(c[7] > c[6] && e[7] == 0.0);
            for t in targets(&c) {
                let k = pick(&c, &e, t);
                assert!(
                    e[k] > 0.0,
                    "picked lane {k} of weight 0: e {e:?} target {t}"
                );
            }
        }
        // The vectors do reach the case the weight test is for.
        assert!(gaps > 100, "only {gaps} non-monotone sums");
    }

    #[test]
    fn a_miss_falls_back_to_the_most_likely_lane() {
        let e = [0.1, 0.4, 0.0, 0.2, 0.4, 0.0, 0.3, 0.0];
        let c = prefix8(&e);
        assert_eq!(pick(&c, &e, c[7]), 1);
        assert_eq!(pick(&c, &e, f32::INFINITY), 1);
    }
}
