//! The tables a band of start rows precomputes so that a step needs no distance: the
//! x0-independent neighbour terms ([`Near`]), the x0 terms of every pixel pair within a window
//! ([`Pairs`]), and each start pixel's window grid of x0 terms ([`Window`]).

use std::ops::Range;

use super::params::{WalkInput, OFFSETS};
use crate::features::{distance_row, FeaturePlanes};
use crate::kernels::fastmath::{exp_neg, exp_neg_row};
use crate::kernels::simd::Kernel;

/// The x0-independent terms of a band of rows: for each pixel i and lane k, −d(i, j)²/(2σ²) and
/// its exp (−∞ and 0 outside the image or on masked pixels). One pixel's 8 terms are one 32-byte
/// block, so a step loads them with one vector load.
#[derive(Default)]
pub(super) struct Near {
    /// Index of the first pixel of the band.
    pub(super) base: usize,
    pub(super) log: Vec<[f32; 8]>,
    pub(super) lin: Vec<[f32; 8]>,
}

impl Near {
    /// The terms of rows `rows`, into `self` (its buffers are reused from band to band), from
    /// `planes`, which hold rows `rows.start - 1` (if there is one) to `rows.end - 1`.
    ///
    /// Each pair of neighbours is computed once, a row at a time with [`distance_row`]: the pair
    /// (p, p + o) for the four offsets o that point forward fills lane o of p and lane −o of p + o.
    pub(super) fn compute(
        &mut self,
        kernel: Kernel,
        input: &WalkInput,
        inv: f32,
        rows: Range<usize>,
        planes: &FeaturePlanes,
    ) {
        let (w, h) = input.color.dims();
        let blocked = |j: usize| input.mask.is_some_and(|m| m[j]);
        let n = rows.len() * w;
        self.base = rows.start * w;
        self.log.clear();
        self.log.resize(n, [f32::NEG_INFINITY; 8]);
        self.lin.clear();
        self.lin.resize(n, [0.0f32; 8]);
        // A pixel's backward lanes come from pairs that start one row above.
        let first = rows.start.saturating_sub(1);
        let depth_weight = input.features.depth_weight();
        let (mut t, mut e) = (vec![0.0f32; w + RUN_PAD], vec![0.0f32; w + RUN_PAD]);
        // (forward lane, its reverse lane) of OFFSETS.
        for (fwd, back) in [(4, 3), (5, 2), (6, 1), (7, 0)] {
            let (dx, dy) = OFFSETS[fwd];
            let lo = (-dx).max(0) as usize;
            let hi = (w as isize - dx).clamp(0, w as isize) as usize;
            for y in first..rows.end {
                let ny = y + dy as usize;
                if ny >= h || ny >= rows.end || lo >= hi {
                    continue;
                }
                let center = planes.offset(lo as isize, y);
                let other = planes.offset(lo as isize + dx, ny);
                let run = lo..lo + (hi - lo).next_multiple_of(8);
                distance_row(kernel, planes, depth_weight, center, other, &mut t[run]);
                let (t, e) = (&mut t[lo..hi], &mut e[lo..hi]);
                for v in t.iter_mut() {
                    *v = -(*v * *v) * inv;
                }
                e.copy_from_slice(t);
                exp_neg_row(kernel, e);
                for (k, x) in (lo..hi).enumerate() {
                    let (p, q) = (y * w + x, ny * w + (x as isize + dx) as usize);
                    if y >= rows.start && !blocked(q) {
                        self.log[p - self.base][fwd] = t[k];
                        self.lin[p - self.base][fwd] = e[k];
                    }
                    if ny >= rows.start && !blocked(p) {
                        self.log[q - self.base][back] = t[k];
                        self.lin[q - self.base][back] = e[k];
                    }
                }
            }
        }
    }

    #[inline]
    pub(super) fn log(&self, i: usize) -> &[f32; 8] {
        &self.log[i - self.base]
    }

    #[inline]
    pub(super) fn lin(&self, i: usize) -> &[f32; 8] {
        &self.lin[i - self.base]
    }
}
/// The x0 terms of a band's start pixels, each pixel pair computed once: for every offset o of
/// the half window (dy > 0, or dy = 0 and dx > 0) and every pixel p from `first_row` to the band's
/// end, −d(p, p + o)²/(2σ²) and its exp (−∞ and 0 where p + o leaves the image). x0's term for
/// x0 + o is entry (o, x0), and for x0 − o entry (o, x0 − o), as d is symmetric bit for bit. A row
/// of one offset is 8 pairs per vector, against 9-wide window rows filled per start pixel before.
#[derive(Default)]
pub(super) struct Pairs {
    offsets: Vec<(isize, isize)>,
    /// Per offset (dx, dy): where its plane starts in `log` and `lin`, and its step dy·w + dx in
    /// pixels, and dy·side + dx in window grid cells (side = 2r + 3).
    steps: Vec<(usize, usize, usize)>,
    first_row: usize,
    rows: usize,
    width: usize,
    log: Vec<f32>,
    lin: Vec<f32>,
    /// Each start pixel's term with itself, −d(x0, x0)²/(2σ²), and its exp, for the band's rows
    /// from `band_start`: computed a row at a time like the pairs, where a window filled cell by
    /// cell computes it alone.
    band_start: usize,
    own_log: Vec<f32>,
    own_lin: Vec<f32>,
}

/// Padding of feature planes so that a run of pairs can be computed in whole groups of 8 (the
/// extra results are dropped).
pub(super) const RUN_PAD: usize = 8;

/// Largest pair table (floats per array) a band builds; larger windows fill cell by cell.
const PAIRS_MAX_FLOATS: usize = 1 << 22;

impl Pairs {
    /// Whether the table of start rows `band` of an image `width` wide and window radius `r` is
    /// small enough to build.
    pub(super) fn fits(width: usize, r: usize, band: Range<usize>) -> bool {
        // The half window's offsets (2r² + 2r) times the rows from r above the band.
        (2 * r * r + 2 * r) * (band.end - band.start.saturating_sub(r)) * width <= PAIRS_MAX_FLOATS
    }

    /// The table for start rows `band` and window radius `r`, into `self` (buffers reused), from
    /// `planes`, which hold rows `band.start - r` to `band.end + r - 1` (those in the image),
    /// padded by at least `r + RUN_PAD` columns.
    pub(super) fn compute(
        &mut self,
        kernel: Kernel,
        input: &WalkInput,
        inv: f32,
        r: usize,
        band: Range<usize>,
        planes: &FeaturePlanes,
    ) {
        let (w, h) = input.color.dims();
        let ri = r as isize;
        let offsets: Vec<(isize, isize)> = (1..=ri)
            .map(|dx| (dx, 0))
            .chain((1..=ri).flat_map(|dy| (-ri..=ri).map(move |dx| (dx, dy))))
            .collect();
        let first_row = band.start.saturating_sub(r);
        let rows = band.end - first_row;
        let n = offsets.len() * rows * w;
        let mut run = vec![0.0f32; w + RUN_PAD];
        let depth_weight = input.features.depth_weight();
        let (log, lin) = (&mut self.log, &mut self.lin);
        log.clear();
        log.resize(n, f32::NEG_INFINITY);
        lin.clear();
        lin.resize(n, 0.0);
        for (o, &(dx, dy)) in offsets.iter().enumerate() {
            let lo = (-dx).max(0) as usize;
            let hi = (w as isize - dx).clamp(0, w as isize) as usize;
            for y in first_row..band.end {
                let ny = y + dy as usize;
                if ny >= h || lo >= hi {
                    continue;
                }
                let at = (o * rows + y - first_row) * w;
                let center = planes.offset(lo as isize, y);
                let other = planes.offset(lo as isize + dx, ny);
                let (log, lin) = (&mut log[at + lo..at + hi], &mut lin[at + lo..at + hi]);
                pair_terms(
                    kernel,
                    planes,
                    (depth_weight, inv),
                    (center, other),
                    &mut run,
                    log,
                    lin,
                );
            }
        }
        let band_len = band.len() * w;
        self.own_log.clear();
        self.own_log.resize(band_len, 0.0);
        self.own_lin.clear();
        self.own_lin.resize(band_len, 0.0);
        for y in band.clone() {
            let at = (y - band.start) * w;
            let center = planes.offset(0, y);
            let (log, lin) = (&mut self.own_log[at..at + w], &mut self.own_lin[at..at + w]);
            pair_terms(
                kernel,
                planes,
                (depth_weight, inv),
                (center, center),
                &mut run,
                log,
                lin,
            );
        }
        self.band_start = band.start;
        let side = 2 * ri + 3;
        self.steps.clear();
        self.steps
            .extend(offsets.iter().enumerate().map(|(o, &(dx, dy))| {
                (
                    o * rows * w,
                    (dy * w as isize + dx) as usize,
                    (dy * side + dx) as usize,
                )
            }));
        (self.offsets, self.first_row, self.rows, self.width) = (offsets, first_row, rows, w);
    }

    /// The grids of start pixels `xs` of row `y0`, one after the other ((side, centre) their
    /// size and centre cell), whose windows lie inside the image and the band: every window cell
    /// from the table, offset by offset for the whole run (its entries for the run are contiguous).
    /// The rings are left as they are.
    fn fill_inner(
        &self,
        input: &WalkInput,
        grid: &mut [f32],
        egrid: &mut [f32],
        (side, center): (usize, usize),
        (xs, y0): (Range<usize>, usize),
    ) {
        let (w, n, cells) = (self.width, xs.len(), side * side);
        assert!(
            grid.len() == n * cells && egrid.len() == n * cells,
            "one grid per start pixel"
        );
        let own = (y0 - self.band_start) * w + xs.start;
        let (own_log, own_lin) = (&self.own_log[own..own + n], &self.own_lin[own..own + n]);
        for (b, (g, e)) in grid
            .chunks_exact_mut(cells)
            .zip(egrid.chunks_exact_mut(cells))
            .enumerate()
        {
            (g[center], e[center]) = (own_log[b], own_lin[b]);
        }
        let at = (y0 - self.first_row) * w + xs.start;
        for &(plane, dpix, dcell) in &self.steps {
            // x0 + o is entry (o, x0); x0 − o is entry (o, x0 − o), as d is symmetric.
            let (up, down) = (plane + at, plane + at - dpix);
            let (log_up, log_down) = (&self.log[up..up + n], &self.log[down..down + n]);
            let (lin_up, lin_down) = (&self.lin[up..up + n], &self.lin[down..down + n]);
            let (fwd, back) = (center + dcell, center - dcell);
            assert!(fwd < cells, "a window cell inside the grid");
            for (b, (g, e)) in grid
                .chunks_exact_mut(cells)
                .zip(egrid.chunks_exact_mut(cells))
                .enumerate()
            {
                (g[fwd], e[fwd]) = (log_up[b], lin_up[b]);
                (g[back], e[back]) = (log_down[b], lin_down[b]);
            }
        }
        if let Some(mask) = input.mask {
            for (b, (g, e)) in grid
                .chunks_exact_mut(cells)
                .zip(egrid.chunks_exact_mut(cells))
                .enumerate()
            {
                let i0 = y0 * w + xs.start + b;
                let cells = self.steps.iter().flat_map(|&(_, dpix, dcell)| {
                    [(i0 + dpix, center + dcell), (i0 - dpix, center - dcell)]
                });
                for (j, c) in std::iter::once((i0, center)).chain(cells) {
                    if mask[j] {
                        (g[c], e[c]) = (f32::NEG_INFINITY, 0.0);
                    }
                }
            }
        }
    }

    /// Start pixel (x, y)'s term with itself and its exp; y is a row of the band.
    #[inline]
    fn own(&self, x: usize, y: usize) -> (f32, f32) {
        let i = (y - self.band_start) * self.width + x;
        (self.own_log[i], self.own_lin[i])
    }

    /// Entry (offset index `o`, pixel (x, y)): the log term and its exp.
    #[inline]
    fn at(&self, o: usize, x: usize, y: usize) -> (f32, f32) {
        let i = (o * self.rows + y - self.first_row) * self.width + x;
        (self.log[i], self.lin[i])
    }
}

/// For the run of `log.len()` pixel pairs from plane offsets `center` and `other`: `log` =
/// −d²·`inv` of each pair's distance d (depth weighted by `depth_weight`) and `lin` its exp, in
/// one pass. `run` is scratch space for the distances, at least the run rounded up to whole
/// groups of 8.
fn pair_terms(
    kernel: Kernel,
    planes: &FeaturePlanes,
    (depth_weight, inv): (f32, f32),
    (center, other): (usize, usize),
    run: &mut [f32],
    log: &mut [f32],
    lin: &mut [f32],
) {
    let n = log.len();
    distance_row(
        kernel,
        planes,
        depth_weight,
        center,
        other,
        &mut run[..n.next_multiple_of(8)],
    );
    for ((t, e), &d) in log.iter_mut().zip(lin.iter_mut()).zip(&run[..n]) {
        let v = -(d * d) * inv;
        (*t, *e) = (v, v);
    }
    exp_neg_row(kernel, lin);
}

/// The x0 terms −d(x0, y)²/(2σ²) of one start pixel and their exps, cached in (2r+3)² grids
/// centred on x0 whose cells outside the window, the image or the mask (and the whole outer ring)
/// are −∞ (exp: 0).
pub(super) struct Window<'g> {
    pub(super) grid: &'g [f32],
    pub(super) egrid: &'g [f32],
    pub(super) side: usize,
    pub(super) i0: usize,
}

impl<'g> Window<'g> {
    /// Fills the grids of start pixels `xs` of row `y0`, one after the other in `grid` and `egrid`
    /// ((2r+3)² cells each), from the band's `pairs` table when there is one, else by computing
    /// each cell's distance (windows too large for a table); pushes each one's centre cell (in the
    /// whole buffer) and pixel index to `starts`.
    ///
    /// The grids' outer rings must hold −∞ and 0 already (as [`Band::run`] leaves them): no fill
    /// writes a ring cell, so the start pixels whose window lies inside the image write only
    /// their window's cells.
    ///
    /// [`Band::run`]: super::band::Band::run
    #[allow(clippy::too_many_arguments)]
    pub(super) fn fill_run(
        input: &WalkInput,
        inv: f32,
        grid: &mut [f32],
        egrid: &mut [f32],
        pairs: Option<&Pairs>,
        r: usize,
        (xs, y0): (Range<usize>, usize),
        starts: &mut Vec<(usize, usize)>,
    ) {
        let (w, h) = input.color.dims();
        let side = 2 * r + 3;
        let cells = side * side;
        let center = (r + 1) * side + r + 1;
        // The start pixels whose whole window is in the image: a run read from the table.
        let inner = if y0 >= r && y0 + r < h {
            xs.start.max(r)..xs.end.min(w.saturating_sub(r))
        } else {
            0..0
        };
        let slot = |x0: usize| (x0 - xs.start) * cells..(x0 - xs.start + 1) * cells;
        if let (Some(pairs), false) = (pairs, inner.is_empty()) {
            let slots = slot(inner.start).start..slot(inner.end - 1).end;
            pairs.fill_inner(
                input,
                &mut grid[slots.clone()],
                &mut egrid[slots],
                (side, center),
                (inner.clone(), y0),
            );
        }
        for x0 in xs.clone() {
            if pairs.is_none() || !inner.contains(&x0) {
                let cell = slot(x0);
                let grids = (&mut grid[cell.clone()], &mut egrid[cell]);
                Self::fill_edge(input, inv, grids, (pairs, r), (x0, y0));
            }
            starts.push((slot(x0).start + center, y0 * w + x0));
        }
    }

    /// One start pixel's grids, the whole grid written (window cells outside the image −∞ / 0),
    /// from the table `pairs` when there is one; `r` is the window's radius.
    fn fill_edge(
        input: &WalkInput,
        inv: f32,
        (grid, egrid): (&mut [f32], &mut [f32]),
        (pairs, r): (Option<&Pairs>, usize),
        (x0, y0): (usize, usize),
    ) {
        let (w, h) = input.color.dims();
        let side = 2 * r + 3;
        let i0 = y0 * w + x0;
        let blocked = |j: usize| input.mask.is_some_and(|m| m[j]);
        let center = (r + 1) * side + r + 1;
        grid.fill(f32::NEG_INFINITY);
        egrid.fill(0.0);
        if let Some(pairs) = pairs {
            if !blocked(i0) {
                (grid[center], egrid[center]) = pairs.own(x0, y0);
            }
            let inside =
                |x: isize, y: isize| x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h;
            let (sx, sy) = (x0 as isize, y0 as isize);
            for (o, &(dx, dy)) in pairs.offsets.iter().enumerate() {
                let cell = dy * side as isize + dx;
                // x0 + o: the entry of x0 itself.
                let (x, y) = (sx + dx, sy + dy);
                if inside(x, y) && !blocked(y as usize * w + x as usize) {
                    let (g, e) = pairs.at(o, x0, y0);
                    let c = (center as isize + cell) as usize;
                    (grid[c], egrid[c]) = (g, e);
                }
                // x0 − o: the entry of x0 − o, whose partner at +o is x0 (d is symmetric).
                let (x, y) = (sx - dx, sy - dy);
                if inside(x, y) && !blocked(y as usize * w + x as usize) {
                    let (g, e) = pairs.at(o, x as usize, y as usize);
                    let c = (center as isize - cell) as usize;
                    (grid[c], egrid[c]) = (g, e);
                }
            }
        } else {
            let (ylo, yhi) = (y0.saturating_sub(r), (y0 + r).min(h - 1));
            let (xlo, xhi) = (x0.saturating_sub(r), (x0 + r).min(w - 1));
            for y in ylo..=yhi {
                for x in xlo..=xhi {
                    let j = y * w + x;
                    if !blocked(j) {
                        let d = input.features.distance(i0, j);
                        let g = (y + r + 1 - y0) * side + r + 1 + x - x0;
                        grid[g] = -(d * d) * inv;
                        egrid[g] = exp_neg(grid[g]);
                    }
                }
            }
        }
    }

    /// The grid cell of x0.
    pub(super) fn center(&self) -> usize {
        (self.side / 2) * self.side + self.side / 2
    }
}
