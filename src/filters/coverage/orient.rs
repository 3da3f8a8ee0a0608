//! Which way each pixel's feature edge runs: the orientation of the features' structure tensor.
//!
//! The guide is albedo and half the normal stacked (a pixel's surface), so an edge of either
//! counts. The tensor's gradients are Sobel's and its sums a Gaussian of σ [`TENSOR_SIGMA`]: wide
//! enough that an edge whose pixels each fell on one side or the other (a few samples a pixel) still
//! has one direction, narrow enough to follow a curve. Also the reads and the noise-gated move the
//! along- and across-edge steps share.

use rayon::prelude::*;

use crate::image::{par_vec, Image};
use crate::kernels::padded::edge_padded_line;
use crate::render_set::{Feature, FeatureSet};

/// σ, in pixels, of the Gaussian the tensor is summed with.
pub const TENSOR_SIGMA: f32 = 1.5;

/// The stacked guide: albedo (3 channels) then half the normal (3), whichever the set has, as
/// channel planes; none when it has neither.
pub struct Guide {
    pub w: usize,
    pub h: usize,
    pub planes: Vec<Vec<f32>>,
    /// How many of the planes, from the first, are albedo (the rest are half the normal).
    pub albedo: usize,
}

impl Guide {
    pub fn new(features: &FeatureSet, (w, h): (usize, usize)) -> Option<Guide> {
        let mut planes = Vec::new();
        let mut albedo = 0;
        for (feature, scale) in [(Feature::Albedo, 1.0f32), (Feature::Normal, 0.5)] {
            let Some(img) = features.get(feature).filter(|i| i.dims() == (w, h)) else {
                continue;
            };
            let c = img.channels();
            for k in 0..c {
                planes.push(plane(img.data(), c, k, |v| {
                    if v.is_finite() {
                        v * scale
                    } else {
                        0.0
                    }
                }));
            }
            if feature == Feature::Albedo {
                albedo = planes.len();
            }
        }
        (!planes.is_empty()).then_some(Guide {
            w,
            h,
            planes,
            albedo,
        })
    }

    /// The guide at (x, y), bilinear between pixel centres, clamped to the image, into `out`.
    pub fn sample(&self, x: f32, y: f32, out: &mut [f32]) {
        let (i, f) = bilinear(x, y, self.w, self.h);
        for (o, p) in out.iter_mut().zip(&self.planes) {
            *o = mix(p, i, f);
        }
    }
}

/// The four pixel indices around (x, y) and its fractions, the position clamped to the image.
pub fn bilinear(x: f32, y: f32, w: usize, h: usize) -> ([usize; 4], (f32, f32)) {
    let (xc, yc) = (x.clamp(0.0, (w - 1) as f32), y.clamp(0.0, (h - 1) as f32));
    let (x0, y0) = (xc.floor() as usize, yc.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    (
        [y0 * w + x0, y0 * w + x1, y1 * w + x0, y1 * w + x1],
        (xc - x0 as f32, yc - y0 as f32),
    )
}

/// A plane's bilinear value at the indices and fractions of [`bilinear`].
pub fn mix(p: &[f32], i: [usize; 4], (fx, fy): (f32, f32)) -> f32 {
    let top = p[i[0]] + fx * (p[i[1]] - p[i[0]]);
    let bottom = p[i[2]] + fx * (p[i[3]] - p[i[2]]);
    top + fy * (bottom - top)
}

/// A 3-channel image's channels as separate planes, for bilinear reads.
pub fn colour_planes(color: &Image) -> [Vec<f32>; 3] {
    std::array::from_fn(|k| plane(color.data(), 3, k, |v| v))
}

/// Channel `k` of `c` interleaved channels as a plane, each value through `f`; in parallel
/// blocks of pixels.
pub fn plane(data: &[f32], c: usize, k: usize, f: impl Fn(f32) -> f32 + Sync) -> Vec<f32> {
    const BLOCK: usize = 1 << 14;
    let mut out = par_vec(0.0f32, data.len() / c);
    out.par_chunks_mut(BLOCK)
        .zip(data.par_chunks(BLOCK * c))
        .for_each(|(out, px)| {
            for (o, px) in out.iter_mut().zip(px.chunks_exact(c)) {
                *o = f(px[k]);
            }
        });
    out
}

/// Moves `px` by `change`, scaled down where the change's mean square exceeds `tolerance` times
/// the noise variance `var` (`blend`'s Wiener rule); the result never below 0. No move when the
/// change is zero or not finite.
pub fn gated_move(px: &mut [f32], change: [f64; 3], var: f64, tolerance: f64) {
    let d2 = change.iter().map(|d| d * d).sum::<f64>() / 3.0;
    if !(d2 > 0.0 && d2.is_finite()) {
        return;
    }
    let keep = (tolerance * var / d2).min(1.0);
    for (v, d) in px.iter_mut().zip(change) {
        *v = (*v as f64 + keep * d).max(0.0) as f32;
    }
}

/// Per pixel, the unit direction (x, y) across its edge: the structure tensor's main axis.
pub fn normals(guide: &Guide) -> Vec<(f32, f32)> {
    let (w, h) = (guide.w, guide.h);
    // The tensor's three entries per pixel, summed over the guide's channels, a row at a time
    // (edges clamped).
    let mut j: Vec<[f32; 3]> = vec![[0.0; 3]; w * h];
    j.par_chunks_mut(w.max(1)).enumerate().for_each(|(y, e)| {
        let (above, below) = (y.saturating_sub(1), (y + 1).min(h - 1));
        for p in &guide.planes {
            let row = |yy: usize| &p[yy * w..(yy + 1) * w];
            sobel_row(row(above), row(y), row(below), e);
        }
    });
    let j = gaussian(&j, w, h, TENSOR_SIGMA);
    j.par_iter().map(|&t| main_axis(t)).collect()
}

/// The unit vector (cos θ, sin θ) at θ = ½·atan2(2·xy, xx − yy), the main axis of the tensor
/// `[xx, yy, xy]`, by the half-angle formulas instead of three calls of libm: the larger of
/// cos θ and |sin θ| from its square root, the other from sin 2θ = 2 sin θ cos θ, so neither
/// cancels. θ lies in [−π/2, π/2], so cos θ ≥ 0; sin θ takes the sign of xy (of a zero's sign
/// too, as `atan2` does). A zero tensor gives (1, 0).
fn main_axis([xx, yy, xy]: [f32; 3]) -> (f32, f32) {
    let (a, b) = ((xx - yy) as f64, 2.0 * xy as f64);
    let r = (a * a + b * b).sqrt();
    if !(r > 0.0 && r.is_finite()) {
        let theta = 0.5 * (2.0 * xy).atan2(xx - yy);
        return (theta.cos(), theta.sin());
    }
    let cos2 = a / r;
    if cos2 >= 0.0 {
        let c = ((1.0 + cos2) / 2.0).sqrt();
        (c as f32, (b / (2.0 * r * c)) as f32)
    } else {
        let s = ((1.0 - cos2) / 2.0).sqrt();
        ((b.abs() / (2.0 * r * s)) as f32, (s.copysign(b)) as f32)
    }
}

/// Adds one plane's Sobel tensor terms (gx², gy², gx·gy) of a row to `e`, from the rows above,
/// at and below it; columns clamped at the edges.
fn sobel_row(um: &[f32], u0: &[f32], up: &[f32], e: &mut [[f32; 3]]) {
    let w = e.len();
    // The same sums in the same order at every pixel, whichever of the two loops it is in.
    #[inline(always)]
    fn add(e: &mut [f32; 3], [m0, mm, mp, zm, zp, p0, pm, pp]: [f32; 8]) {
        let gx = mp + 2.0 * zp + pp - mm - 2.0 * zm - pm;
        let gy = pm + 2.0 * p0 + pp - mm - 2.0 * m0 - mp;
        e[0] += gx * gx;
        e[1] += gy * gy;
        e[2] += gx * gy;
    }
    let edge = |x: usize| {
        let (xm, xp) = (x.saturating_sub(1), (x + 1).min(w - 1));
        [um[x], um[xm], um[xp], u0[xm], u0[xp], up[x], up[xm], up[xp]]
    };
    if w < 3 {
        for (x, e) in e.iter_mut().enumerate() {
            add(e, edge(x));
        }
        return;
    }
    add(&mut e[0], edge(0));
    let inner = e[1..w - 1]
        .iter_mut()
        .zip(um.windows(3).zip(u0.windows(3)).zip(up.windows(3)));
    for (e, ((m, z), p)) in inner {
        add(e, [m[1], m[0], m[2], z[0], z[2], p[1], p[0], p[2]]);
    }
    add(&mut e[w - 1], edge(w - 1));
}

/// A separable Gaussian (σ `sigma`, radius ⌈3σ⌉, edges clamped) of three planes at once. Each
/// pixel adds its taps in order from −r to r, then divides by their sum.
fn gaussian(v: &[[f32; 3]], w: usize, h: usize, sigma: f32) -> Vec<[f32; 3]> {
    let r = (3.0 * sigma).ceil() as usize;
    let ri = r as isize;
    let taps: Vec<f32> = (-ri..=ri)
        .map(|d| (-(d * d) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let norm: f32 = taps.iter().sum();
    // Along the rows: each row with r copies of its edge pixels each side, so that every tap is
    // one shifted slice.
    let mut across = vec![[0.0f32; 3]; w * h];
    across
        .par_chunks_mut(w.max(1))
        .enumerate()
        .for_each_init(Vec::new, |line, (y, out)| {
            let src = &v[y * w..(y + 1) * w];
            edge_padded_line(line, src, r);
            let out = out.as_flattened_mut();
            for (d, &t) in taps.iter().enumerate() {
                let shifted = line[d..d + w].as_flattened();
                for (o, &s) in out.iter_mut().zip(shifted) {
                    *o += t * s;
                }
            }
            for o in out.iter_mut() {
                *o /= norm;
            }
        });
    // Down the columns: whole rows, clamped at the edges.
    let mut out = vec![[0.0f32; 3]; w * h];
    out.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, out)| {
            let out = out.as_flattened_mut();
            for (d, &t) in (-ri..=ri).zip(&taps) {
                let yy = (y as isize + d).clamp(0, h as isize - 1) as usize;
                for (o, &s) in out
                    .iter_mut()
                    .zip(across[yy * w..(yy + 1) * w].as_flattened())
                {
                    *o += t * s;
                }
            }
            for o in out.iter_mut() {
                *o /= norm;
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn guide_of(w: usize, h: usize, f: impl Fn(usize, usize) -> f32) -> Guide {
        Guide {
            w,
            h,
            planes: vec![(0..w * h).map(|i| f(i % w, i / w)).collect()],
            albedo: 1,
        }
    }

    #[test]
    fn the_main_axis_is_the_half_angle_of_every_tensor() {
        // Against ½·atan2 on a grid of tensors, every quadrant, the axes and signed zeros.
        let vals = [-3.0f32, -1.0, -1e-6, -0.0, 0.0, 1e-6, 0.5, 2.0];
        for &xx in &vals {
            for &yy in &vals {
                for &xy in &vals {
                    let theta = 0.5 * ((2.0 * xy) as f64).atan2((xx - yy) as f64);
                    let (c, s) = main_axis([xx, yy, xy]);
                    assert!(
                        (c as f64 - theta.cos()).abs() < 1e-6
                            && (s as f64 - theta.sin()).abs() < 1e-6,
                        "[{xx}, {yy}, {xy}]: ({c}, {s}) against θ {theta}"
                    );
                }
            }
        }
        assert_eq!(main_axis([0.0, 0.0, 0.0]), (1.0, 0.0));
        let (c, s) = main_axis([f32::NAN, 0.0, 1.0]);
        assert!(c.is_nan() && s.is_nan());
    }

    #[test]
    fn a_vertical_edge_runs_up_a_horizontal_one_across() {
        let v = normals(&guide_of(16, 16, |x, _| if x < 8 { 0.0 } else { 1.0 }));
        let (nx, ny) = v[8 * 16 + 8];
        assert!(nx.abs() > 0.99 && ny.abs() < 0.05, "{nx} {ny}");
        let hz = normals(&guide_of(16, 16, |_, y| if y < 8 { 0.0 } else { 1.0 }));
        let (nx, ny) = hz[8 * 16 + 8];
        assert!(ny.abs() > 0.99 && nx.abs() < 0.05, "{nx} {ny}");
    }

    /// The tensor's directions pixel by pixel, every read clamped on its own: what the row
    /// passes of [`normals`] must give to the bit.
    fn normals_by_pixel(guide: &Guide) -> Vec<(f32, f32)> {
        let (w, h) = (guide.w, guide.h);
        let at = |p: &[f32], x: isize, y: isize| {
            p[(y.clamp(0, h as isize - 1) as usize) * w + x.clamp(0, w as isize - 1) as usize]
        };
        let mut j = vec![[0.0f32; 3]; w * h];
        for (i, e) in j.iter_mut().enumerate() {
            let (x, y) = ((i % w) as isize, (i / w) as isize);
            for p in &guide.planes {
                let gx = at(p, x + 1, y - 1) + 2.0 * at(p, x + 1, y) + at(p, x + 1, y + 1)
                    - at(p, x - 1, y - 1)
                    - 2.0 * at(p, x - 1, y)
                    - at(p, x - 1, y + 1);
                let gy = at(p, x - 1, y + 1) + 2.0 * at(p, x, y + 1) + at(p, x + 1, y + 1)
                    - at(p, x - 1, y - 1)
                    - 2.0 * at(p, x, y - 1)
                    - at(p, x + 1, y - 1);
                e[0] += gx * gx;
                e[1] += gy * gy;
                e[2] += gx * gy;
            }
        }
        let r = (3.0 * TENSOR_SIGMA).ceil() as isize;
        let taps: Vec<f32> = (-r..=r)
            .map(|d| (-(d * d) as f32 / (2.0 * TENSOR_SIGMA * TENSOR_SIGMA)).exp())
            .collect();
        let norm: f32 = taps.iter().sum();
        let pass = |src: &[[f32; 3]], horizontal: bool| -> Vec<[f32; 3]> {
            let mut out = vec![[0.0f32; 3]; w * h];
            for (i, o) in out.iter_mut().enumerate() {
                let (x, y) = ((i % w) as isize, (i / w) as isize);
                for (d, &t) in (-r..=r).zip(&taps) {
                    let j = if horizontal {
                        y as usize * w + (x + d).clamp(0, w as isize - 1) as usize
                    } else {
                        (y + d).clamp(0, h as isize - 1) as usize * w + x as usize
                    };
                    for k in 0..3 {
                        o[k] += t * src[j][k];
                    }
                }
                for k in o.iter_mut() {
                    *k /= norm;
                }
            }
            out
        };
        pass(&pass(&j, true), false)
            .iter()
            .map(|&t| main_axis(t))
            .collect()
    }

    #[test]
    fn the_row_passes_give_the_per_pixel_directions_bit_for_bit() {
        // Two planes of scattered values (negative ones and zeros among them), on sizes narrower
        // and lower than the Sobel and Gaussian windows too.
        for (w, h) in [(1, 1), (2, 5), (3, 3), (7, 2), (13, 11), (40, 9)] {
            let value = |i: usize, k: usize| ((i * 37 + k * 11) % 17) as f32 / 8.0 - 0.9;
            let guide = Guide {
                w,
                h,
                planes: (0..2)
                    .map(|k| (0..w * h).map(|i| value(i, k)).collect())
                    .collect(),
                albedo: 1,
            };
            let bits = |v: Vec<(f32, f32)>| -> Vec<(u32, u32)> {
                v.iter().map(|(a, b)| (a.to_bits(), b.to_bits())).collect()
            };
            assert_eq!(
                bits(normals(&guide)),
                bits(normals_by_pixel(&guide)),
                "{w}x{h}"
            );
        }
    }

    #[test]
    fn bilinear_is_exact_at_centres_and_clamped_outside() {
        let g = guide_of(3, 2, |x, y| (x + 10 * y) as f32);
        let mut o = [0.0];
        g.sample(1.0, 1.0, &mut o);
        assert_eq!(o[0], 11.0);
        g.sample(0.5, 0.0, &mut o);
        assert_eq!(o[0], 0.5);
        g.sample(-5.0, 9.0, &mut o);
        assert_eq!(o[0], 10.0);
    }
}
