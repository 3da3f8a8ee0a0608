//! Range checks of stage keys, through the shipped pipelines and `--set`: a value out of range is
//! refused when the pipeline is built, naming the stage's key and the range.

use gsid::PipelineSpec;

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

/// A pyramid with nothing to run at its levels is refused, naming its sub-list (it was accepted
/// and blended the input's levels back into the input).
#[test]
fn a_pyramid_without_sub_stages_is_refused() {
    let text = "name = \"x\"\n[[stage]]\nkind = \"pyramid\"\nlevels = 2\n";
    let err = PipelineSpec::parse(text, "x.toml")
        .unwrap()
        .build()
        .err()
        .expect("refused")
        .to_string();
    assert!(
        err.contains("x.toml") && err.contains("pyramid.stages"),
        "{err}"
    );
}
