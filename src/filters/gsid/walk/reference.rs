//! The reference kernel: the readable specification of the walks (docs/ALGORITHM.md §3), with every
//! distance recomputed where a step needs it. The fast kernels must give its bits.

use super::params::{inv_two_sigma2, WalkInput, WalkParams, WalkStats, OFFSETS};
use super::rng::{uniform, walk_key};
use super::step::{choose, step_weight, Accum};
use crate::image::Image;
use crate::kernels::fastmath::exp_neg;

#[inline]
fn neighbour(x: usize, y: usize, k: usize, w: usize, h: usize) -> Option<(usize, usize)> {
    let (dx, dy) = OFFSETS[k];
    let nx = x as isize + dx;
    let ny = y as isize + dy;
    (nx >= 0 && ny >= 0 && (nx as usize) < w && (ny as usize) < h)
        .then_some((nx as usize, ny as usize))
}

/// [`Engine::Reference`](super::job::Engine::Reference): every logit recomputed from the
/// features, on one thread. `on_row` is called once per finished row; false skips the remaining rows.
pub(super) fn denoise(
    input: &WalkInput,
    params: &WalkParams,
    on_row: &(dyn Fn(usize) -> bool + Sync),
) -> (Image, WalkStats) {
    let (w, h) = input.color.dims();
    let inv = inv_two_sigma2(params.sigma);
    let ln_pmin = params.p_min.ln();
    let blocked = |j: usize| input.mask.is_some_and(|m| m[j]);
    let mut out = Image::new(w, h, 3);
    let mut stats = WalkStats::default();
    for y0 in 0..h {
        for x0 in 0..w {
            let i0 = y0 * w + x0;
            let pkey = input.key(i0);
            let mut acc = Accum::new(input, i0, params);
            for walk in 0..params.walks {
                stats.walks += 1;
                let key = walk_key(pkey, walk);
                let (mut x, mut y) = (x0, y0);
                let mut log_p = 0.0f64;
                let mut part = Accum::default();
                for step in 1..=params.max_steps {
                    let i = y * w + x;
                    let mut a = [f32::NEG_INFINITY; 8];
                    let mut l = [0.0f32; 8];
                    for k in 0..8 {
                        let Some((nx, ny)) = neighbour(x, y, k, w, h) else {
                            continue;
                        };
                        let in_window = params.window.is_none_or(|r| {
                            nx.abs_diff(x0) <= r as usize && ny.abs_diff(y0) <= r as usize
                        });
                        let j = ny * w + nx;
                        if !in_window || blocked(j) {
                            continue;
                        }
                        let d0 = input.features.distance(i0, j);
                        let dj = input.features.distance(i, j);
                        let (t0, tj) = (-(d0 * d0) * inv, -(dj * dj) * inv);
                        a[k] = t0 + tj;
                        l[k] = exp_neg(t0) * exp_neg(tj);
                    }
                    let Some((k, lp)) = choose(&a, &l, uniform(key, step)) else {
                        break;
                    };
                    log_p += lp as f64;
                    if log_p < ln_pmin {
                        break;
                    }
                    (x, y) = neighbour(x, y, k, w, h).expect("chosen neighbour is inside");
                    stats.steps += 1;
                    part.add(input.color.pixel(y * w + x), step_weight(log_p, step));
                }
                acc.merge(&part);
            }
            acc.write(input.color.pixel(i0), out.pixel_mut(i0));
        }
        if !on_row(1) {
            break;
        }
    }
    (out, stats)
}
