//! Tests of the blend's noise-level cap through its keep weights (`noise_level.rs` holds the
//! function, `weights.rs` the weights that use it): a blurred band handed back, a spike, a darker
//! input, a small change and white noise not, the same bits on 1 and 2 threads.

use super::noise_level::NoiseLevel;
use super::weights::keep_weights_metered;
use crate::filters::noise::from_image::tests::noisy_flat;
use crate::image::Image;
use crate::kernels::simd::Kernel;
use crate::meter::Meter;
use crate::render_set::{Feature, FeatureSet};

const SIDE: usize = 48;
/// The flat background's noise σ, and the level it sits at.
const STD: f32 = 0.02;
const FLAT: f32 = 0.2;
/// The level of [`background`]'s bright right part, as noisy as the rest.
const BRIGHT: f32 = 0.85;

/// A grey background of noise σ `STD` (its own deterministic noise in every pixel, one value
/// for all three channels), at `FLAT`, or at `BRIGHT` from column 32 on when `bright`.
fn background(seed: u64, bright: bool) -> Image {
    let noise = noisy_flat(SIDE, SIDE, 0.0, STD, seed);
    Image::from_fn(SIDE, SIDE, 3, |x, y, _| {
        let level = if bright && x >= 32 { BRIGHT } else { FLAT };
        level + noise.pixel(y * SIDE + x)[0]
    })
}

/// The blend's keep weights (tolerance 2, leak 4) with the noise-level cap at `q` (0: off).
fn keep(color: &Image, filtered: &Image, variance: &Image, q: f64) -> Vec<f32> {
    keep_weights_metered(
        Kernel::detect(),
        (color, filtered, variance),
        &FeatureSet::default(),
        (2.0, 4.0, q, 0.0),
        None,
        &Meter::default(),
    )
}

/// The blurred band's filtered profile from column 20 to 26: a 3-pixel band (columns 22..=24)
/// of input `BAND` on the 0.2 background, spread by the filter over 7 columns.
const PROFILE: [f32; 7] = [0.25, 0.3, 0.75, 0.9, 0.75, 0.3, 0.25];
const BAND: f32 = 0.95;
/// The local estimate's variance around the band: above the background's, below the output's
/// own variation at the band's edges.
const BAND_VAR: f32 = 0.0125;

/// A vertical band of light on the noisy background, which the filter blurred to `PROFILE`;
/// the local estimate around it reads part of the band as noise (`BAND_VAR` over columns
/// 18..=28), the background's is its true 0.0004, and so is that of the bright part, which
/// gives the image's level at the band's brightness.
pub(super) fn blurred_band() -> (Image, Image, Image) {
    let mut color = background(3, true);
    for y in 0..SIDE {
        for x in 22..=24 {
            color.pixel_mut(y * SIDE + x).fill(BAND);
        }
    }
    let filtered = Image::from_fn(SIDE, SIDE, 3, |x, _, _| match x {
        20..=26 => PROFILE[x - 20],
        32.. => BRIGHT,
        _ => FLAT,
    });
    let variance = Image::from_fn(SIDE, SIDE, 3, |x, _, _| {
        if (18..=28).contains(&x) {
            BAND_VAR
        } else {
            STD * STD
        }
    });
    (color, filtered, variance)
}

#[test]
fn a_blurred_band_comes_back_at_its_edges() {
    let (color, filtered, variance) = blurred_band();
    let (off, on) = (
        keep(&color, &filtered, &variance, 0.0),
        keep(&color, &filtered, &variance, 0.75),
    );
    for y in [2, 24, SIDE - 3] {
        // The band's edge pixels, where the filter's output still shows the band: against the
        // inflated estimate the blur looks like noise removed and most of it is kept; against
        // the image's level for that brightness the input comes back.
        for x in [22, 24] {
            let i = y * SIDE + x;
            assert!(off[i] > 0.5, "off at ({x}, {y}): keep {}", off[i]);
            assert!(on[i] < 0.1, "on at ({x}, {y}): keep {}", on[i]);
        }
        // The halo, where the filter added light, and the background: as they were.
        for x in [0, 10, 21, 25, 40] {
            let i = y * SIDE + x;
            assert_eq!(off[i], on[i], "({x}, {y})");
        }
    }
}

#[test]
fn the_same_bits_on_one_and_two_threads() {
    let (color, filtered, variance) = blurred_band();
    let on = |threads| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let keep = pool.install(|| keep(&color, &filtered, &variance, 0.75));
        keep.iter().map(|k| k.to_bits()).collect::<Vec<_>>()
    };
    assert_eq!(on(1), on(2));
}

#[test]
fn a_spike_a_darker_input_or_a_small_change_is_not_handed_back() {
    let (mut color, filtered, variance) = blurred_band();
    // On the band's edges (filtered 0.75, estimate σ 0.11): one pixel 3σ above the filtered
    // value, one below it. Neither is light the filter took from the band.
    let (spike, dark) = (20 * SIDE + 22, 20 * SIDE + 24);
    color.pixel_mut(spike).fill(0.75 + 3.0 * BAND_VAR.sqrt());
    color.pixel_mut(dark).fill(0.55);
    // And one above it by 2σ of the image's level there: a change that level explains.
    let small = 16 * SIDE + 22;
    let level = NoiseLevel::fit(&filtered, &variance, 0.75).unwrap();
    let sigma = level.at(&[0.75; 3]).sqrt() as f32;
    color.pixel_mut(small).fill(0.75 + 2.0 * sigma);
    let (off, on) = (
        keep(&color, &filtered, &variance, 0.0),
        keep(&color, &filtered, &variance, 0.75),
    );
    assert_eq!(off[spike], on[spike], "spike");
    assert_eq!(off[dark], on[dark], "darker input");
    assert_eq!(off[small], on[small], "a change within the level's noise");
    // Their neighbours along the edge still come back.
    assert!(on[22 * SIDE + 22] < 0.1 && on[22 * SIDE + 24] < 0.1);
}

#[test]
fn white_noise_removed_is_not_handed_back() {
    // The filter took the background's noise out, and in a 16×16 patch noise four times as
    // strong (its estimate right, and far above the image's level): the filtered image is flat
    // there, so nothing reads as structure and every weight is what it was without the cap.
    let loud = |x: usize, y: usize| (16..32).contains(&x) && (16..32).contains(&y);
    let quiet = background(5, false);
    let strong = noisy_flat(SIDE, SIDE, FLAT, 4.0 * STD, 6);
    let color = Image::from_fn(SIDE, SIDE, 3, |x, y, _| {
        let i = y * SIDE + x;
        if loud(x, y) {
            strong.pixel(i)[0]
        } else {
            quiet.pixel(i)[0]
        }
    });
    let filtered = Image::filled(SIDE, SIDE, 3, FLAT);
    let variance = Image::from_fn(SIDE, SIDE, 3, |x, y, _| {
        let s = if loud(x, y) { 4.0 * STD } else { STD };
        s * s
    });
    let off = keep(&color, &filtered, &variance, 0.0);
    let on = keep(&color, &filtered, &variance, 0.75);
    assert_eq!(off, on);
    // The loud patch does sit far above the image's level: only the flat output kept the
    // cap from acting there.
    let level = NoiseLevel::fit(&filtered, &variance, 0.75).unwrap();
    assert!(level.at(&[FLAT; 3]) < ((4.0 * STD).powi(2) / 4.0) as f64);
}

#[test]
fn a_pixel_without_surface_mates_keeps_its_own_estimate() {
    // The blurred band's edge pixel (22, 22) is of its own albedo: it has no surface-mate, its
    // estimate is the noise stage's reading of its window alone (a chrome pixel showing the
    // scene), and the image's level, fitted over surfaces, is not its noise.
    let (color, filtered, variance) = blurred_band();
    let lone = 22 * SIDE + 22;
    let mut set = FeatureSet::default();
    let albedo = Image::from_fn(
        SIDE,
        SIDE,
        3,
        |x, y, _| {
            if y * SIDE + x == lone {
                0.9
            } else {
                0.5
            }
        },
    );
    set.set(Feature::Albedo, albedo).unwrap();
    let keep = |q| {
        keep_weights_metered(
            Kernel::detect(),
            (&color, &filtered, &variance),
            &set,
            (2.0, 4.0, q, 0.0),
            None,
            &Meter::default(),
        )
    };
    let (off, on) = (keep(0.0), keep(0.75));
    assert_eq!(off[lone], on[lone], "the lone pixel");
    assert!(
        on[lone] > 0.5,
        "its estimate explains the change: {}",
        on[lone]
    );
    // Its neighbours along the edge still come back.
    assert!(on[23 * SIDE + 22] < 0.1 && on[21 * SIDE + 22] < 0.1);
}
