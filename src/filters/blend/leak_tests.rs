//! Tests of the blend's `leak_level` (the leak test held against the image's noise-level
//! function, `noise_level.rs`): a dark pixel beside a highlight that the filter lit comes back
//! where the local estimate reads the highlight as noise; black pixels do not read as a level.

use super::weights::keep_weights_metered;
use crate::filters::noise::from_image::tests::noisy_flat;
use crate::image::Image;
use crate::kernels::simd::Kernel;
use crate::meter::Meter;
use crate::render_set::FeatureSet;

const SIDE: usize = 48;
/// The surface's level and noise σ: small against its brightness, as at many samples a pixel.
const FLAT: f32 = 0.5;
const STD: f32 = 0.01;
/// Columns of the dark pixels beside the highlight whose light the filter moved into them,
/// raising them to the surface's level; the local estimate there reads the highlight as noise
/// (`STRUCTURE_VAR`, σ 0.2).
const LIT: std::ops::RangeInclusive<usize> = 20..=21;
const STRUCTURE_VAR: f32 = 0.04;

/// (colour, filtered, variance): the noisy flat surface filtered to its mean, the `LIT` columns
/// too from their input `dark`; their estimate and their neighbours' reads `STRUCTURE_VAR`.
pub(super) fn lit_beside_highlight(dark: f32) -> (Image, Image, Image) {
    let noise = noisy_flat(SIDE, SIDE, 0.0, STD, 7);
    let color = Image::from_fn(SIDE, SIDE, 3, |x, y, _| {
        if LIT.contains(&x) {
            dark
        } else {
            FLAT + noise.pixel(y * SIDE + x)[0]
        }
    });
    let filtered = Image::filled(SIDE, SIDE, 3, FLAT);
    let variance = Image::from_fn(SIDE, SIDE, 3, |x, _, _| {
        if (18..=23).contains(&x) {
            STRUCTURE_VAR
        } else {
            STD * STD
        }
    });
    (color, filtered, variance)
}

/// The blend's keep weights (tolerance 2, leak 4, no noise-level cap) with `leak_level` `q`.
fn keep((color, filtered, variance): &(Image, Image, Image), q: f64) -> Vec<f32> {
    keep_weights_metered(
        Kernel::detect(),
        (color, filtered, variance),
        &FeatureSet::default(),
        (2.0, 4.0, 0.0, q),
        &Meter::default(),
    )
}

#[test]
fn light_moved_into_a_dark_pixel_the_estimate_misreads_comes_back() {
    let case = lit_beside_highlight(0.3);
    let (off, on) = (keep(&case, 0.0), keep(&case, 0.5));
    let i = 24 * SIDE + 20;
    // By its own estimate (σ 0.2) a rise of 0.2 is within 2σ: kept whole.
    assert_eq!(off[i], 1.0);
    // By the image's level (σ 0.01, a fiftieth of its brightness) it is 20σ: taken back,
    // κ = 4 · 0.0001 / 0.04 at most.
    assert!(on[i] <= 0.0101, "keep {}", on[i]);
    // The surface itself is untouched (no rise tested, and the same weights).
    let flat = 24 * SIDE + 40;
    assert_eq!(on[flat], off[flat]);
}

#[test]
fn black_pixels_do_not_make_the_level_zero() {
    // The left half black (every sample missed: no light, no measured noise), a dark column of
    // a few samples beside it that the filter lit tenfold, its estimate a tenth of its input.
    // Over every pixel the dark bins would read no noise and take that light back; over the
    // pixels with some noise, the level at that brightness is the surface's (σ 0.01), far
    // above a tenth of it, and the rise is kept.
    let (w, h) = (SIDE, SIDE);
    let black = |x: usize| x < 24;
    let color = Image::from_fn(w, h, 3, |x, _, _| match x {
        _ if black(x) => 0.0,
        30 => 0.001,
        _ => FLAT,
    });
    let filtered = Image::from_fn(w, h, 3, |x, _, _| match x {
        _ if black(x) => 0.0,
        30 => 0.01,
        _ => FLAT,
    });
    let variance = Image::from_fn(w, h, 3, |x, _, _| match x {
        _ if black(x) => 0.0,
        30 => 1e-8,
        _ => STD * STD,
    });
    let case = (color, filtered, variance);
    let i = 24 * SIDE + 30;
    assert_eq!(keep(&case, 0.5)[i], keep(&case, 0.0)[i]);
}
