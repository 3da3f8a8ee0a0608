//! How long a cancelled run takes to return, cancelled at points spread over the whole run: the
//! worst case is what a user pressing Esc waits for, and the stage it happened in says where a
//! row check is missing.
//!
//! `cargo run --release --example cancel_latency -- [SIZE] [PIPELINE] [POINTS]`
//! (default 1024 full 24) prints one line per cancel point and the median and worst latency.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use gsid::{Buffers, CancelToken, DenoiseOptions, Error, Feature, Image, PipelineSpec, RenderSet};

/// A noisy frame with albedo, normal and depth: smooth shading, two materials, hashed noise.
fn frame(n: usize) -> Buffers {
    let noise = |i: usize| ((i.wrapping_mul(2_654_435_761) >> 7) % 1000) as f32 / 1000.0 - 0.5;
    let color = Image::from_fn(n, n, 3, |x, y, c| {
        let (u, v) = (x as f32 / n as f32, y as f32 / n as f32);
        let base = 0.5 + 0.4 * (u * 20.0 + c as f32).sin() * (v * 13.0).cos();
        (base + 0.3 * noise((y * n + x) * 3 + c)).max(0.0)
    });
    let albedo = Image::from_fn(
        n,
        n,
        3,
        |x, y, _| if (x / 64 + y / 64) % 2 == 0 { 0.8 } else { 0.3 },
    );
    let normal = Image::from_fn(n, n, 3, |_, _, c| [0.0, 0.0, 1.0][c]);
    let depth = Image::from_fn(n, n, 1, |x, _, _| 1.0 + x as f32 / n as f32);
    let set = RenderSet::new(color)
        .with(Feature::Albedo, albedo)
        .and_then(|s| s.with(Feature::Normal, normal))
        .and_then(|s| s.with(Feature::Depth, depth))
        .expect("buffers of one size");
    Buffers::from(set)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let size: usize = args.first().map_or(1024, |s| s.parse().expect("SIZE"));
    let name = args.get(1).map_or("full", String::as_str);
    let points: usize = args.get(2).map_or(24, |s| s.parse().expect("POINTS"));
    let pipeline = PipelineSpec::builtin(name)
        .expect("a built-in pipeline")
        .build()
        .expect("builds");
    let start = Instant::now();
    let (_, report) = pipeline
        .run(&mut frame(size), &DenoiseOptions::default())
        .expect("runs");
    let whole = start.elapsed();
    println!(
        "{name} at {size}²: {:.2} s uncancelled",
        whole.as_secs_f64()
    );
    for stage in &report.stages {
        println!(
            "  {:>6.0} ms {} (level {})",
            stage.seconds * 1e3,
            stage.id,
            stage.level
        );
    }
    let mut latencies = Vec::new();
    for k in 0..points {
        let at = whole.mul_f64((k as f64 + 0.5) / points as f64);
        let cancel = CancelToken::new();
        let stage = Arc::new(Mutex::new(String::new()));
        let sink = stage.clone();
        let options = DenoiseOptions {
            cancel: Some(cancel.clone()),
            progress: Some(Arc::new(move |_, s: &str| {
                *sink.lock().unwrap() = s.to_string()
            })),
            ..DenoiseOptions::default()
        };
        let mut buffers = frame(size);
        let (latency, what) = std::thread::scope(|s| {
            let run = s.spawn(|| pipeline.run(&mut buffers, &options).map(|_| ()));
            std::thread::sleep(at);
            let what = stage.lock().unwrap().clone();
            let t0 = Instant::now();
            cancel.cancel();
            let result = run.join().expect("no panic");
            let latency = t0.elapsed();
            match result {
                Err(Error::Cancelled) => (latency, what),
                Ok(()) => (Duration::ZERO, format!("{what} (finished first)")),
                Err(e) => panic!("{e}"),
            }
        });
        println!(
            "cancel at {:5.2} s in {what:<12} returned after {:4.0} ms",
            at.as_secs_f64(),
            latency.as_secs_f64() * 1e3
        );
        latencies.push(latency);
    }
    latencies.sort();
    println!(
        "median {:.0} ms, worst {:.0} ms over {points} points",
        latencies[points / 2].as_secs_f64() * 1e3,
        latencies[points - 1].as_secs_f64() * 1e3
    );
}
