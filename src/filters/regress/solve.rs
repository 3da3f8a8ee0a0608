//! The 3×3 normal equations of each pixel's window solved for its intercept, brought back to
//! colour, with the intercept's variance.

use super::params::{Inputs, Params, DEMODULATION_EPS};
use super::planes::{Planes, V, VALID};
use super::window_sums::{GroupSums, S00, S01, S02, S11, S12, S22};

impl<const G: usize> GroupSums<G> {
    /// Solves the fits of the `n` pixels from (x0, y) and writes their intercepts (brought back to
    /// colour) and variances into the row's `out` and `out_var`.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn solve(
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
pub(super) fn first_column_of_inverse(a: [f64; 6], ridge: f64) -> [f64; 3] {
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

#[cfg(test)]
mod tests {
    use super::*;

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
