//! Walk kernel throughput, in walk steps per second (docs/ALGORITHM.md §5).
//!
//! Run: `cargo bench --bench walk`. Criterion's "elem/s" is walk steps per second on all threads;
//! the `1 thread` group gives the per-core figure.

use std::path::Path;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use gsid::features::{Features, Tone, Weights};
use gsid::filters::gsid::walk::{self, Engine, FeatureSource, Kernel, WalkJob, WalkParams};
use gsid::{condition, io};

fn bench_walks(c: &mut Criterion) {
    let mut set = io::load_render_set(Path::new("fixtures/mitsuba-cornell/spp4"))
        .unwrap()
        .set;
    condition::sanitize(Some(&mut set.color), &mut set.features);
    let color = &set.color;
    let (features, _) = Features::build(
        color,
        &set.features,
        &Weights::default(),
        Tone::Reinhard,
        1.0,
    )
    .unwrap();
    let params = WalkParams::default();
    let job = |engine| WalkJob {
        engine,
        ..WalkJob::new(color, FeatureSource::Whole(&features), &params)
    };
    let run = |job: &WalkJob| walk::run(job).unwrap();
    let steps = run(&job(Engine::Fast(Kernel::Scalar))).1.steps;

    for threads in [1usize, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let mut group =
            c.benchmark_group(format!("walk kernel, {threads} thread(s), 128x128 gsid"));
        group.throughput(Throughput::Elements(steps));
        group.sample_size(20);
        for kernel in [Kernel::Avx2, Kernel::Scalar] {
            if !kernel.is_available() {
                continue;
            }
            let job = job(Engine::Fast(kernel));
            group.bench_function(format!("fast {kernel:?}"), |b| {
                b.iter(|| pool.install(|| run(&job)))
            });
        }
        if threads == 1 {
            let job = job(Engine::Reference);
            group.bench_function("reference", |b| b.iter(|| run(&job)));
        }
        group.finish();
    }
}

criterion_group!(benches, bench_walks);
criterion_main!(benches);
