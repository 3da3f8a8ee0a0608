//! Edges only the colour shows: a light's rim on a ceiling of the same albedo, a hard shadow's
//! boundary, a reflection's edge. At a few samples a pixel the pixels along such an edge each show
//! the side their samples landed on, like a feature edge's, but no feature marks it, so the
//! along-edge step finds it from the colour itself: the guide is the filtered colour, tone-mapped
//! (c / (1 + c) per channel, so a light's rim and a dim shadow's count alike), and the noise that
//! gates the move is at least the colour's scatter along the edge ([`Gate::Scatter`]), which is
//! that coverage noise. A clean edge (no scatter along it), a thin line (the same colour on both
//! sides) and stripes (another edge within three pixels) pass unchanged.

use super::along::{along_edges, Gate};
use super::orient::{normals, plane, Guide};
use crate::image::Image;
use crate::meter::Meter;

/// The tone-mapped colour as a guide: three planes of c / (1 + c), a value that is not a finite
/// non-negative number read as 0.
pub fn colour_guide(color: &Image) -> Guide {
    let (w, h) = color.dims();
    let tone = |v: f32| {
        if v.is_finite() && v > 0.0 {
            v / (1.0 + v)
        } else {
            0.0
        }
    };
    let planes = (0..3).map(|k| plane(color.data(), 3, k, tone)).collect();
    Guide {
        w,
        h,
        planes,
        albedo: 3,
    }
}

/// `color` moved towards its mean along the edges its own tone-mapped values show (`reach` pixels
/// each way), as far as the larger of its noise `variance` and its scatter along the edge covers,
/// with `tolerance` as `blend`'s slack.
pub fn along_colour_edges(
    color: &Image,
    variance: &Image,
    (reach, tolerance): (usize, f64),
    meter: &Meter,
) -> Image {
    let guide = colour_guide(color);
    let dirs = normals(&guide);
    along_edges(
        color,
        variance,
        &guide,
        &dirs,
        (reach, tolerance, Gate::Scatter),
        meter,
    )
}

#[cfg(test)]
#[path = "colour_tests.rs"]
mod tests;
