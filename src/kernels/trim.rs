//! Trimmed means of small windows: the mean of a window's values with its largest ones left out,
//! the robust statistic the noise estimate, the feature prefilter and the blend read noise with.
//!
//! [`lanes`] runs `L` windows side by side, one per lane (the pixels of a row, each with its own
//! valid values and its own count to leave out): it keeps every lane's largest values in a short
//! sorted list by branch-free min/max insertion, then sums what lies below the cut, so `L` = 4
//! runs in one 256-bit register per step, with no selection's unpredictable branches. A lane's
//! result is the same bits on every CPU, lane grouping and thread count.

/// Pixels of a row whose windows run side by side: one 256-bit register of f64.
pub(crate) const LANES: usize = 4;

/// Fills a row `LANES` pixels at a time: `by_lanes!(out, |x| lanes, |x| one)` stores `lanes`
/// (pixels x..x + LANES) for every whole group, then `one` (pixel x) for the last pixels. A macro,
/// not a function of closures, so the kernels stay inlined in their row's AVX2 copy.
macro_rules! by_lanes {
    ($out:expr, |$x:ident| $lanes:expr, |$x1:ident| $one:expr $(,)?) => {{
        let out = $out;
        let first = out.len() - out.len() % $crate::kernels::trim::LANES;
        let (whole, tail) = out.split_at_mut(first);
        for (c, chunk) in whole
            .chunks_exact_mut($crate::kernels::trim::LANES)
            .enumerate()
        {
            let $x = c * $crate::kernels::trim::LANES;
            chunk.copy_from_slice(&$lanes);
        }
        for (t, o) in tail.iter_mut().enumerate() {
            let $x1 = first + t;
            *o = $one;
        }
    }};
}
pub(crate) use by_lanes;

/// Radius of the windows whose adjacent pairs [`PAIRS`] lists (5×5).
pub(crate) const RADIUS: isize = 2;
const SIDE: usize = 2 * RADIUS as usize + 1;
/// Adjacent pairs in such a window: every horizontal and vertical pair.
pub(crate) const MAX_PAIRS: usize = 2 * SIDE * (SIDE - 1);

/// The adjacent pairs of the window, (dx, dy) of both cells, in raster order of the first cell,
/// its right partner before its lower one.
pub(crate) const PAIRS: [[(isize, isize); 2]; MAX_PAIRS] = {
    let mut pairs = [[(0, 0); 2]; MAX_PAIRS];
    let (mut n, r) = (0, RADIUS);
    let mut dy = -r;
    while dy <= r {
        let mut dx = -r;
        while dx <= r {
            if dx < r {
                pairs[n] = [(dx, dy), (dx + 1, dy)];
                n += 1;
            }
            if dy < r {
                pairs[n] = [(dx, dy), (dx, dy + 1)];
                n += 1;
            }
            dx += 1;
        }
        dy += 1;
    }
    pairs
};

/// Per lane l, the mean of the finite `values[..][l]` without the `dropped[l]` largest, or 0 when
/// none is kept. Values must be ≥ 0 or NaN; a value that is not finite is left out, so a caller
/// marks a cell that is not valid with NaN (adding [`valid_or_nan`] to its value). `dropped[l]` is
/// at most `T`. A tie at the cut keeps as many copies as a sort would.
///
/// The sum runs over `values` in order, so a lane's result depends on its own values alone.
#[inline(always)]
pub(crate) fn lanes<const L: usize, const N: usize, const T: usize>(
    values: &[[f64; L]; N],
    dropped: [usize; L],
) -> [f64; L] {
    // top[r][l]: lane l's (r + 1)-th largest finite value so far (−∞ while there are fewer). The
    // compare-selects are exactly `vmaxpd` and `vminpd`, so with AVX2 a slot is two instructions.
    // Validity is a comparison of the value itself (NaN and ∞ fail `<= MAX`), so every test is
    // one vector compare, with no mask to widen from bytes.
    debug_assert!(
        dropped.iter().all(|&d| d <= T),
        "more dropped than the lists hold"
    );
    let mut top = [[f64::NEG_INFINITY; L]; T];
    let (mut count, mut zeros) = ([0usize; L], [0usize; L]);
    for v in values {
        for l in 0..L {
            count[l] += usize::from(v[l] <= f64::MAX);
            zeros[l] += usize::from(v[l] == 0.0);
        }
    }
    // Values are ≥ 0, so where the kept ones are all zeros the mean is 0: the common case of a
    // uniform feature, without the lists.
    if (0..L).all(|l| zeros[l] + dropped[l] >= count[l]) {
        return [0.0; L];
    }
    for v in values {
        let mut carry = [f64::NEG_INFINITY; L];
        for l in 0..L {
            carry[l] = if v[l] <= f64::MAX {
                v[l]
            } else {
                f64::NEG_INFINITY
            };
        }
        for slot in &mut top {
            for l in 0..L {
                let (a, b) = (slot[l], carry[l]);
                slot[l] = if a > b { a } else { b };
                carry[l] = if b < a { b } else { a };
            }
        }
    }
    // The cut: the dropped[l]-th largest (+∞ when nothing is dropped, so every value is below).
    let mut cut = [f64::INFINITY; L];
    for (r, slot) in top.iter().enumerate() {
        for l in 0..L {
            cut[l] = if r + 1 == dropped[l] { slot[l] } else { cut[l] };
        }
    }
    let mut sum = [0.0f64; L];
    let mut at_or_above = [0usize; L];
    for v in values {
        for l in 0..L {
            // NaN is neither below nor at or above; ∞ is never below the cut.
            let below = v[l] < cut[l];
            sum[l] += if below { v[l] } else { 0.0 };
            at_or_above[l] += usize::from((v[l] >= cut[l]) & (v[l] <= f64::MAX));
        }
    }
    let mut mean = [0.0; L];
    for l in 0..L {
        let kept = count[l].saturating_sub(dropped[l]);
        // Copies of the cut value beyond the dropped ones are kept.
        let ties = at_or_above[l].saturating_sub(dropped[l]);
        let ties = if ties > 0 { ties as f64 * cut[l] } else { 0.0 };
        mean[l] = if kept > 0 {
            (sum[l] + ties) / kept as f64
        } else {
            0.0
        };
    }
    mean
}

/// What a caller adds to a cell's value for [`lanes`]: 0 keeps it, NaN leaves it out (the sum is
/// the value itself, bit for bit, or NaN).
#[inline(always)]
pub(crate) fn valid_or_nan(valid: bool) -> f64 {
    if valid {
        0.0
    } else {
        f64::NAN
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A xorshift64 stream: the unit tests' random numbers, fixed by `seed`.
    pub(crate) fn xorshift(seed: u64) -> impl FnMut() -> u64 {
        let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        }
    }

    /// The mean of the smallest `kept` of `x`, by a sort.
    fn sorted_mean(x: &[f64], kept: usize) -> f64 {
        let mut sorted = x.to_vec();
        sorted.sort_by(f64::total_cmp);
        sorted[..kept].iter().sum::<f64>() / kept as f64
    }

    #[test]
    fn lanes_keep_the_smallest_values() {
        const N: usize = 40;
        const T: usize = 14;
        let mut next = xorshift(1);
        for trial in 0..400 {
            // Few distinct values (ties), or a firefly's dynamic range (1e-6 to 1e12).
            let mut values = [[0.0f64; 4]; N];
            let mut valid = [[false; 4]; N];
            for (v, ok) in values.iter_mut().zip(valid.iter_mut()) {
                for l in 0..4 {
                    let r = next();
                    v[l] = if trial % 2 == 0 {
                        (r % 4) as f64
                    } else {
                        10f64.powi((r % 19) as i32 - 6) * (1.0 + (r >> 40) as f64 / 1e7)
                    };
                    // Lane 0 has every value; the others a random share.
                    ok[l] = l == 0 || !(r >> 20).is_multiple_of(4);
                }
            }
            let lane_values = |l: usize| -> Vec<f64> {
                (0..N)
                    .filter(|&p| valid[p][l])
                    .map(|p| values[p][l])
                    .collect()
            };
            let counts: [usize; 4] = std::array::from_fn(|l| lane_values(l).len());
            let dropped: [usize; 4] =
                std::array::from_fn(|l| (trial / 2 + l) % (T + 1).min(counts[l]));
            let marked: [[f64; 4]; N] = std::array::from_fn(|p| {
                std::array::from_fn(|l| values[p][l] + valid_or_nan(valid[p][l]))
            });
            let got = lanes::<4, N, T>(&marked, dropped);
            for l in 0..4 {
                let want = sorted_mean(&lane_values(l), counts[l] - dropped[l]);
                assert!(
                    (got[l] - want).abs() <= 1e-12 * want.abs(),
                    "trial {trial} lane {l}: {} of {} dropped, {} against {want}",
                    dropped[l],
                    counts[l],
                    got[l]
                );
                // A lane alone gives the same bits as beside others.
                let alone =
                    lanes::<1, N, T>(&std::array::from_fn(|p| [marked[p][l]]), [dropped[l]]);
                assert_eq!(alone[0].to_bits(), got[l].to_bits());
            }
        }
    }

    #[test]
    fn values_that_are_not_finite_are_left_out() {
        let values = [[1.0], [f64::NAN], [3.0], [f64::INFINITY], [2.0]];
        assert_eq!(lanes::<1, 5, 2>(&values, [1]), [1.5]);
        // Everything left out, or nothing valid: 0, not NaN.
        assert_eq!(lanes::<1, 5, 2>(&values, [2]), [1.0]);
        assert_eq!(lanes::<1, 5, 2>(&[[f64::NAN]; 5], [0]), [0.0]);
        assert_eq!(lanes::<1, 1, 2>(&[[f64::NAN]], [0]), [0.0]);
        // A value marked not valid is left out, whatever it was; a valid one is itself.
        assert!((5.0 + valid_or_nan(false)).is_nan());
        assert_eq!((5.0 + valid_or_nan(true)).to_bits(), 5.0f64.to_bits());
        assert_eq!(
            lanes::<1, 3, 1>(&[[4.0 + valid_or_nan(false)], [1.0], [2.0]], [0]),
            [1.5]
        );
    }

    #[test]
    fn the_pairs_are_every_adjacent_pair_once() {
        let mut seen = std::collections::HashSet::new();
        for [(ax, ay), (bx, by)] in PAIRS {
            assert!((ax - bx).abs() + (ay - by).abs() == 1, "not adjacent");
            assert!([ax, ay, bx, by].iter().all(|c| c.abs() <= RADIUS));
            assert!(seen.insert((ax, ay, bx, by)), "listed twice");
        }
        assert_eq!(seen.len(), MAX_PAIRS);
    }
}
