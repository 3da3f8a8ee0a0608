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
fn keep(case: &(Image, Image, Image), q: f64) -> Vec<f32> {
    keep_with(case, q, None)
}

/// [`keep`] with the normal's reliability `rho` (one value a pixel) when one is given.
fn keep_with(
    (color, filtered, variance): &(Image, Image, Image),
    q: f64,
    rho: Option<&[f32]>,
) -> Vec<f32> {
    keep_weights_metered(
        Kernel::detect(),
        (color, filtered, variance),
        &FeatureSet::default(),
        (2.0, 4.0, 0.0, q),
        rho,
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

#[test]
fn a_dark_dot_of_skewed_noise_keeps_its_surfaces_level() {
    // A surface of level 0.5 whose noise σ is 0.1, a fifth of its brightness (a few samples in
    // fog), and in it a dot where every sample missed (0). The filter put the dot at the
    // surface's level: a rise of 5σ, which the leak test alone takes back to κ = 4 · 0.01 / 0.25.
    // The surface-mates' median input (0.5) explains that rise where the level's σ is at least a
    // tenth of it and the surface's geometry is mostly noise, and the filtered value stays.
    const SKEWED: f32 = 0.1;
    let noise = noisy_flat(SIDE, SIDE, 0.0, SKEWED, 11);
    let dot = 24 * SIDE + 24;
    let color = Image::from_fn(SIDE, SIDE, 3, |x, y, _| {
        let i = y * SIDE + x;
        if i == dot {
            0.0
        } else {
            (FLAT + noise.pixel(i)[0]).max(0.0)
        }
    });
    let filtered = Image::filled(SIDE, SIDE, 3, FLAT);
    let variance = Image::filled(SIDE, SIDE, 3, SKEWED * SKEWED);
    let case = (color, filtered, variance);
    // The normal's reliability around it: fog's (a quarter), or clean geometry's (1).
    let (fog, clean) = (vec![0.25f32; SIDE * SIDE], vec![1.0f32; SIDE * SIDE]);
    let off = keep_with(&case, 0.0, Some(&fog));
    let on = keep_with(&case, 0.5, Some(&fog));
    assert!(off[dot] <= 0.17, "keep without the level {}", off[dot]);
    assert!(on[dot] >= 0.9, "keep {}", on[dot]);
    // The surface's own pixels: the same weights either way.
    for i in [dot - 5, dot + 7 * SIDE] {
        assert_eq!(on[i], off[i]);
    }
    // On clean geometry the dark pixel may be a texel the albedo's reliability gate smoothed away,
    // and without a reliability there is nothing to tell: the leak test stands.
    for rho in [Some(clean.as_slice()), None] {
        assert_eq!(keep_with(&case, 0.5, rho)[dot], off[dot]);
    }
}
