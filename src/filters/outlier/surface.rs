//! The `feature` rule's same-surface test of every pixel with every neighbour, made once for the
//! whole image as window bits, the pairs compared side by side in vector lanes.

use std::ops::Range;

use super::params::{DetectParams, Guides};
use crate::image::Image;
use crate::kernels::simd::{row_kernel, Kernel};
use crate::kernels::window_bits::window_bits;

/// Largest radius up to which the `feature` rule tests its pairs once, side by side
/// ([`surface_bits`]).
pub(super) const BITS_RADIUS: usize = crate::kernels::window_bits::MOST_RADIUS;

/// Per pixel, a bit per cell of its (2r+1)² window in raster order: set when that neighbour is
/// inside the image and on the pixel's surface (`Guides::distances` within both tolerances, the
/// same f32 operations, so the same neighbours).
pub(super) fn surface_bits(guides: &Guides, p: &DetectParams, w: usize, h: usize) -> Vec<u64> {
    let kernel = Kernel::detect();
    window_bits(
        w,
        h,
        p.radius,
        false,
        |rows| SurfacePlanes::of_rows(guides, p, rows, w),
        |planes, i0, j0, bit, out| row_kernel!(kernel, same_surface_run(planes: &SurfacePlanes, i0: usize, j0: usize, bit: u32, out: &mut [u64])),
    )
}

/// What [`surface_bits`] compares, one plane per channel.
struct SurfacePlanes {
    albedo: [Vec<f32>; 3],
    normal: [Vec<f32>; 3],
    known: Vec<bool>,
    /// Albedo and normal tolerances.
    tol: (f32, f32),
}

impl SurfacePlanes {
    /// The planes of the `w`-pixel rows `rows`. Albedo (3), normal (3), normal known: zeros stand
    /// for a missing buffer, whose distance is then 0, as `distances` has it.
    fn of_rows<'a>(guides: &Guides<'a>, p: &DetectParams, rows: Range<usize>, w: usize) -> Self {
        let (first, n) = (rows.start * w, rows.len() * w);
        let pixels = |img: &'a Image| img.data()[3 * first..3 * (first + n)].chunks_exact(3);
        let plane = |img: Option<&'a Image>, k: usize| -> Vec<f32> {
            img.map_or_else(|| vec![0.0; n], |img| pixels(img).map(|px| px[k]).collect())
        };
        SurfacePlanes {
            albedo: std::array::from_fn(|k| plane(guides.albedo, k)),
            normal: std::array::from_fn(|k| plane(guides.normal, k)),
            known: guides.normal.map_or_else(
                || vec![false; n],
                |img| pixels(img).map(|v| v.iter().any(|&c| c != 0.0)).collect(),
            ),
            tol: (p.albedo_tol, p.normal_tol),
        }
    }
}

/// Sets `bit` of `out[t]` where pixels i0 + t and j0 + t lie on one surface: `Guides::distances`,
/// operation for operation, over a run of pixels.
#[inline(always)]
fn same_surface_run(planes: &SurfacePlanes, i0: usize, j0: usize, bit: u32, out: &mut [u64]) {
    let n = out.len();
    let [a0, a1, a2] = &planes.albedo;
    let [n0, n1, n2] = &planes.normal;
    let (pa, qa) = (
        [&a0[i0..i0 + n], &a1[i0..i0 + n], &a2[i0..i0 + n]],
        [&a0[j0..j0 + n], &a1[j0..j0 + n], &a2[j0..j0 + n]],
    );
    let (pn, qn) = (
        [&n0[i0..i0 + n], &n1[i0..i0 + n], &n2[i0..i0 + n]],
        [&n0[j0..j0 + n], &n1[j0..j0 + n], &n2[j0..j0 + n]],
    );
    let (pk, qk) = (&planes.known[i0..i0 + n], &planes.known[j0..j0 + n]);
    let (albedo_tol, normal_tol) = planes.tol;
    for (t, b) in out.iter_mut().enumerate() {
        let da = ((pa[0][t] - qa[0][t]).powi(2)
            + (pa[1][t] - qa[1][t]).powi(2)
            + (pa[2][t] - qa[2][t]).powi(2))
        .sqrt();
        let dot = pn[0][t] * qn[0][t] + pn[1][t] * qn[1][t] + pn[2][t] * qn[2][t];
        let dn = if pk[t] & qk[t] {
            ((1.0 - dot) * 0.5).clamp(0.0, 1.0)
        } else {
            0.0
        };
        *b |= u64::from((da <= albedo_tol) & (dn <= normal_tol)) << bit;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filters::outlier::neighbourhood::window;
    use crate::filters::outlier::params::fixtures::{guide_sets, params};
    use crate::filters::outlier::params::Rule;

    #[test]
    fn surface_bits_are_the_pairwise_test_in_window_order() {
        // Taller than `window_bits`' bands of rows, so windows cross from one band to the next.
        let (w, h) = (13, 37);
        // Few distinct albedos and normals (ties at the tolerances), unknown normals, a NaN.
        let albedo = Image::from_fn(w, h, 3, |x, y, k| {
            if (x, y) == (4, 4) {
                f32::NAN
            } else {
                [0.2, 0.25, 0.3, 0.7][(x * 3 + y * 5 + k) % 4]
            }
        });
        let normal = Image::from_fn(w, h, 3, |x, y, k| match (x + 2 * y) % 5 {
            0 => 0.0,
            1 => [0.0, 0.6, 0.8][k],
            _ => [0.0, 0.0, 1.0][k],
        });
        for guides in guide_sets(&albedo, &normal) {
            for radius in 1..=BITS_RADIUS {
                let p = DetectParams {
                    radius,
                    albedo_tol: 0.05,
                    normal_tol: 0.1,
                    ..params(Rule::Feature)
                };
                let bits = surface_bits(&guides, &p, w, h);
                let side = 2 * radius + 1;
                for (i, &m) in bits.iter().enumerate() {
                    let (x, y) = ((i % w) as isize, (i / w) as isize);
                    let got: Vec<usize> = (0..side * side)
                        .filter(|&b| m >> b & 1 == 1)
                        .map(|b| {
                            let (dx, dy) = ((b % side) as isize, (b / side) as isize);
                            ((y + dy - radius as isize) * w as isize + x + dx - radius as isize)
                                as usize
                        })
                        .collect();
                    let want: Vec<usize> = window(x as usize, y as usize, radius, w, h)
                        .filter(|&j| {
                            let (da, dn) = guides.distances(i, j);
                            da <= p.albedo_tol && dn <= p.normal_tol
                        })
                        .collect();
                    assert_eq!(got, want, "pixel ({x}, {y}), radius {radius}");
                }
            }
        }
    }
}
