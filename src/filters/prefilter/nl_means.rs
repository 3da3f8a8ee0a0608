//! The NL-means filter of a feature buffer, its patch distances counted in units of the noise:
//! offset by offset over bands of rows, or pixel by pixel where few pixels are noisy.

use rayon::prelude::*;

use super::params::{known, Kind, Params};
use crate::image::Image;
use crate::kernels::fastmath::exp_neg_row;
use crate::kernels::padded::{Margin, Padded};
use crate::kernels::simd::{row_kernel, Kernel};
use crate::kernels::trim::{self, LANES};
use crate::meter::Meter;

/// Smallest variance (in the feature's units squared) a patch distance is divided by: a difference
/// of 1 % of an albedo or normal component is one unit where the estimate reads no noise at all.
const EPS: f64 = 1e-4;

/// Largest patch radius the stage accepts (a larger one is filtered offset by offset only).
pub const MAX_PATCH: usize = 3;
/// Largest search radius the stage accepts (likewise), and its offsets.
pub const MAX_RADIUS: usize = 8;
const MAX_OFFSETS: usize = (2 * MAX_RADIUS + 1) * (2 * MAX_RADIUS + 1);

/// Rows one parallel task filters: every pixel's sums still run over the offsets in one fixed
/// order, so the band size changes no bit.
const BAND: usize = 16;

/// NL-means over `img` with its per-pixel `variance` ([`variance`](super::variance)). The
/// distance of the patches around i and j, per channel and patch pixel p (q its partner in j's
/// patch), is
/// ((u_p − u_q)² − (v_p + min(v_p, v_q))) / (ε_p + k²(v_p + v_q)), averaged; j weighs
/// exp(−max(0, that)). Subtracting the expected noise makes two noisy samples of one value
/// distance 0; dividing by it makes a difference the noise cannot explain (an edge, a texture)
/// weigh nothing. A pixel whose variance reads 0 is kept as it is.
///
/// Computed offset by offset (the classic fast NL-means): for one offset, the per-pixel terms over
/// a band of rows, box-summed over the patch, give every pixel's distance to its partner at once.
pub fn filter(img: &Image, variance: &[f32], kind: Kind, p: &Params) -> Image {
    filter_with(Kernel::detect(), img, variance, kind, p)
}

/// [`filter`] with a chosen kernel for the weights' exponentials (all give the same bits).
pub fn filter_with(kernel: Kernel, img: &Image, variance: &[f32], kind: Kind, p: &Params) -> Image {
    filter_by(kernel, SPARSE, img, variance, kind, p, &Meter::default())
}

/// [`filter`] in a run: its bands tell `meter` as they finish and are skipped once it is
/// cancelled (the result is then unfinished, for the caller to throw away).
pub fn filter_metered(
    img: &Image,
    variance: &[f32],
    kind: Kind,
    p: &Params,
    meter: &Meter,
) -> Image {
    filter_by(Kernel::detect(), SPARSE, img, variance, kind, p, meter)
}

/// A band is filtered pixel by pixel ([`filter_sparse`]) when fewer than one pixel in `SPARSE` is
/// active, offset by offset otherwise: per active pixel the first costs about nine times what the
/// second costs per pixel of the band (1024² albedo, all active or 3 % active).
const SPARSE: usize = 8;

/// [`filter_with`], a band taken pixel by pixel when fewer than one pixel in `sparse` is active
/// (0: never, `usize::MAX`: always). Both ways give the same bits.
fn filter_by(
    kernel: Kernel,
    sparse: usize,
    img: &Image,
    variance: &[f32],
    kind: Kind,
    p: &Params,
    meter: &Meter,
) -> Image {
    let (w, h) = img.dims();
    let c = img.channels();
    let data = img.data();
    let (r, f) = (p.radius as isize, p.patch as isize);
    let known_pixels: Vec<bool> = (0..w * h)
        .into_par_iter()
        .map(|i| known(img, kind, i))
        .collect();
    let nl = NlMeans {
        kernel: kernel.or_portable(),
        sparse,
        kind,
        dims: (w, h, c),
        active: known_pixels
            .par_iter()
            .zip(variance)
            .map(|(&k, &v)| k && v > 0.0)
            .collect(),
        known: known_pixels,
        r,
        f,
        k2: p.strength * p.strength,
        // A patch cell beyond the image reads the nearest edge pixel: with a margin that repeats
        // it, every offset's terms are one contiguous run of both patches' cells.
        // ε is a plane of its own for depth only; elsewhere it is the constant EPS.
        planes: Padded::new(
            (w, h),
            c + 1 + usize::from(kind == Kind::Depth),
            (r + f) as usize,
            Margin::Edge,
            |i, k| {
                if k < c {
                    data[i * c + k] as f64
                } else if k == c {
                    variance[i] as f64
                } else {
                    (EPS * (data[i] as f64).powi(2)).max(f64::MIN_POSITIVE)
                }
            },
        ),
    };
    let mut out = img.par_clone();
    meter.pass(h);
    out.data_mut()
        .par_chunks_mut(BAND * w * c)
        .enumerate()
        .for_each(|(band, rows)| {
            if meter.cancelled() {
                return;
            }
            let nl = &nl;
            row_kernel!(nl.kernel, filter_band(nl: &NlMeans, band: usize, rows: &mut [f32]));
            meter.rows(BAND);
        });
    out
}

/// What every band of [`filter_with`] reads.
struct NlMeans {
    kernel: Kernel,
    /// Bands with fewer than one active pixel in `sparse` are filtered pixel by pixel.
    sparse: usize,
    kind: Kind,
    /// Width, height, channels.
    dims: (usize, usize, usize),
    known: Vec<bool>,
    /// Whether pixel i is filtered: known, with some noise.
    active: Vec<bool>,
    /// Search and patch radius.
    r: isize,
    f: isize,
    /// k².
    k2: f64,
    /// Edge-padded planes: the channels, then the variance, then (depth only) ε.
    planes: Padded,
}

impl NlMeans {
    /// The ε plane, where ε differs from pixel to pixel (depth); `None` where it is EPS.
    fn eps(&self) -> Option<&[f64]> {
        self.planes.planes.get(self.dims.2 + 1).map(Vec::as_slice)
    }
}

/// A row of patch terms from the channels' squared differences `row` to
/// (row − c·(v_a + min(v_a, v_b))) / (ε_a + k²(v_a + v_b)), the patch distance's terms.
#[inline(always)]
fn scale_terms(
    row: &mut [f64],
    (va, vb): (&[f64], &[f64]),
    ea: impl Iterator<Item = f64>,
    c: f64,
    k2: f64,
) {
    for (((t, &va), &vb), ea) in row.iter_mut().zip(va).zip(vb).zip(ea) {
        let expected = va + if vb < va { vb } else { va };
        let scale = ea + k2 * (va + vb);
        *t = (*t - c * expected) / scale;
    }
}

/// Filters the `BAND` rows of band `band` into `rows`. Every loop runs over a contiguous run of
/// the band's columns, so each compiles to vector lanes; each pixel's sums still take the offsets,
/// the patch cells and the channels in the one order the results are defined by.
#[inline(always)]
fn filter_band(nl: &NlMeans, band: usize, rows: &mut [f32]) {
    let ((w, h, c), (r, f), k2) = (nl.dims, (nl.r, nl.f), nl.k2);
    let (known, active, kind, kernel) = (&nl.known, &nl.active, nl.kind, nl.kernel);
    let edge = &nl.planes;
    let (chans, var, eps) = (&edge.planes[..c], &edge.planes[c], nl.eps());
    let terms = ((2 * f + 1) * (2 * f + 1)) as f64 * c as f64;
    let y0 = band * BAND;
    let y1 = (y0 + BAND).min(h);
    let band_active = |x: usize| (y0..y1).any(|y| active[y * w + x]);
    // Only the columns an active pixel (and its patch) reaches are computed.
    let Some(x_lo) = (0..w).find(|&x| band_active(x)) else {
        return;
    };
    let count = (y0 * w..y1 * w).filter(|&i| active[i]).count();
    let fits = r as usize <= MAX_RADIUS && f as usize <= MAX_PATCH;
    if fits && count.saturating_mul(nl.sparse) < w * (y1 - y0) {
        return filter_sparse(nl, y0, y1, rows);
    }
    let x_hi = (0..w)
        .rev()
        .find(|&x| band_active(x))
        .expect("an active column exists");
    let n = x_hi + 1 - x_lo;
    let side = 2 * f as usize + 1;
    // Terms over the band's rows widened by the patch radius, and its columns x_lo..=x_hi
    // widened likewise: term column t is pixel column x_lo − f + t.
    let (tw, th) = (n + 2 * f as usize, y1 - y0 + 2 * f as usize);
    let mut term = vec![0.0f64; tw * th];
    // Sums over the patch's columns, then its rows; column t is pixel column x_lo + t.
    let mut across = vec![0.0f64; n * th];
    let mut dist = vec![0.0f64; n];
    let mut weight = vec![0.0f32; n];
    // Per channel, then the weight total: every band pixel's sums, row by row.
    let mut sum = vec![0.0f64; c * (y1 - y0) * n];
    let mut total = vec![0.0f64; (y1 - y0) * n];
    for oy in -r..=r {
        for ox in -r..=r {
            for (ty, row) in term.chunks_exact_mut(tw).enumerate() {
                let py = y0 as isize + ty as isize - f;
                let a = edge.index(x_lo as isize - f, py);
                let b = edge.index(x_lo as isize - f + ox, py + oy);
                row.fill(0.0);
                for ch in chans.iter() {
                    let (ua, ub) = (&ch[a..a + tw], &ch[b..b + tw]);
                    for ((t, &u), &v) in row.iter_mut().zip(ua).zip(ub) {
                        let d = u - v;
                        *t += d * d;
                    }
                }
                let v = (&var[a..a + tw], &var[b..b + tw]);
                match eps {
                    Some(eps) => scale_terms(row, v, eps[a..].iter().copied(), c as f64, k2),
                    None => scale_terms(row, v, std::iter::repeat(EPS), c as f64, k2),
                }
            }
            for (row, acc) in term.chunks_exact(tw).zip(across.chunks_exact_mut(n)) {
                acc.fill(-0.0);
                for dx in 0..side {
                    for (a, &t) in acc.iter_mut().zip(&row[dx..dx + n]) {
                        *a += t;
                    }
                }
            }
            // The columns whose partner x + ox is inside the image.
            let lo = (x_lo as isize).max(-ox);
            let hi = (x_hi as isize).min(w as isize - 1 - ox);
            if lo > hi {
                continue;
            }
            let (lo, hi) = (lo as usize, hi as usize);
            for y in y0..y1 {
                let (ny, ly) = (y as isize + oy, y - y0);
                if ny < 0 || ny >= h as isize {
                    continue;
                }
                dist.fill(-0.0);
                for dy in 0..side {
                    for (d, &a) in dist
                        .iter_mut()
                        .zip(&across[(ly + dy) * n..(ly + dy + 1) * n])
                    {
                        *d += a;
                    }
                }
                // Who takes part: an active pixel and a known partner inside the image; the
                // others weigh exp(−∞) = 0.
                weight.fill(f32::NEG_INFINITY);
                let partners = ny as usize * w;
                let here = &active[y * w + lo..=y * w + hi];
                let there =
                    &known[(partners as isize + lo as isize + ox) as usize..][..hi + 1 - lo];
                let cols = lo - x_lo..hi + 1 - x_lo;
                for (((e, &d), &a), &k) in weight[cols.clone()]
                    .iter_mut()
                    .zip(&dist[cols.clone()])
                    .zip(here)
                    .zip(there)
                {
                    let v = -(d / terms).max(0.0) as f32;
                    *e = if a & k { v } else { f32::NEG_INFINITY };
                }
                exp_neg_row(kernel, &mut weight[cols.clone()]);
                let at = edge.index(x_lo as isize + ox, ny);
                let pixels = ly * n..(ly + 1) * n;
                for (ch, plane) in chans.iter().enumerate() {
                    let acc = &mut sum[ch * (y1 - y0) * n..][pixels.clone()];
                    for ((s, &e), &u) in acc.iter_mut().zip(&weight).zip(&plane[at..at + n]) {
                        *s += if e > 0.0 { e as f64 * u } else { 0.0 };
                    }
                }
                for (t, &e) in total[pixels].iter_mut().zip(&weight) {
                    *t += if e > 0.0 { e as f64 } else { 0.0 };
                }
            }
        }
    }
    for (l, px) in rows.chunks_exact_mut(c).enumerate() {
        let (ly, x) = (l / w, l % w);
        if !active[(y0 + ly) * w + x] {
            continue;
        }
        let p = ly * n + x - x_lo;
        // The pixel itself is its own partner at offset 0, weight exp(0) = 1, so total ≥ 1.
        let v = std::array::from_fn(|ch| {
            if ch < c {
                sum[ch * (y1 - y0) * n + p] / total[p]
            } else {
                0.0
            }
        });
        write_pixel(kind, v, px);
    }
}

/// Writes a filtered pixel's channel means `v` to `px`: a normal renormalised, or left as it was
/// when the mean is too short to have a direction.
#[inline(always)]
fn write_pixel(kind: Kind, mut v: [f64; 3], px: &mut [f32]) {
    if kind == Kind::Normal {
        let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if len <= 1e-6 {
            return;
        }
        v.iter_mut().for_each(|x| *x /= len);
    }
    for (o, x) in px.iter_mut().zip(v) {
        *o = x as f32;
    }
}

/// [`filter_band`] pixel by pixel, for bands where few pixels are active: each active pixel's
/// patch distances are summed cell by cell in the order the offset-wise sums take (columns within
/// a patch row, then the rows), so the result is the same bits.
#[inline(always)]
fn filter_sparse(nl: &NlMeans, y0: usize, y1: usize, rows: &mut [f32]) {
    let ((w, h, c), (r, f)) = (nl.dims, (nl.r, nl.f));
    let (known, active, kind) = (&nl.known, &nl.active, nl.kind);
    let chans = &nl.planes.planes[..c];
    let terms = ((2 * f + 1) * (2 * f + 1)) as f64 * c as f64;
    let offsets = (2 * r + 1) as usize;
    for y in y0..y1 {
        for x in 0..w {
            if !active[y * w + x] {
                continue;
            }
            // Every offset's exponent first, so the offsets' chains of sums overlap in the
            // pipeline and the exponentials run in vector lanes; then the sums, in offset order.
            let mut partners = [0usize; MAX_OFFSETS];
            let mut weight = [0.0f32; MAX_OFFSETS];
            let mut n = 0;
            for oy in -r..=r {
                let ny = y as isize + oy;
                if ny < 0 || ny >= h as isize {
                    continue;
                }
                // The distances of the whole row of offsets, `LANES` side by side (each lane's
                // sums in its own fixed order); an offset whose partner is outside the image or
                // unknown reads the edge margin and is then left out.
                let mut dist = [0.0f64; 2 * MAX_RADIUS + 1];
                trim::by_lanes!(
                    &mut dist[..offsets],
                    |i| patch_distances::<LANES>(nl, x, y, (i as isize - r, oy)),
                    |i| patch_distances::<1>(nl, x, y, (i as isize - r, oy))[0],
                );
                for (ox, &dist) in (-r..=r).zip(&dist) {
                    let nx = x as isize + ox;
                    if nx < 0 || nx >= w as isize || !known[ny as usize * w + nx as usize] {
                        continue;
                    }
                    weight[n] = -(dist / terms).max(0.0) as f32;
                    partners[n] = nl.planes.index(nx, ny);
                    n += 1;
                }
            }
            exp_neg_row(nl.kernel, &mut weight[..n]);
            let mut sum = [0.0f64; 3];
            let mut total = 0.0f64;
            for (&e, &at) in weight[..n].iter().zip(&partners[..n]) {
                if e > 0.0 {
                    for (s, plane) in sum.iter_mut().zip(chans) {
                        *s += e as f64 * plane[at];
                    }
                    total += e as f64;
                }
            }
            let v = std::array::from_fn(|ch| if ch < c { sum[ch] / total } else { 0.0 });
            write_pixel(kind, v, &mut rows[((y - y0) * w + x) * c..][..c]);
        }
    }
}

/// The patch distances (before division by the number of terms) from pixel (x, y) to the pixels
/// at offsets (ox0 + l, oy), l < L, |ox0 + l| ≤ r: per lane, per patch row, the channels' squared
/// differences of each column, less the expected noise and over its scale, summed over the columns
/// in order; the rows' sums added in order. The offset-wise band filter sums the same terms in the
/// same order, so both give the same bits; with lanes over the offsets, the divisions run 4 at once.
#[inline(always)]
fn patch_distances<const L: usize>(
    nl: &NlMeans,
    x: usize,
    y: usize,
    (ox0, oy): (isize, isize),
) -> [f64; L] {
    let (c, f, k2) = (nl.dims.2, nl.f, nl.k2);
    let edge = &nl.planes;
    let (chans, var, eps) = (&edge.planes[..c], &edge.planes[c], nl.eps());
    let side = 2 * f as usize + 1;
    let mut dist = [-0.0f64; L];
    for dy in -f..=f {
        let (px, py) = (x as isize - f, y as isize + dy);
        let (a, b) = (edge.index(px, py), edge.index(px + ox0, py + oy));
        let mut t = [[0.0f64; L]; 2 * MAX_PATCH + 1];
        for ch in chans {
            for (col, t) in t[..side].iter_mut().enumerate() {
                let (u, v) = (ch[a + col], &ch[b + col..b + col + L]);
                for l in 0..L {
                    let d = u - v[l];
                    t[l] += d * d;
                }
            }
        }
        let mut sum = [-0.0f64; L];
        for (col, t) in t[..side].iter().enumerate() {
            let ea = eps.map_or(EPS, |eps| eps[a + col]);
            let (va, vb) = (var[a + col], &var[b + col..b + col + L]);
            for l in 0..L {
                let expected = va + if vb[l] < va { vb[l] } else { va };
                let scale = ea + k2 * (va + vb[l]);
                sum[l] += (t[l] - c as f64 * expected) / scale;
            }
        }
        for l in 0..L {
            dist[l] += sum[l];
        }
    }
    dist
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filters::prefilter::estimate::tests::white_field;

    #[test]
    fn pixel_by_pixel_and_offset_by_offset_give_the_same_bits() {
        let p = Params {
            strength: 0.25,
            radius: 3,
            patch: 1,
            keep: 0.65,
        };
        // Noise on a few pixels only, on most of them, on a normal buffer with unknown pixels,
        // and on 1×1 and odd-sized images.
        let noisy = white_field(37, 5);
        let normals = Image::from_fn(23, 19, 3, |x, y, k| {
            if (x + 2 * y) % 7 == 0 {
                0.0
            } else {
                [0.6, 0.0, 0.8][k] + 0.05 * ((x * 7 + y * 3 + k) % 5) as f32
            }
        });
        let cases = [
            (noisy.clone(), Kind::Plain, 3),
            (noisy, Kind::Plain, 1),
            (normals, Kind::Normal, 1),
            (white_field(1, 2), Kind::Plain, 1),
        ];
        for (img, kind, every) in cases {
            let v: Vec<f32> = (0..img.dims().0 * img.dims().1)
                .map(|i| if i % every == 0 { 2.5e-3 } else { 0.0 })
                .collect();
            for kernel in [Kernel::Scalar, Kernel::Avx2] {
                let offsets = filter_by(kernel, 0, &img, &v, kind, &p, &Meter::default());
                let pixels = filter_by(kernel, usize::MAX, &img, &v, kind, &p, &Meter::default());
                if img.dims().0 > 1 {
                    assert_ne!(offsets.data(), img.data(), "{kind:?}: nothing filtered");
                }
                let bits = |im: &Image| im.data().iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&offsets), bits(&pixels), "{kind:?} every {every}");
            }
        }
    }
}
