//! exp and ln for the walk kernel: fast, accurate to about 2 ulp, and specified operation by operation.
//!
//! The walk kernel has a scalar and an AVX2 version that must pick the same neighbours, so both
//! evaluate these functions with the same sequence of IEEE additions and multiplications (no fused
//! multiply-add, no library calls whose rounding could differ between platforms). The polynomials
//! are Cephes' `expf` and `logf` minimax fits, evaluated in Estrin's scheme: the walk step is
//! latency-bound, and Estrin halves the dependency chain of Horner's rule.

/// exp(x) is returned as 0 below this: ln of the smallest normal f32, so 2^n never goes subnormal.
pub const EXP_MIN_ARG: f32 = -87.336_55;
pub const LOG2E: f32 = std::f32::consts::LOG2_E;
/// ln 2 split so that n·LN2_HI is exact for the |n| ≤ 126 used here.
pub const LN2_HI: f32 = 0.693_359_4;
pub const LN2_LO: f32 = -2.121_944_4e-4;
/// exp polynomial coefficients of r^5 .. r^0 (then e^r ≈ 1 + r + r²·P(r)).
pub const EXP_POLY: [f32; 6] = [
    1.987_569_2e-4,
    1.398_199_9e-3,
    8.333_452e-3,
    4.166_579_6e-2,
    1.666_666_5e-1,
    0.5,
];

/// e^x for x ≤ 0 (larger x is treated as 0; −∞ and NaN give 0). exp_neg(0) is exactly 1.
#[inline]
pub fn exp_neg(x: f32) -> f32 {
    // Branch-free (a select at the end, NaN fails the test) so loops over it vectorise.
    let valid = x >= EXP_MIN_ARG;
    // max/min rather than clamp: the NaN handling of the AVX2 version's maxps/minps.
    #[allow(clippy::manual_clamp)]
    let x = x.max(EXP_MIN_ARG).min(0.0);
    // Round to nearest by truncating v − ½ (v ≤ 0): one cvttss2si, no libm call, and the same
    // instruction the AVX2 version uses. Unchecked, so a loop over it compiles to one vector
    // conversion instead of a saturating one lane at a time.
    // SAFETY: x is in [EXP_MIN_ARG, 0] here (max and min above; a NaN became EXP_MIN_ARG), so
    // x·LOG2E − ½ is finite and in [−126.5, −0.5], inside i32's range.
    let ni = unsafe { (x * LOG2E - 0.5).to_int_unchecked::<i32>() };
    let n = ni as f32;
    let r = (x - n * LN2_HI) - n * LN2_LO;
    let [c5, c4, c3, c2, c1, c0] = EXP_POLY;
    let r2 = r * r;
    let r4 = r2 * r2;
    let p = (c5 * r + c4) * r4 + ((c3 * r + c2) * r2 + (c1 * r + c0));
    let p = (p * r2 + r) + 1.0;
    let e = p * f32::from_bits(((ni + 127) as u32) << 23);
    if valid {
        e
    } else {
        0.0
    }
}

/// v[x] = exp_neg(v[x]) over a slice, in place, 8 at a time with AVX2 (same bits either way).
pub fn exp_neg_row(kernel: crate::kernels::simd::Kernel, v: &mut [f32]) {
    let done = match kernel.or_portable() {
        #[cfg(target_arch = "x86_64")]
        crate::kernels::simd::Kernel::Avx512 => {
            #[target_feature(enable = "avx2,avx512f,avx512vl,avx512bw,avx512dq")]
            fn avx512(v: &mut [f32]) {
                exp_neg_all(v)
            }
            // SAFETY: or_portable returns Avx512 only when the CPU has its four extensions.
            unsafe { avx512(v) };
            v.len()
        }
        #[cfg(target_arch = "x86_64")]
        // SAFETY: or_portable returns Avx2 only when the CPU has it.
        crate::kernels::simd::Kernel::Avx2 => unsafe { avx2::exp_neg_row(v) },
        _ => 0,
    };
    exp_neg_all(&mut v[done..]);
}

/// exp_neg of every value, in place: a loop the compiler vectorises (16 lanes with AVX-512).
#[inline(always)]
fn exp_neg_all(v: &mut [f32]) {
    for x in v {
        *x = exp_neg(*x);
    }
}

/// logf polynomial coefficients of f^8 .. f^0.
pub const LN_POLY: [f32; 9] = [
    7.037_683_6e-2,
    -1.151_461e-1,
    1.167_699_9e-1,
    -1.242_014_1e-1,
    1.424_932_3e-1,
    -1.666_805_8e-1,
    2.000_071_4e-1,
    -2.499_999_4e-1,
    3.333_333e-1,
];

/// ln x for positive normal x (the kernel's normalisers lie in [1e-30, 8]).
#[inline]
pub fn ln_normal(x: f32) -> f32 {
    let bits = x.to_bits();
    let mut e = ((bits >> 23) & 0xff) as i32 - 127;
    let mut m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000);
    if m > std::f32::consts::SQRT_2 {
        m *= 0.5;
        e += 1;
    }
    let f = m - 1.0;
    let z = f * f;
    let f4 = z * z;
    let [c8, c7, c6, c5, c4, c3, c2, c1, c0] = LN_POLY;
    let y = ((c1 * f + c0) + (c3 * f + c2) * z) + ((c5 * f + c4) + (c7 * f + c6) * z) * f4;
    let y = y + c8 * (f4 * f4);
    let ef = e as f32;
    let y = (y * f) * z + ef * LN2_LO - 0.5 * z;
    (f + y) + ef * LN2_HI
}

/// AVX2 versions, operation for operation the same as the scalar ones (so bit-identical).
#[cfg(target_arch = "x86_64")]
pub mod avx2 {
    use std::arch::x86_64::*;

    use super::{EXP_MIN_ARG, EXP_POLY, LN2_HI, LN2_LO, LOG2E};

    /// `super::exp_neg_row` for the whole groups of 8; returns how many it did.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[target_feature(enable = "avx2")]
    pub unsafe fn exp_neg_row(v: &mut [f32]) -> usize {
        let full = v.len() / 8 * 8;
        for x in (0..full).step_by(8) {
            let p = v[x..x + 8].as_mut_ptr();
            // SAFETY: x + 8 <= len; unaligned load and store.
            unsafe { _mm256_storeu_ps(p, exp_neg8(_mm256_loadu_ps(p))) };
        }
        full
    }

    /// `fastmath::exp_neg` on 8 lanes.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[inline]
    #[target_feature(enable = "avx2")]
    pub fn exp_neg8(x: __m256) -> __m256 {
        let set = _mm256_set1_ps;
        let (add, mul, sub) = (_mm256_add_ps, _mm256_mul_ps, _mm256_sub_ps);
        let valid = _mm256_cmp_ps::<_CMP_GE_OQ>(x, set(EXP_MIN_ARG));
        let x = _mm256_min_ps(_mm256_max_ps(x, set(EXP_MIN_ARG)), _mm256_setzero_ps());
        let ni = _mm256_cvttps_epi32(sub(mul(x, set(LOG2E)), set(0.5)));
        let n = _mm256_cvtepi32_ps(ni);
        let r = sub(sub(x, mul(n, set(LN2_HI))), mul(n, set(LN2_LO)));
        let [c5, c4, c3, c2, c1, c0] = EXP_POLY;
        let r2 = mul(r, r);
        let r4 = mul(r2, r2);
        let p = add(
            mul(add(mul(set(c5), r), set(c4)), r4),
            add(
                mul(add(mul(set(c3), r), set(c2)), r2),
                add(mul(set(c1), r), set(c0)),
            ),
        );
        let p = add(add(mul(p, r2), r), set(1.0));
        let scale = _mm256_castsi256_ps(_mm256_slli_epi32::<23>(_mm256_add_epi32(
            ni,
            _mm256_set1_epi32(127),
        )));
        _mm256_and_ps(mul(p, scale), valid)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_is_accurate_on_its_domain() {
        assert_eq!(exp_neg(0.0), 1.0);
        assert_eq!(exp_neg(-0.0), 1.0);
        assert_eq!(exp_neg(f32::NEG_INFINITY), 0.0);
        assert_eq!(exp_neg(f32::NAN), 0.0);
        // Outside the domain: the unchecked conversion's invariant (see exp_neg) must hold.
        assert_eq!(exp_neg(f32::INFINITY), 1.0);
        assert_eq!(exp_neg(f32::MAX), 1.0);
        assert_eq!(exp_neg(f32::MIN), 0.0);
        assert_eq!(exp_neg(-1e-45), 1.0);
        assert_eq!(exp_neg(-100.0), 0.0);
        let mut worst = 0.0f64;
        let mut x = 0.0f32;
        while x > EXP_MIN_ARG {
            let exact = (x as f64).exp();
            worst = worst.max(((exp_neg(x) as f64 - exact) / exact).abs());
            x -= 0.000_731;
        }
        assert!(worst < 3e-7, "worst relative error {worst}");
    }

    #[test]
    fn ln_is_accurate_on_its_domain() {
        assert_eq!(ln_normal(1.0), 0.0);
        let mut worst = 0.0f64;
        let mut x = 1e-30f32;
        while x < 64.0 {
            let exact = (x as f64).ln();
            // Relative where |ln x| is large, absolute (in f32 ulps of 1) near x = 1.
            worst = worst.max((ln_normal(x) as f64 - exact).abs() / exact.abs().max(1.0));
            x *= 1.000_37;
        }
        assert!(worst < 3e-7, "worst error {worst}");
    }
}
