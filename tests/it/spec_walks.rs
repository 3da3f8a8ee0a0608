//! gsid's random walks against an independent f64 implementation of ALGORITHM.md §2–3, written from
//! the spec alone: its own features, its own RNG, its own log-domain sampling. The two agree when
//! their difference is no larger than Monte Carlo noise; a deliberately wrong copy must not.

use std::path::Path;

use crate::common::{gsid, stderr};
use rand::rngs::Xoshiro256PlusPlus;
use rand::{RngExt, SeedableRng};

/// A float image: `c` interleaved channels, row-major.
#[derive(Clone)]
struct Plane {
    w: usize,
    h: usize,
    c: usize,
    data: Vec<f32>,
}

impl Plane {
    fn at(&self, i: usize) -> &[f32] {
        &self.data[i * self.c..(i + 1) * self.c]
    }

    fn crop(&self, x0: usize, y0: usize, size: usize) -> Plane {
        let mut data = Vec::with_capacity(size * size * self.c);
        for y in y0..y0 + size {
            data.extend_from_slice(
                &self.data[(y * self.w + x0) * self.c..(y * self.w + x0 + size) * self.c],
            );
        }
        Plane {
            w: size,
            h: size,
            c: self.c,
            data,
        }
    }
}

/// The only gsid library calls of this file: EXR files in and out.
mod exr_io {
    use super::Plane;
    use std::path::Path;

    pub fn read(path: &Path, channels: usize) -> Plane {
        let img = gsid::io::read_image(path, channels).unwrap();
        Plane {
            w: img.width(),
            h: img.height(),
            c: channels,
            data: img.data().to_vec(),
        }
    }

    pub fn write(path: &Path, p: &Plane) {
        let img = gsid::Image::from_vec(p.w, p.h, p.c, p.data.clone()).unwrap();
        gsid::io::write_exr(path, &img).unwrap();
    }
}

/// The buffers of ALGORITHM.md §1 and their channel counts.
const BUFFERS: [(&str, usize); 6] = [
    ("color", 3),
    ("albedo", 3),
    ("normal", 3),
    ("material", 3),
    ("shadow", 1),
    ("depth", 1),
];

/// One render set in memory, in `BUFFERS` order.
struct Set(Vec<Plane>);

impl Set {
    fn read_crop(dir: &Path, x0: usize, y0: usize, size: usize) -> Set {
        Set(BUFFERS
            .iter()
            .map(|(name, c)| exr_io::read(&dir.join(format!("{name}.exr")), *c).crop(x0, y0, size))
            .collect())
    }

    fn write(&self, dir: &Path) {
        std::fs::create_dir_all(dir).unwrap();
        for ((name, _), p) in BUFFERS.iter().zip(&self.0) {
            exr_io::write(&dir.join(format!("{name}.exr")), p);
        }
    }
}

/// A change to the independent implementation that must make the comparison fail.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Variant {
    Spec,
    /// Steps guided by d(x0, y) only, without the d(x_j, y) term.
    NoStepTerm,
    /// Weight exp(L_k) instead of the geometric mean exp(L_k / k).
    WeightExpL,
    /// The normal feature switched off.
    NoNormal,
}

/// Walk parameters, as in the pipeline files the comparison runs.
struct Params {
    sigma: f64,
    walks: u32,
    p_min: f64,
    max_steps: u32,
    window: usize,
    weights: [f64; 8],
}

/// Per-pixel features of ALGORITHM.md §2, in f64, with §1's sanitising.
struct Features {
    w: usize,
    h: usize,
    tone: Vec<[f64; 3]>,
    albedo: Vec<[f64; 3]>,
    normal: Vec<[f64; 3]>,
    material: Vec<[f64; 3]>,
    shadow: Vec<f64>,
    depth: Vec<f64>,
    weights: [f64; 8],
}

fn rgb(p: &Plane, i: usize) -> [f64; 3] {
    let v = p.at(i);
    [v[0] as f64, v[1] as f64, v[2] as f64]
}

/// The factor that brings the colour's robust brightness (mean luminance of the pixels at or below
/// the 99th percentile) to 0.072, as gsid does before filtering (docs/HOW_IT_WORKS.md, "Brightness").
/// It only moves the tone curve: averaging is linear and the result is scaled back.
fn exposure(color: &[[f64; 3]]) -> f64 {
    let mut lum: Vec<f64> = color
        .iter()
        .map(|c| 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2])
        .collect();
    lum.sort_by(f64::total_cmp);
    let p99 = lum[((lum.len() - 1) as f64 * 0.99) as usize];
    let kept: Vec<f64> = lum.into_iter().filter(|&l| l <= p99).collect();
    let mean = kept.iter().sum::<f64>() / kept.len() as f64;
    if mean > 0.0 {
        0.072 / mean
    } else {
        1.0
    }
}

impl Features {
    fn new(set: &Set, weights: [f64; 8]) -> Features {
        let [color, albedo, normal, material, shadow, depth] = &set.0[..] else {
            unreachable!()
        };
        let n = color.w * color.h;
        let linear: Vec<[f64; 3]> = (0..n)
            .map(|i| rgb(color, i).map(|v| if v.is_finite() { v.max(0.0) } else { 0.0 }))
            .collect();
        let s = exposure(&linear);
        let normals = (0..n)
            .map(|i| {
                let v = rgb(normal, i);
                let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                assert!(
                    len > 1e-6,
                    "pixel {i}: the crop must hold no unknown normals"
                );
                v.map(|x| x / len)
            })
            .collect();
        let depths: Vec<f64> = (0..n).map(|i| depth.at(i)[0] as f64).collect();
        assert!(
            depths.iter().all(|z| z.is_finite()),
            "the crop must hold no misses"
        );
        Features {
            w: color.w,
            h: color.h,
            tone: linear
                .iter()
                .map(|c| c.map(|v| s * v / (1.0 + s * v)))
                .collect(),
            albedo: (0..n).map(|i| rgb(albedo, i)).collect(),
            normal: normals,
            material: (0..n).map(|i| rgb(material, i)).collect(),
            shadow: (0..n).map(|i| shadow.at(i)[0] as f64).collect(),
            depth: depths,
            weights,
        }
    }

    /// d(i, j) = Σ W_k F_k(i, j).
    fn d(&self, i: usize, j: usize) -> f64 {
        let norm = |a: &[f64; 3], b: &[f64; 3]| {
            ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
        };
        let dot = |a: &[f64; 3], b: &[f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let (zi, zj) = (self.depth[i], self.depth[j]);
        let f = [
            norm(&self.tone[i], &self.tone[j]),
            norm(&self.albedo[i], &self.albedo[j]),
            (1.0 - dot(&self.normal[i], &self.normal[j])) / 2.0,
            (self.material[i][0] - self.material[j][0]).abs(),
            (self.material[i][1] - self.material[j][1]).abs(),
            (self.material[i][2] - self.material[j][2]).abs(),
            (self.shadow[i] - self.shadow[j]).abs(),
            (zi - zj).abs() / zi.max(zj).max(1e-8),
        ];
        f.iter().zip(&self.weights).map(|(f, w)| f * w).sum()
    }
}

/// ALGORITHM.md §3 from every pixel: N walks, log-domain steps, weight exp(L_k/k), Σw·c / Σw.
fn independent_denoise(set: &Set, p: &Params, seed: u64, variant: Variant) -> Vec<f32> {
    let mut weights = p.weights;
    if variant == Variant::NoNormal {
        weights[2] = 0.0;
    }
    let f = Features::new(set, weights);
    let (w, h) = (f.w, f.h);
    let color = &set.0[0];
    let inv = 1.0 / (2.0 * p.sigma * p.sigma);
    let ln_pmin = p.p_min.ln();
    let r = p.window as isize;
    let mut out = Vec::with_capacity(w * h * 3);
    for i0 in 0..w * h {
        let (x0, y0) = ((i0 % w) as isize, (i0 / w) as isize);
        let mut rng =
            Xoshiro256PlusPlus::seed_from_u64(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ i0 as u64);
        let (mut sum, mut wsum) = ([0.0f64; 3], 0.0f64);
        for _ in 0..p.walks {
            let (mut x, mut y) = (x0, y0);
            let mut log_p = 0.0f64;
            for k in 1..=p.max_steps {
                let here = (y * w as isize + x) as usize;
                let mut next: Vec<(usize, f64)> = Vec::with_capacity(8);
                for (dx, dy) in (-1..=1).flat_map(|dy| (-1..=1).map(move |dx| (dx, dy))) {
                    if (dx, dy) == (0, 0) {
                        continue;
                    }
                    let (nx, ny) = (x + dx, y + dy);
                    let inside = nx >= 0 && ny >= 0 && nx < w as isize && ny < h as isize;
                    if !inside || (nx - x0).abs() > r || (ny - y0).abs() > r {
                        continue;
                    }
                    let j = (ny * w as isize + nx) as usize;
                    let d0 = f.d(i0, j);
                    let dj = if variant == Variant::NoStepTerm {
                        0.0
                    } else {
                        f.d(here, j)
                    };
                    next.push((j, -(d0 * d0 + dj * dj) * inv));
                }
                let top = next.iter().map(|n| n.1).fold(f64::NEG_INFINITY, f64::max);
                let z: f64 = next.iter().map(|n| (n.1 - top).exp()).sum();
                let target = rng.random::<f64>() * z;
                let mut cdf = 0.0;
                let pick = next
                    .iter()
                    .find(|n| {
                        cdf += (n.1 - top).exp();
                        target < cdf
                    })
                    .or_else(|| next.iter().max_by(|a, b| a.1.total_cmp(&b.1)))
                    .expect("every pixel has a neighbour in its window");
                log_p += pick.1 - top - z.ln();
                if log_p < ln_pmin {
                    break;
                }
                (x, y) = ((pick.0 % w) as isize, (pick.0 / w) as isize);
                let weight = match variant {
                    Variant::WeightExpL => log_p.exp(),
                    _ => (log_p / k as f64).exp(),
                };
                let c = rgb(color, pick.0);
                for ch in 0..3 {
                    sum[ch] += weight * c[ch];
                }
                wsum += weight;
            }
        }
        let c = rgb(color, i0);
        out.extend((0..3).map(|ch| if wsum > 0.0 { sum[ch] / wsum } else { c[ch] } as f32));
    }
    out
}

/// `gsid denoise` of the set in `dir` with `pipeline`, `walks` walks and `seed`.
fn gsid_denoise(dir: &Path, pipeline: &str, walks: u32, seed: u64) -> Vec<f32> {
    let out = dir.join(format!("out-{pipeline}-{seed}.exr"));
    let run = gsid(&[
        "denoise",
        dir.to_str().unwrap(),
        "--pipeline",
        pipeline,
        "--set",
        &format!("gsid.walks={walks}"),
        "--seed",
        &seed.to_string(),
        "-o",
        out.to_str().unwrap(),
        "-q",
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    exr_io::read(&out, 3).data
}

fn mean_sq_diff(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (*x as f64 - *y as f64).powi(2))
        .sum::<f64>()
        / a.len() as f64
}

/// The report's weights and SID's, as `pipelines/gsid.toml` and `pipelines/sid.toml` set them.
const GSID_WEIGHTS: [f64; 8] = [2.0, 2.0, 3.0, 1.0, 2.0, 1.0, 0.5, 2.0];
const SID_WEIGHTS: [f64; 8] = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];

const WALKS: u32 = 1000;
/// The largest accepted ratio of gsid-vs-independent to run-vs-run mean squared difference.
const BOUND: f64 = 1.5;

/// Whether gsid and the independent implementation agree within Monte Carlo error, and that the
/// check rejects each `wrong` variant.
///
/// The bound: gsid with seeds s1, s2 gives G1, G2, the independent version with two seeds I1, I2.
/// Per pixel, if both estimate the same expectation μ with variances v_G and v_I,
/// E(G − I)² = v_G + v_I = E[((G1 − G2)² + (I1 − I2)²) / 2], while a bias b adds b² to the left side
/// only. Pixels use independent random streams, so each mean over the crop's pixels estimates its
/// expectation to a few percent; 1.5 leaves room for that and for f32 rounding, and a bias of
/// √(v_G + v_I) per pixel already breaks it. 1000 walks make v small, so such a bias is small.
fn check(dir: &Path, set: &Set, pipeline: &str, params: &Params, wrong: &[Variant]) {
    let g = [
        gsid_denoise(dir, pipeline, WALKS, 1),
        gsid_denoise(dir, pipeline, WALKS, 2),
    ];
    let i = [
        independent_denoise(set, params, 11, Variant::Spec),
        independent_denoise(set, params, 12, Variant::Spec),
    ];
    let noise = (mean_sq_diff(&g[0], &g[1]) + mean_sq_diff(&i[0], &i[1])) / 2.0;
    let cross = (mean_sq_diff(&g[0], &i[0]) + mean_sq_diff(&g[1], &i[1])) / 2.0;
    let ratio = cross / noise;
    eprintln!(
        "{pipeline}: gsid vs independent {cross:.3e}, run vs run {noise:.3e}, ratio {ratio:.3}"
    );
    assert!(
        ratio < BOUND,
        "{pipeline}: gsid departs from ALGORITHM.md §2–3 (ratio {ratio:.3})"
    );
    for &variant in wrong {
        let bad = independent_denoise(set, params, 13, variant);
        let ratio = mean_sq_diff(&g[0], &bad) / noise;
        eprintln!("{pipeline}: {variant:?} ratio {ratio:.3}");
        assert!(
            ratio > BOUND,
            "{pipeline}: the check misses {variant:?} (ratio {ratio:.3})"
        );
    }
}

/// A 24×24 crop of the Mitsuba box at 4 spp with the tall block's edge, the floor and a wall.
fn crop_set(dir: &Path) -> Set {
    let set = Set::read_crop(
        Path::new("fixtures/mitsuba-cornell/spp4"),
        CROP.0,
        CROP.1,
        24,
    );
    set.write(dir);
    let f = Features::new(&set, GSID_WEIGHTS);
    let dot = |i: usize, j: usize| (0..3).map(|k| f.normal[i][k] * f.normal[j][k]).sum::<f64>();
    let creases = (0..24 * 23)
        .filter(|&i| dot(i + i / 23, i + i / 23 + 1) < 0.5)
        .count();
    assert!(
        creases >= 10,
        "the crop must hold edges between surfaces, has {creases}"
    );
    eprintln!("crop: {creases} horizontal neighbour pairs across a crease");
    set
}

const CROP: (usize, usize) = (24, 70);

/// The crop through `pipeline` (whose file sets σ and `weights`) and through the independent version.
fn compare(pipeline: &str, sigma: f64, weights: [f64; 8], wrong: &[Variant]) {
    let tmp = tempfile::tempdir().unwrap();
    let set = crop_set(tmp.path());
    let params = Params {
        sigma,
        walks: WALKS,
        p_min: 1e-6,
        max_steps: 64,
        window: 4,
        weights,
    };
    check(tmp.path(), &set, pipeline, &params, wrong);
}

#[test]
fn gsid_walks_match_an_independent_implementation_of_the_spec() {
    compare(
        "gsid",
        1.0,
        GSID_WEIGHTS,
        &[Variant::NoStepTerm, Variant::WeightExpL, Variant::NoNormal],
    );
}

#[test]
fn sid_walks_match_an_independent_implementation_of_the_spec() {
    compare(
        "sid",
        0.1,
        SID_WEIGHTS,
        &[Variant::NoStepTerm, Variant::WeightExpL],
    );
}
