//! The metrics agree with scikit-image (values made by scripts/skimage_metrics.py).

use std::path::Path;

use gsid::{io, metrics, Image};
use serde_json::Value;

fn expectations() -> Value {
    let text = std::fs::read_to_string("tests/data/skimage_metrics.json").unwrap();
    serde_json::from_str(&text).unwrap()
}

#[test]
fn fixture_scores_match_scikit_image() {
    let json = expectations();
    for case in json["fixtures"].as_array().unwrap() {
        let img = io::read_image(Path::new(case["image"].as_str().unwrap()), 3).unwrap();
        let reference = io::read_image(Path::new(case["reference"].as_str().unwrap()), 3).unwrap();
        let s = metrics::score(&img, &reference).unwrap();
        let name = case["name"].as_str().unwrap();
        let want = |k: &str| case[k].as_f64().unwrap();
        assert!(
            (s.ssim - want("ssim")).abs() < 1e-4,
            "{name}: ssim {} vs {}",
            s.ssim,
            want("ssim")
        );
        assert!(
            (s.psnr - want("psnr")).abs() < 1e-3,
            "{name}: psnr {} vs {}",
            s.psnr,
            want("psnr")
        );
        assert!(
            (s.relmse - want("relmse")).abs() < 1e-6 * want("relmse").max(1.0),
            "{name}: relmse"
        );
    }
}

#[test]
fn synthetic_ssim_matches_scikit_image_at_odd_sizes() {
    let json = expectations();
    for case in json["synthetic"].as_array().unwrap() {
        let (w, h) = (
            case["width"].as_u64().unwrap() as usize,
            case["height"].as_u64().unwrap() as usize,
        );
        let load = |k: &str| -> Image {
            let v: Vec<f32> = case[k]
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap() as f32)
                .collect();
            Image::from_vec(w, h, 3, v).unwrap()
        };
        let (a, b) = (load("a"), load("b"));
        let got = metrics::ssim_planes(&metrics::planes_of(&a), &metrics::planes_of(&b), w, h);
        let want = case["ssim"].as_f64().unwrap();
        assert!(
            (got - want).abs() < 1e-4,
            "{}: {got} vs {want}",
            case["name"]
        );
    }
}
