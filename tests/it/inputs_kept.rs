//! No run writes over its own inputs: a folder of render sets whose output folder is one of the
//! sets (or inside one) is refused before any work, whatever the sets are called.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::common::*;
use proptest::prelude::*;

/// Every file under `root` with its bytes.
fn snapshot(root: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else {
                out.insert(path.clone(), std::fs::read(&path).unwrap());
            }
        }
    }
    out
}

/// A folder `renders/` holding one small render set per name.
fn sets(root: &Path, names: &[&str]) -> PathBuf {
    let renders = root.join("renders");
    for name in names {
        write_set(&renders.join(name), &synthetic_set(8, 6));
    }
    renders
}

/// `gsid denoise RENDERS -o TARGET -p fast`.
fn denoise_sets(renders: &Path, target: &Path) -> std::process::Output {
    gsid(&[
        "denoise",
        renders.to_str().unwrap(),
        "-o",
        target.to_str().unwrap(),
        "-p",
        "fast",
    ])
}

/// The reported case: a set named like a buffer (`color`) beside the set the output goes into.
#[test]
fn a_folder_of_sets_is_never_written_into_one_of_its_sets() {
    let tmp = tempfile::tempdir().unwrap();
    let renders = sets(tmp.path(), &["color", "setA"]);
    let before = snapshot(&renders);
    let target = renders.join("setA");
    let out = denoise_sets(&renders, &target);
    assert_bad_input(&out, "setA");
    assert!(
        stderr(&out).contains("refusing to write over an input"),
        "{}",
        stderr(&out)
    );
    assert_eq!(snapshot(&renders), before, "no file written or changed");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// Random sets (some named like buffers) and an output folder anywhere among them: a run
    /// either writes only new files outside every set, or is refused having written nothing.
    #[test]
    fn no_input_file_is_ever_written(
        names in proptest::sample::subsequence(
            vec!["color", "albedo", "normal", "depth", "setA", "setB"], 1..=4),
        pick in 0usize..4,
        inside in any::<bool>(),
    ) {
        let tmp = tempfile::tempdir().unwrap();
        let renders = sets(tmp.path(), &names);
        let before = snapshot(&renders);
        let mut target = match pick {
            0 => renders.clone(),
            1 => tmp.path().join("out"),
            _ => renders.join(names[pick % names.len()]),
        };
        if inside {
            target = target.join("sub");
        }
        let out = denoise_sets(&renders, &target);
        let after = snapshot(&renders);
        for (path, bytes) in &before {
            prop_assert_eq!(after.get(path), Some(bytes), "{} changed", path.display());
        }
        for path in after.keys().filter(|p| !before.contains_key(*p)) {
            let in_a_set = names.iter().any(|n| path.starts_with(renders.join(n)));
            prop_assert!(!in_a_set, "{} written inside an input set", path.display());
        }
        if out.status.code() == Some(2) {
            prop_assert_eq!(after.len(), before.len(), "refused, yet wrote: {}", stderr(&out));
        } else {
            prop_assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
        }
    }
}

/// A folder of render sets goes into a folder: `-o out.exr` is refused (it made a folder named
/// `out.exr` holding the images).
#[test]
fn a_folder_of_sets_refuses_an_image_file_as_its_output() {
    let tmp = tempfile::tempdir().unwrap();
    let renders = sets(tmp.path(), &["setA", "setB"]);
    let target = tmp.path().join("out.exr");
    let out = denoise_sets(&renders, &target);
    assert_bad_input(&out, "out.exr");
    assert!(!target.exists());
}
