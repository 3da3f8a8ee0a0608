//! The `reliability` stage's gate of each feature buffer: `balanced`'s median centre and `full`'s
//! surface mean, on the albedo, the normals and the depth. Pixels per second on the 4 spp
//! `textured` fixture. The surface mean visits a pulled pixel's whole 7×7 window (or its line), so
//! its cost follows how many pixels its feature's noise pulls: on a receding plane, nearly every
//! depth pixel.
//!
//! Run: `cargo bench --bench reliability`.

mod common;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use gsid::filters::reliability::{gate, Centre, Domain, Params};
use gsid::render_set::Feature;

fn bench_reliability(c: &mut Criterion) {
    let (set, _, _) = common::textured_4spp();
    let (w, h) = set.color.dims();
    let mut group = c.benchmark_group(format!("reliability, {w}x{h} textured 4 spp"));
    group.throughput(Throughput::Elements((w * h) as u64));
    group.sample_size(20);
    for (feature, domain) in [
        (Feature::Albedo, Domain::Linear),
        (Feature::Normal, Domain::Normal),
        (Feature::Depth, Domain::Log),
    ] {
        let img = set
            .features
            .get(feature)
            .expect("the fixture has albedo, normals and depth");
        for (centre, name) in [(Centre::Median, "median"), (Centre::Mean, "mean")] {
            let p = Params {
                radius: 3,
                pair_noise: 2.0,
                centre,
            };
            group.bench_function(format!("{} ({name})", feature.name()), |b| {
                b.iter(|| gate(img, domain, p))
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench_reliability);
criterion_main!(benches);
