//! The pyramid stage: exact reconstruction when untouched, level clipping, per-level keys.

mod common;

use common::synthetic_set;
use gsid::pipeline::PipelineSpec;
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
                .run(&mut b, 0, false)
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
