//! The noise estimate (docs/ALGORITHM.md §8), the blend's keep weights and the albedo prefilter,
//! which every preset runs at full size: pixels per second on a 4 spp fixture, with the kernel
//! this CPU runs (AVX2 where it has it) and the portable one (the same bits).
//!
//! Run: `cargo bench --bench noise`.

mod common;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use gsid::filters::blend::keep_weights;
use gsid::filters::noise;
use gsid::filters::prefilter::{self, Kind, PrefilterParams};
use gsid::kernels::simd::Kernel;
use gsid::render_set::Feature;

fn bench_noise(c: &mut Criterion) {
    let (set, variance, filtered) = common::textured_4spp();
    let (color, features) = (&set.color, &set.features);
    let (w, h) = color.dims();
    let mut group = c.benchmark_group(format!("noise, {w}x{h} textured 4 spp"));
    group.throughput(Throughput::Elements((w * h) as u64));
    group.sample_size(30);
    let albedo = features
        .get(Feature::Albedo)
        .expect("the fixture has albedo");
    let p = PrefilterParams::default().kernel_params();
    let albedo_variance = prefilter::variance(albedo, Kind::Plain, p.keep);
    for (name, kernel) in [("", Kernel::detect()), (" (portable)", Kernel::Scalar)] {
        group.bench_function(format!("estimate{name}"), |b| {
            b.iter(|| noise::estimate_with(kernel, color, features))
        });
        group.bench_function(format!("keep_weights{name}"), |b| {
            b.iter(|| keep_weights(kernel, color, &filtered, &variance, features, 2.0, 4.0))
        });
        group.bench_function(format!("prefilter variance{name}"), |b| {
            b.iter(|| prefilter::variance_with(kernel, albedo, Kind::Plain, p.keep))
        });
        group.bench_function(format!("prefilter filter{name}"), |b| {
            b.iter(|| prefilter::filter_with(kernel, albedo, &albedo_variance, Kind::Plain, &p))
        });
    }
    group.finish();
}

criterion_group!(benches, bench_noise);
criterion_main!(benches);
