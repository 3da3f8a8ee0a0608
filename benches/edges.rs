//! The stages at the end of every preset that read the features per pixel pair or per edge: the
//! spread of the clamp's light back to its surfaces and the coverage stage's edge directions
//! (structure tensor of the feature guide and of the tone-mapped colour). Pixels per second on the
//! 4 spp `textured` fixture.
//!
//! Run: `cargo bench --bench edges`.

mod common;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use gsid::filters::coverage::{colour_guide, normals, Guide};
use gsid::filters::outlier::{spread_light, Guides, SpreadParams};
use gsid::meter::Meter;
use gsid::render_set::Feature;
use gsid::Image;

fn bench_edges(c: &mut Criterion) {
    let (set, variance, filtered) = common::textured_4spp();
    let (color, features) = (&set.color, &set.features);
    let (w, h) = color.dims();
    let mut group = c.benchmark_group(format!("edges, {w}x{h} textured 4 spp"));
    group.throughput(Throughput::Elements((w * h) as u64));
    group.sample_size(30);
    // One pixel in fifty lost light to the clamp: about what it takes from a 4 spp render.
    let light = Image::from_fn(
        w,
        h,
        3,
        |x, y, _| {
            if (y * w + x) % 50 == 0 {
                2.0
            } else {
                0.0
            }
        },
    );
    let guides = Guides {
        albedo: features.get(Feature::Albedo),
        normal: features.get(Feature::Normal),
    };
    let params = SpreadParams::default();
    group.bench_function("spread_light", |b| {
        b.iter(|| {
            let mut out = filtered.clone();
            spread_light(
                &mut out,
                &light,
                &variance,
                &guides,
                &params,
                &Meter::default(),
            );
            out
        })
    });
    let guide = Guide::new(features, (w, h)).expect("the fixture has albedo and normals");
    group.bench_function("normals (features)", |b| b.iter(|| normals(&guide)));
    group.bench_function("normals (colour)", |b| {
        b.iter(|| normals(&colour_guide(&filtered)))
    });
    group.finish();
}

criterion_group!(benches, bench_edges);
criterion_main!(benches);
