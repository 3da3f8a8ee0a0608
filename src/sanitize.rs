//! Input sanitisation (ALGORITHM.md §1): make every buffer finite and in range before any maths,
//! and count what changed so the run can report it.

use rayon::prelude::*;
use serde::Serialize;

use crate::buffers::Buffers;

/// How many samples or pixels sanitisation changed, per kind of fix.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct SanitizeReport {
    /// Colour samples that were NaN or ±Inf, set to 0.
    pub color_nonfinite: usize,
    /// Colour samples below 0, set to 0.
    pub color_negative: usize,
    /// Normals that were NaN or (near) zero length, set to the "unknown" zero vector.
    pub normal_unknown: usize,
    /// Depth values that were infinite, NaN or negative, set to the background depth.
    pub depth_background: usize,
    /// Albedo, material or shadow samples that were non-finite or outside [0, 1], clamped.
    pub feature_clamped: usize,
}

impl SanitizeReport {
    pub fn total(&self) -> usize {
        self.color_nonfinite
            + self.color_negative
            + self.normal_unknown
            + self.depth_background
            + self.feature_clamped
    }

    /// One line for the user, or `None` when nothing changed.
    pub fn summary(&self) -> Option<String> {
        if self.total() == 0 {
            return None;
        }
        let parts: Vec<String> = [
            (self.color_nonfinite, "non-finite colour samples → 0"),
            (self.color_negative, "negative colour samples → 0"),
            (self.normal_unknown, "invalid normals → unknown"),
            (
                self.depth_background,
                "infinite/invalid depths → background",
            ),
            (self.feature_clamped, "feature samples clamped to [0, 1]"),
        ]
        .iter()
        .filter(|(n, _)| *n > 0)
        .map(|(n, what)| format!("{n} {what}"))
        .collect();
        Some(format!("sanitised input: {}", parts.join(", ")))
    }
}

/// Applies `fix` to every value, in parallel chunks; `fix` reports which of N kinds of change it
/// made, and the result counts each kind.
fn fix_each<const N: usize>(
    data: &mut [f32],
    fix: impl Fn(&mut f32) -> [bool; N] + Sync,
) -> [usize; N] {
    let add = |mut a: [usize; N], b: [usize; N]| {
        for (x, y) in a.iter_mut().zip(b) {
            *x += y;
        }
        a
    };
    data.par_chunks_mut(1 << 16)
        .map(|chunk| {
            chunk
                .iter_mut()
                .fold([0; N], |acc, v| add(acc, fix(v).map(usize::from)))
        })
        .reduce(|| [0; N], add)
}

/// Sanitises every known buffer in place.
pub fn sanitize(buffers: &mut Buffers) -> SanitizeReport {
    let mut report = SanitizeReport::default();
    for name in ["color", "reference"] {
        if let Some(img) = buffers.get_mut(name) {
            let [nonfinite, negative] = fix_each(img.data_mut(), |v| {
                let kinds = [!v.is_finite(), v.is_finite() && *v < 0.0];
                if kinds.contains(&true) {
                    *v = 0.0;
                }
                kinds
            });
            report.color_nonfinite += nonfinite;
            report.color_negative += negative;
        }
    }
    for name in ["albedo", "material", "shadow"] {
        if let Some(img) = buffers.get_mut(name) {
            let [clamped] = fix_each(img.data_mut(), |v| {
                let clean = if v.is_finite() {
                    v.clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let changed = clean != *v;
                *v = clean;
                [changed]
            });
            report.feature_clamped += clamped;
        }
    }
    if let Some(img) = buffers.get_mut("normal") {
        report.normal_unknown += img
            .data_mut()
            .par_chunks_mut(3 << 14)
            .map(|chunk| {
                let mut unknown = 0;
                for n in chunk.chunks_exact_mut(3) {
                    let len2 = n[0] * n[0] + n[1] * n[1] + n[2] * n[2];
                    if !len2.is_finite() || len2 < 1e-12 {
                        if n.iter().any(|v| *v != 0.0) || !len2.is_finite() {
                            unknown += 1;
                        }
                        n.fill(0.0);
                    } else {
                        // Averaged normals at an edge are shorter than 1; renormalising keeps F3 on
                        // its scale.
                        let inv = 1.0 / len2.sqrt();
                        n.iter_mut().for_each(|v| *v *= inv);
                    }
                }
                unknown
            })
            .sum::<usize>();
    }
    if let Some(img) = buffers.get_mut("depth") {
        let max_finite = img
            .data()
            .par_iter()
            .copied()
            .filter(|v| v.is_finite() && *v >= 0.0)
            .reduce(|| 0.0f32, f32::max);
        // Larger than every finite depth, so misses differ from every surface.
        let background = if max_finite > 0.0 {
            max_finite * 2.0
        } else {
            1.0
        };
        let [misses] = fix_each(img.data_mut(), |v| {
            let miss = !v.is_finite() || *v < 0.0;
            if miss {
                *v = background;
            }
            [miss]
        });
        report.depth_background += misses;
    }
    report
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Image;

    #[test]
    fn counts_and_fixes_bad_samples() {
        let mut b = Buffers::new();
        let color =
            Image::from_vec(2, 1, 3, vec![f32::NAN, -1.0, 0.5, f32::INFINITY, 1.0, 2.0]).unwrap();
        b.insert("color", color).unwrap();
        let normal = Image::from_vec(2, 1, 3, vec![0.0, 0.0, 0.0, 0.0, 2.0, 0.0]).unwrap();
        b.insert("normal", normal).unwrap();
        let depth = Image::from_vec(2, 1, 1, vec![f32::INFINITY, 3.0]).unwrap();
        b.insert("depth", depth).unwrap();
        let r = sanitize(&mut b);
        assert_eq!(r.color_nonfinite, 2);
        assert_eq!(r.color_negative, 1);
        assert_eq!(r.depth_background, 1);
        assert_eq!(
            b.get("color").unwrap().data(),
            &[0.0, 0.0, 0.5, 0.0, 1.0, 2.0]
        );
        assert_eq!(
            b.get("normal").unwrap().data(),
            &[0.0, 0.0, 0.0, 0.0, 1.0, 0.0]
        );
        assert_eq!(b.get("depth").unwrap().data(), &[6.0, 3.0]);
        assert!(r.summary().unwrap().contains("2 non-finite colour"));
    }
}
