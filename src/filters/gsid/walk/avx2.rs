//! The windowed walk with AVX2, bit for bit equal to `super::scalar::walk_windowed`.
//!
//! Eight walks advance in lockstep, one per lane, and a step is vertical: each walk's 8
//! neighbour weights (its pixel's precomputed factors times its window's) are built as one
//! register, the 8 registers are transposed so that register k holds neighbour k of every walk,
//! and then the prefix sum, the pick, ln of the normaliser, the f64 log-probability, the weight
//! and the colour sums are each a handful of instructions for all eight walks. When a walk ends
//! its lane takes the next walk of the batch, which may belong to the next start pixel, so
//! lanes seldom idle. Two such groups of eight step in turn: each step waits on its own loads,
//! and the other group's independent step runs in that time.
//!
//! A step is one chain of dependent operations (where a walk stands decides what it loads
//! next), so the walk loop does only what the next step needs; the weights and colour sums run
//! after it, in `super::avx2_weigh`, from a record of every step (handed over in bounded
//! chunks), where nothing waits on the walks.
//!
//! Every operation mirrors the scalar spec (the same IEEE operations in the same order, the
//! random numbers from the same integer arithmetic), so the results are bit-identical.

use std::arch::x86_64::*;

use super::avx2_weigh::{Record, Weigh, FLUSH_RECORDS};
use super::rng::{walk_key, GAMMA};
use super::step::{choose_log, Accum, LINEAR_MIN};
use super::tables::Near;
use super::{lane_offsets, WalkInput, WalkParams};
use crate::kernels::fastmath::{LN2_HI, LN2_LO, LN_POLY};

/// Walks in lockstep: one per f32 lane.
pub(super) const SLOTS: usize = 8;

/// Walks per batch to aim for. Lanes idle only while a batch's last walks finish, so more
/// walks per batch idle less; the batch's window grids must still fit in L1.
const BATCH_WALKS: usize = 96;

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

/// The window factors of cell g's 8 neighbours, in lane order: three above, left, right,
/// three below.
///
/// # Safety
/// Cells g ± (side + 1) must lie inside the grid at `grid`.
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn window_block(grid: *const f32, g: usize, side: usize) -> __m256 {
    let above = _mm_loadu_ps(grid.add(g - side - 1));
    let below = _mm_loadu_ps(grid.add(g + side - 2));
    let lo = _mm_blend_ps::<0b1000>(above, _mm_broadcast_ss(&*grid.add(g - 1)));
    let hi = _mm_blend_ps::<0b0001>(below, _mm_broadcast_ss(&*grid.add(g + 1)));
    _mm256_set_m128(hi, lo)
}

/// Transposes 8 registers of 8 lanes: lane s of the result's register k is lane k of r[s].
#[inline]
#[target_feature(enable = "avx2")]
fn transpose8(r: [__m256; 8]) -> [__m256; 8] {
    let t0 = _mm256_unpacklo_ps(r[0], r[1]);
    let t1 = _mm256_unpackhi_ps(r[0], r[1]);
    let t2 = _mm256_unpacklo_ps(r[2], r[3]);
    let t3 = _mm256_unpackhi_ps(r[2], r[3]);
    let t4 = _mm256_unpacklo_ps(r[4], r[5]);
    let t5 = _mm256_unpackhi_ps(r[4], r[5]);
    let t6 = _mm256_unpacklo_ps(r[6], r[7]);
    let t7 = _mm256_unpackhi_ps(r[6], r[7]);
    let u0 = _mm256_shuffle_ps::<0x44>(t0, t2);
    let u1 = _mm256_shuffle_ps::<0xee>(t0, t2);
    let u2 = _mm256_shuffle_ps::<0x44>(t1, t3);
    let u3 = _mm256_shuffle_ps::<0xee>(t1, t3);
    let u4 = _mm256_shuffle_ps::<0x44>(t4, t6);
    let u5 = _mm256_shuffle_ps::<0xee>(t4, t6);
    let u6 = _mm256_shuffle_ps::<0x44>(t5, t7);
    let u7 = _mm256_shuffle_ps::<0xee>(t5, t7);
    [
        _mm256_permute2f128_ps::<0x20>(u0, u4),
        _mm256_permute2f128_ps::<0x20>(u1, u5),
        _mm256_permute2f128_ps::<0x20>(u2, u6),
        _mm256_permute2f128_ps::<0x20>(u3, u7),
        _mm256_permute2f128_ps::<0x31>(u0, u4),
        _mm256_permute2f128_ps::<0x31>(u1, u5),
        _mm256_permute2f128_ps::<0x31>(u2, u6),
        _mm256_permute2f128_ps::<0x31>(u3, u7),
    ]
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
fn load_lanes(a: &[i32; SLOTS]) -> __m256i {
    // SAFETY: `a` holds 8 i32; unaligned load.
    unsafe { _mm256_loadu_si256(a.as_ptr().cast()) }
}

/// Neighbour index steps as one register (they fit in i32: [`fits`] bounds the tables).
#[inline]
#[target_feature(enable = "avx2")]
fn offsets8(o: [isize; 8]) -> __m256i {
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

/// Start pixels per call of [`walk_batch`] for `walks` walks each.
pub(super) fn batch(walks: u32) -> usize {
    BATCH_WALKS.div_ceil(walks.max(1) as usize).max(1)
}

/// Whether [`walk_batch`]'s 32-bit indices reach every entry of the band's tables.
pub(super) fn fits(near: &Near) -> bool {
    near.lin.len() * 8 <= i32::MAX as usize
}

/// The window grids of a batch of start pixels, in one buffer.
pub(super) struct Batch<'a> {
    pub grid: &'a [f32],
    pub egrid: &'a [f32],
    pub side: usize,
    /// Per start pixel: the grid cell of its centre, and its pixel index.
    pub starts: &'a [(usize, usize)],
}

/// Per-lane state of the walks in flight, in memory between the vector parts of a step.
struct Lanes {
    job: [usize; SLOTS],
    cell: [i32; SLOTS],
    pixel: [i32; SLOTS],
    step: [i32; SLOTS],
    ctr: [u64; SLOTS],
}

impl Lanes {
    /// Lane `s` takes the next job, if one is left; whether it did.
    fn take(&mut self, s: usize, jobs: &mut Jobs) -> bool {
        if jobs.next >= jobs.total {
            return false;
        }
        (self.cell[s], self.pixel[s], self.ctr[s]) = jobs.start(jobs.next);
        self.job[s] = jobs.next;
        jobs.next += 1;
        true
    }
}

/// Groups of SLOTS walks that step in turn. A step is one chain of dependent operations, so one
/// group leaves the core idle while it waits; a second group's chain, independent of the first,
/// fills those cycles.
const GROUPS: usize = 2;

/// Per-batch scratch of [`walk_batch`], reused from batch to batch.
#[derive(Default)]
pub(super) struct Walks {
    /// Each walk's sums, merged per start pixel in walk order at the end.
    parts: Vec<Accum>,
    /// Per group, the steps not yet weighed: at most [`FLUSH_RECORDS`].
    records: [Vec<Record>; GROUPS],
    /// Per group, the jobs of the walks that ended in its `records`, in the order they ended.
    ends: [Vec<usize>; GROUPS],
}

/// What every step of a batch reads: the band's tables, the batch's grids and the lane offsets.
struct Ctx<'a> {
    near: &'a Near,
    win: &'a Batch<'a>,
    lin: *const f32,
    log: *const f32,
    grid: *const f32,
    egrid: *const f32,
    goff_arr: [isize; 8],
    goff: __m256i,
    ioff: __m256i,
    ln_pmin: __m256d,
    max_steps: __m256i,
}

/// The jobs of a batch: walk j is walk j % walks of start pixel j / walks.
struct Jobs<'a> {
    starts: &'a [(usize, usize)],
    keys: [u64; BATCH_WALKS],
    walks: usize,
    base: usize,
    total: usize,
    next: usize,
}

impl Jobs<'_> {
    /// Walk j's start cell, pixel (relative to the band's first row) and first counter.
    fn start(&self, j: usize) -> (i32, i32, u64) {
        let (cell, i0) = self.starts[j / self.walks];
        let key = walk_key(self.keys[j / self.walks], (j % self.walks) as u32);
        (
            cell as i32,
            (i0 - self.base) as i32,
            key.wrapping_add(GAMMA.wrapping_mul(2)),
        )
    }
}

/// SLOTS walks in lockstep: the lanes' state, in registers and in memory.
struct Group {
    st: Lanes,
    cell: __m256i,
    pixel: __m256i,
    step: __m256i,
    ctr: [__m256i; 2],
    log_p: [__m256d; 2],
    /// Lanes with a walk.
    live: i32,
}

impl Group {
    /// A group whose lanes take the next jobs. Lanes without a walk sit on the batch's last
    /// walk's start cell, so their loads stay in bounds.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn new(jobs: &mut Jobs) -> Group {
        let mut st = Lanes {
            job: [0; SLOTS],
            cell: [0; SLOTS],
            pixel: [0; SLOTS],
            step: [0; SLOTS],
            ctr: [0; SLOTS],
        };
        let mut live = 0i32;
        for s in 0..SLOTS {
            if st.take(s, jobs) {
                live |= 1 << s;
            } else {
                (st.cell[s], st.pixel[s], st.ctr[s]) = jobs.start(jobs.total - 1);
            }
        }
        Group {
            cell: load_lanes(&st.cell),
            pixel: load_lanes(&st.pixel),
            step: load_lanes(&st.step),
            // SAFETY: both loads read 4 of `st.ctr`'s 8 values.
            ctr: unsafe {
                [
                    _mm256_loadu_si256(st.ctr.as_ptr().cast()),
                    _mm256_loadu_si256(st.ctr[4..].as_ptr().cast()),
                ]
            },
            log_p: [_mm256_setzero_pd(); 2],
            st,
            live,
        }
    }

    /// One step of every live walk, with no branch that depends on it (the next group's step can
    /// start before this one's ends): the record of where each walk stands now.
    ///
    /// # Safety
    /// As [`walk_batch`]: every lane stands inside its window and the band.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn advance(&mut self, cx: &Ctx) -> Record {
        let Ctx {
            near,
            win,
            lin,
            log,
            grid,
            egrid,
            goff_arr,
            goff,
            ioff,
            ln_pmin,
            max_steps,
        } = *cx;
        let side = win.side;
        let st = &mut self.st;
        let u = uniform8(self.ctr);
        // Each walk's 8 neighbour weights, one register per walk, then one per neighbour.
        _mm256_storeu_si256(st.cell.as_mut_ptr().cast(), self.cell);
        _mm256_storeu_si256(st.pixel.as_mut_ptr().cast(), self.pixel);
        // Their log-domain twins are loaded too, so that the picked one's is a permute away
        // once the pick is known (a gather would wait on memory). A plain loop, not a
        // closure, which a build may leave out of line: a call per walk.
        let mut rows = [_mm256_setzero_ps(); SLOTS];
        let mut logs = [_mm256_setzero_ps(); SLOTS];
        for s in 0..SLOTS {
            // The loads below are in bounds because every lane stands inside its window and
            // the band: walks move only to a neighbour of weight > 0 (`pick_lane`), and the
            // grid's ring and the band's halo hold the cells around a window's edge.
            debug_assert!(
                (st.pixel[s] as usize) < near.lin.len()
                    && (st.cell[s] as usize) > side
                    && (st.cell[s] as usize) + side + 1 < win.grid.len(),
                "walk left its window: pixel {} cell {}",
                st.pixel[s],
                st.cell[s]
            );
            let (i, g) = (8 * st.pixel[s] as usize, st.cell[s] as usize);
            let e = _mm256_loadu_ps(lin.add(i));
            rows[s] = _mm256_mul_ps(window_block(egrid, g, side), e);
            logs[s] = _mm256_add_ps(window_block(grid, g, side), _mm256_loadu_ps(log.add(i)));
        }
        let cand = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(
            max_steps, self.step,
        ))) & self.live;
        let (k, lp, picked) = choose8(&transpose8(rows), &logs, u, cand, |s| {
            let (g, i) = (st.cell[s] as isize, st.pixel[s] as usize);
            let t = near.log[i];
            std::array::from_fn(|n| win.grid[(g + goff_arr[n]) as usize] + t[n])
        });
        let lp = to_f64(lp);
        let new_log_p = [
            _mm256_add_pd(self.log_p[0], lp[0]),
            _mm256_add_pd(self.log_p[1], lp[1]),
        ];
        let above = _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_NLT_UQ>(new_log_p[0], ln_pmin))
            | _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_NLT_UQ>(new_log_p[1], ln_pmin)) << 4;
        let going = picked & above;
        let going_v = lanes(going);
        let moved = widen(going_v);
        // Only walks that go on move: a walk that stops stays where it stood (inside its
        // window and the image), so a lane left without a new walk still loads in bounds.
        self.cell = _mm256_blendv_epi8(
            self.cell,
            _mm256_add_epi32(self.cell, _mm256_permutevar8x32_epi32(goff, k)),
            going_v,
        );
        self.pixel = _mm256_blendv_epi8(
            self.pixel,
            _mm256_add_epi32(self.pixel, _mm256_permutevar8x32_epi32(ioff, k)),
            going_v,
        );
        self.step = _mm256_sub_epi32(self.step, going_v);
        let gamma = _mm256_set1_epi64x(GAMMA as i64);
        for h in 0..2 {
            self.ctr[h] = _mm256_add_epi64(
                self.ctr[h],
                _mm256_and_si256(gamma, _mm256_castpd_si256(moved[h])),
            );
        }
        // The weights and colour sums wait for the second loop: off this loop's chain of
        // dependent steps, they run at the vector units' full rate there.
        let mut rec = Record {
            pixel: [0; SLOTS],
            log_p: [0.0; SLOTS],
            step: [0; SLOTS],
            going,
            ended: self.live & !going,
        };
        _mm256_storeu_si256(rec.pixel.as_mut_ptr().cast(), self.pixel);
        _mm256_storeu_si256(rec.step.as_mut_ptr().cast(), self.step);
        for h in 0..2 {
            _mm256_storeu_pd(rec.log_p[4 * h..].as_mut_ptr(), new_log_p[h]);
            self.log_p[h] = _mm256_blendv_pd(self.log_p[h], new_log_p[h], moved[h]);
        }
        rec
    }

    /// Ended walks (`ended`, from the record [`advance`](Group::advance) just gave) hand in
    /// their steps and jobs; their lanes take the next jobs. The resets are blends, and the new
    /// walks' starts one blend per field. Returns the ended walks' steps.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn refill(&mut self, ended: i32, jobs: &mut Jobs, ends: &mut Vec<usize>) -> u64 {
        if ended == 0 {
            return 0;
        }
        let st = &mut self.st;
        let mut steps = 0u64;
        // SAFETY: stores 8 i32 into `st.step`'s 8.
        unsafe { _mm256_storeu_si256(st.step.as_mut_ptr().cast(), self.step) };
        let mut refilled = 0i32;
        let mut bits = ended;
        while bits != 0 {
            let s = bits.trailing_zeros() as usize;
            bits &= bits - 1;
            steps += st.step[s] as u64;
            ends.push(st.job[s]);
            if st.take(s, jobs) {
                refilled |= 1 << s;
            } else {
                self.live &= !(1 << s);
            }
        }
        let ended_v = lanes(ended);
        let reset = widen(ended_v);
        self.step = _mm256_andnot_si256(ended_v, self.step);
        for h in 0..2 {
            self.log_p[h] = _mm256_andnot_pd(reset[h], self.log_p[h]);
        }
        if refilled != 0 {
            let fresh = lanes(refilled);
            self.cell = _mm256_blendv_epi8(self.cell, load_lanes(&st.cell), fresh);
            self.pixel = _mm256_blendv_epi8(self.pixel, load_lanes(&st.pixel), fresh);
            let fresh = widen(fresh);
            for h in 0..2 {
                // SAFETY: reads 4 of `st.ctr`'s 8 values.
                let new = unsafe { _mm256_loadu_si256(st.ctr[4 * h..].as_ptr().cast()) };
                self.ctr[h] = _mm256_castpd_si256(_mm256_blendv_pd(
                    _mm256_castsi256_pd(self.ctr[h]),
                    _mm256_castsi256_pd(new),
                    fresh[h],
                ));
            }
        }
        steps
    }
}

/// `super::scalar::walk_windowed` for every start pixel of `win`, bit for bit, their walks sharing the
/// lanes of [`GROUPS`] groups. `scratch` is reused space for the walks' sums; `accs[b]` receives
/// start pixel b's result. Returns the steps taken.
///
/// Any walk may run in any lane of any group: each walk's steps are weighed in its own order by
/// its group's [`Weigh`], and the walks' sums are merged per start pixel in walk order, so the
/// result does not depend on which lane took which walk.
///
/// The steps are weighed with AVX-512 registers if `wide`.
///
/// # Safety
/// The CPU must support AVX2 (and AVX-512 F if `wide`), and [`fits`] must hold for `near`.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn walk_batch(
    input: &WalkInput,
    params: &WalkParams,
    near: &Near,
    win: Batch,
    wide: bool,
    scratch: &mut Walks,
    accs: &mut [Accum],
) -> u64 {
    let w = input.color.width();
    let walks = params.walks as usize;
    let total = walks * win.starts.len();
    assert!(
        win.starts.len() <= BATCH_WALKS,
        "batch larger than `batch` gives"
    );
    let Walks {
        parts,
        records,
        ends,
    } = scratch;
    parts.clear();
    parts.resize(total, Accum::default());
    for g in 0..GROUPS {
        records[g].clear();
        ends[g].clear();
    }
    if total == 0 {
        return 0;
    }
    // Pixel indices are relative to the band's first row, so they fit in 32 bits.
    let base = near.base;
    let color = input.color.data()[3 * base..].as_ptr();
    let goff_arr = lane_offsets(win.side);
    let cx = Ctx {
        near,
        win: &win,
        lin: near.lin.as_ptr().cast::<f32>(),
        log: near.log.as_ptr().cast::<f32>(),
        grid: win.grid.as_ptr(),
        egrid: win.egrid.as_ptr(),
        goff_arr,
        goff: offsets8(goff_arr),
        ioff: offsets8(lane_offsets(w)),
        ln_pmin: _mm256_set1_pd(params.p_min.ln()),
        max_steps: _mm256_set1_epi32(params.max_steps.min(i32::MAX as u32) as i32),
    };
    // One key per start pixel ([`batch`] never gives more than BATCH_WALKS start pixels).
    let mut jobs = Jobs {
        starts: win.starts,
        keys: [0u64; BATCH_WALKS],
        walks,
        base,
        total,
        next: 0,
    };
    for (key, &(_, i0)) in jobs.keys.iter_mut().zip(win.starts) {
        *key = input.key(i0);
    }
    let mut groups: [Group; GROUPS] = std::array::from_fn(|_| Group::new(&mut jobs));
    let mut weigh: [Weigh; GROUPS] = std::array::from_fn(|_| Weigh::new(wide));
    let mut steps = 0u64;
    while groups.iter().any(|g| g.live != 0) {
        // Every group's step first, then the refills, whose branches depend on the steps: a
        // mispredicted one then discards no other group's work.
        let mut ended = [0i32; GROUPS];
        for g in 0..GROUPS {
            if groups[g].live != 0 {
                let rec = groups[g].advance(&cx);
                ended[g] = rec.ended;
                records[g].push(rec);
            }
        }
        for g in 0..GROUPS {
            steps += groups[g].refill(ended[g], &mut jobs, &mut ends[g]);
            // Weighs what has accumulated, so the records never outgrow a fixed bound; `weigh`
            // carries the sums of the walks in flight, and `ends` holds exactly the ended walks'.
            if records[g].len() >= FLUSH_RECORDS {
                weigh[g].run(&records[g], &ends[g], color, parts);
                records[g].clear();
                ends[g].clear();
            }
        }
    }
    for g in 0..GROUPS {
        weigh[g].run(&records[g], &ends[g], color, parts);
    }
    for (b, &(_, i0)) in win.starts.iter().enumerate() {
        let mut acc = Accum::new(input, i0, params);
        for part in &parts[b * walks..(b + 1) * walks] {
            acc.merge(part);
        }
        accs[b] = acc;
    }
    steps
}
