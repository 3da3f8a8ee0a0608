//! The fixture renderer: agreement with Mitsuba 3, energy sanity, reproducibility, effect specialisation,
//! scene-file errors and the render-set layout.

use std::path::{Path, PathBuf};
use std::process::Command;

use gsid::image::Image;
use gsid::io::read_image;
use gsid::render::{render, seed_for, EffectSet, RenderResult, Scene};
use indicatif::ProgressBar;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn scene(name: &str) -> Scene {
    Scene::load(&root().join("fixtures/scenes").join(format!("{name}.toml"))).unwrap()
}

fn scene_text(text: &str) -> Scene {
    Scene::parse(text, Path::new(".")).unwrap()
}

fn draw(scene: &Scene, spp: u32, seed: u64, effects: EffectSet) -> RenderResult {
    render(scene, spp, seed, effects, &ProgressBar::hidden())
}

/// mean over pixels and channels of (x − r)² / (r² + 0.01).
fn rel_mse(x: &Image, r: &Image) -> f64 {
    let n = x.data().len() as f64;
    x.data()
        .iter()
        .zip(r.data())
        .map(|(&a, &b)| ((a - b) as f64).powi(2) / ((b as f64).powi(2) + 0.01))
        .sum::<f64>()
        / n
}

fn mean(x: &Image) -> f64 {
    x.data().iter().map(|&v| v as f64).sum::<f64>() / x.data().len() as f64
}

/// Averages `b`×`b` blocks: compares low frequencies without most of the Monte Carlo noise.
fn block_mean(x: &Image, b: usize) -> Image {
    let (w, h, c) = (x.width() / b, x.height() / b, x.channels());
    Image::from_fn(w, h, c, |i, j, k| {
        let mut s = 0.0;
        for y in j * b..(j + 1) * b {
            for xx in i * b..(i + 1) * b {
                s += x.at(xx, y)[k];
            }
        }
        s / (b * b) as f32
    })
}

#[test]
fn agrees_with_mitsuba_on_the_cornell_box() {
    let s = scene("mitsuba-cornell");
    assert_eq!(
        s.effects,
        EffectSet::default(),
        "a diffuse box needs no effects"
    );
    let ours = draw(&s, 64, 7, s.effects).color;
    let theirs = read_image(&root().join("fixtures/mitsuba-cornell/reference.exr"), 3).unwrap();
    let (m, r) = (mean(&ours), mean(&theirs));
    assert!((m / r - 1.0).abs() < 0.02, "mean {m} vs Mitsuba {r}");
    // Full-resolution relMSE at 64 spp is dominated by our own noise; 8×8 blocks remove most of it.
    let coarse = rel_mse(&block_mean(&ours, 8), &block_mean(&theirs, 8));
    assert!(coarse < 1e-3, "8×8-block relMSE {coarse}");
    let full = rel_mse(&ours, &theirs);
    assert!(full < 0.05, "relMSE {full}");
}

const FURNACE: &str = r#"
[render]
width = 32
height = 32
max_depth = 200
[camera]
eye = [0, 0.5, 4]
target = [0, 0, 0]
fov = 45
[environment]
radiance = 1.0
[materials.white]
type = "diffuse"
reflectance = 1.0
[materials.glass]
type = "dielectric"
ior = 1.5
[[shapes]]
type = "sphere"
material = "white"
translate = [-0.6, 0, 0]
scale = 0.7
[[shapes]]
type = "cube"
material = "white"
translate = [0.7, -0.2, -0.3]
rotate = [10, 30, 0]
scale = 0.5
"#;

#[test]
fn white_furnace_returns_the_environment() {
    let s = scene_text(FURNACE);
    let r = draw(&s, 32, 1, s.effects);
    let m = mean(&r.color);
    assert!((m - 1.0).abs() < 0.01, "furnace mean {m}");
    let worst = r
        .color
        .data()
        .iter()
        .map(|v| (v - 1.0).abs())
        .fold(0.0f32, f32::max);
    assert!(worst < 0.5, "worst pixel off by {worst}");
}

#[test]
fn glass_sphere_neither_gains_nor_loses_energy() {
    let text = FURNACE.replace("material = \"white\"", "material = \"glass\"");
    let s = scene_text(&text);
    assert!(s.effects.refraction);
    let r = draw(&s, 16, 2, s.effects);
    let m = mean(&r.color);
    assert!((m - 1.0).abs() < 0.01, "glass furnace mean {m}");
    assert!(r.stats.refractions > 0);
}

#[test]
fn a_scene_without_glass_never_samples_refraction() {
    let s = scene("cornell");
    assert!(!s.effects.refraction);
    let glass = scene("caustics");
    assert!(glass.effects.refraction && glass.effects.reflection && !glass.effects.textures);
    // The all-effects integrator can refract: it does on glass, so its zero on the box means something.
    assert!(draw(&glass, 1, 3, EffectSet::ALL).stats.refractions > 0);
    for fx in [s.effects, EffectSet::ALL] {
        let r = draw(&s, 2, 3, fx);
        assert_eq!(r.stats.refractions, 0);
        assert!(r.stats.paths == 2 * 128 * 128);
    }
    assert!(draw(&glass, 1, 3, glass.effects).stats.refractions > 0);
    // Glass with refraction switched off: its integrator is counted like any other and must not refract.
    let text = std::fs::read_to_string(root().join("fixtures/scenes/caustics.toml")).unwrap();
    let off = scene_text(&format!("{text}\n[effects]\nrefraction = false\n"));
    assert!(!off.effects.refraction && off.effects.reflection);
    assert_eq!(draw(&off, 1, 3, off.effects).stats.refractions, 0);
}

#[test]
fn caustics_can_be_switched_off() {
    let text = std::fs::read_to_string(root().join("fixtures/scenes/caustics.toml")).unwrap();
    let on = scene_text(&text);
    let off = scene_text(&format!("{text}\n[effects]\ncaustics = false\n"));
    let (a, b) = (draw(&on, 2, 4, on.effects), draw(&off, 2, 4, off.effects));
    assert!(b.stats.refractions < a.stats.refractions);
    assert!(mean(&b.color) < mean(&a.color));
}

#[test]
fn specialised_and_all_effects_integrators_agree() {
    let s = scene("cornell");
    let a = draw(&s, 16, 5, s.effects);
    let b = draw(&s, 16, 6, EffectSet::ALL);
    let (ma, mb) = (mean(&a.color), mean(&b.color));
    assert!((ma / mb - 1.0).abs() < 0.01, "{ma} vs {mb}");
    assert!(rel_mse(&block_mean(&a.color, 8), &block_mean(&b.color, 8)) < 2e-3);
    assert!((mean(&a.albedo) / mean(&b.albedo) - 1.0).abs() < 1e-3);
}

#[test]
fn same_bits_on_any_thread_count() {
    let s = scene("textured");
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let three = rayon::ThreadPoolBuilder::new()
        .num_threads(3)
        .build()
        .unwrap();
    let a = one.install(|| draw(&s, 2, 9, s.effects));
    let b = three.install(|| draw(&s, 2, 9, s.effects));
    for (x, y) in [
        (&a.color, &b.color),
        (&a.normal, &b.normal),
        (&a.shadow, &b.shadow),
        (&a.depth, &b.depth),
    ] {
        assert!(x
            .data()
            .iter()
            .zip(y.data())
            .all(|(p, q)| p.to_bits() == q.to_bits()));
    }
}

fn gsid() -> Command {
    let bin = std::env::var_os("GSID_BIN").unwrap_or_else(|| env!("CARGO_BIN_EXE_gsid").into());
    Command::new(bin)
}

#[test]
fn committed_fixtures_render_again_to_the_same_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    for name in ["cornell", "caustics", "textured", "detail"] {
        let out = tmp.path().join(name);
        let status = gsid()
            .args(["render", "-q", "--spp", "1", "--reference-spp", "0", "-o"])
            .arg(&out)
            .arg(root().join("fixtures/scenes").join(format!("{name}.toml")))
            .status()
            .unwrap();
        assert!(status.success());
        for buffer in ["color", "albedo", "normal", "material", "shadow", "depth"] {
            let file = format!("spp1/{buffer}.exr");
            let fresh = std::fs::read(out.join(&file)).unwrap();
            let committed = std::fs::read(root().join("fixtures").join(name).join(&file)).unwrap();
            assert!(
                fresh == committed,
                "{name}/{file} differs from the committed fixture"
            );
        }
    }
}

#[test]
fn render_writes_the_render_set_layout() {
    let tmp = tempfile::tempdir().unwrap();
    let scene_file = tmp.path().join("small.toml");
    std::fs::write(
        &scene_file,
        FURNACE
            .replace("width = 32", "width = 16")
            .replace("height = 32", "height = 8"),
    )
    .unwrap();
    let out = tmp.path().join("set");
    let status = gsid()
        .args(["render", "-q", "--spp", "1,2", "--reference-spp", "4", "-o"])
        .arg(&out)
        .arg(&scene_file)
        .status()
        .unwrap();
    assert!(status.success());
    assert!(out.join("scene.toml").is_file() && out.join("reference.exr").is_file());
    let s2 = read_image(&out.join("sample_variance.exr"), 3).unwrap();
    assert_eq!((s2.width(), s2.height()), (16, 8));
    for buffer in ["variance", "color_a", "color_b"] {
        assert!(
            !out.join("spp1").join(format!("{buffer}.exr")).exists(),
            "a 1-spp set has no {buffer}"
        );
        let img = read_image(&out.join("spp2").join(format!("{buffer}.exr")), 3).unwrap();
        assert_eq!((img.width(), img.height()), (16, 8));
    }
    for spp in ["spp1", "spp2"] {
        for (buffer, channels) in [
            ("color", 3),
            ("albedo", 3),
            ("normal", 3),
            ("material", 3),
            ("shadow", 1),
            ("depth", 1),
        ] {
            let img = read_image(&out.join(spp).join(format!("{buffer}.exr")), channels).unwrap();
            assert_eq!((img.width(), img.height()), (16, 8));
        }
    }
    // Different sample counts use different seeds.
    assert_ne!(seed_for(0, 1, false), seed_for(0, 2, false));
    assert_ne!(seed_for(0, 4, false), seed_for(0, 4, true));
}

#[test]
fn noise_buffers_are_the_samples_own_statistics() {
    let s = scene("cornell");
    let one = draw(&s, 1, 3, s.effects);
    assert!(one.noise.variance.is_none() && one.noise.halves.is_none());
    assert!(one.sample_variance.is_none());
    for spp in [2, 4] {
        let r = draw(&s, spp, 3, s.effects);
        let variance = r.noise.variance.as_ref().unwrap();
        let s2 = r.sample_variance.as_ref().unwrap();
        let [a, b] = r.noise.halves.as_ref().unwrap();
        for p in 0..r.color.data().len() {
            let (c, a, b) = (r.color.data()[p], a.data()[p], b.data()[p]);
            assert!(
                ((a + b) / 2.0 - c).abs() <= 1e-6 * c.abs().max(1e-3),
                "{spp} spp: the halves' mean {} is not the colour {c}",
                (a + b) / 2.0
            );
            let v = variance.data()[p];
            assert!(v >= 0.0 && (s2.data()[p] / spp as f32 - v).abs() <= 1e-6 * v.max(1e-9));
            if spp == 2 {
                // For two samples s²/N is exactly (a − b)²/4.
                let d = (a - b) * (a - b) / 4.0;
                assert!(
                    (v - d).abs() <= 1e-5 * d.max(1e-9),
                    "variance {v} against {d}"
                );
            }
        }
    }
}

#[test]
fn sample_variance_over_n_is_an_n_spp_renders_noise() {
    // s² from a many-sample render, divided by N, against the variance an N-spp render measures of
    // itself (another seed): the two agree on the image mean. Fireflies make both heavy-tailed.
    let s = scene("cornell");
    let many = draw(&s, 64, 5, s.effects);
    let four = draw(&s, 4, 6, s.effects);
    let truth = mean(many.sample_variance.as_ref().unwrap()) / 4.0;
    let measured = mean(four.noise.variance.as_ref().unwrap());
    assert!(
        (measured / truth - 1.0).abs() < 0.15,
        "measured {measured} against s²/N {truth}"
    );
    // The halves' squared difference estimates the same thing: E[(a − b)²] / 4 = σ² / N.
    let [a, b] = four.noise.halves.as_ref().unwrap();
    let halves = a
        .data()
        .iter()
        .zip(b.data())
        .map(|(&a, &b)| ((a - b) as f64).powi(2) / 4.0)
        .sum::<f64>()
        / a.data().len() as f64;
    assert!(
        (halves / truth - 1.0).abs() < 0.15,
        "halves {halves} against s²/N {truth}"
    );
}

#[test]
fn scene_errors_name_the_key_and_exit_with_2() {
    let tmp = tempfile::tempdir().unwrap();
    for (from, to, key) in [
        ("ior = 1.5", "ior = 0.5", "materials.glass.ior"),
        ("scale = 0.7", "scale = [0.7, 0.2, 0.7]", "shapes[0].scale"),
        ("fov = 45", "fov = 45\nzoom = 2", "zoom"),
        // A non-finite placement dropped the shape without a word.
        (
            "translate = [-0.6, 0, 0]",
            "translate = [nan, 0, 0]",
            "shapes[0].translate",
        ),
        (
            "rotate = [10, 30, 0]",
            "rotate = [10, inf, 0]",
            "shapes[1].rotate",
        ),
        (
            "material = \"white\"",
            "material = \"whit\"",
            "shapes[0].material",
        ),
    ] {
        let file = tmp.path().join("bad.toml");
        std::fs::write(&file, FURNACE.replacen(from, to, 1)).unwrap();
        let out = gsid()
            .args(["render", "-o"])
            .arg(tmp.path().join("o"))
            .arg(&file)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{err}");
        assert!(
            err.contains(key) && err.lines().count() == 1,
            "expected `{key}` in: {err}"
        );
    }
}

#[test]
fn image_textures_and_depth_of_field_render() {
    let tmp = tempfile::tempdir().unwrap();
    let tex = Image::from_fn(4, 4, 3, |x, y, c| [x as f32 / 4.0, y as f32 / 4.0, 0.5][c]);
    gsid::io::write_exr(&tmp.path().join("tex.exr"), &tex).unwrap();
    let text = r#"
[render]
width = 16
height = 16
[camera]
eye = [0, 0, 3]
target = [0, 0, 0]
fov = 30
aperture = 0.05
[environment]
radiance = 0.5
[textures.img]
type = "image"
path = "tex.exr"
[materials.wall]
type = "diffuse"
reflectance = "img"
[[shapes]]
type = "rectangle"
material = "wall"
scale = 2
"#;
    let file = tmp.path().join("scene.toml");
    std::fs::write(&file, text).unwrap();
    let s = Scene::load(&file).unwrap();
    assert!(s.effects.textures && s.effects.depth_of_field && s.effects.environment);
    let r = draw(&s, 4, 1, s.effects);
    assert!(r.color.all_finite());
    // The rectangle fills the view and shows the image upright: columns left to right, row 0 at the top.
    let (left, right) = (r.albedo.at(1, 8)[0], r.albedo.at(14, 8)[0]);
    let (top, bottom) = (r.albedo.at(8, 1)[1], r.albedo.at(8, 14)[1]);
    assert!(
        left < right && top < bottom,
        "{left} {right} {top} {bottom}"
    );
}

/// `render -o` replaces only a folder it wrote (it holds the marker `.gsid-render-set`) or an empty
/// one: a folder of the user's is refused with everything in it kept (it was deleted, exit 0), and
/// so is the working folder (`-o .` failed late and left temporary folders behind).
#[test]
fn render_replaces_only_a_folder_it_wrote() {
    let tmp = tempfile::tempdir().unwrap();
    let scene_file = tmp.path().join("small.toml");
    let small = FURNACE
        .replace("width = 32", "width = 8")
        .replace("height = 32", "height = 4");
    std::fs::write(&scene_file, small).unwrap();
    let render = |out: &Path, cwd: &Path| {
        gsid()
            .current_dir(cwd)
            .args(["render", "-q", "--spp", "1", "--reference-spp", "0", "-o"])
            .arg(out)
            .arg(&scene_file)
            .output()
            .unwrap()
    };
    let mine = tmp.path().join("myrenders");
    std::fs::create_dir_all(mine.join("keepme")).unwrap();
    std::fs::write(mine.join("notes.txt"), "mine").unwrap();
    std::fs::write(mine.join("keepme/a.txt"), "mine too").unwrap();
    let out = render(&mine, tmp.path());
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("myrenders") && err.lines().count() == 1,
        "{err}"
    );
    assert_eq!(
        std::fs::read_to_string(mine.join("notes.txt")).unwrap(),
        "mine"
    );
    assert!(mine.join("keepme/a.txt").is_file());
    // A set it wrote, or an empty folder, is replaced.
    let set = tmp.path().join("set");
    std::fs::create_dir(&set).unwrap();
    for _ in 0..2 {
        let out = render(&set, tmp.path());
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(set.join("spp1/color.exr").is_file() && set.join(".gsid-render-set").is_file());
    }
    // The working folder, even one it wrote.
    let out = render(Path::new("."), &set);
    assert_eq!(
        out.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let litter: Vec<_> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(".gsid-"))
        .collect();
    assert!(litter.is_empty(), "{litter:?}");
    assert!(set.join("spp1/color.exr").is_file());
}
