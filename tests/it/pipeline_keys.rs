//! Range checks of stage keys, through the shipped pipelines and `--set`: a value out of range is
//! refused when the pipeline is built, naming the stage's key and the range.

use gsid::{DenoiseOptions, Image, PipelineSpec, RenderSet};

/// The notes of `spec` run on a small colour-only image.
fn notes_of(spec: &PipelineSpec) -> Vec<String> {
    let color = Image::from_fn(16, 12, 3, |x, y, c| {
        0.1 + ((x + 2 * y + c) % 5) as f32 * 0.1
    });
    let pipeline = spec.build().unwrap();
    let mut buffers = RenderSet::new(color).into();
    let (_, report) = pipeline
        .run(&mut buffers, &DenoiseOptions::default())
        .unwrap();
    report.notes
}

/// `local_noise` is checked like the other noise keys, in both stages that take it.
#[test]
fn out_of_range_local_noise_is_named() {
    for (stage, value) in [
        ("pyramid.gsid", "-0.5"),
        ("pyramid.gsid", "nan"),
        ("atrous", "5"),
    ] {
        let mut spec = PipelineSpec::builtin("full").unwrap();
        spec.apply_set(&format!("{stage}.local_noise={value}"))
            .unwrap();
        let err = spec.build().err().expect("rejected").to_string();
        assert!(
            err.contains("local_noise") && err.contains("0 to 4"),
            "{stage} = {value}: {err}"
        );
    }
    let mut spec = PipelineSpec::builtin("full").unwrap();
    spec.apply_set("atrous.local_noise=0.5").unwrap();
    assert!(spec.build().is_ok());
}

#[test]
fn out_of_range_factors_are_named() {
    for (key, value) in [
        ("leak", "-1"),
        ("leak", "0"),
        ("tolerance", "nan"),
        ("leak", "1e9"),
    ] {
        let mut spec = PipelineSpec::builtin("full").unwrap();
        spec.apply_set(&format!("blend.{key}={value}")).unwrap();
        let err = spec.build().err().expect("rejected").to_string();
        assert!(
            err.contains(&format!("blend.{key}")) && err.contains("above 0"),
            "{err}"
        );
    }
}

#[test]
fn the_blend_noise_levels_are_quantiles() {
    for key in ["blend.noise_level", "blend.leak_level"] {
        assert_range(
            key,
            &["0", "0.5", "1"],
            &["-0.1", "1.5", "nan"],
            "0 (off) to 1",
        );
    }
}

/// The spread's highlight test takes a significance level, on a single frame and on a stacked
/// one: off at 0, at most one half.
#[test]
fn the_spread_highlights_is_a_significance_level() {
    for key in ["spread.highlights", "spread.stack_highlights"] {
        assert_range(
            key,
            &["0", "0.05"],
            &["-0.01", "0.6", "nan"],
            "0 (off) to 0.5",
        );
    }
}

/// `full` with `key` set to each of `accepted` builds; to each of `rejected` it fails with an
/// error that names the key and its `range`.
fn assert_range(key: &str, accepted: &[&str], rejected: &[&str], range: &str) {
    let build = |value: &str| {
        let mut spec = PipelineSpec::builtin("full").unwrap();
        spec.apply_set(&format!("{key}={value}")).unwrap();
        spec.build()
    };
    for value in rejected {
        let err = build(value).err().expect("rejected").to_string();
        assert!(
            err.contains(key) && err.contains(range),
            "{key} = {value}: {err}"
        );
    }
    for value in accepted {
        assert!(build(value).is_ok(), "{key} = {value}");
    }
}

/// A pyramid with nothing to run at its levels says so (it was accepted silently); it stays
/// allowed, as the identity that tests the split and the blend.
#[test]
fn a_pyramid_without_sub_stages_says_so() {
    let text = "name = \"x\"\n[[stage]]\nkind = \"pyramid\"\nlevels = 2\n";
    let spec = PipelineSpec::parse(text, "x.toml").unwrap();
    let notes = notes_of(&spec);
    assert!(
        notes.iter().any(|n| n.contains("no sub-stages")),
        "{notes:?}"
    );
}

/// `n` stages of one kind, each with its own id.
fn many_stages(n: usize) -> String {
    let mut text = String::from("name = \"many\"\n");
    for k in 0..n {
        text.push_str(&format!("[[stage]]\nkind = \"atrous\"\nid = \"a{k}\"\n"));
    }
    text
}

/// A pipeline file is bounded: at most `MAX_STAGES` stages (a 10 MB file of 171 k stages took 77 s to
/// parse, its ids compared pairwise), sub-lists at most `MAX_NESTING` deep (each level of nested
/// pyramids doubled the memory: 20 levels took 3 GB on an 8×8 image).
#[test]
fn stage_count_and_nesting_are_bounded() {
    use gsid::spec::{MAX_NESTING, MAX_STAGES};
    assert!(PipelineSpec::parse(&many_stages(MAX_STAGES), "m.toml").is_ok());
    for n in [MAX_STAGES + 1, 20_000] {
        let err = PipelineSpec::parse(&many_stages(n), "m.toml")
            .err()
            .unwrap();
        assert!(
            err.to_string()
                .contains(&format!("more than {MAX_STAGES} stages")),
            "{err}"
        );
    }
    // Pyramids nested `depth` deep, each holding the next, the innermost an à-trous pass.
    let nested = |depth: usize| {
        let mut text = String::from("name = \"nest\"\n");
        let mut table = String::from("stage");
        for level in 0..depth {
            text.push_str(&format!(
                "[[{table}]]\nkind = \"pyramid\"\nid = \"p{level}\"\n"
            ));
            table.push_str(".stages");
        }
        text.push_str(&format!("[[{table}]]\nkind = \"atrous\"\n"));
        text
    };
    PipelineSpec::parse(&nested(MAX_NESTING), "n.toml")
        .unwrap()
        .build()
        .unwrap();
    for depth in [MAX_NESTING + 1, 20] {
        let err = PipelineSpec::parse(&nested(depth), "n.toml").err().unwrap();
        assert!(err.to_string().contains("nest deeper"), "{depth}: {err}");
    }
}

/// A noise stage's `reuse` naming a buffer no earlier stage wrote says so (it was accepted silently
/// and measured again).
#[test]
fn reuse_of_a_buffer_nobody_wrote_says_so() {
    let mut spec = PipelineSpec::builtin("full").unwrap();
    spec.apply_set("pyramid.level_noise.reuse=\"nonexistent\"")
        .unwrap();
    let notes = notes_of(&spec);
    assert!(
        notes
            .iter()
            .any(|n| n.contains("`reuse` names buffer `nonexistent`")),
        "{notes:?}"
    );
}

/// The walk budget is the pipeline's: two gsid stages each within it, together beyond it, are
/// refused, naming the figure; a pyramid's coarser levels count by their size.
#[test]
fn the_walk_budget_counts_every_gsid_stage_and_level() {
    let two = |walks: u32| {
        format!(
            "name = \"two\"\n[[stage]]\nkind = \"gsid\"\nid = \"a\"\nwalks = {walks}\nmax_steps = 100\n\
             [[stage]]\nkind = \"gsid\"\nid = \"b\"\ninput = \"out\"\nwalks = {walks}\nmax_steps = 100\n"
        )
    };
    assert!(PipelineSpec::parse(&two(300), "t.toml")
        .unwrap()
        .build()
        .is_ok());
    let err = PipelineSpec::parse(&two(400), "t.toml")
        .unwrap()
        .build()
        .err()
        .expect("80 000 steps a pixel refused")
        .to_string();
    assert!(
        err.contains("80000 steps per pixel") && err.contains("65536"),
        "{err}"
    );
    // 600 × 100 on every level of 3: 60 000 · (1 + 1/4 + 1/16) = 78 750.
    let pyramid = "name = \"p\"\n[[stage]]\nkind = \"pyramid\"\nlevels = 3\n\
                   [[stage.stages]]\nkind = \"gsid\"\nwalks = 600\nmax_steps = 100\n";
    let err = PipelineSpec::parse(pyramid, "p.toml")
        .unwrap()
        .build()
        .err()
        .unwrap();
    assert!(err.to_string().contains("78750 steps per pixel"), "{err}");
}

#[test]
fn out_of_range_coverage_keys_are_named() {
    for (key, value, range) in [
        ("reach", "0", "1 to 4"),
        ("reach", "5", "1 to 4"),
        ("tolerance", "0", "above 0"),
        ("tolerance", "nan", "above 0"),
    ] {
        let mut spec = PipelineSpec::builtin("full").unwrap();
        spec.apply_set(&format!("coverage.{key}={value}")).unwrap();
        let err = spec.build().err().expect("rejected").to_string();
        assert!(
            err.contains(&format!("coverage.{key}")) && err.contains(range),
            "{key} = {value}: {err}"
        );
    }
    // `across` is a switch: a number for it is rejected, naming the key.
    let mut spec = PipelineSpec::builtin("full").unwrap();
    let err = match spec.apply_set("coverage.across=2") {
        Err(e) => e.to_string(),
        Ok(()) => spec.build().err().expect("rejected").to_string(),
    };
    assert!(err.contains("across"), "{err}");
    let mut spec = PipelineSpec::builtin("full").unwrap();
    spec.apply_set("coverage.across=false").unwrap();
    assert!(spec.build().is_ok());
    // So is `colour`.
    let mut spec = PipelineSpec::builtin("full").unwrap();
    let err = match spec.apply_set("coverage.colour=1") {
        Err(e) => e.to_string(),
        Ok(()) => spec.build().err().expect("rejected").to_string(),
    };
    assert!(err.contains("colour"), "{err}");
    // Without albedo or normal no feature edge is followed, only the colour's own, and a note
    // says so; with `colour` off the image passes unchanged.
    let notes = notes_of(&PipelineSpec::builtin("full").unwrap());
    assert!(
        notes
            .iter()
            .any(|n| n.starts_with("coverage: no albedo or normal")
                && n.contains("only the colour's own edges")),
        "{notes:?}"
    );
    let mut spec = PipelineSpec::builtin("full").unwrap();
    spec.apply_set("coverage.colour=false").unwrap();
    let notes = notes_of(&spec);
    assert!(
        notes
            .iter()
            .any(|n| n.starts_with("coverage: no albedo or normal")
                && n.contains("passes unchanged")),
        "{notes:?}"
    );
}

/// `color_guide` and `stack_color_guide` are range-checked, and need the `noise` their patch
/// distances count in.
#[test]
fn out_of_range_color_guide_is_named() {
    for key in ["color_guide", "stack_color_guide"] {
        for value in ["-0.5", "nan", "11"] {
            let mut spec = PipelineSpec::builtin("full").unwrap();
            spec.apply_set(&format!("pyramid.gsid.{key}={value}"))
                .unwrap();
            let err = spec.build().err().expect("rejected").to_string();
            assert!(
                err.contains(key) && err.contains("0 (off) to 10"),
                "{key} {value}: {err}"
            );
        }
        let mut spec = PipelineSpec::builtin("gsid").unwrap();
        spec.apply_set(&format!("gsid.{key}=0.5")).unwrap();
        let err = spec.build().err().expect("rejected").to_string();
        assert!(err.contains(key) && err.contains("noise"), "{err}");
    }
    let mut spec = PipelineSpec::builtin("full").unwrap();
    spec.apply_set("pyramid.gsid.color_guide=0.5").unwrap();
    assert!(spec.build().is_ok());
    notes_of(&spec);
}
