//! The `regress` stage's kernel (docs/ALGORITHM.md §9): the first-order fit and the mix, pixels
//! per second on a 4 spp fixture, with every kernel this CPU runs (portable, AVX2, AVX-512; the
//! same bits), at the presets' radius and a smaller one.
//!
//! Run: `cargo bench --bench regress`.

mod common;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use gsid::filters::regress::{self, RegressParams};
use gsid::kernels::simd::Kernel;
use gsid::render_set::Feature;

fn bench_regress(c: &mut Criterion) {
    let (set, variance, filtered) = common::textured_4spp();
    let (color, features) = (&set.color, &set.features);
    let (w, h) = color.dims();
    let inputs = regress::Inputs {
        noisy: color,
        filtered: &filtered,
        variance: &variance,
        albedo: features.get(Feature::Albedo),
        normal: features.get(Feature::Normal),
    };
    let mut group = c.benchmark_group(format!("regress, {w}x{h} textured 4 spp"));
    group.throughput(Throughput::Elements((w * h) as u64));
    group.sample_size(30);
    let preset = RegressParams::default().kernel_params();
    for radius in [preset.radius, 4] {
        let p = regress::Params {
            radius,
            ..preset.clone()
        };
        for kernel in Kernel::ALL.into_iter().filter(|k| k.is_available()) {
            group.bench_function(format!("radius {radius} {kernel:?}"), |b| {
                b.iter(|| regress::refine_with(kernel, inputs, &p))
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench_regress);
criterion_main!(benches);
