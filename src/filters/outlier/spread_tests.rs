//! The `spread` stage's tests: the light given back, its cap, its surfaces, bad input and threads.

use super::*;

fn params(cap: f64) -> SpreadParams {
    SpreadParams {
        cap,
        ..SpreadParams::default()
    }
}

/// [`spread_light`] with the default settings but `cap`, and no meter.
fn spread(out: &mut Image, light: &Image, variance: &Image, guides: &Guides, cap: f64) -> Given {
    spread_light(
        out,
        light,
        variance,
        guides,
        &params(cap),
        &Meter::default(),
    )
}

/// A 31×31 frame of 0.2 with one pixel's removed light at its centre.
fn one_source(removed: f32) -> (Image, Image, Image) {
    let (w, h) = (31, 31);
    let out = Image::filled(w, h, 3, 0.2);
    let mut light = Image::new(w, h, 3);
    light.pixel_mut(15 * w + 15).fill(removed);
    (out, light, Image::filled(w, h, 3, 0.01))
}

#[test]
fn without_a_cap_every_bit_of_light_comes_back_around_the_spike() {
    let (mut out, light, variance) = one_source(9.0);
    let given = spread(&mut out, &light, &variance, &Guides::default(), 1e6);
    let rise = |x: usize, y: usize| (out.pixel(y * 31 + x)[0] - 0.2) as f64;
    let added: f64 = (0..31)
        .flat_map(|y| (0..31).map(move |x| (x, y)))
        .map(|(x, y)| rise(x, y))
        .sum();
    assert!((added - 9.0).abs() < 1e-3, "{added}");
    assert!(
        (given.returned - 27.0).abs() < 1e-6 && (given.removed - 27.0).abs() < 1e-9,
        "{given:?}"
    );
    // Not on the spike itself; a smooth bump, symmetric, falling away from it.
    assert_eq!(rise(15, 15), 0.0);
    assert!(
        (rise(14, 15) - rise(15, 16)).abs() < 1e-7 && (rise(10, 12) - rise(20, 18)).abs() < 1e-7
    );
    assert!(rise(14, 15) > rise(10, 15) && rise(10, 15) > rise(2, 15) && rise(2, 15) > 0.0);
}

#[test]
fn no_pixel_rises_by_more_than_the_cap_and_the_spike_stays_gone() {
    let (mut out, light, variance) = one_source(1e6);
    let given = spread(&mut out, &light, &variance, &Guides::default(), 0.5);
    let most = out.data().iter().fold(0.0f32, |m, &v| m.max(v));
    assert!((most - 0.25).abs() < 1e-6, "{most}");
    assert!(given.returned < given.removed, "{given:?}");
}

/// A spike on a sliver of surface three pixels wide: at a flat surface's density most of its
/// light would fall on the other surface and be lost; with `conserve` it all comes back, on
/// the sliver.
#[test]
fn conserve_gives_a_sliver_its_whole_light() {
    let albedo = Image::from_fn(
        31,
        31,
        3,
        |x, _, _| {
            if (14..=16).contains(&x) {
                0.8
            } else {
                0.2
            }
        },
    );
    let guides = Guides {
        albedo: Some(&albedo),
        normal: None,
    };
    for conserve in [false, true] {
        let (mut out, light, variance) = one_source(9.0);
        let p = SpreadParams {
            cap: 1e6,
            conserve,
            ..SpreadParams::default()
        };
        let given = spread_light(&mut out, &light, &variance, &guides, &p, &Meter::default());
        let off: f64 = (0..31 * 31)
            .filter(|i| !(14..=16).contains(&(i % 31)))
            .map(|i| (out.pixel(i)[0] - 0.2) as f64)
            .sum();
        let share = given.returned / given.removed;
        if conserve {
            assert!(
                (share - 1.0).abs() < 1e-9 && off.abs() < 1e-3,
                "{share} {off}"
            );
        } else {
            assert!(share < 0.5, "{share}");
        }
    }
}

#[test]
fn light_stays_on_its_surface() {
    // Left half albedo 0.2, right half 0.8; the source on the left, beside the edge.
    let (mut out, mut light, variance) = one_source(0.0);
    let albedo = Image::from_fn(31, 31, 3, |x, _, _| if x < 16 { 0.2 } else { 0.8 });
    light.pixel_mut(15 * 31 + 15).fill(3.0);
    let guides = Guides {
        albedo: Some(&albedo),
        normal: None,
    };
    spread(&mut out, &light, &variance, &guides, 1e6);
    let right: f64 = (0..31 * 31)
        .filter(|i| i % 31 >= 16)
        .map(|i| out.pixel(i)[0] as f64 - 0.2)
        .sum();
    // exp(−½ (0.6 / 0.1)²) of it, and that only beside the edge.
    assert!(right.abs() < 1e-6 * 3.0, "{right} went across the edge");
}

#[test]
fn bad_light_and_bad_noise_add_nothing() {
    let (mut out, mut light, _) = one_source(0.0);
    light
        .pixel_mut(3)
        .copy_from_slice(&[f32::NAN, f32::INFINITY, -1.0]);
    light.pixel_mut(40).fill(1.0);
    let variance = Image::filled(31, 31, 3, f32::NAN);
    let before = out.clone();
    spread(&mut out, &light, &variance, &Guides::default(), 0.5);
    assert_eq!(out, before);
}

#[test]
fn a_feature_that_is_not_a_number_shares_nothing() {
    let (mut out, light, variance) = one_source(3.0);
    let albedo = Image::from_fn(31, 31, 3, |x, _, _| if x == 16 { f32::NAN } else { 0.5 });
    let guides = Guides {
        albedo: Some(&albedo),
        normal: None,
    };
    spread(&mut out, &light, &variance, &guides, 1e6);
    assert!(out.data().iter().all(|v| v.is_finite()));
    assert_eq!(out.pixel(15 * 31 + 16)[0], 0.2, "the NaN column took light");
}

#[test]
fn a_row_of_surface_distances_is_each_pairs() {
    // Albedo and normals of three and of four channels, with unknown (zero) and NaN normals,
    // each guide alone and both: every cell the pair's own distances give, to the bit.
    let (w, h) = (23, 4);
    for c in [3, 4] {
        let albedo = Image::from_fn(w, h, c, |x, y, k| {
            ((x * 7 + y * 3 + k * 5) % 11) as f32 / 10.0
        });
        let normal = Image::from_fn(w, h, c, |x, y, k| match (x % 5, x + y) {
            (0, _) => 0.0,
            (_, 9) => f32::NAN,
            _ => ((x + 2 * y + k) % 7) as f32 / 7.0 - 0.4,
        });
        let guides = [
            Guides {
                albedo: Some(&albedo),
                normal: Some(&normal),
            },
            Guides {
                albedo: Some(&albedo),
                normal: None,
            },
            Guides {
                albedo: None,
                normal: Some(&normal),
            },
            Guides::default(),
        ];
        let (ka, kn) = (50.0f32, 200.0f32);
        for g in &guides {
            for i in [0, w + 5, 2 * w + 7, 3 * w + 22] {
                for y in 0..h {
                    let mut out = vec![-1.0f32; w];
                    row_unlike(g, (ka, kn), i, y * w, &mut out);
                    for (x, &u) in out.iter().enumerate() {
                        let (da2, dn) = g.squared_distances(i, y * w + x);
                        let want = ka * da2 + kn * dn * dn;
                        assert!(
                            u.to_bits() == want.to_bits() || (u.is_nan() && want.is_nan()),
                            "c {c}, source {i}, ({x}, {y}): {u} against {want}"
                        );
                    }
                }
            }
        }
    }
}

#[test]
fn the_same_bits_on_one_and_two_threads() {
    let (w, h) = (40, 23);
    let out = Image::from_fn(w, h, 3, |x, y, c| ((x * 7 + y * 13 + c) % 11) as f32 / 11.0);
    let light = Image::from_fn(w, h, 3, |x, y, _| {
        if (x * 31 + y * 17) % 23 == 0 {
            5.0
        } else {
            0.0
        }
    });
    let variance = Image::filled(w, h, 3, 0.04);
    let albedo = Image::from_fn(
        w,
        h,
        3,
        |x, y, _| if (x / 5 + y / 7) % 2 == 0 { 0.3 } else { 0.6 },
    );
    let run = |threads| {
        crate::options::thread_pool(threads).unwrap().install(|| {
            let mut o = out.clone();
            let guides = Guides {
                albedo: Some(&albedo),
                normal: None,
            };
            spread(&mut o, &light, &variance, &guides, 0.5);
            o
        })
    };
    assert_eq!(run(1), run(2));
}
