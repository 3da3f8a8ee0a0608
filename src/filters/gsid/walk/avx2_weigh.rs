//! The second loop of `super::avx2::walk_batch`: each step's weight exp(L_k / k) (in f32 as the
//! spec rounds it) and the colour sums, lane by lane in the order the walk loop took the steps,
//! so every sum is the spec's, bit for bit. Nothing here feeds back into the walks, so the steps
//! overlap each other.
//!
//! The walk loop hands over its records in chunks of at most [`FLUSH_RECORDS`], so their memory
//! does not grow with walks × max_steps; the per-lane running sums of the walks still in flight
//! are kept in [`Weigh`] from one chunk to the next, so the sums are formed as in one pass.

use std::arch::x86_64::*;

use super::avx2_lanes::{lanes, to_f64, widen, SLOTS};
use super::step::Accum;
use crate::kernels::fastmath::avx2::exp_neg8;

/// Records the walk loop keeps before it weighs them: a bound on its memory, large enough that
/// the weighing still runs long stretches with nothing waiting on the walks.
pub(super) const FLUSH_RECORDS: usize = 4096;

/// What one step of the walk loop leaves for [`Weigh::run`]: per lane the pixel a walk stands
/// on, its log-probability and step count, and which walks moved and which ended.
#[derive(Clone, Copy)]
pub(super) struct Record {
    pub(super) pixel: [i32; SLOTS],
    pub(super) log_p: [f64; SLOTS],
    pub(super) step: [i32; SLOTS],
    pub(super) going: i32,
    pub(super) ended: i32,
}

/// Per-lane colour and weight sums of the walks in flight, carried across chunks of records (in
/// memory between chunks, in registers within one).
pub(super) struct Weigh {
    /// Colour sums (three channels), then the weight sums, one f64 per lane.
    sums: [[f64; SLOTS]; 4],
    /// Whether the CPU runs AVX-512: the sums of all eight lanes then fit one register.
    wide: bool,
}

/// acc + x where `m` is set, acc elsewhere.
#[inline]
#[target_feature(enable = "avx2")]
fn add_where(acc: __m256d, x: __m256d, m: __m256d) -> __m256d {
    _mm256_blendv_pd(acc, _mm256_add_pd(acc, x), m)
}

/// One record's step weights exp(L_k / k) (0 where a walk did not move), as 8 f32: the same
/// operations for either register width.
#[inline]
#[target_feature(enable = "avx2")]
fn step_weights(rec: &Record, going_v: __m256i) -> __m256 {
    // SAFETY: each load reads 8 i32 or 4 f64 of the record's arrays of 8.
    let (step, log_p) = unsafe {
        (
            _mm256_loadu_si256(rec.step.as_ptr().cast()),
            [
                _mm256_loadu_pd(rec.log_p.as_ptr()),
                _mm256_loadu_pd(rec.log_p[4..].as_ptr()),
            ],
        )
    };
    let step_pd = [
        _mm256_cvtepi32_pd(_mm256_castsi256_si128(step)),
        _mm256_cvtepi32_pd(_mm256_extracti128_si256::<1>(step)),
    ];
    let ratio = _mm256_set_m128(
        _mm256_cvtpd_ps(_mm256_div_pd(log_p[1], step_pd[1])),
        _mm256_cvtpd_ps(_mm256_div_pd(log_p[0], step_pd[0])),
    );
    // Lanes that did not move may hold 0/0: they get exp(0), masked by the caller.
    let ratio = _mm256_and_ps(ratio, _mm256_castsi256_ps(going_v));
    exp_neg8(ratio)
}

/// Where each moving lane's colour starts in the interleaved colour (0 for the others): the
/// gathers' index, the same for all three channels.
#[inline]
#[target_feature(enable = "avx2")]
fn colour_index(rec: &Record, going_v: __m256i) -> __m256i {
    // SAFETY: reads the record's 8 pixels.
    let pixel = unsafe { _mm256_loadu_si256(rec.pixel.as_ptr().cast()) };
    let at3 = _mm256_mullo_epi32(pixel, _mm256_set1_epi32(3));
    _mm256_blendv_epi8(_mm256_setzero_si256(), at3, going_v)
}

/// Channel `ch` of the colours at `index` ([`colour_index`]), as 8 f32.
///
/// # Safety
/// Every index must be a pixel of `color`.
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn colours(index: __m256i, color: *const f32, ch: usize) -> __m256 {
    _mm256_i32gather_ps::<4>(color.add(ch), index)
}

impl Weigh {
    /// Sums of no steps, for a batch's first chunk; `wide` where the CPU runs AVX-512 (F).
    pub(super) fn new(wide: bool) -> Self {
        Weigh {
            sums: [[0.0; SLOTS]; 4],
            wide,
        }
    }

    /// Adds the steps of `records` to the running sums; each walk that ends in them takes the
    /// next job of `ends` (the jobs of exactly those walks, in the order they ended) and leaves
    /// its sums in `parts[job]`.
    ///
    /// # Safety
    /// The CPU must support AVX2 (and AVX-512 F if `wide`), and every pixel of a moving lane must
    /// index `color`'s pixels.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn run(
        &mut self,
        records: &[Record],
        ends: &[usize],
        color: *const f32,
        parts: &mut [Accum],
    ) {
        if self.wide {
            self.run_wide(records, ends, color, parts);
            return;
        }
        // Colour channels, then the weight; two registers of four lanes each.
        let mut acc: [[__m256d; 2]; 4] = std::array::from_fn(|k| {
            let lane = |h: usize| _mm256_loadu_pd(self.sums[k][4 * h..].as_ptr());
            [lane(0), lane(1)]
        });
        let store = |acc: &[[__m256d; 2]; 4], sums: &mut [[f64; SLOTS]; 4]| {
            for (a, out) in acc.iter().zip(sums) {
                for h in 0..2 {
                    _mm256_storeu_pd(out[4 * h..].as_mut_ptr(), a[h]);
                }
            }
        };
        let mut ends = ends.iter();
        for rec in records {
            let going_v = lanes(rec.going);
            let moved = widen(going_v);
            let wgt = to_f64(step_weights(rec, going_v));
            let wgt = [
                _mm256_and_pd(wgt[0], moved[0]),
                _mm256_and_pd(wgt[1], moved[1]),
            ];
            let index = colour_index(rec, going_v);
            for ch in 0..3 {
                let col = to_f64(colours(index, color, ch));
                for h in 0..2 {
                    acc[ch][h] = add_where(acc[ch][h], _mm256_mul_pd(wgt[h], col[h]), moved[h]);
                }
            }
            for h in 0..2 {
                acc[3][h] = add_where(acc[3][h], wgt[h], moved[h]);
            }
            if rec.ended != 0 {
                store(&acc, &mut self.sums);
                hand_in(rec.ended, &self.sums, &mut ends, parts);
                let reset = widen(lanes(rec.ended));
                for a in &mut acc {
                    for h in 0..2 {
                        a[h] = _mm256_andnot_pd(reset[h], a[h]);
                    }
                }
            }
        }
        debug_assert!(ends.next().is_none(), "a job for a walk that did not end");
        store(&acc, &mut self.sums);
    }

    /// [`run`](Weigh::run) with each sum's eight lanes in one AVX-512 register and the lanes
    /// chosen by mask registers: the same operations on every lane, so the same bits.
    ///
    /// # Safety
    /// As [`run`](Weigh::run), with AVX-512 F.
    #[target_feature(enable = "avx2,avx512f")]
    unsafe fn run_wide(
        &mut self,
        records: &[Record],
        ends: &[usize],
        color: *const f32,
        parts: &mut [Accum],
    ) {
        let mut acc: [__m512d; 4] = std::array::from_fn(|k| _mm512_loadu_pd(self.sums[k].as_ptr()));
        let store = |acc: &[__m512d; 4], sums: &mut [[f64; SLOTS]; 4]| {
            for (a, out) in acc.iter().zip(sums) {
                _mm512_storeu_pd(out.as_mut_ptr(), *a);
            }
        };
        let mut ends = ends.iter();
        for rec in records {
            let going_v = lanes(rec.going);
            let moved = rec.going as __mmask8;
            let wgt = _mm512_maskz_mov_pd(moved, _mm512_cvtps_pd(step_weights(rec, going_v)));
            let index = colour_index(rec, going_v);
            for ch in 0..3 {
                let col = _mm512_cvtps_pd(colours(index, color, ch));
                acc[ch] = _mm512_mask_add_pd(acc[ch], moved, acc[ch], _mm512_mul_pd(wgt, col));
            }
            acc[3] = _mm512_mask_add_pd(acc[3], moved, acc[3], wgt);
            if rec.ended != 0 {
                store(&acc, &mut self.sums);
                hand_in(rec.ended, &self.sums, &mut ends, parts);
                let kept = !(rec.ended as __mmask8);
                for a in &mut acc {
                    *a = _mm512_maskz_mov_pd(kept, *a);
                }
            }
        }
        debug_assert!(ends.next().is_none(), "a job for a walk that did not end");
        store(&acc, &mut self.sums);
    }
}

/// The walks of `ended` leave their sums (`sums`: colour channels, then weight, per lane) in
/// `parts`, each at the next job of `ends`.
#[inline]
fn hand_in(
    ended: i32,
    sums: &[[f64; SLOTS]; 4],
    ends: &mut std::slice::Iter<usize>,
    parts: &mut [Accum],
) {
    let mut bits = ended;
    while bits != 0 {
        let s = bits.trailing_zeros() as usize;
        bits &= bits - 1;
        let job = *ends.next().expect("one job per ended walk");
        parts[job] = Accum {
            sum: [sums[0][s], sums[1][s], sums[2][s]],
            weight: sums[3][s],
        };
    }
}
