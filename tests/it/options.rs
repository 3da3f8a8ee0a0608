//! The one set of run options (`DenoiseOptions`): progress is told in order, a cancelled run ends
//! with `Cancelled` and no image, and a thread count changes no bit.

use std::sync::{Arc, Mutex};

use gsid::{Buffers, CancelToken, DenoiseOptions, Error, Feature, Image, PipelineSpec, RenderSet};

/// A small noisy set with albedo and normals.
fn buffers() -> Buffers {
    let (w, h) = (33, 21);
    let noisy: Vec<f32> = (0..w * h * 3)
        .map(|i| 0.2 + 0.3 * ((i * 7919 % 17) as f32 / 17.0))
        .collect();
    let albedo = vec![0.7; w * h * 3];
    let normal: Vec<f32> = (0..w * h).flat_map(|_| [0.0, 0.0, 1.0]).collect();
    let set = RenderSet::new(Image::from_vec(w, h, 3, noisy).unwrap())
        .with(Feature::Albedo, Image::from_vec(w, h, 3, albedo).unwrap())
        .unwrap()
        .with(Feature::Normal, Image::from_vec(w, h, 3, normal).unwrap())
        .unwrap();
    Buffers::from(set)
}

#[test]
fn progress_is_told_stage_by_stage_in_order_and_ends_at_one() {
    let pipeline = PipelineSpec::builtin("full").unwrap().build().unwrap();
    let seen = Arc::new(Mutex::new(Vec::<(f32, String)>::new()));
    let sink = seen.clone();
    let options = DenoiseOptions {
        progress: Some(Arc::new(move |f, stage: &str| {
            sink.lock().unwrap().push((f, stage.to_string()))
        })),
        ..DenoiseOptions::seeded(3)
    };
    pipeline.run(&mut buffers(), &options).unwrap();
    let seen = seen.lock().unwrap();
    // Every stage is told as it begins, at the start of its share, in order; calls within a
    // stage name it and stay inside its share.
    let ids: Vec<&str> = pipeline.stages.iter().map(|s| s.id()).collect();
    let count = ids.len() as f32;
    let mut next = 0;
    for (f, stage) in seen.iter().take(seen.len() - 1) {
        if next < ids.len() && *stage == ids[next] && *f == next as f32 / count {
            next += 1;
            continue;
        }
        assert!(
            next > 0 && *stage == ids[next - 1],
            "{stage} at {f}: {seen:?}"
        );
        assert!(*f < next as f32 / count, "{stage} at {f}: {seen:?}");
    }
    assert_eq!(next, ids.len(), "{seen:?}");
    assert!(seen.windows(2).all(|w| w[0].0 <= w[1].0), "{seen:?}");
    assert_eq!(seen[0].0, 0.0);
    assert_eq!(*seen.last().unwrap(), (1.0, "done".to_string()));
}

/// A 128² frame: big enough that the heavy stages tell progress from within.
fn larger_buffers() -> Buffers {
    let (w, h) = (128, 128);
    let noisy: Vec<f32> = (0..w * h * 3)
        .map(|i| 0.2 + 0.3 * ((i * 7919 % 17) as f32 / 17.0))
        .collect();
    let albedo: Vec<f32> = (0..w * h * 3)
        .map(|i| 0.3 + 0.4 * ((i / 3 / w) % 2) as f32)
        .collect();
    let set = RenderSet::new(Image::from_vec(w, h, 3, noisy).unwrap())
        .with(Feature::Albedo, Image::from_vec(w, h, 3, albedo).unwrap())
        .unwrap();
    Buffers::from(set)
}

#[test]
fn the_heavy_stages_tell_progress_from_within() {
    let pipeline = PipelineSpec::builtin("full").unwrap().build().unwrap();
    let seen = Arc::new(Mutex::new(Vec::<(f32, String)>::new()));
    let sink = seen.clone();
    let options = DenoiseOptions {
        progress: Some(Arc::new(move |f, stage: &str| {
            sink.lock().unwrap().push((f, stage.to_string()))
        })),
        ..DenoiseOptions::seeded(3)
    };
    pipeline.run(&mut larger_buffers(), &options).unwrap();
    let seen = seen.lock().unwrap();
    for stage in ["prefilter", "noise", "pyramid", "regress"] {
        let within = seen.iter().filter(|(_, s)| s == stage).count();
        assert!(within > 2, "{stage}: {within} calls; {seen:?}");
    }
    assert!(seen.windows(2).all(|w| w[0].0 <= w[1].0), "{seen:?}");
}

/// A pyramid with no sub-stages: its only rows told are those of the blend of its levels.
const PYRAMID_BLEND_ONLY: &str = r#"
name = "pyramid-blend"
[[stage]]
kind = "pyramid"
levels = 2
domain = "log"
guided = true
clamp_radius = 1
"#;

#[test]
fn a_cancel_inside_a_stage_stops_its_rows() {
    // One thread: once a row loop sees the cancel, no further row is done or told; a stage of
    // short passes stops at the next one.
    let cases = [
        ("gsid", "gsid"),
        ("full", "prefilter"),
        ("full", "regress"),
        // The surface-mates' rows (`window_bits`), the first rows of both.
        ("full", "noise"),
        ("full", "blend"),
        ("full", "reliability"),
        ("full", "atrous"),
        (PYRAMID_BLEND_ONLY, "pyramid"),
    ];
    for (pipeline, stage) in cases {
        let spec = match PipelineSpec::builtin(pipeline) {
            Ok(spec) => spec,
            Err(_) => PipelineSpec::parse(pipeline, "test").unwrap(),
        };
        let pipeline = spec.build().unwrap();
        let cancel = CancelToken::new();
        let trigger = cancel.clone();
        let start = pipeline
            .stages
            .iter()
            .position(|s| s.id() == stage)
            .unwrap();
        let share = start as f32 / pipeline.stages.len() as f32;
        let after = Arc::new(Mutex::new(Vec::<(f32, String)>::new()));
        let sink = after.clone();
        let options = DenoiseOptions {
            threads: Some(1),
            progress: Some(Arc::new(move |f, s: &str| {
                if trigger.is_cancelled() {
                    sink.lock().unwrap().push((f, s.to_string()));
                } else if s == stage && f > share {
                    trigger.cancel();
                }
            })),
            cancel: Some(cancel.clone()),
            ..DenoiseOptions::default()
        };
        let err = pipeline.run(&mut larger_buffers(), &options).err();
        assert!(cancel.is_cancelled(), "{stage}: never told from within");
        assert!(matches!(err, Some(Error::Cancelled)), "{err:?}");
        assert_eq!(*after.lock().unwrap(), [], "{stage}");
    }
}

#[test]
fn a_cancelled_run_ends_with_cancelled_and_no_image() {
    let pipeline = PipelineSpec::builtin("full").unwrap().build().unwrap();
    // Cancelled before the run: no stage runs.
    let cancel = CancelToken::new();
    cancel.cancel();
    let options = DenoiseOptions {
        cancel: Some(cancel),
        ..DenoiseOptions::default()
    };
    let err = pipeline.run(&mut buffers(), &options).err().unwrap();
    assert!(matches!(err, Error::Cancelled), "{err}");
    // Cancelled from the progress callback once the second stage is about to run.
    let cancel = CancelToken::new();
    let trigger = cancel.clone();
    let second = pipeline.stages[1].id().to_string();
    let options = DenoiseOptions {
        progress: Some(Arc::new(move |_, stage: &str| {
            if stage == second {
                trigger.cancel()
            }
        })),
        cancel: Some(cancel),
        ..DenoiseOptions::default()
    };
    let mut b = buffers();
    let err = pipeline.run(&mut b, &options).err().unwrap();
    assert!(matches!(err, Error::Cancelled), "{err}");
    assert!(b.get("out").is_none());
}

#[test]
fn a_thread_count_changes_no_bit_and_is_checked() {
    let pipeline = PipelineSpec::builtin("balanced").unwrap().build().unwrap();
    let run = |threads| {
        let options = DenoiseOptions {
            threads,
            ..DenoiseOptions::seeded(11)
        };
        pipeline.run(&mut buffers(), &options).unwrap().0
    };
    let one = run(Some(1));
    assert_eq!(one.data(), run(Some(3)).data());
    assert_eq!(one.data(), run(None).data());
    let options = DenoiseOptions {
        threads: Some(0),
        ..DenoiseOptions::default()
    };
    let err = pipeline.run(&mut buffers(), &options).err().unwrap();
    assert!(err.to_string().contains("threads"), "{err}");
}
