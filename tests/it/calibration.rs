//! ALGORITHM.md §3's calibration table ("what a plain implementation scores"), through the binary:
//! gsid with the table's settings must land within ±0.01 SSIM of every entry on the Mitsuba box.

use crate::score;

use std::path::Path;

const FIXTURE: &str = "fixtures/mitsuba-cornell";
const SPP: [u32; 4] = [1, 4, 16, 64];
const TOLERANCE: f64 = 0.01;

/// (pipeline, σ, SSIM at 1/4/16/64 spp) of the table; σ `None` is the input row.
const TABLE: [(&str, Option<f32>, [f64; 4]); 5] = [
    ("input", None, [0.302, 0.472, 0.680, 0.857]),
    ("sid", Some(0.1), [0.495, 0.742, 0.920, 0.962]),
    ("sid", Some(0.3), [0.706, 0.859, 0.917, 0.932]),
    ("gsid", Some(0.3), [0.569, 0.807, 0.952, 0.983]),
    ("gsid", Some(1.0), [0.767, 0.899, 0.959, 0.976]),
];

/// The table's settings, spelled out so a change to the pipeline files cannot move them.
fn settings(sigma: f32) -> Vec<String> {
    [
        format!("gsid.sigma={sigma}"),
        "gsid.walks=20".into(),
        "gsid.p_min=1e-6".into(),
        "gsid.window=4".into(),
        "gsid.max_steps=64".into(),
        "gsid.tone=\"reinhard\"".into(),
    ]
    .into()
}

#[test]
fn calibration_table_of_the_spec() {
    let tmp = tempfile::tempdir().unwrap();
    let reference = Path::new(FIXTURE).join("reference.exr");
    let mut misses = Vec::new();
    for (pipeline, sigma, expected) in TABLE {
        for (spp, want) in SPP.iter().zip(expected) {
            let set = Path::new(FIXTURE).join(format!("spp{spp}"));
            let got = match sigma {
                None => score::ssim(&set.join("color.exr"), &reference),
                Some(s) => {
                    let out = tmp.path().join(format!("{pipeline}-{s}-{spp}.exr"));
                    score::denoised_ssim(&set, pipeline, &settings(s), &out, &reference)
                }
            };
            let line = format!("{pipeline} σ {sigma:?} {spp} spp: {got:.4} (table {want:.3})");
            eprintln!("{line}");
            if (got - want).abs() > TOLERANCE {
                misses.push(line);
            }
        }
    }
    assert!(
        misses.is_empty(),
        "off the table by more than {TOLERANCE}:\n{}",
        misses.join("\n")
    );
}
