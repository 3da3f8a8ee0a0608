//! Lane plumbing shared by the AVX2 walk loop and its weighing: the lane count, lane masks from
//! bits, and lanes of i32 or f32 loaded or widened to f64.

use std::arch::x86_64::*;

/// Walks in lockstep: one per f32 lane.
pub(super) const SLOTS: usize = 8;

/// The 8-lane mask vector of the low 8 bits of `bits`.
#[inline]
#[target_feature(enable = "avx2")]
pub(super) fn lanes(bits: i32) -> __m256i {
    let sel = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
    _mm256_cmpeq_epi32(_mm256_and_si256(_mm256_set1_epi32(bits), sel), sel)
}

/// 8 lanes of i32 from memory.
#[inline]
#[target_feature(enable = "avx2")]
pub(super) fn load_lanes(a: &[i32; SLOTS]) -> __m256i {
    // SAFETY: `a` holds 8 i32; unaligned load.
    unsafe { _mm256_loadu_si256(a.as_ptr().cast()) }
}

/// Neighbour index steps as one register (they fit in i32: [`fits`](super::avx2::fits) bounds the
/// tables).
#[inline]
#[target_feature(enable = "avx2")]
pub(super) fn offsets8(o: [isize; 8]) -> __m256i {
    let o = o.map(|v| v as i32);
    // SAFETY: `o` holds 8 i32; unaligned load.
    unsafe { _mm256_loadu_si256(o.as_ptr().cast()) }
}

/// A 32-bit lane mask widened to two f64 masks (lanes 0–3, lanes 4–7).
#[inline]
#[target_feature(enable = "avx2")]
pub(super) fn widen(m: __m256i) -> [__m256d; 2] {
    [
        _mm256_castsi256_pd(_mm256_cvtepi32_epi64(_mm256_castsi256_si128(m))),
        _mm256_castsi256_pd(_mm256_cvtepi32_epi64(_mm256_extracti128_si256::<1>(m))),
    ]
}

/// f32 lanes 0–3 and 4–7 as f64.
#[inline]
#[target_feature(enable = "avx2")]
pub(super) fn to_f64(x: __m256) -> [__m256d; 2] {
    [
        _mm256_cvtps_pd(_mm256_castps256_ps128(x)),
        _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(x)),
    ]
}
