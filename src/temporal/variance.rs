//! The variance of each merged pixel mean, measured from the stack (docs/ALGORITHM.md §10): the
//! spread of the samples a pixel took across the window's frames, pooled over its surface-mates
//! so it rests on tens of degrees of freedom instead of the four of one pixel's five samples. A
//! pixel whose neighbours were all rejected (a disocclusion, a reflection that moved unlike its
//! surface) and has no mates that took any falls back to the frame's own estimate from the image.

use rayon::prelude::*;

use crate::filters::noise::surface::Surface;
use crate::image::Image;
use crate::render_set::FeatureSet;

/// Radius of the same-surface window the spreads are pooled over (3×3).
pub const POOL_RADIUS: usize = 1;
/// Degrees of freedom the image-only estimate counts for beside the measured spreads: it decides
/// only where the stack measured (almost) nothing.
const PRIOR_DOF: f64 = 1.0;

/// What one pixel's merge measured of the noise of one frame's value.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Spread {
    /// Σ w (c − m)² of the samples about their weighted mean, per channel.
    pub deviation: [f64; 3],
    /// Its expected value in units of one frame's pixel variance σ²: Σ w a − Σ w² a / Σ w, where
    /// a sample's a is the share of σ² its reprojection kept (1 at a whole pixel, down to 1/4 for
    /// a bilinear sample halfway between four). 0: nothing measured.
    pub dof: f64,
    /// The merged mean's variance in units of σ²: Σ w² a / (Σ w)².
    pub shrink: f64,
}

/// Sums over one pixel's samples c with weights w and kept shares a, from which its [`Spread`]
/// follows.
#[derive(Clone, Copy, Debug, Default)]
pub struct Sums {
    pub w: f64,
    pub wa: f64,
    pub w2a: f64,
    pub wc: [f64; 3],
    pub wc2: [f64; 3],
}

impl Sums {
    /// Adds a sample `c` of weight `w` whose reprojection kept the share `a` of a pixel's variance.
    pub fn add(&mut self, w: f64, a: f64, c: &[f64]) {
        self.w += w;
        self.wa += w * a;
        self.w2a += w * w * a;
        for (k, &c) in c.iter().take(3).enumerate() {
            self.wc[k] += w * c;
            self.wc2[k] += w * c * c;
        }
    }

    pub fn spread(&self) -> Spread {
        if self.w <= 0.0 {
            return Spread::default();
        }
        Spread {
            deviation: std::array::from_fn(|k| {
                (self.wc2[k] - self.wc[k] * self.wc[k] / self.w).max(0.0)
            }),
            dof: (self.wa - self.w2a / self.w).max(0.0),
            shrink: self.w2a / (self.w * self.w),
        }
    }
}

/// The variance of every merged pixel mean (RGB): one frame's σ² pooled from the demodulated
/// spreads of the pixel's surface-mates (`features`: the centre frame's) and, at [`PRIOR_DOF`],
/// the frame's own estimate `fallback`, times the pixel's own shrink.
pub fn pooled(spreads: &[Spread], features: &FeatureSet, fallback: &Image) -> Image {
    let (w, h) = fallback.dims();
    let surface = Surface::new(features, (w, h));
    let mates = surface.mates(w, h, POOL_RADIUS);
    let mut out = Image::new(w, h, 3);
    out.data_mut()
        .par_chunks_mut(3)
        .enumerate()
        .for_each(|(i, px)| {
            let s = surface.scale(i);
            let prior = fallback.pixel(i);
            let mut acc: [f64; 3] =
                std::array::from_fn(|k| PRIOR_DOF * (prior[k].max(0.0) as f64) / (s[k] * s[k]));
            let mut dof = PRIOR_DOF;
            for j in mates.of(i) {
                let spread = &spreads[j];
                if spread.dof <= 0.0 {
                    continue;
                }
                let d = surface.demodulate_variance(j, spread.deviation.iter().copied());
                for k in 0..3 {
                    acc[k] += d[k];
                }
                dof += spread.dof;
            }
            let shrink = spreads[i].shrink;
            for k in 0..3 {
                px[k] = (acc[k] / dof * s[k] * s[k] * shrink) as f32;
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn five_equal_whole_pixel_samples_hold_four_degrees_and_a_fifth_of_the_variance() {
        let mut sums = Sums::default();
        for c in [1.0, 2.0, 3.0, 4.0, 5.0] {
            sums.add(1.0, 1.0, &[c, c, c]);
        }
        let s = sums.spread();
        assert!((s.dof - 4.0).abs() < 1e-12);
        assert!((s.shrink - 0.2).abs() < 1e-12);
        // Σ (c − 3)² = 10: the unbiased variance 10 / 4.
        assert!((s.deviation[0] / s.dof - 2.5).abs() < 1e-12);
        let mut alone = Sums::default();
        alone.add(1.0, 1.0, &[7.0, 7.0, 7.0]);
        assert_eq!(alone.spread().dof, 0.0);
        assert_eq!(alone.spread().shrink, 1.0);
    }
}
