//! Which of the clamp's pixels were a highlight, not a firefly: the light of those is given back
//! where it was taken, not spread.
//!
//! A firefly is one lucky sample: where it lands is independent of where the others land, so two
//! flagged pixels side by side happen only as often as the image's share of flagged pixels makes
//! them. A real highlight (a chrome torus's reflected light at 64 samples a pixel) covers a few
//! pixels that are all above their surface-mates, and the clamp flags them together. So a flagged
//! pixel with a flagged 8-neighbour is kept as a highlight when chance alone would give a flagged
//! pixel such a neighbour with a probability below the stage's significance level: the share `p` of
//! flagged pixels is read from the image itself, and the chance is 1 − (1 − p)⁸. At a few samples
//! fireflies are many (a share of several per cent), the test never passes and every spike stays
//! clamped; at many samples the clamp flags a handful, and those that touch are structure.
//! A lone flagged pixel is always a firefly to this test, whatever the sample count.

use rayon::prelude::*;

use crate::image::Image;

/// Neighbours a pixel has at most: the chance is for all eight.
const NEIGHBOURS: i32 = 8;

/// Per pixel, whether the clamp took light from it (`light` positive and finite in a channel).
fn flagged(light: &Image) -> Vec<bool> {
    light
        .data()
        .par_chunks_exact(3)
        .map(|p| p.iter().any(|&v| v.is_finite() && v > 0.0))
        .collect()
}

/// The chance that a flagged pixel has at least one flagged 8-neighbour when a share `p` of the
/// image's pixels is flagged at random.
pub fn chance_of_a_neighbour(p: f64) -> f64 {
    1.0 - (1.0 - p.clamp(0.0, 1.0)).powi(NEIGHBOURS)
}

/// The pixels of `light` (what the clamp took, 3 channels) that were highlights under
/// significance level `alpha`: flagged, with a flagged 8-neighbour, in an image whose share of
/// flagged pixels makes that less likely than `alpha` by chance. All false when `alpha` is 0.
pub fn highlights(light: &Image, alpha: f64) -> Vec<bool> {
    let (w, h) = light.dims();
    if alpha <= 0.0 {
        return vec![false; w * h];
    }
    let flags = flagged(light);
    let n = flags.len();
    let count = flags.iter().filter(|&&f| f).count();
    if n == 0 || count == 0 || chance_of_a_neighbour(count as f64 / n as f64) >= alpha {
        return vec![false; n];
    }
    (0..n)
        .into_par_iter()
        .map(|i| {
            let (x, y) = (i % w, i / w);
            flags[i]
                && (y.saturating_sub(1)..(y + 2).min(h)).any(|yy| {
                    (x.saturating_sub(1)..(x + 2).min(w))
                        .any(|xx| (xx, yy) != (x, y) && flags[yy * w + xx])
                })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn light_at(w: usize, h: usize, at: &[(usize, usize)]) -> Image {
        Image::from_fn(
            w,
            h,
            3,
            |x, y, _| {
                if at.contains(&(x, y)) {
                    1.0
                } else {
                    0.0
                }
            },
        )
    }

    #[test]
    fn touching_flags_among_few_are_highlights_and_a_lone_one_is_not() {
        let light = light_at(64, 64, &[(10, 10), (11, 10), (40, 40)]);
        let kept = highlights(&light, 0.01);
        assert!(kept[10 * 64 + 10] && kept[10 * 64 + 11]);
        assert!(!kept[40 * 64 + 40]);
        assert_eq!(kept.iter().filter(|&&k| k).count(), 2);
        // Off: nothing is a highlight.
        assert!(highlights(&light, 0.0).iter().all(|&k| !k));
    }

    #[test]
    fn touching_flags_among_many_are_chance() {
        // One pixel in ten flagged (a few samples a pixel): neighbours are likely, nothing kept.
        let at: Vec<(usize, usize)> = (0..64 * 64)
            .filter(|i| i % 10 == 0)
            .map(|i| (i % 64, i / 64))
            .chain([(10, 10), (11, 10)])
            .collect();
        let kept = highlights(&light_at(64, 64, &at), 0.01);
        assert!(kept.iter().all(|&k| !k));
    }

    #[test]
    fn the_chance_follows_the_share() {
        assert_eq!(chance_of_a_neighbour(0.0), 0.0);
        assert!((chance_of_a_neighbour(0.5) - (1.0 - 0.5f64.powi(8))).abs() < 1e-12);
        assert_eq!(chance_of_a_neighbour(1.0), 1.0);
    }
}
