//! Effect specialisation pays: the diffuse Cornell box through its own integrator vs the all-effects one.
//! Both draw the same picture (the image means are printed once, to check).

use std::path::Path;

use criterion::{criterion_group, criterion_main, Criterion};
use gsid::render::{render, EffectSet, Scene};
use indicatif::ProgressBar;

fn mean(data: &[f32]) -> f64 {
    data.iter().map(|&v| v as f64).sum::<f64>() / data.len() as f64
}

fn bench_specialisation(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/scenes/cornell.toml");
    let scene = Scene::load(&path).expect("fixtures/scenes/cornell.toml");
    let bar = ProgressBar::hidden();
    let spp = 4;
    for (name, fx) in [
        ("specialised", scene.effects),
        ("all_effects", EffectSet::ALL),
    ] {
        let r = render(&scene, 64, 1, fx, &bar);
        eprintln!(
            "cornell {name}: image mean at 64 spp {:.5}",
            mean(r.color.data())
        );
    }
    let mut group = c.benchmark_group("render_cornell_128x128_4spp");
    group.sample_size(20);
    group.bench_function("specialised", |b| {
        b.iter(|| render(&scene, spp, 1, scene.effects, &bar))
    });
    group.bench_function("all_effects", |b| {
        b.iter(|| render(&scene, spp, 1, EffectSet::ALL, &bar))
    });
    group.finish();
}

criterion_group!(benches, bench_specialisation);
criterion_main!(benches);
