//! The tap loop: a group of pixels' weighted sums over the whole window (the normal equations,
//! right-hand sides and the variance's matrix), with its AVX2 and AVX-512 compilations.

use super::params::MAX_RADIUS;
use super::planes::{A, C, F, INV, KNOWN, LANES, N, ROW, V};
use crate::kernels::simd::Kernel;

/// A group's f64 sums over the whole window, lane by lane: the normal equations A (6 entries of
/// the symmetric 3×3), the right-hand sides B (3 regressors × 3 channels) and the variance's
/// matrix M (6 entries).
pub(super) struct GroupSums<const G: usize> {
    pub(super) a: [[f64; G]; 6],
    pub(super) b: [[f64; G]; 9],
    pub(super) m: [[f64; G]; 6],
}

impl<const G: usize> GroupSums<G> {
    pub(super) fn new() -> Self {
        GroupSums {
            a: [[0.0; G]; 6],
            b: [[0.0; G]; 9],
            m: [[0.0; G]; 6],
        }
    }
}

/// Indices of the symmetric 3×3 entries 00, 01, 02, 11, 12, 22.
pub(super) const S00: usize = 0;
pub(super) const S01: usize = 1;
pub(super) const S02: usize = 2;
pub(super) const S11: usize = 3;
pub(super) const S12: usize = 4;
pub(super) const S22: usize = 5;

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
pub(super) struct Taps<'a> {
    pub(super) lanes: &'a [&'a [f32]; LANES],
    pub(super) stride: usize,
    pub(super) r: usize,
    pub(super) inv_albedo: f32,
    pub(super) cos: f32,
}

/// [`window_sums`] compiled for `kernel`: the same operations, so the same bits, in AVX2 or
/// AVX-512 registers where the CPU has them.
pub(super) fn window_sums_with<const G: usize>(
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
