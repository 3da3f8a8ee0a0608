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
//!
//! Here the batch: its walks' jobs handed to the lanes of [`GROUPS`] groups (`super::avx2_group`,
//! with the step's arithmetic in `super::avx2_step`), and the records they leave weighed.

use std::arch::x86_64::*;

pub(super) use super::avx2_group::Batch;
use super::avx2_group::{Ctx, Group, Jobs, BATCH_WALKS};
use super::avx2_lanes::offsets8;
use super::avx2_weigh::{Record, Weigh, FLUSH_RECORDS};
use super::params::{lane_offsets, WalkInput, WalkParams};
use super::step::Accum;
use super::tables::Near;

/// Start pixels per call of [`walk_batch`] for `walks` walks each.
pub(super) fn batch(walks: u32) -> usize {
    BATCH_WALKS.div_ceil(walks.max(1) as usize).max(1)
}

/// Whether [`walk_batch`]'s 32-bit indices reach every entry of the band's tables.
pub(super) fn fits(near: &Near) -> bool {
    near.lin.len() * 8 <= i32::MAX as usize
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
