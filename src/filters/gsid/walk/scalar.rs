//! The portable kernel: walks lane by lane, from the band's tables ([`Near`], [`Window`]).

use super::params::{lane_offsets, WalkInput, WalkParams};
use super::rng::{uniform, walk_key};
use super::step::{choose, step_weight, Accum};
use super::tables::{Near, Window};
use crate::kernels::fastmath::exp_neg;

/// Walks from the window's x0, lane by lane (the portable kernel).
#[inline(never)]
pub(super) fn walk_windowed(
    input: &WalkInput,
    params: &WalkParams,
    near: &Near,
    win: &Window,
) -> (Accum, u64) {
    let w = input.color.width();
    let goff = lane_offsets(win.side);
    let ioff = lane_offsets(w);
    let ln_pmin = params.p_min.ln();
    let pkey = input.key(win.i0);
    let mut acc = Accum::new(input, win.i0, params);
    let mut steps = 0u64;
    for walk in 0..params.walks {
        let key = walk_key(pkey, walk);
        let (mut g, mut i) = (win.center(), win.i0);
        let mut log_p = 0.0f64;
        let mut part = Accum::default();
        for step in 1..=params.max_steps {
            let (t, e) = (near.log(i), near.lin(i));
            let mut a = [0.0f32; 8];
            let mut l = [0.0f32; 8];
            for k in 0..8 {
                let gk = (g as isize + goff[k]) as usize;
                a[k] = win.grid[gk] + t[k];
                l[k] = win.egrid[gk] * e[k];
            }
            let Some((k, lp)) = choose(&a, &l, uniform(key, step)) else {
                break;
            };
            log_p += lp as f64;
            if log_p < ln_pmin {
                break;
            }
            g = (g as isize + goff[k]) as usize;
            i = (i as isize + ioff[k]) as usize;
            steps += 1;
            part.add(input.color.pixel(i), step_weight(log_p, step));
        }
        acc.merge(&part);
    }
    (acc, steps)
}

/// Walks from (x0, y0) with no window: the x0 term is computed on the fly.
pub(super) fn walk_unbounded(
    input: &WalkInput,
    params: &WalkParams,
    near: &Near,
    inv: f32,
    x0: usize,
    y0: usize,
) -> (Accum, u64) {
    let w = input.color.width();
    let i0 = y0 * w + x0;
    let ioff = lane_offsets(w);
    let ln_pmin = params.p_min.ln();
    let pkey = input.key(i0);
    let mut acc = Accum::new(input, i0, params);
    let mut steps = 0u64;
    for walk in 0..params.walks {
        let key = walk_key(pkey, walk);
        let mut i = i0;
        let mut log_p = 0.0f64;
        let mut part = Accum::default();
        for step in 1..=params.max_steps {
            let (t, e) = (near.log(i), near.lin(i));
            let mut a = [f32::NEG_INFINITY; 8];
            let mut l = [0.0f32; 8];
            for k in 0..8 {
                if t[k] != f32::NEG_INFINITY {
                    let d0 = input.features.distance(i0, (i as isize + ioff[k]) as usize);
                    let t0 = -(d0 * d0) * inv;
                    a[k] = t0 + t[k];
                    l[k] = exp_neg(t0) * e[k];
                }
            }
            let Some((k, lp)) = choose(&a, &l, uniform(key, step)) else {
                break;
            };
            log_p += lp as f64;
            if log_p < ln_pmin {
                break;
            }
            i = (i as isize + ioff[k]) as usize;
            steps += 1;
            part.add(input.color.pixel(i), step_weight(log_p, step));
        }
        acc.merge(&part);
    }
    (acc, steps)
}
