//! The pyramid stage: exact reconstruction when untouched, level clipping, per-level keys.

use crate::common::synthetic_set;
use gsid::pipeline::PipelineSpec;
use gsid::DenoiseOptions;
use gsid::Image;

fn untouched(levels: u32, domain: &str, guided: bool) -> PipelineSpec {
    let text = format!(
        "name = \"untouched\"\n[[stage]]\nkind = \"pyramid\"\nlevels = {levels}\ndomain = \"{domain}\"\nguided = {guided}\n"
    );
    PipelineSpec::parse(&text, "untouched.toml").unwrap()
}

fn max_rel(a: &Image, b: &Image) -> f32 {
    a.data()
        .iter()
        .zip(b.data())
        .map(|(x, y)| ((x - y) / y.abs().max(1e-3)).abs())
        .fold(0.0, f32::max)
}

#[test]
fn untouched_pyramid_reconstructs_its_input_at_odd_sizes_and_1x1() {
    for (w, h) in [(37, 23), (1, 1), (64, 48), (9, 5)] {
        for (domain, guided) in [("linear", false), ("log", false), ("log", true)] {
            let mut b = synthetic_set(w, h);
            let input = b.get("color").unwrap().clone();
            let (out, report) = untouched(4, domain, guided)
                .build()
                .unwrap()
                .run(&mut b, &DenoiseOptions::seeded(0))
                .unwrap();
            assert!(
                max_rel(&out, &input) < 1e-5,
                "{w}x{h} {domain} {guided}: {}",
                max_rel(&out, &input)
            );
            if w < 32 {
                assert!(
                    report.notes.iter().any(|n| n.contains("allows")),
                    "{w}x{h}: no clipping notice"
                );
            }
        }
    }
}

#[test]
fn per_level_overrides_are_checked() {
    let base = "name = \"p\"\n[[stage]]\nkind = \"pyramid\"\nlevels = 2\n[[stage.stages]]\nkind = \"gsid\"\n";
    let mut spec = PipelineSpec::parse(base, "p.toml").unwrap();
    spec.apply_set("pyramid.level1.gsid.sigma=0.5").unwrap();
    spec.apply_set("pyramid.gsid.walks=4").unwrap();
    spec.build().unwrap();
    let mut bad = PipelineSpec::parse(base, "p.toml").unwrap();
    bad.apply_set("pyramid.level5.gsid.sigma=0.5").unwrap();
    let err = bad.build().err().unwrap().to_string();
    assert!(err.contains("pyramid.level5"), "{err}");
    let mut bad = PipelineSpec::parse(base, "p.toml").unwrap();
    bad.apply_set("pyramid.level1.gsid.sigam=0.5").unwrap();
    let err = bad.build().err().unwrap().to_string();
    assert!(
        err.contains("sigam") && err.contains("pyramid.level1"),
        "{err}"
    );
    let mut bad = PipelineSpec::parse(base, "p.toml").unwrap();
    bad.apply_set("pyramid.levles=3").unwrap();
    assert!(bad.build().err().unwrap().to_string().contains("levles"));
}

/// `gsid::filters::pyramid`'s REDUCE, EXPAND and two-level linear blend: the perturbed-pyramid test's only
/// calls into the module, so a renamed API is adapted here.
mod levels {
    use gsid::filters::pyramid::blend::{blend, BlendDomain};
    use gsid::filters::pyramid::levels::{expand, reduce};
    use gsid::Image;

    pub fn reduce_of(img: &Image) -> Image {
        reduce(img).unwrap()
    }

    pub fn expand_to(img: &Image, w: usize, h: usize) -> Image {
        expand(img, w, h).unwrap()
    }

    pub fn blend_two(fine: &Image, coarse: &Image, guided: bool) -> Image {
        blend(
            vec![fine.clone(), coarse.clone()],
            &[],
            BlendDomain::Linear,
            guided,
            None,
        )
        .unwrap()
    }
}

fn rms_diff(a: &Image, b: &Image) -> f64 {
    let n = a.data().len() as f64;
    (a.data()
        .iter()
        .zip(b.data())
        .map(|(x, y)| ((x - y) as f64).powi(2))
        .sum::<f64>()
        / n)
        .sqrt()
}

/// img − EXPAND(REDUCE(img)): the detail band.
fn detail(img: &Image) -> Image {
    let up = levels::expand_to(&levels::reduce_of(img), img.width(), img.height());
    Image::from_fn(img.width(), img.height(), img.channels(), |x, y, c| {
        img.at(x, y)[c] - up.at(x, y)[c]
    })
}

#[test]
fn blend_takes_low_frequencies_from_a_perturbed_coarse_level_and_detail_from_the_fine() {
    let (w, h) = (64, 48);
    // Fine level: edges (the synthetic set's square) and pixel-scale texture.
    let fine = synthetic_set(w, h).get("color").unwrap().clone();
    let reduced = levels::reduce_of(&fine);
    let (cw, ch) = reduced.dims();
    // Coarse level: REDUCE(fine) plus a smooth, positive offset, as a denoised D_1 would differ.
    let offset = Image::from_fn(cw, ch, 3, |x, y, c| {
        0.3 + 0.2 * ((x as f32 / 6.0 + c as f32).sin() * (y as f32 / 7.0).cos())
    });
    let coarse = Image::from_fn(cw, ch, 3, |x, y, c| {
        reduced.at(x, y)[c] + offset.at(x, y)[c]
    });
    let zero = Image::new(cw, ch, 3);
    let offset_size = rms_diff(&offset, &zero);
    let detail_size = rms_diff(&detail(&fine), &Image::new(w, h, 3));
    for guided in [false, true] {
        let r = levels::blend_two(&fine, &coarse, guided);
        let low = rms_diff(&levels::reduce_of(&r), &coarse);
        assert!(
            low < 0.05 * offset_size,
            "guided {guided}: REDUCE(result) is {low} from the coarse level (offset {offset_size})"
        );
        let band = rms_diff(&detail(&r), &detail(&fine));
        assert!(
            band < 0.1 * detail_size,
            "guided {guided}: detail is {band} from the fine level's (its size {detail_size})"
        );
    }
}
