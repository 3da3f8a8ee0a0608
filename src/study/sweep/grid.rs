//! The sweep's grid: `--vary` axes, and every combination of their values applied to the pipeline
//! and built (all validation before any denoising).

use crate::error::{Error, Result};
use crate::pipeline::Pipeline;
use crate::spec::PipelineSpec;

/// One `--vary` axis: a pipeline key (the syntax `--set` takes) and the values it takes, in order.
#[derive(Clone, Debug, PartialEq)]
pub struct Axis {
    pub key: String,
    pub values: Vec<String>,
}

/// Parses one `--vary KEY=V1,V2,...`. Values are split on commas and trimmed; each is later read as
/// TOML by [`PipelineSpec::apply_set`], so a value cannot itself contain a comma (no TOML arrays).
pub fn parse_axis(arg: &str) -> Result<Axis> {
    let (key, list) = arg.split_once('=').ok_or_else(|| {
        Error::config(
            format!("--vary {arg}"),
            "needs KEY=V1,V2,..., e.g. --vary gsid.walks=5,10,20",
        )
    })?;
    let key = key.trim();
    if key.is_empty() {
        return Err(Error::config(
            format!("--vary {arg}"),
            "the key is empty; give STAGE.PARAM, e.g. gsid.walks",
        ));
    }
    if list.trim().is_empty() {
        return Err(Error::config(
            format!("--vary {key}"),
            "has no values; give V1,V2,... after the `=`",
        ));
    }
    let values: Vec<String> = list.split(',').map(|v| v.trim().to_string()).collect();
    if values.iter().any(|v| v.is_empty()) {
        return Err(Error::config(
            format!("--vary {key}"),
            format!("`{list}` has an empty value (two commas in a row, or one at an end)"),
        ));
    }
    for (i, v) in values.iter().enumerate() {
        if values[..i].contains(v) {
            return Err(Error::config(
                format!("--vary {key}"),
                format!("value `{v}` is listed twice"),
            ));
        }
    }
    Ok(Axis {
        key: key.to_string(),
        values,
    })
}

/// Parses every `--vary`, rejecting a key given twice or also fixed by `--set` (which one would win
/// is not obvious, so neither does).
pub fn parse_axes(varies: &[String], sets: &[String]) -> Result<Vec<Axis>> {
    if varies.is_empty() {
        return Err(Error::config(
            "--vary",
            "give at least one, e.g. --vary gsid.walks=5,10,20",
        ));
    }
    let mut axes: Vec<Axis> = Vec::new();
    for arg in varies {
        let axis = parse_axis(arg)?;
        if axes.iter().any(|a| a.key == axis.key) {
            return Err(Error::config(
                format!("--vary {}", axis.key),
                "is given twice; list all its values in one --vary",
            ));
        }
        let fixed = sets
            .iter()
            .filter_map(|s| s.split_once('=').map(|(k, _)| k.trim()))
            .any(|k| k == axis.key);
        if fixed {
            return Err(Error::config(
                format!("--vary {}", axis.key),
                "is also fixed by --set; drop one of them",
            ));
        }
        axes.push(axis);
    }
    Ok(axes)
}

/// Short names for the axes in labels and the plot: the last segment of each key (`gsid.walks` →
/// `walks`), lengthened from the end only where two keys would otherwise share a name
/// (`level1.gsid.sigma` and `level2.gsid.sigma`).
pub fn short_names(keys: &[String]) -> Vec<String> {
    let parts: Vec<Vec<&str>> = keys.iter().map(|k| k.split('.').collect()).collect();
    let mut take = vec![1usize; keys.len()];
    let name = |i: usize, n: usize| parts[i][parts[i].len().saturating_sub(n)..].join(".");
    loop {
        let names: Vec<String> = (0..keys.len()).map(|i| name(i, take[i])).collect();
        let mut grew = false;
        let mut clash = false;
        for i in 0..keys.len() {
            if (0..keys.len()).any(|j| j != i && names[j] == names[i]) {
                clash = true;
                if take[i] < parts[i].len() {
                    take[i] += 1;
                    grew = true;
                }
            }
        }
        // Distinct keys always separate once written in full; the second test only guards the loop.
        if !clash || !grew {
            return names;
        }
    }
}

/// One point of the sweep: a value for every axis, and the pipeline those values give.
pub struct Setting {
    /// `walks=5 levels=2`: the axes' short names and values.
    pub label: String,
    /// The value of each axis, in axis order.
    pub values: Vec<String>,
    pub spec: PipelineSpec,
    pub pipeline: Pipeline,
    /// What the sweep changed beyond the axes' values (per-level overrides left out), for the user.
    pub notes: Vec<String>,
}

/// Most settings one sweep runs: each is a full pipeline run (times `--repeat`), so a larger grid
/// is a typo, and every setting's spec is built up front.
pub const MAX_SETTINGS: usize = 10_000;

/// Every combination of the axes' values (first axis slowest), each applied to `base` and built.
///
/// All validation happens here, before any denoising. A combination that does not build is reported
/// with the `--vary` value at fault when that value also fails on its own (a bad value, an unknown
/// key), else as a clash of the combination (values fine alone can clash: `pyramid.level2.gsid.sigma`
/// needs `pyramid.levels` of 3 or more). A value is not checked alone first, since a value that needs
/// another axis (that same `level2`) would then be rejected although every combination is valid.
pub fn settings(base: &PipelineSpec, axes: &[Axis]) -> Result<Vec<Setting>> {
    let names = short_names(&axes.iter().map(|a| a.key.clone()).collect::<Vec<_>>());
    let count = axes
        .iter()
        .try_fold(1usize, |n, a| n.checked_mul(a.values.len()))
        .filter(|&n| n <= MAX_SETTINGS)
        .ok_or_else(|| {
            let sizes: Vec<String> = axes.iter().map(|a| a.values.len().to_string()).collect();
            Error::config(
                "--vary",
                format!(
                    "the grid has {} settings, more than the {MAX_SETTINGS} a sweep runs",
                    sizes.join(" × ")
                ),
            )
        })?;
    let mut out = Vec::with_capacity(count);
    for n in 0..count {
        // Mixed-radix digits of n, the last axis fastest.
        let mut digits = vec![0usize; axes.len()];
        let mut rest = n;
        for (d, axis) in digits.iter_mut().zip(axes).rev() {
            *d = rest % axis.values.len();
            rest /= axis.values.len();
        }
        let values: Vec<String> = digits
            .iter()
            .zip(axes)
            .map(|(&d, a)| a.values[d].clone())
            .collect();
        let label = names
            .iter()
            .zip(&values)
            .map(|(k, v)| format!("{k}={v}"))
            .collect::<Vec<_>>()
            .join(" ");
        let assignments: Vec<String> = axes
            .iter()
            .zip(&values)
            .map(|(a, v)| format!("{}={v}", a.key))
            .collect();
        let mut spec = base.clone();
        let mut notes = Vec::new();
        let built = assignments
            .iter()
            .try_for_each(|a| spec.apply_set(a))
            .and_then(|()| {
                notes = drop_missing_levels(&mut spec, axes);
                spec.build()
            });
        let pipeline = match built {
            Ok(p) => p,
            Err(e) => return Err(combination_error(base, axes, &assignments, &label, e)),
        };
        out.push(Setting {
            label,
            values,
            spec,
            pipeline,
            notes,
        });
    }
    Ok(out)
}

/// When `--vary` sets a pyramid's `levels`, drops the pipeline's own per-level overrides (`levelN`)
/// for levels the setting does not have, and says so.
///
/// Without this, `--vary pyramid.levels=1,2,3` on `full` (whose file tunes `level1`) fails at
/// levels=1, since a pyramid rejects overrides of missing levels to catch typos. Overrides that a
/// `--vary` itself gives are kept, so a clash between two axes is still an error.
fn drop_missing_levels(spec: &mut PipelineSpec, axes: &[Axis]) -> Vec<String> {
    let mut notes = Vec::new();
    for axis in axes {
        let Some(id) = axis.key.strip_suffix(".levels") else {
            continue;
        };
        let Some(stage) = spec
            .stages
            .iter_mut()
            .find(|s| s.id == id && s.kind == "pyramid")
        else {
            continue;
        };
        let Some(levels) = stage.params.get("levels").and_then(|v| v.as_integer()) else {
            continue;
        };
        let varied = |key: &str| {
            let prefix = format!("{id}.{key}.");
            axes.iter().any(|a| a.key.starts_with(&prefix))
        };
        let missing: Vec<String> = stage
            .overrides
            .levels
            .iter()
            .filter(|(k, o)| o.level as i64 >= levels && !varied(k))
            .map(|(k, _)| k.clone())
            .collect();
        for key in missing {
            stage.overrides.levels.remove(&key);
            notes.push(format!(
                "{id}.{key} of pipeline {} left out: levels = {levels}",
                spec.name
            ));
        }
    }
    notes
}

/// The one-line error for a combination that does not build, naming the `--vary` value at fault:
/// the first that also fails as the only axis (with the same treatment of missing levels).
fn combination_error(
    base: &PipelineSpec,
    axes: &[Axis],
    assignments: &[String],
    label: &str,
    e: Error,
) -> Error {
    let fails_alone = |(axis, a): &(&Axis, &String)| {
        let mut spec = base.clone();
        spec.apply_set(a)
            .and_then(|()| {
                drop_missing_levels(&mut spec, std::slice::from_ref(*axis));
                spec.build()
            })
            .is_err()
    };
    let culprit = axes.iter().zip(assignments).find(fails_alone);
    let key = match (culprit, assignments.len()) {
        (Some((_, a)), 1) => format!("--vary {a}"),
        (Some((_, a)), _) => format!("--vary {a} (in {label})"),
        (None, _) => format!("--vary combination {label}"),
    };
    Error::config(key, e)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axes_parse_and_reject_bad_forms() {
        let a = parse_axis("gsid.walks= 5, 10 ,20").unwrap();
        assert_eq!(a.key, "gsid.walks");
        assert_eq!(a.values, ["5", "10", "20"]);
        for bad in [
            "gsid.walks",
            "gsid.walks=",
            "=5",
            "gsid.walks=5,,10",
            "gsid.walks=5,",
            "gsid.walks=5,5",
        ] {
            let err = parse_axis(bad).err().unwrap().to_string();
            assert!(err.contains("--vary"), "{bad}: {err}");
            assert_eq!(err.lines().count(), 1);
        }
        let varies = ["gsid.walks=1,2".to_string(), "gsid.walks=3".to_string()];
        let err = parse_axes(&varies, &[]).err().unwrap().to_string();
        assert!(err.contains("gsid.walks") && err.contains("twice"), "{err}");
        let err = parse_axes(&varies[..1], &["gsid.walks=4".to_string()])
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("--set"), "{err}");
        assert!(parse_axes(&[], &[]).is_err());
    }

    #[test]
    fn short_names_lengthen_only_on_a_clash() {
        let keys = |k: &[&str]| k.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert_eq!(
            short_names(&keys(&["gsid.walks", "pyramid.levels"])),
            ["walks", "levels"]
        );
        assert_eq!(
            short_names(&keys(&[
                "pyramid.level1.gsid.sigma",
                "pyramid.level2.gsid.sigma",
                "pyramid.levels"
            ])),
            ["level1.gsid.sigma", "level2.gsid.sigma", "levels"]
        );
        assert_eq!(
            short_names(&keys(&["gsid.walks", "pyramid.gsid.walks"])),
            ["gsid.walks", "pyramid.gsid.walks"]
        );
    }

    #[test]
    fn settings_are_the_product_first_axis_slowest() {
        let base = PipelineSpec::resolve("full").unwrap();
        let axes = vec![
            parse_axis("pyramid.gsid.walks=4,8").unwrap(),
            parse_axis("pyramid.levels=1,2,3").unwrap(),
        ];
        let s = settings(&base, &axes).unwrap();
        let labels: Vec<&str> = s.iter().map(|s| s.label.as_str()).collect();
        assert_eq!(
            labels,
            [
                "walks=4 levels=1",
                "walks=4 levels=2",
                "walks=4 levels=3",
                "walks=8 levels=1",
                "walks=8 levels=2",
                "walks=8 levels=3"
            ]
        );
        assert_eq!(s[4].values, ["8", "2"]);
        let pyramid = s[4].spec.stages.iter().find(|s| s.id == "pyramid").unwrap();
        assert_eq!(pyramid.params["levels"].as_integer(), Some(2));
        assert_eq!(
            pyramid.overrides.every_level["gsid"]["walks"].as_integer(),
            Some(8)
        );
    }

    #[test]
    fn bad_keys_values_and_combinations_are_named_before_any_work() {
        let base = PipelineSpec::resolve("gsid").unwrap();
        for (vary, culprit) in [
            ("gsid.walkz=1,2", "gsid.walkz"),
            ("gsid.walks=4,-1", "gsid.walks=-1"),
            ("gsid.walks=abc", "gsid.walks=abc"),
            ("blur.radius=1", "blur.radius"),
        ] {
            let err = settings(&base, &[parse_axis(vary).unwrap()])
                .err()
                .unwrap()
                .to_string();
            assert!(err.contains(culprit), "{vary}: {err}");
            assert_eq!(err.lines().count(), 1, "{err}");
        }
        // `level2` needs three levels: invalid against the base (two levels) but fine with levels=3 ...
        let full = PipelineSpec::resolve("full").unwrap();
        let mut axes = vec![
            parse_axis("pyramid.levels=3,4").unwrap(),
            parse_axis("pyramid.level2.gsid.sigma=0.5").unwrap(),
        ];
        assert_eq!(settings(&full, &axes).unwrap().len(), 2);
        // ... and named, with the combination, when one combination has two levels.
        axes[0] = parse_axis("pyramid.levels=3,2").unwrap();
        let err = settings(&full, &axes).err().unwrap().to_string();
        assert!(
            err.contains("--vary pyramid.level2.gsid.sigma=0.5 (in levels=2 sigma=0.5)"),
            "{err}"
        );
        // Fine alone, clashing together: named as a combination.
        let axes = [
            parse_axis("pyramid.levels=1,3").unwrap(),
            parse_axis("pyramid.level1.gsid.sigma=0.5").unwrap(),
        ];
        let err = settings(&full, &axes).err().unwrap().to_string();
        assert!(err.contains("combination levels=1 sigma=0.5"), "{err}");
    }

    #[test]
    fn varying_levels_drops_the_files_overrides_of_missing_levels() {
        // `pyramid` tunes level1 (σ 0.25); with one level that override has nothing to apply to.
        let pyramid_spec = PipelineSpec::resolve("pyramid").unwrap();
        let s = settings(&pyramid_spec, &[parse_axis("pyramid.levels=1,2").unwrap()]).unwrap();
        let pyramid = |i: usize| s[i].spec.stages.iter().find(|s| s.id == "pyramid").unwrap();
        assert!(!pyramid(0).overrides.levels.contains_key("level1"));
        assert_eq!(s[0].notes.len(), 1, "{:?}", s[0].notes);
        assert!(s[0].notes[0].contains("pyramid.level1"), "{:?}", s[0].notes);
        assert_eq!(
            pyramid(1).overrides.levels["level1"].stages["gsid"]["sigma"].as_float(),
            Some(0.25)
        );
        assert!(s[1].notes.is_empty());
    }
}
