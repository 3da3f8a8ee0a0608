//! Quality on the fixtures, scored by the project's protocol: the Mitsuba Cornell box, the folder
//! fixtures' preset order and `balanced`'s rule on a Blender render. The issue's acceptance orderings;
//! numbers are in README.md.

use std::path::Path;

use gsid::pipeline::PipelineSpec;
use gsid::{io, metrics, DenoiseOptions};

fn ssim_of(pipeline: Option<&str>, spp: u32) -> f64 {
    let dir = format!("fixtures/mitsuba-cornell/spp{spp}");
    let set = io::load_render_set(Path::new(&dir)).unwrap();
    let reference = io::read_image(set.reference.as_ref().unwrap(), 3).unwrap();
    let image = match pipeline {
        None => set.set.color.clone(),
        Some(p) => {
            PipelineSpec::resolve(p)
                .unwrap()
                .build()
                .unwrap()
                .run(&mut set.set.into(), &DenoiseOptions::seeded(0))
                .unwrap()
                .0
        }
    };
    metrics::ssim(&image, &reference).unwrap()
}

#[test]
fn gsid_beats_sid_beats_input_at_16_and_64_spp() {
    for spp in [16, 64] {
        let input = ssim_of(None, spp);
        let sid = ssim_of(Some("sid"), spp);
        let gsid = ssim_of(Some("gsid"), spp);
        assert!(
            gsid > sid && sid > input,
            "spp{spp}: gsid {gsid:.4}, sid {sid:.4}, input {input:.4}"
        );
        if spp == 16 {
            assert!(
                gsid >= input + 0.15,
                "spp16: gsid {gsid:.4} vs input {input:.4}"
            );
        }
    }
}

/// Every fixture with a reference: Mitsuba's and the ones `gsid render` drew.
const FIXTURES: [&str; 5] = [
    "mitsuba-cornell",
    "cornell",
    "caustics",
    "textured",
    "detail",
];

fn scores_of(pipeline: &str, fixture: &str, spp: u32) -> metrics::Scores {
    let dir = format!("fixtures/{fixture}/spp{spp}");
    let set = io::load_render_set(Path::new(&dir)).unwrap();
    let reference = io::read_image(set.reference.as_ref().unwrap(), 3).unwrap();
    let out = PipelineSpec::resolve(pipeline)
        .unwrap()
        .build()
        .unwrap()
        .run(&mut set.set.into(), &DenoiseOptions::seeded(0))
        .unwrap()
        .0;
    metrics::score(&out, &reference).unwrap()
}

#[test]
fn full_beats_single_scale_gsid_at_very_low_spp_and_holds_at_64() {
    for f in FIXTURES {
        for spp in [1, 4] {
            let (full, gsid) = (scores_of("full", f, spp), scores_of("gsid", f, spp));
            assert!(
                full.ssim > gsid.ssim,
                "{f} spp{spp}: SSIM full {:.4} vs gsid {:.4}",
                full.ssim,
                gsid.ssim
            );
            assert!(
                full.relmse < gsid.relmse,
                "{f} spp{spp}: relMSE full {:.5} vs gsid {:.5}",
                full.relmse,
                gsid.relmse
            );
        }
        let (full, gsid) = (scores_of("full", f, 64), scores_of("gsid", f, 64));
        assert!(
            full.ssim >= gsid.ssim - 0.005,
            "{f} spp64: SSIM full {:.4} vs gsid {:.4}",
            full.ssim,
            gsid.ssim
        );
    }
}

/// The presets keep the order they were chosen for (docs/RESULTS.md "Presets"): on the mean over the
/// fixtures at 4 spp more time buys more SSIM (`quality` is `full` with more walks and a wider window,
/// so at least as good); on every fixture `balanced` (2 walks, the prefilter) beats `fast` (1 walk)
/// and every preset is far better than the input. `quality` against `balanced` is only a mean property: on
/// `caustics` the single-scale `balanced` scores 0.002 above it.
#[test]
fn presets_trade_time_for_quality_in_order() {
    let mut means = [0.0f64; 4];
    for f in FIXTURES {
        let input = {
            let dir = format!("fixtures/{f}/spp4");
            let set = io::load_render_set(Path::new(&dir)).unwrap();
            let reference = io::read_image(set.reference.as_ref().unwrap(), 3).unwrap();
            metrics::ssim(&set.set.color, &reference).unwrap()
        };
        let scores = ["fast", "balanced", "full", "quality"].map(|p| scores_of(p, f, 4).ssim);
        let [fast, balanced, _, quality] = scores;
        assert!(
            balanced > fast && fast > input + 0.15 && quality > input + 0.15,
            "{f}: quality {quality:.4}, balanced {balanced:.4}, fast {fast:.4}, input {input:.4}"
        );
        for (m, s) in means.iter_mut().zip(scores) {
            *m += s / FIXTURES.len() as f64;
        }
    }
    let [fast, balanced, full, quality] = means;
    assert!(
        quality >= full && full >= balanced && balanced > fast,
        "means: quality {quality:.4}, full {full:.4}, balanced {balanced:.4}, fast {fast:.4}"
    );
}

/// `balanced` keeps the rule it was chosen by (docs/RESULTS.md "Presets"): within 0.01 SSIM of
/// `quality`, and above `fast`, on a render from a renderer we did not write at its fewest samples
/// (Blender's multilayer file as Blender wrote it, scored as `scripts/compare_denoisers.py` does).
/// Left without its across-edge spread for speed, it broke both there (0.9038 against `quality`'s
/// 0.9181 and `fast`'s 0.9077).
#[test]
fn balanced_stays_within_its_rule_on_a_blender_render_at_1_spp() {
    let tmp = tempfile::tempdir().unwrap();
    let ssim = |preset: &str| {
        let out = tmp.path().join(format!("{preset}.exr"));
        let out = out.to_str().unwrap();
        let args = [
            "denoise",
            "fixtures/cycles-studio/spp1.exr",
            "-p",
            preset,
            "-o",
            out,
            "-q",
        ];
        let run = crate::common::gsid(&args);
        assert_eq!(
            run.status.code(),
            Some(0),
            "{}",
            crate::common::stderr(&run)
        );
        let reference = "fixtures/cycles-studio/reference.exr";
        let run = crate::common::gsid(&["eval", out, "-r", reference, "--json", "-q"]);
        let json = String::from_utf8(run.stdout).unwrap();
        let at = json.find("\"ssim\":").expect("an ssim field") + "\"ssim\":".len();
        let number = json[at..].split([',', '}']).next().unwrap();
        number.trim().parse::<f64>().unwrap()
    };
    let [fast, balanced, quality] = ["fast", "balanced", "quality"].map(ssim);
    assert!(
        balanced >= quality - 0.01 && balanced > fast,
        "quality {quality:.4}, balanced {balanced:.4}, fast {fast:.4}"
    );
}
