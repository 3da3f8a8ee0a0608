//! The noise estimate (docs/ALGORITHM.md §8) and the blend's keep weights, which every preset runs
//! at full size: pixels per second on a 4 spp fixture.
//!
//! Run: `cargo bench --bench noise`.

use std::path::Path;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use gsid::{condition, io, noise};

fn bench_noise(c: &mut Criterion) {
    let mut set = io::load_render_set(Path::new("fixtures/textured/spp4"))
        .unwrap()
        .set;
    condition::sanitize(Some(&mut set.color), &mut set.features);
    let (color, features) = (&set.color, &set.features);
    let variance = noise::estimate(color, features);
    let (w, h) = color.dims();
    // A stand-in for a filtered image: the input with its noise halved.
    let filtered = gsid::Image::from_fn(w, h, 3, |x, y, k| {
        let (c, v) = (color.at(x, y)[k], variance.at(x, y)[k]);
        c + 0.5 * v.sqrt()
    });
    let mut group = c.benchmark_group(format!("noise, {w}x{h} textured 4 spp"));
    group.throughput(Throughput::Elements((w * h) as u64));
    group.sample_size(30);
    group.bench_function("estimate", |b| b.iter(|| noise::estimate(color, features)));
    group.bench_function("keep_weights", |b| {
        b.iter(|| noise::keep_weights(color, &filtered, &variance, features, 2.0, 4.0))
    });
    group.finish();
}

criterion_group!(benches, bench_noise);
criterion_main!(benches);
