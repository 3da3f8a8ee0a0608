//! A group of eight walks in lockstep: the lanes' state, the batch's jobs a lane takes when its
//! walk ends (`refill`), and one vertical step of all eight (`advance`).

use std::arch::x86_64::*;

use super::avx2_lanes::{lanes, load_lanes, to_f64, widen, SLOTS};
use super::avx2_step::{choose8, uniform8};
use super::avx2_weigh::Record;
use super::rng::{walk_key, GAMMA};
use super::tables::Near;

/// Walks per batch to aim for. Lanes idle only while a batch's last walks finish, so more
/// walks per batch idle less; the batch's window grids must still fit in L1.
pub(super) const BATCH_WALKS: usize = 96;

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

/// What every step of a batch reads: the band's tables, the batch's grids and the lane offsets.
pub(super) struct Ctx<'a> {
    pub(super) near: &'a Near,
    pub(super) win: &'a Batch<'a>,
    pub(super) lin: *const f32,
    pub(super) log: *const f32,
    pub(super) grid: *const f32,
    pub(super) egrid: *const f32,
    pub(super) goff_arr: [isize; 8],
    pub(super) goff: __m256i,
    pub(super) ioff: __m256i,
    pub(super) ln_pmin: __m256d,
    pub(super) max_steps: __m256i,
}

/// The jobs of a batch: walk j is walk j % walks of start pixel j / walks.
pub(super) struct Jobs<'a> {
    pub(super) starts: &'a [(usize, usize)],
    pub(super) keys: [u64; BATCH_WALKS],
    pub(super) walks: usize,
    pub(super) base: usize,
    pub(super) total: usize,
    pub(super) next: usize,
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

/// SLOTS walks in lockstep: the lanes' state, in registers and in memory.
pub(super) struct Group {
    st: Lanes,
    cell: __m256i,
    pixel: __m256i,
    step: __m256i,
    ctr: [__m256i; 2],
    log_p: [__m256d; 2],
    /// Lanes with a walk.
    pub(super) live: i32,
}

impl Group {
    /// A group whose lanes take the next jobs. Lanes without a walk sit on the batch's last
    /// walk's start cell, so their loads stay in bounds.
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(super) fn new(jobs: &mut Jobs) -> Group {
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
    /// As [`walk_batch`](super::avx2::walk_batch): every lane stands inside its window and the
    /// band.
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn advance(&mut self, cx: &Ctx) -> Record {
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
    pub(super) fn refill(&mut self, ended: i32, jobs: &mut Jobs, ends: &mut Vec<usize>) -> u64 {
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
