//! The reliability gate's albedo floor (`reliability.albedo_by_geometry`): texture coverage on clean
//! geometry keeps guiding, a per-sample mix of medium and surface does not.

use gsid::pipeline::PipelineSpec;
use gsid::{Buffers, DenoiseOptions, Image};

/// A xorshift stream: the same pattern on every run.
fn coin(state: &mut u64, in_ten: u64) -> bool {
    *state ^= *state << 13;
    *state ^= *state >> 7;
    *state ^= *state << 17;
    *state % 10 < in_ten
}

/// A brick wall at a few samples: light mortar lines (rows every 5 pixels, a 1-pixel joint every
/// 10 columns, offset every other course) that each pixel's samples hit 7 times in 10, on a flat
/// wall whose normal and depth are clean. Or, `fog`, the same wall seen through a medium: 3 pixels
/// in 10 are the medium's sample, with its albedo (0.9) and, as Blender writes it, a normal facing
/// the camera. Returns (the set, which pixels are mortar or medium).
fn wall(fog: bool) -> (Buffers, Vec<bool>) {
    let (w, h) = (40, 40);
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let odd: Vec<bool> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            if fog {
                coin(&mut state, 3)
            } else {
                let course = y / 5;
                let joint = (x + 5 * (course % 2)) % 10 == 0;
                (y % 5 == 0 || joint) && coin(&mut state, 7)
            }
        })
        .collect();
    let albedo = Image::from_fn(w, h, 3, |x, y, _| if odd[y * w + x] { 0.9 } else { 0.3 });
    let mut b = Buffers::new();
    let color = Image::from_fn(w, h, 3, |x, y, c| albedo.at(x, y)[c] * 0.8);
    b.insert("color", color).unwrap();
    b.insert("albedo", albedo).unwrap();
    let normal = Image::from_fn(w, h, 3, |x, y, c| match (fog && odd[y * w + x], c) {
        (true, 2) => -1.0,
        (false, 1) => 1.0,
        _ => 0.0,
    });
    b.insert("normal", normal).unwrap();
    b.insert("depth", Image::filled(w, h, 1, 2.0)).unwrap();
    (b, odd)
}

/// The albedo's mean reliability over the odd pixels (mortar or medium), away from the border,
/// after `full` with the key set as given.
fn albedo_reliability(fog: bool, by_geometry: bool) -> f64 {
    let (mut b, odd) = wall(fog);
    let mut spec = PipelineSpec::resolve("full").unwrap();
    spec.apply_set(&format!("reliability.albedo_by_geometry={by_geometry}"))
        .unwrap();
    spec.build()
        .unwrap()
        .run(&mut b, &DenoiseOptions::seeded(5))
        .unwrap();
    let rho = b.get("albedo_reliability").expect("kept for --save-buffer");
    let w = rho.width();
    let (mut sum, mut n) = (0.0f64, 0.0f64);
    for y in 4..rho.height() - 4 {
        for x in 4..w - 4 {
            if odd[y * w + x] {
                sum += rho.at(x, y)[0] as f64;
                n += 1.0;
            }
        }
    }
    sum / n
}

#[test]
fn mortar_on_clean_geometry_keeps_guiding() {
    let (off, on) = (
        albedo_reliability(false, false),
        albedo_reliability(false, true),
    );
    // The gate alone reads the broken grid of lines as noise; the flat wall's clean normal says the
    // pixel sees one surface, so its albedo is its texture's coverage and is kept.
    assert!(off < 0.7, "gate alone: {off}");
    assert!(on > 0.95, "with the geometry's floor: {on}");
}

#[test]
fn fog_mixes_the_normal_too_and_stays_gated() {
    let (off, on) = (
        albedo_reliability(true, false),
        albedo_reliability(true, true),
    );
    assert!(off < 0.3, "gate alone: {off}");
    // The medium's samples face the camera: the normal is as unreliable as the albedo, no floor.
    assert!(on < 0.3, "with the geometry's floor: {on}");
}
