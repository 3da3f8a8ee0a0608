//! The step specification (`super::step`, `super::rng::uniform`, `fastmath::ln_normal`) on eight
//! walks at once, one per lane: the same IEEE operations in the same order, so the same bits.

use std::arch::x86_64::*;

use super::avx2_lanes::{lanes, SLOTS};
use super::step::{choose_log, LINEAR_MIN};
use crate::kernels::fastmath::{LN2_HI, LN2_LO, LN_POLY};

/// `fastmath::ln_normal` on 8 lanes.
#[inline]
#[target_feature(enable = "avx2")]
fn ln_normal8(x: __m256) -> __m256 {
    let set = _mm256_set1_ps;
    let (add, mul, sub) = (_mm256_add_ps, _mm256_mul_ps, _mm256_sub_ps);
    let bits = _mm256_castps_si256(x);
    let e = _mm256_sub_epi32(
        _mm256_and_si256(_mm256_srli_epi32::<23>(bits), _mm256_set1_epi32(0xff)),
        _mm256_set1_epi32(127),
    );
    let m = _mm256_castsi256_ps(_mm256_or_si256(
        _mm256_and_si256(bits, _mm256_set1_epi32(0x007f_ffff)),
        _mm256_set1_epi32(0x3f80_0000),
    ));
    let big = _mm256_cmp_ps::<_CMP_GT_OQ>(m, set(std::f32::consts::SQRT_2));
    let m = _mm256_blendv_ps(m, mul(m, set(0.5)), big);
    // `big` lanes are all ones, i.e. −1: subtracting adds 1 to the exponent.
    let e = _mm256_sub_epi32(e, _mm256_castps_si256(big));
    let f = sub(m, set(1.0));
    let z = mul(f, f);
    let f4 = mul(z, z);
    let [c8, c7, c6, c5, c4, c3, c2, c1, c0] = LN_POLY;
    let lin = |hi: f32, lo: f32| add(mul(set(hi), f), set(lo));
    let y = add(
        add(lin(c1, c0), mul(lin(c3, c2), z)),
        mul(add(lin(c5, c4), mul(lin(c7, c6), z)), f4),
    );
    let y = add(y, mul(set(c8), mul(f4, f4)));
    let ef = _mm256_cvtepi32_ps(e);
    let y = sub(
        add(mul(mul(y, f), z), mul(ef, set(LN2_LO))),
        mul(set(0.5), z),
    );
    add(add(f, y), mul(ef, set(LN2_HI)))
}

/// The low 64 bits of z · c per u64 lane (AVX2 has no 64-bit multiply).
#[inline]
#[target_feature(enable = "avx2")]
fn mul64(z: __m256i, c: u64) -> __m256i {
    let (c_lo, c_hi) = (
        _mm256_set1_epi64x((c & 0xffff_ffff) as i64),
        _mm256_set1_epi64x((c >> 32) as i64),
    );
    let cross = _mm256_add_epi64(
        _mm256_mul_epu32(_mm256_srli_epi64::<32>(z), c_lo),
        _mm256_mul_epu32(z, c_hi),
    );
    _mm256_add_epi64(_mm256_mul_epu32(z, c_lo), _mm256_slli_epi64::<32>(cross))
}

/// `super::rng::splitmix` after its increment, cut to the top 24 bits, per u64 lane.
#[inline]
#[target_feature(enable = "avx2")]
fn mix24(z: __m256i) -> __m256i {
    let z = mul64(
        _mm256_xor_si256(z, _mm256_srli_epi64::<30>(z)),
        0xbf58_476d_1ce4_e5b9,
    );
    let z = mul64(
        _mm256_xor_si256(z, _mm256_srli_epi64::<27>(z)),
        0x94d0_49bb_1331_11eb,
    );
    _mm256_srli_epi64::<40>(_mm256_xor_si256(z, _mm256_srli_epi64::<31>(z)))
}

/// `super::rng::uniform` for 8 walks whose streams stand at `ctr` (key + (step + 2)·GAMMA: the
/// draw's counter with splitmix's own increment already added), lanes 0–3 then 4–7.
#[inline]
#[target_feature(enable = "avx2")]
pub(super) fn uniform8(ctr: [__m256i; 2]) -> __m256 {
    let even = _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6);
    let lo = _mm256_permutevar8x32_epi32(mix24(ctr[0]), even);
    let hi = _mm256_permutevar8x32_epi32(mix24(ctr[1]), even);
    let bits = _mm256_permute2x128_si256::<0x20>(lo, hi);
    // Values below 2^24 convert exactly, as the scalar u64 → f32 cast does.
    _mm256_mul_ps(_mm256_cvtepi32_ps(bits), _mm256_set1_ps(1.0 / 16_777_216.0))
}

/// Lane s of the result is lane k[s] of rows[s].
#[inline]
#[target_feature(enable = "avx2")]
fn pick8(rows: &[__m256; SLOTS], k: __m256i) -> __m256 {
    let [p0, p1, p2, p3, p4, p5, p6, p7] = [
        _mm256_permutevar8x32_ps(rows[0], k),
        _mm256_permutevar8x32_ps(rows[1], k),
        _mm256_permutevar8x32_ps(rows[2], k),
        _mm256_permutevar8x32_ps(rows[3], k),
        _mm256_permutevar8x32_ps(rows[4], k),
        _mm256_permutevar8x32_ps(rows[5], k),
        _mm256_permutevar8x32_ps(rows[6], k),
        _mm256_permutevar8x32_ps(rows[7], k),
    ];
    let lo = _mm256_blend_ps::<0b1100>(
        _mm256_blend_ps::<0b10>(p0, p1),
        _mm256_blend_ps::<0b1000>(p2, p3),
    );
    let hi = _mm256_blend_ps::<0b1100_0000>(
        _mm256_blend_ps::<0b10_0000>(p4, p5),
        _mm256_blend_ps::<0b1000_0000>(p6, p7),
    );
    _mm256_blend_ps::<0b1111_0000>(lo, hi)
}

/// `super::step::pick` on 8 walks: per lane, the first neighbour of weight > 0 whose cumulative
/// weight `c` exceeds `target` (8 where none does), from the neighbour weights `l`.
///
/// The weight test keeps a walk from picking a neighbour outside its window or the image,
/// which the sums alone do not (they are not monotone to the last ulp); such a walk would
/// then load from outside the band's tables.
#[inline]
#[target_feature(enable = "avx2")]
pub(super) fn pick_lane(c: &[__m256; 8], l: &[__m256; 8], target: __m256) -> __m256i {
    let mut k = _mm256_setzero_si256();
    let mut run = _mm256_set1_epi32(-1);
    for (ck, lk) in c.iter().zip(l) {
        let hit = _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_LT_OQ>(target, *ck),
            _mm256_cmp_ps::<_CMP_GT_OQ>(*lk, _mm256_setzero_ps()),
        );
        run = _mm256_andnot_si256(_mm256_castps_si256(hit), run);
        k = _mm256_sub_epi32(k, run);
    }
    k
}

/// `super::step::most_likely` on 8 walks: the first neighbour of the largest weight > 0.
#[inline]
#[target_feature(enable = "avx2")]
pub(super) fn most_likely8(l: &[__m256; 8]) -> __m256i {
    let mut best = _mm256_setzero_si256();
    let mut top = _mm256_setzero_ps();
    for (lane, lk) in l.iter().enumerate() {
        let gt = _mm256_cmp_ps::<_CMP_GT_OQ>(*lk, top);
        top = _mm256_blendv_ps(top, *lk, gt);
        best = _mm256_blendv_epi8(
            best,
            _mm256_set1_epi32(lane as i32),
            _mm256_castps_si256(gt),
        );
    }
    best
}

/// `super::step::choose` on 8 walks: per lane the neighbour picked and the step's
/// log-probability (0 where none is), and the mask of lanes that picked. `l` holds the weights
/// (register k: neighbour k of every walk), `logs` the log-weights (register s: walk s's), `cand`
/// the lanes that may step. Walks whose Σ is below `LINEAR_MIN` pick in the log domain one at a
/// time, from the log-weights `log_row(s)`: a function, so the vector loop never builds them.
///
/// # Safety
/// The CPU must support AVX2.
#[inline]
#[target_feature(enable = "avx2")]
pub(super) unsafe fn choose8(
    l: &[__m256; 8],
    logs: &[__m256; SLOTS],
    u: __m256,
    cand: i32,
    log_row: impl Fn(usize) -> [f32; 8],
) -> (__m256i, __m256, i32) {
    // `prefix8`, vertically.
    let c3 = _mm256_add_ps(_mm256_add_ps(l[3], l[2]), _mm256_add_ps(l[1], l[0]));
    let h7 = _mm256_add_ps(_mm256_add_ps(l[7], l[6]), _mm256_add_ps(l[5], l[4]));
    let c = [
        l[0],
        _mm256_add_ps(l[1], l[0]),
        _mm256_add_ps(_mm256_add_ps(l[2], l[1]), l[0]),
        c3,
        _mm256_add_ps(l[4], c3),
        _mm256_add_ps(_mm256_add_ps(l[5], l[4]), c3),
        _mm256_add_ps(_mm256_add_ps(_mm256_add_ps(l[6], l[5]), l[4]), c3),
        _mm256_add_ps(h7, c3),
    ];
    let mut total_w = c[7];
    let target = _mm256_mul_ps(u, total_w);
    let mut k = pick_lane(&c, l, target);
    let linear = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_GE_OQ>(
        total_w,
        _mm256_set1_ps(LINEAR_MIN),
    )) & cand;
    let missed = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(
        k,
        _mm256_set1_epi32(8),
    ))) & linear;
    if missed != 0 {
        k = _mm256_blendv_epi8(k, most_likely8(l), lanes(missed));
    }
    let k_safe = _mm256_min_epi32(k, _mm256_set1_epi32(7));
    let mut x = pick8(logs, k_safe);
    let mut picked = linear;
    let fallback = cand & !linear;
    if fallback != 0 {
        // Weights near underflow: these walks pick in the log domain, one at a time.
        let mut ks = [0i32; SLOTS];
        let (mut xs, mut sums, mut us) = ([0f32; SLOTS], [0f32; SLOTS], [0f32; SLOTS]);
        _mm256_storeu_si256(ks.as_mut_ptr().cast(), k_safe);
        _mm256_storeu_ps(xs.as_mut_ptr(), x);
        _mm256_storeu_ps(sums.as_mut_ptr(), total_w);
        _mm256_storeu_ps(us.as_mut_ptr(), u);
        for s in 0..SLOTS {
            if fallback & (1 << s) == 0 {
                continue;
            }
            if let Some((kk, xx, ss)) = choose_log(&log_row(s), us[s]) {
                (ks[s], xs[s], sums[s]) = (kk as i32, xx, ss);
                picked |= 1 << s;
            }
        }
        k = _mm256_loadu_si256(ks.as_ptr().cast());
        x = _mm256_loadu_ps(xs.as_ptr());
        total_w = _mm256_loadu_ps(sums.as_ptr());
    } else {
        k = k_safe;
    }
    // Walks that cannot step get (x, sum) = (0, 1): finite, and masked below.
    let picked_v = lanes(picked);
    let picked_f = _mm256_castsi256_ps(picked_v);
    x = _mm256_and_ps(x, picked_f);
    total_w = _mm256_blendv_ps(_mm256_set1_ps(1.0), total_w, picked_f);
    (k, _mm256_sub_ps(x, ln_normal8(total_w)), picked)
}

#[cfg(test)]
mod tests {
    //! The AVX2 pick against the scalar one, on the adversarial weights of `step`'s tests: lanes
    //! of weight 0, and targets on every cumulative sum.
    use super::*;
    use crate::filters::gsid::walk::step::tests::{adversarial, targets};
    use crate::filters::gsid::walk::step::{pick, prefix8};

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_avx2_pick_is_the_scalar_pick() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        let vectors = adversarial();
        for chunk in vectors.chunks_exact(8) {
            let cs: Vec<[f32; 8]> = chunk.iter().map(prefix8).collect();
            for probe in 0..targets(&cs[0]).len() {
                let t: [f32; 8] = std::array::from_fn(|s| targets(&cs[s])[probe]);
                // Register k holds lane k of every walk, as in the kernel.
                // SAFETY: AVX2 is present (checked above); loads read 8 floats of local arrays.
                let got = unsafe {
                    let col = |m: &[[f32; 8]], k: usize| -> __m256 {
                        let v: [f32; 8] = std::array::from_fn(|s| m[s][k]);
                        _mm256_loadu_ps(v.as_ptr())
                    };
                    let l: [__m256; 8] = std::array::from_fn(|k| col(chunk, k));
                    let c: [__m256; 8] = std::array::from_fn(|k| col(&cs, k));
                    let k = pick_lane(&c, &l, _mm256_loadu_ps(t.as_ptr()));
                    let missed = _mm256_cmpeq_epi32(k, _mm256_set1_epi32(8));
                    let k = _mm256_blendv_epi8(k, most_likely8(&l), missed);
                    let mut out = [0i32; 8];
                    _mm256_storeu_si256(out.as_mut_ptr().cast(), k);
                    out
                };
                for s in 0..8 {
                    let k = got[s] as usize;
                    assert!(
                        chunk[s][k] > 0.0,
                        "AVX2 picked lane {k} of weight 0: {:?}",
                        chunk[s]
                    );
                    let want = pick(&cs[s], &chunk[s], t[s]);
                    assert_eq!(
                        got[s] as usize, want,
                        "lane {s}: e {:?} target {}",
                        chunk[s], t[s]
                    );
                }
            }
        }
    }
}
