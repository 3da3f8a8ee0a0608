//! First-order regression of the noisy colour, guided by a filtered image, and a per-pixel mix of
//! the two by their estimated errors (docs/ALGORITHM.md §9).
//!
//! Why: every other filter in gsid averages (a zero-order fit). Where a pixel's neighbours on its
//! own surface lie on one side only — along every geometric edge and into every corner — and the
//! light changes across them (a corner darkens, a wall brightens towards the light), the average
//! is biased towards the inside of the surface, in a band a few pixels wide. A weighted
//! least-squares fit of colour = β₀ + β₁·dx + β₂·dy over the pixel's window extrapolates instead,
//! and its intercept β₀ has no first-order bias. Its weights choose the neighbours: the filtered
//! image's colour difference measured in units of the noise, the albedo and the normal.
//!
//! The fit is less smooth than the filter it refines, and its variance is known exactly from its
//! weights. So the output is the filtered value f moved towards the fit g by the Wiener weight
//! κ = b²/(b² + s²): s² the fit's variance, b² the filter's squared bias, read as |g − f|² less
//! s² (see [`keep`]). Where f is right, κ ≈ 0 and nothing changes.
//!
//! Deterministic: each pixel's sums run in one fixed order (f32 along a window row, f64 across
//! rows), so the result is the same bits on any thread count and with either kernel.

use rayon::prelude::*;

use crate::image::{par_vec, Image};
use crate::kernels::simd::Kernel;

/// Added to the albedo before dividing by it: a black surface keeps its (small) colour.
pub const DEMODULATION_EPS: f32 = 0.02;

/// Largest window radius accepted (a 33×33 window).
pub const MAX_RADIUS: usize = 16;

/// Output rows per parallel task; each task copies its rows plus the window's reach into planes.
const BAND_ROWS: usize = 32;

/// Columns of a band swept row by row before the next: the window's rows of every lane stay in
/// the core's cache from one output row to the next.
const TILE_COLUMNS: usize = 64;
const _: () = assert!(
    TILE_COLUMNS.is_multiple_of(WIDE_GROUP) && WIDE_GROUP.is_multiple_of(GROUP),
    "a tile holds whole groups"
);

/// Pixels of a row whose window sums are formed together, side by side: one AVX2 register of f32.
const GROUP: usize = 8;

/// The group with AVX-512: one 512-bit register (the f64 sums are two, as AVX2's f32 group's are).
const WIDE_GROUP: usize = 16;

/// Cells a window row's taps read for a group, at the largest radius and group: each lane's row
/// is taken as one array of this length, so no tap's load needs its own bounds check.
const ROW: usize = 2 * MAX_RADIUS + WIDE_GROUP;

/// Relative size of the fit's rounding error: a fit this close to the filtered value leaves it.
const ROUNDING: f64 = 1e-5;

/// Floor under a pixel's noise variance in the weight's denominator, so a pixel read as
/// noise-free weighs only neighbours whose filtered colour equals its own (and never divides by 0).
const VARIANCE_FLOOR: f32 = 1e-12;

/// Settings of the regression and the mix.
#[derive(Clone, Debug, PartialEq)]
pub struct Params {
    /// Window radius: the fit reads (2r + 1)² pixels.
    pub radius: usize,
    /// Scale of the filtered image's colour difference, in units of the pixel's noise standard
    /// deviation: a neighbour weighs [`falloff`] of |Δf|² / (2σ²v) + |Δa|² / (2 albedo_sigma²).
    pub sigma: f32,
    /// Each noisy sample's departure from the filtered image is capped at `clip` standard
    /// deviations of its noise, so a firefly the filter removed does not come back.
    pub clip: f32,
    /// Scale of the albedo difference (see `sigma`).
    pub albedo_sigma: f32,
    /// Neighbours whose normal is at a cosine below this from the pixel's get no weight.
    pub normal_cos: f32,
    /// Ridge on the two slopes, relative to the sum of weights: a window whose weights lie along
    /// a line fits no slope across it.
    pub ridge: f64,
    /// Fit colour / (albedo + ε) (the lighting), so texture the albedo carries is not a slope.
    pub demodulate: bool,
}

impl Default for Params {
    fn default() -> Self {
        Params {
            radius: 6,
            sigma: 1.0,
            clip: 3.0,
            albedo_sigma: 0.4,
            normal_cos: 0.9,
            ridge: 1e-3,
            demodulate: true,
        }
    }
}

/// What the regression reads; every image is `noisy`'s size, colour buffers have 3 channels.
#[derive(Clone, Copy)]
pub struct Inputs<'a> {
    /// The colour as sampled (after any firefly clamp): what the fit regresses.
    pub noisy: &'a Image,
    /// A filtered image of it: its colour differences choose the neighbours, and it is what the
    /// mix refines.
    pub filtered: &'a Image,
    /// Variance of each pixel's mean in `noisy`, per channel.
    pub variance: &'a Image,
    pub albedo: Option<&'a Image>,
    pub normal: Option<&'a Image>,
}

/// The fit at every pixel and its variance (mean over the channels).
pub struct Fit {
    pub color: Image,
    pub variance: Vec<f32>,
}

/// The refined image: the filtered one moved towards the fit by each pixel's Wiener weight.
pub fn refine(inputs: Inputs, p: &Params) -> Image {
    refine_with(Kernel::detect(), inputs, p)
}

/// [`refine`] with a chosen row kernel (all give the same bits).
pub fn refine_with(kernel: Kernel, inputs: Inputs, p: &Params) -> Image {
    let fit = regress_with(kernel, inputs, p);
    mix(inputs.filtered, &fit)
}

/// Lanes of a band's planes.
const C: usize = 0; // clipped noisy colour, demodulated (3)
const F: usize = 3; // filtered colour, demodulated (3)
const V: usize = 6; // noise variance, demodulated, mean over channels
const INV: usize = 7; // 1 / (2σ² v + floor)
const A: usize = 8; // albedo (3)
const N: usize = 11; // normal (3); NaN where VALID is 0
const KNOWN: usize = 14; // 1 where the normal is known (non-zero), 0 where not; NaN where VALID is 0
const VALID: usize = 15; // 1 inside the image with finite inputs, 0 in the margin
const LANES: usize = 16;

/// The fit of the noisy colour at every pixel, with its variance.
pub fn regress_with(kernel: Kernel, inputs: Inputs, p: &Params) -> Fit {
    let kernel = kernel.or_portable();
    let (w, h) = inputs.noisy.dims();
    let mut color = Image::new(w, h, 3);
    let mut variance = par_vec(0.0f32, w * h);
    if w == 0 || h == 0 {
        return Fit { color, variance };
    }
    match kernel {
        Kernel::Avx512 => fit_bands::<WIDE_GROUP>(kernel, inputs, p, &mut color, &mut variance),
        _ => fit_bands::<GROUP>(kernel, inputs, p, &mut color, &mut variance),
    }
    Fit { color, variance }
}

/// The fit of every band of rows into `color` and `variance`, G pixels of a row at a time.
fn fit_bands<const G: usize>(
    kernel: Kernel,
    inputs: Inputs,
    p: &Params,
    color: &mut Image,
    variance: &mut [f32],
) {
    let (w, h) = inputs.noisy.dims();
    let (r, cos) = (p.radius, p.normal_cos);
    let inv_albedo = 1.0 / (2.0 * p.albedo_sigma * p.albedo_sigma);
    color
        .data_mut()
        .par_chunks_mut(3 * w * BAND_ROWS)
        .zip(variance.par_chunks_mut(w * BAND_ROWS))
        .enumerate()
        .for_each(|(band, (out, out_var))| {
            let y0 = band * BAND_ROWS;
            let y1 = (y0 + BAND_ROWS).min(h);
            let planes = Planes::build(inputs, p, y0, y1);
            let lanes: [&[f32]; LANES] = std::array::from_fn(|l| planes.lanes[l].as_slice());
            let taps = Taps {
                lanes: &lanes,
                stride: planes.stride,
                r,
                inv_albedo,
                cos,
            };
            let mut sums = GroupSums::<G>::new();
            for tile in (0..w).step_by(TILE_COLUMNS) {
                for y in y0..y1 {
                    let at = y - y0;
                    for x0 in (tile..(tile + TILE_COLUMNS).min(w)).step_by(G) {
                        let center = planes.offset(0, at, 0) + x0;
                        window_sums_with(kernel, &taps, center, &mut sums);
                        sums.solve(
                            p,
                            &planes,
                            inputs,
                            (x0, y),
                            G.min(w - x0),
                            &mut out[3 * w * at..3 * w * (at + 1)],
                            &mut out_var[w * at..w * (at + 1)],
                        );
                    }
                }
            }
        });
}

/// A band's inputs as padded f32 planes: rows y0 − r .. y1 + r, columns −r .. w + r, zeros (and
/// VALID 0) outside the image, so every tap of a row reads one contiguous run.
struct Planes {
    lanes: Vec<Vec<f32>>,
    stride: usize,
    radius: usize,
    /// The band's first output row (the planes' row `radius`).
    first_row: usize,
}

impl Planes {
    /// Lanes of `rows` rows for an image `w` wide and a window of radius `r`, every cell as the
    /// margin's (zeros, NaN normals), and their stride.
    fn blank(w: usize, r: usize, rows: usize) -> (Vec<Vec<f32>>, usize) {
        let stride = w + 2 * r + 8;
        // Past the last row, room for a whole `ROW` read from any window row's first cell.
        let mut lanes = vec![vec![0.0f32; stride * rows + ROW]; LANES];
        // A cell that takes no part matches no pixel's normal: its NaNs fail both tests of
        // `window_sums`, so the kernel needs no VALID factor.
        for lane in &mut lanes[N..=KNOWN] {
            lane.fill(f32::NAN);
        }
        (lanes, stride)
    }

    fn build(inputs: Inputs, p: &Params, y0: usize, y1: usize) -> Planes {
        let (w, h) = inputs.noisy.dims();
        let r = p.radius;
        let rows = y1 - y0 + 2 * r;
        let (mut lanes, stride) = Planes::blank(w, r, rows);
        let inv_scale = 2.0 * p.sigma * p.sigma;
        let demodulate = p.demodulate && inputs.albedo.is_some();
        // A missing albedo or normal reads as zeros: finite, so it passes the finiteness test as
        // when it is not tested, and a zero normal is unknown.
        let zeros = vec![0.0f32; 3 * w];
        fn row_of(img: &Image, i0: usize, w: usize) -> &[f32] {
            &img.data()[3 * i0..3 * (i0 + w)]
        }
        for row in 0..rows {
            let y = (y0 + row) as isize - r as isize;
            if y < 0 || y >= h as isize {
                continue;
            }
            let i0 = y as usize * w;
            let px = |img| row_of(img, i0, w);
            let (noisy, filtered, var) =
                (px(inputs.noisy), px(inputs.filtered), px(inputs.variance));
            let albedo = inputs.albedo.map_or(zeros.as_slice(), px);
            let normal = inputs.normal.map_or(zeros.as_slice(), px);
            let at = row * stride + r;
            let mut rows_out = lanes.iter_mut().map(|l| &mut l[at..at + w]);
            let out: [&mut [f32]; LANES] =
                std::array::from_fn(|_| rows_out.next().expect("LANES lanes"));
            // Every value is computed and then chosen by `finite`, with no branch: a pixel with
            // non-finite inputs keeps the margin's cell (zeros, NaN normals).
            for x in 0..w {
                let at3 = |s: &[f32]| -> [f32; 3] { [s[3 * x], s[3 * x + 1], s[3 * x + 2]] };
                let (nz, fl, vr, al, nm) = (
                    at3(noisy),
                    at3(filtered),
                    at3(var),
                    at3(albedo),
                    at3(normal),
                );
                let finite = nz
                    .iter()
                    .chain(&fl)
                    .chain(&vr)
                    .chain(&al)
                    .all(|v| v.is_finite());
                let pick = |v: f32| if finite { v } else { 0.0 };
                let mut v_mean = 0.0f32;
                for k in 0..3 {
                    let scale = if demodulate {
                        al[k].max(0.0) + DEMODULATION_EPS
                    } else {
                        1.0
                    };
                    let v = vr[k].max(0.0);
                    let limit = p.clip * v.sqrt();
                    // `clamp`'s own choices, written as selects.
                    let d = nz[k] - fl[k];
                    let d = if d < -limit { -limit } else { d };
                    let d = if d > limit { limit } else { d };
                    out[C + k][x] = pick((fl[k] + d) / scale);
                    out[F + k][x] = pick(fl[k] / scale);
                    out[A + k][x] = pick(al[k]);
                    v_mean += v / (scale * scale);
                }
                v_mean /= 3.0;
                let known = nm.iter().all(|v| v.is_finite()) & nm.iter().any(|&v| v != 0.0);
                out[V][x] = pick(v_mean);
                out[INV][x] = pick(1.0 / (inv_scale * v_mean + VARIANCE_FLOOR));
                for k in 0..3 {
                    let n = if known { nm[k] } else { 0.0 };
                    out[N + k][x] = if finite { n } else { f32::NAN };
                }
                let k = if known { 1.0 } else { 0.0 };
                out[KNOWN][x] = if finite { k } else { f32::NAN };
                out[VALID][x] = pick(1.0);
            }
        }
        Planes {
            lanes,
            stride,
            radius: r,
            first_row: y0,
        }
    }

    /// Index of the cell (dx, dy) from the band's row `row`, column 0.
    fn offset(&self, dx: isize, row: usize, dy: isize) -> usize {
        let r = self.radius as isize;
        ((row as isize + r + dy) * self.stride as isize + r + dx) as usize
    }

    fn lane(&self, lane: usize, offset: usize, n: usize) -> &[f32] {
        &self.lanes[lane][offset..offset + n]
    }
}

/// A group's f64 sums over the whole window, lane by lane: the normal equations A (6 entries of
/// the symmetric 3×3), the right-hand sides B (3 regressors × 3 channels) and the variance's
/// matrix M (6 entries).
struct GroupSums<const G: usize> {
    a: [[f64; G]; 6],
    b: [[f64; G]; 9],
    m: [[f64; G]; 6],
}

impl<const G: usize> GroupSums<G> {
    fn new() -> Self {
        GroupSums {
            a: [[0.0; G]; 6],
            b: [[0.0; G]; 9],
            m: [[0.0; G]; 6],
        }
    }
}

/// Indices of the symmetric 3×3 entries 00, 01, 02, 11, 12, 22.
const S00: usize = 0;
const S01: usize = 1;
const S02: usize = 2;
const S11: usize = 3;
const S12: usize = 4;
const S22: usize = 5;

/// (1 − x/8)⁸ for x < 8, else 0: the weight of a neighbour at squared distance x. It follows
/// e^(−x) to within 0.04 and is 0 where e^(−x) < 3.4e-4; six operations instead of an
/// exponential's two dozen, so the window costs about half as much (`benches/regress.rs`).
#[inline(always)]
pub fn falloff(x: f32) -> f32 {
    let q = (1.0 - x * 0.125).max(0.0);
    let q2 = q * q;
    let q4 = q2 * q2;
    q4 * q4
}

/// G values of a lane from `at`.
#[inline(always)]
fn load<const G: usize>(lane: &[f32], at: usize) -> [f32; G] {
    lane[at..at + G].try_into().expect("G values")
}

/// What every group's window sums of a band read: the band's planes and the weights' settings.
struct Taps<'a> {
    lanes: &'a [&'a [f32]; LANES],
    stride: usize,
    r: usize,
    inv_albedo: f32,
    cos: f32,
}

/// [`window_sums`] compiled for `kernel`: the same operations, so the same bits, in AVX2 or
/// AVX-512 registers where the CPU has them.
fn window_sums_with<const G: usize>(
    kernel: Kernel,
    taps: &Taps,
    center: usize,
    sums: &mut GroupSums<G>,
) {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx2")]
        fn avx2<const G: usize>(taps: &Taps, center: usize, sums: &mut GroupSums<G>) {
            window_sums(taps, center, sums)
        }
        #[target_feature(enable = "avx2,avx512f,avx512vl,avx512bw,avx512dq")]
        fn avx512<const G: usize>(taps: &Taps, center: usize, sums: &mut GroupSums<G>) {
            window_sums(taps, center, sums)
        }
        match kernel.or_portable() {
            // SAFETY: `or_portable` gives Avx512 only when the CPU reports its four extensions.
            Kernel::Avx512 => return unsafe { avx512(taps, center, sums) },
            // SAFETY: and Avx2 only when it reports AVX2.
            Kernel::Avx2 => return unsafe { avx2(taps, center, sums) },
            Kernel::Scalar => {}
        }
    }
    window_sums(taps, center, sums)
}

/// The window sums of the G pixels from plane cell `center`, every tap in turn: the regressors
/// are (1, u, v) with u = dx / r, v = dy / r. Each window row's sums are formed in f32 (at most
/// 2r + 1 terms) and added to the f64 sums; every lane loop is over a fixed G, so it runs in
/// one or two vector registers.
#[inline(always)]
fn window_sums<const G: usize>(taps: &Taps, center: usize, sums: &mut GroupSums<G>) {
    let &Taps {
        lanes,
        stride,
        r,
        inv_albedo,
        cos,
    } = taps;
    let at = |l: usize| load::<G>(lanes[l], center);
    let (fc, ac, nc) = (
        [at(F), at(F + 1), at(F + 2)],
        [at(A), at(A + 1), at(A + 2)],
        [at(N), at(N + 1), at(N + 2)],
    );
    let (inv, known_c) = (at(INV), at(KNOWN));
    *sums = GroupSums::new();
    let ri = r as isize;
    // Taps in a window row; at most ROW − G + 1, which the loads' bounds follow from.
    let taps = (2 * r + 1).min(ROW - G + 1);
    // One window row's tap weights, rewritten row by row (zeroed once here, not at every row).
    let mut e = [[0.0f32; G]; 2 * MAX_RADIUS + 1];
    // The taps' u = dx / r, divided once here rather than at every tap of every row.
    let mut us = [0.0f32; 2 * MAX_RADIUS + 1];
    for (j, u) in us[..taps].iter_mut().enumerate() {
        *u = (j as isize - ri) as f32 / r as f32;
    }
    for dy in -ri..=ri {
        let mut t = [[0.0f32; G]; 3];
        let mut c0 = [[0.0f32; G]; 3];
        let mut c1 = [[0.0f32; G]; 3];
        let mut m = [[0.0f32; G]; 3];
        let row = (center as isize + dy * stride as isize - ri) as usize;
        let span = |l: usize| -> &[f32; ROW] {
            lanes[l][row..row + ROW]
                .try_into()
                .expect("planes padded by ROW")
        };
        let (f, a) = (
            [span(F), span(F + 1), span(F + 2)],
            [span(A), span(A + 1), span(A + 2)],
        );
        // The weights of the whole window row first: they do not depend on each other, so their
        // chains of operations overlap.
        for (j, e) in e[..taps].iter_mut().enumerate() {
            let (fo, ao) = (f.map(|s| load::<G>(s, j)), a.map(|s| load::<G>(s, j)));
            for l in 0..G {
                let df = [
                    fc[0][l] - fo[0][l],
                    fc[1][l] - fo[1][l],
                    fc[2][l] - fo[2][l],
                ];
                let da = [
                    ac[0][l] - ao[0][l],
                    ac[1][l] - ao[1][l],
                    ac[2][l] - ao[2][l],
                ];
                let f2 = df[0] * df[0] + df[1] * df[1] + df[2] * df[2];
                let a2 = da[0] * da[0] + da[1] * da[1] + da[2] * da[2];
                e[l] = falloff(f2 * inv[l] + a2 * inv_albedo);
            }
        }
        let (n, known, c, vr) = (
            [span(N), span(N + 1), span(N + 2)],
            span(KNOWN),
            [span(C), span(C + 1), span(C + 2)],
            span(V),
        );
        for (j, (e, &u)) in e[..taps].iter().zip(&us).enumerate() {
            let no = n.map(|s| load::<G>(s, j));
            let known_o = load::<G>(known, j);
            let color = c.map(|s| load::<G>(s, j));
            let var = load::<G>(vr, j);
            // Read whole before the lanes choose: a choice between `e` and 0 made on the load
            // itself compiles to a masked load, which keeps the sums below out of registers.
            let e = *e;
            for l in 0..G {
                let dot = nc[0][l] * no[0][l] + nc[1][l] * no[1][l] + nc[2][l] * no[2][l];
                // `|` on bools, not `||`: no branch, so the lanes stay in one register. Two
                // unknown normals match; a cell outside the image or with non-finite inputs
                // (NaN normal and KNOWN) matches none.
                let same = (dot >= cos) | ((known_c[l] + known_o[l]) == 0.0);
                let wgt = if same { e[l] } else { 0.0 };
                let wu = wgt * u;
                t[0][l] += wgt;
                t[1][l] += wu;
                t[2][l] += wu * u;
                for k in 0..3 {
                    let wc = wgt * color[k][l];
                    c0[k][l] += wc;
                    c1[k][l] += wc * u;
                }
                let wv = wgt * wgt * var[l];
                let wvu = wv * u;
                m[0][l] += wv;
                m[1][l] += wvu;
                m[2][l] += wvu * u;
            }
        }
        let v = dy as f64 / r as f64;
        add_moments(&mut sums.a, t, v);
        add_moments(&mut sums.m, m, v);
        for k in 0..3 {
            for l in 0..G {
                let (s0, s1) = (c0[k][l] as f64, c1[k][l] as f64);
                sums.b[3 * k][l] += s0;
                sums.b[3 * k + 1][l] += s1;
                sums.b[3 * k + 2][l] += v * s0;
            }
        }
    }
}

/// Adds a window row's f32 sums of w, w·u and w·u² (row v) to the f64 entries of its symmetric
/// 3×3 moment matrix. The row is taken by value: a reference to it would keep the tap loop's
/// sums in memory, stored at every tap.
#[inline(always)]
fn add_moments<const G: usize>(out: &mut [[f64; G]; 6], row: [[f32; G]; 3], v: f64) {
    let v2 = v * v;
    for l in 0..G {
        let (s0, s1, s2) = (row[0][l] as f64, row[1][l] as f64, row[2][l] as f64);
        out[S00][l] += s0;
        out[S01][l] += s1;
        out[S02][l] += v * s0;
        out[S11][l] += s2;
        out[S12][l] += v * s1;
        out[S22][l] += v2 * s0;
    }
}

impl<const G: usize> GroupSums<G> {
    /// Solves the fits of the `n` pixels from (x0, y) and writes their intercepts (brought back to
    /// colour) and variances into the row's `out` and `out_var`.
    #[allow(clippy::too_many_arguments)]
    fn solve(
        &self,
        p: &Params,
        planes: &Planes,
        inputs: Inputs,
        (x0, y): (usize, usize),
        n: usize,
        out: &mut [f32],
        out_var: &mut [f32],
    ) {
        let w = out_var.len();
        let at = planes.offset(0, y - planes.first_row, 0) + x0;
        let (valid, noise) = (planes.lane(VALID, at, n), planes.lane(V, at, n));
        for l in 0..n {
            let (x, i) = (x0 + l, y * w + x0 + l);
            let filtered = inputs.filtered.pixel(i);
            let px = &mut out[3 * x..3 * x + 3];
            if noise[l] == 0.0 && valid[l] != 0.0 {
                // Read as noise-free: nothing to fit past the filtered value, which it keeps.
                px.copy_from_slice(filtered);
                out_var[x] = 0.0;
                continue;
            }
            if valid[l] == 0.0 {
                // A pixel with non-finite inputs is not fitted: it keeps the filtered value, or
                // the noisy one where that is not finite, or 0.
                let noisy = inputs.noisy.pixel(i);
                for k in 0..3 {
                    px[k] = [filtered[k], noisy[k], 0.0]
                        .into_iter()
                        .find(|v| v.is_finite())
                        .unwrap_or(0.0);
                }
                out_var[x] = 0.0;
                continue;
            }
            let a = |s: usize| self.a[s][l];
            let u =
                first_column_of_inverse([a(S00), a(S01), a(S02), a(S11), a(S12), a(S22)], p.ridge);
            let scale: [f64; 3] = match inputs.albedo {
                Some(alb) if p.demodulate => {
                    std::array::from_fn(|k| (alb.pixel(i)[k].max(0.0) + DEMODULATION_EPS) as f64)
                }
                _ => [1.0; 3],
            };
            for k in 0..3 {
                let b = &self.b[3 * k..3 * k + 3];
                px[k] = ((u[0] * b[0][l] + u[1] * b[1][l] + u[2] * b[2][l]) * scale[k]) as f32;
            }
            let m = |s: usize| self.m[s][l];
            let quad = u[0] * u[0] * m(S00)
                + u[1] * u[1] * m(S11)
                + u[2] * u[2] * m(S22)
                + 2.0 * (u[0] * u[1] * m(S01) + u[0] * u[2] * m(S02) + u[1] * u[2] * m(S12));
            let s2 = scale.iter().map(|s| s * s).sum::<f64>() / 3.0;
            out_var[x] = (quad.max(0.0) * s2) as f32;
        }
    }
}

/// A⁻¹e₁ for the symmetric normal equations A (entries 00, 01, 02, 11, 12, 22), with `ridge`·A₀₀
/// added to the two slopes' diagonal: the weights of the intercept's estimate. A singular or
/// non-finite system falls back to the weighted mean (1/A₀₀, 0, 0).
fn first_column_of_inverse(a: [f64; 6], ridge: f64) -> [f64; 3] {
    let [a00, a01, a02, a11, a12, a22] = a;
    let (a11, a22) = (a11 + ridge * a00, a22 + ridge * a00);
    let c00 = a11 * a22 - a12 * a12;
    let c01 = a02 * a12 - a01 * a22;
    let c02 = a01 * a12 - a11 * a02;
    let det = a00 * c00 + a01 * c01 + a02 * c02;
    // Relative to the scale of the entries: below it the slopes are not determined.
    if det > 1e-12 * a00 * a00 * a00 && det.is_finite() {
        [c00 / det, c01 / det, c02 / det]
    } else if a00 > 0.0 {
        [1.0 / a00, 0.0, 0.0]
    } else {
        [0.0; 3]
    }
}

/// How far each pixel moves from the filtered value f towards the fit g: κ = b² / (b² + s²),
/// the Wiener weight, with s² the fit's variance and b² = max(0, |g − f|² − s²) the filter's
/// squared bias read from this pixel alone (|g − f|² estimates b² + s²). That is
/// κ = max(0, 1 − s² / |g − f|²), the positive-part James–Stein shrinkage of g towards f: a
/// difference the fit's own noise explains leaves f; one far beyond it takes g.
pub fn keep(filtered: &[f32], fit: &[f32], fit_variance: f32) -> f32 {
    let (mut d2, mut f2) = (0.0f64, 0.0f64);
    for k in 0..3 {
        let (f, g) = (filtered[k] as f64, fit[k] as f64);
        d2 += (g - f) * (g - f);
        f2 += f * f;
    }
    // A difference within the fit's rounding (its f32 row sums) is not a bias.
    if d2 <= ROUNDING * ROUNDING * f2 {
        return 0.0;
    }
    let k = 1.0 - fit_variance as f64 / (d2 / 3.0);
    if k > 0.0 && k.is_finite() {
        k as f32
    } else {
        0.0
    }
}

/// The filtered image moved towards the fit by each pixel's [`keep`] weight. A filtered value
/// that is not finite is replaced by the fit (which always is).
pub fn mix(filtered: &Image, fit: &Fit) -> Image {
    let mut out = filtered.par_clone();
    out.data_mut()
        .par_chunks_mut(3)
        .zip(fit.color.data().par_chunks(3))
        .zip(fit.variance.par_iter())
        .for_each(|((px, g), &s2)| {
            if !px.iter().all(|v| v.is_finite()) {
                px.copy_from_slice(g);
                return;
            }
            let k = keep(px, g, s2);
            for c in 0..3 {
                let v = px[c] + k * (g[c] - px[c]);
                if v.is_finite() {
                    px[c] = v;
                }
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(w: usize, h: usize, f: impl Fn(usize, usize) -> f32) -> Image {
        Image::from_fn(w, h, 3, |x, y, _| f(x, y))
    }

    /// The fit of `img` (noisy and filtered alike) with a uniform variance `v`, no features, no
    /// demodulation and no ridge, with weights that ignore colour (σ 1e3).
    fn plain_fit(img: &Image, v: f32, radius: usize) -> Fit {
        let (w, h) = img.dims();
        let p = Params {
            demodulate: false,
            sigma: 1e3,
            ridge: 0.0,
            radius,
            ..Params::default()
        };
        let inputs = Inputs {
            noisy: img,
            filtered: img,
            variance: &Image::filled(w, h, 3, v),
            albedo: None,
            normal: None,
        };
        regress_with(Kernel::Scalar, inputs, &p)
    }

    #[test]
    fn a_linear_ramp_is_fitted_exactly_up_to_the_edge() {
        // A ramp with no noise: the fit recovers it at every pixel, including the borders, where
        // the window is one-sided.
        let ramp = plane(20, 13, |x, y| 0.1 + 0.01 * x as f32 + 0.02 * y as f32);
        let fit = plain_fit(&ramp, 1e-4, Params::default().radius);
        for (g, t) in fit.color.data().iter().zip(ramp.data()) {
            assert!((g - t).abs() < 1e-5, "{g} vs {t}");
        }
    }

    #[test]
    fn the_fits_variance_is_the_mean_over_its_window_in_the_middle() {
        // In the middle of the image the intercept of a symmetric window with flat weights is the
        // plain mean, variance v / n.
        let w = 21;
        let fit = plain_fit(&Image::filled(w, w, 3, 0.5), 0.01, 3);
        let v = fit.variance[10 * w + 10];
        assert!((v - 0.01 / 49.0).abs() < 1e-7, "{v}");
        // At a corner only a quarter of the window is there and the fit extrapolates: more.
        assert!(fit.variance[0] > 4.0 * v, "{}", fit.variance[0]);
    }

    /// A band's planes as the textbook builds them, pixel by pixel with branches: the cell of a
    /// pixel with a non-finite input is left as the margin's.
    fn textbook_planes(inputs: Inputs, p: &Params, y0: usize, y1: usize) -> Vec<Vec<f32>> {
        let (w, h) = inputs.noisy.dims();
        let r = p.radius;
        let rows = y1 - y0 + 2 * r;
        let (mut lanes, stride) = Planes::blank(w, r, rows);
        for row in 0..rows {
            let y = (y0 + row) as isize - r as isize;
            if y < 0 || y >= h as isize {
                continue;
            }
            for x in 0..w {
                let (i, cell) = (y as usize * w + x, row * stride + x + r);
                let (noisy, filtered) = (inputs.noisy.pixel(i), inputs.filtered.pixel(i));
                let var = inputs.variance.pixel(i);
                let albedo = inputs.albedo.map(|a| a.pixel(i));
                let all = noisy.iter().chain(filtered).chain(var);
                if !all.chain(albedo.unwrap_or_default()).all(|v| v.is_finite()) {
                    continue;
                }
                let mut v_mean = 0.0f32;
                for k in 0..3 {
                    let scale = match albedo {
                        Some(a) if p.demodulate => a[k].max(0.0) + DEMODULATION_EPS,
                        _ => 1.0,
                    };
                    let v = var[k].max(0.0);
                    let limit = p.clip * v.sqrt();
                    let clipped = filtered[k] + (noisy[k] - filtered[k]).clamp(-limit, limit);
                    lanes[C + k][cell] = clipped / scale;
                    lanes[F + k][cell] = filtered[k] / scale;
                    v_mean += v / (scale * scale);
                    lanes[A + k][cell] = albedo.map_or(0.0, |a| a[k]);
                }
                v_mean /= 3.0;
                lanes[V][cell] = v_mean;
                lanes[INV][cell] = 1.0 / (2.0 * p.sigma * p.sigma * v_mean + VARIANCE_FLOOR);
                let normal = inputs
                    .normal
                    .map(|n| n.pixel(i))
                    .filter(|n| n.iter().all(|v| v.is_finite()) && n.iter().any(|&v| v != 0.0));
                for k in 0..3 {
                    lanes[N + k][cell] = normal.map_or(0.0, |n| n[k]);
                }
                lanes[KNOWN][cell] = if normal.is_some() { 1.0 } else { 0.0 };
                lanes[VALID][cell] = 1.0;
            }
        }
        lanes
    }

    #[test]
    fn planes_are_the_textbook_cells_bit_for_bit_with_bad_inputs() {
        // Random inputs with NaN, ±∞, negative variances, zero normals and black albedo in every
        // buffer; with and without albedo and normals, demodulated or not; bands at both edges.
        let mut next = crate::kernels::trim::tests::xorshift(7);
        let (w, h) = (23, 29);
        let mut value = |scale: f32| {
            let r = next();
            match r % 23 {
                0 => f32::NAN,
                1 => f32::INFINITY,
                2 => f32::NEG_INFINITY,
                3 => 0.0,
                4 => -scale * (r >> 40) as f32 / (1u64 << 24) as f32,
                _ => scale * (r >> 40) as f32 / (1u64 << 24) as f32,
            }
        };
        let mut image = |scale: f32| Image::from_fn(w, h, 3, |_, _, _| value(scale));
        let (noisy, filtered, variance) = (image(2.0), image(2.0), image(0.1));
        let (albedo, normal) = (image(1.0), image(1.0));
        for (with_features, demodulate, (y0, y1)) in [
            (true, true, (0, 8)),
            (true, false, (8, 16)),
            (false, true, (21, 29)),
            (false, false, (0, 29)),
        ] {
            let inputs = Inputs {
                noisy: &noisy,
                filtered: &filtered,
                variance: &variance,
                albedo: with_features.then_some(&albedo),
                normal: with_features.then_some(&normal),
            };
            let p = Params {
                demodulate,
                radius: 3,
                ..Params::default()
            };
            let planes = Planes::build(inputs, &p, y0, y1);
            let textbook = textbook_planes(inputs, &p, y0, y1);
            for (l, (got, want)) in planes.lanes.iter().zip(&textbook).enumerate() {
                for (cell, (g, t)) in got.iter().zip(want).enumerate() {
                    assert_eq!(
                        g.to_bits(),
                        t.to_bits(),
                        "lane {l}, cell {cell}: {g} vs {t}"
                    );
                }
            }
        }
    }

    #[test]
    fn singular_systems_fall_back_to_the_mean() {
        assert_eq!(
            first_column_of_inverse([2.0, 0.0, 0.0, 0.0, 0.0, 0.0], 0.0),
            [0.5, 0.0, 0.0]
        );
        assert_eq!(first_column_of_inverse([0.0; 6], 0.0), [0.0; 3]);
        let u = first_column_of_inverse([f64::NAN, 0.0, 0.0, 1.0, 0.0, 1.0], 0.0);
        assert!(u.iter().all(|v| !v.is_nan()) || u == [0.0; 3]);
    }
}
#[cfg(test)]
mod reference_tests {
    use super::*;

    /// A direct per-pixel solve in f64 of what `regress_with` computes.
    fn direct(inputs: Inputs, p: &Params) -> (Vec<[f64; 3]>, Vec<f64>) {
        let (w, h) = inputs.noisy.dims();
        let r = p.radius as isize;
        let scale = |i: usize, k: usize| match inputs.albedo {
            Some(a) if p.demodulate => (a.pixel(i)[k].max(0.0) + DEMODULATION_EPS) as f64,
            _ => 1.0,
        };
        let clipped = |i: usize, k: usize| {
            let (c, f, v) = (
                inputs.noisy.pixel(i)[k] as f64,
                inputs.filtered.pixel(i)[k] as f64,
                inputs.variance.pixel(i)[k].max(0.0) as f64,
            );
            let lim = p.clip as f64 * v.sqrt();
            (f + (c - f).clamp(-lim, lim)) / scale(i, k)
        };
        let vbar = |i: usize| {
            (0..3)
                .map(|k| inputs.variance.pixel(i)[k].max(0.0) as f64 / scale(i, k).powi(2))
                .sum::<f64>()
                / 3.0
        };
        let mut out = vec![];
        let mut var = vec![];
        for y in 0..h as isize {
            for x in 0..w as isize {
                let i = (y * w as isize + x) as usize;
                let mut a = [[0.0f64; 3]; 3];
                let mut m = [[0.0f64; 3]; 3];
                let mut b = [[0.0f64; 3]; 3];
                for dy in -r..=r {
                    for dx in -r..=r {
                        let (nx, ny) = (x + dx, y + dy);
                        if nx < 0 || ny < 0 || nx >= w as isize || ny >= h as isize {
                            continue;
                        }
                        let j = (ny * w as isize + nx) as usize;
                        let mut f2 = 0.0;
                        let mut a2 = 0.0;
                        for k in 0..3 {
                            let d = inputs.filtered.pixel(i)[k] as f64 / scale(i, k)
                                - inputs.filtered.pixel(j)[k] as f64 / scale(j, k);
                            f2 += d * d;
                            if let Some(al) = inputs.albedo {
                                let d = (al.pixel(i)[k] - al.pixel(j)[k]) as f64;
                                a2 += d * d;
                            }
                        }
                        let inv = 1.0 / (2.0 * (p.sigma as f64).powi(2) * vbar(i) + 1e-12);
                        let x = f2 * inv + a2 / (2.0 * (p.albedo_sigma as f64).powi(2));
                        let mut wgt = (1.0 - x / 8.0).max(0.0).powi(8);
                        if let Some(n) = inputs.normal {
                            let (ni, nj) = (n.pixel(i), n.pixel(j));
                            let dot: f32 = (0..3).map(|k| ni[k] * nj[k]).sum();
                            if dot < p.normal_cos {
                                wgt = 0.0;
                            }
                        }
                        let xr = [1.0, dx as f64 / r as f64, dy as f64 / r as f64];
                        for s in 0..3 {
                            for t in 0..3 {
                                a[s][t] += wgt * xr[s] * xr[t];
                                m[s][t] += wgt * wgt * vbar(j) * xr[s] * xr[t];
                            }
                            for (k, b) in b[s].iter_mut().enumerate() {
                                *b += wgt * xr[s] * clipped(j, k);
                            }
                        }
                    }
                }
                let u = first_column_of_inverse(
                    [a[0][0], a[0][1], a[0][2], a[1][1], a[1][2], a[2][2]],
                    p.ridge,
                );
                out.push(std::array::from_fn(|k| {
                    (0..3).map(|s| u[s] * b[s][k]).sum::<f64>() * scale(i, k)
                }));
                let q: f64 = (0..3)
                    .flat_map(|s| (0..3).map(move |t| (s, t)))
                    .map(|(s, t)| u[s] * m[s][t] * u[t])
                    .sum();
                var.push(q * (0..3).map(|k| scale(i, k).powi(2)).sum::<f64>() / 3.0);
            }
        }
        (out, var)
    }

    #[test]
    fn matches_a_direct_solve() {
        let (w, h) = (19, 14);
        let mut s = 12345u64;
        let mut rnd = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        let noisy = Image::from_fn(w, h, 3, |x, _, _| 0.2 + 0.01 * x as f32 + 0.1 * rnd());
        let filtered = Image::from_fn(w, h, 3, |x, y, _| 0.25 + 0.01 * x as f32 + 0.001 * y as f32);
        let variance = Image::from_fn(w, h, 3, |_, _, _| 0.002 + 0.001 * rnd());
        let albedo = Image::from_fn(
            w,
            h,
            3,
            |x, _, k| if x < 9 { 0.5 } else { 0.2 + 0.1 * k as f32 },
        );
        let normal = Image::from_fn(w, h, 3, |_, y, k| match (y < 7, k) {
            (true, 2) | (false, 1) => 1.0,
            _ => 0.0,
        });
        let inputs = Inputs {
            noisy: &noisy,
            filtered: &filtered,
            variance: &variance,
            albedo: Some(&albedo),
            normal: Some(&normal),
        };
        // Radius 3, and the largest, whose window is wider than the image: every window row's
        // reads then run to the end of the band's padded planes.
        for radius in [3, MAX_RADIUS] {
            for kernel in Kernel::ALL.into_iter().filter(|k| k.is_available()) {
                check_against_direct(inputs, radius, kernel);
            }
        }
    }

    fn check_against_direct(inputs: Inputs, radius: usize, kernel: Kernel) {
        let p = Params {
            radius,
            ..Params::default()
        };
        let fit = regress_with(kernel, inputs, &p);
        let (want, want_var) = direct(inputs, &p);
        for (i, want) in want.iter().enumerate() {
            for (k, &t) in want.iter().enumerate() {
                let g = fit.color.pixel(i)[k] as f64;
                assert!(
                    (g - t).abs() < 1e-4 * t.abs().max(1.0),
                    "pixel {i} channel {k}: {g} vs {t}"
                );
            }
            let (v, t) = (fit.variance[i] as f64, want_var[i]);
            assert!((v - t).abs() < 1e-3 * t, "pixel {i} variance: {v} vs {t}");
        }
    }
}
