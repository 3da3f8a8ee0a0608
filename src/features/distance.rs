//! The pixel difference d: between two packed records ([`distance`]), and along runs of pixel pairs
//! of [`FeaturePlanes`] ([`distance_row`], with its AVX2 kernel), bit for bit the same.

use super::planes::FeaturePlanes;
use crate::kernels::simd::Kernel;

/// Floats per pixel record (padded to a cache line).
pub const FEATURE_LANES: usize = 16;
/// Guards the relative depth difference against two zero depths.
pub const DEPTH_EPS: f32 = 1e-8;
/// Record lanes that enter d (the rest is padding).
pub const USED_LANES: usize = 14;

/// d for runs of pixel pairs: `out[x]` = d(pixel at plane offset `center + x`, pixel at
/// `other + x`) of `planes`, for x < out.len(). Bit for bit equal to [`distance`] on the two records
/// (the AVX2 kernel runs the same operations 8 pairs at a time).
#[allow(clippy::needless_range_loop)] // x indexes the output and two plane slices alike
pub fn distance_row(
    kernel: Kernel,
    planes: &FeaturePlanes,
    depth_weight: f32,
    center: usize,
    other: usize,
    out: &mut [f32],
) {
    let done = match kernel.or_portable() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: or_portable returns Avx2 or Avx512 only when the CPU has AVX2.
        Kernel::Avx2 | Kernel::Avx512 => unsafe {
            avx2::distance_row(planes, depth_weight, center, other, out)
        },
        _ => 0,
    };
    let n = out.len();
    let mut a = [0.0f32; FEATURE_LANES];
    let mut b = [0.0f32; FEATURE_LANES];
    for x in done..n {
        for lane in 0..USED_LANES {
            a[lane] = planes.lane(lane, center, n)[x];
            b[lane] = planes.lane(lane, other, n)[x];
        }
        out[x] = distance(&a, &b, depth_weight);
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use super::{FeaturePlanes, DEPTH_EPS, USED_LANES};

    /// `super::distance_row` for the whole groups of 8 pairs; returns how many pairs it did.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[target_feature(enable = "avx2")]
    pub unsafe fn distance_row(
        planes: &FeaturePlanes,
        depth_weight: f32,
        center: usize,
        other: usize,
        out: &mut [f32],
    ) -> usize {
        let (add, mul, sub) = (_mm256_add_ps, _mm256_mul_ps, _mm256_sub_ps);
        let abs_mask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fff_ffff));
        let dw = _mm256_set1_ps(depth_weight);
        let full = out.len() / 8 * 8;
        // Every load below reads lane < USED_LANES at center + x or other + x, x + 8 <= full: one
        // check for all of them.
        let last = (USED_LANES - 1) * planes.plane_len + center.max(other) + full;
        assert!(last <= planes.data.len(), "a run beyond the planes");
        let data = planes.data.as_ptr();
        let mut x = 0;
        while x < full {
            // SAFETY: lane * plane_len + at + x + 8 <= last <= data.len() (checked above);
            // unaligned loads.
            let ld = |lane: usize, at: usize| unsafe {
                _mm256_loadu_ps(data.add(lane * planes.plane_len + at + x))
            };
            let diff = |lane: usize| sub(ld(lane, center), ld(lane, other));
            let sq = |lane: usize| {
                let d = diff(lane);
                mul(d, d)
            };
            let abs = |lane: usize| _mm256_and_ps(diff(lane), abs_mask);
            let color = _mm256_sqrt_ps(add(add(sq(0), sq(1)), sq(2)));
            let albedo = _mm256_sqrt_ps(add(add(sq(3), sq(4)), sq(5)));
            let normal = add(add(sq(6), sq(7)), sq(8));
            let mut d = add(add(color, albedo), normal);
            if planes.material {
                d = add(d, add(add(add(abs(9), abs(10)), abs(11)), abs(12)));
            }
            if depth_weight > 0.0 {
                let denom = _mm256_max_ps(
                    _mm256_max_ps(ld(13, center), ld(13, other)),
                    _mm256_set1_ps(DEPTH_EPS),
                );
                d = add(d, _mm256_div_ps(mul(dw, abs(13)), denom));
            }
            // SAFETY: x + 8 <= out.len(); unaligned store.
            unsafe { _mm256_storeu_ps(out[x..x + 8].as_mut_ptr(), d) };
            x += 8;
        }
        full
    }
}

/// d between two packed records; symmetric bit for bit (so d(i, j) == d(j, i) exactly).
#[inline]
pub fn distance(a: &[f32; FEATURE_LANES], b: &[f32; FEATURE_LANES], depth_weight: f32) -> f32 {
    let mut diff = [0.0f32; FEATURE_LANES];
    for k in 0..FEATURE_LANES {
        diff[k] = a[k] - b[k];
    }
    let sq = |k: usize| diff[k] * diff[k];
    let color = (sq(0) + sq(1) + sq(2)).sqrt();
    let albedo = (sq(3) + sq(4) + sq(5)).sqrt();
    let normal = sq(6) + sq(7) + sq(8);
    let material = diff[9].abs() + diff[10].abs() + diff[11].abs() + diff[12].abs();
    let depth = if depth_weight > 0.0 {
        depth_weight * diff[13].abs() / a[13].max(b[13]).max(DEPTH_EPS)
    } else {
        0.0
    };
    color + albedo + normal + material + depth
}
