//! Unidirectional path tracing with next-event estimation and MIS (power heuristic), Russian roulette,
//! and per-pixel random streams; one function per effect set (see `effects`), rayon over tiles.
//!
//! Depth follows Mitsuba: `max_depth` 1 shows only lights seen directly, each further unit adds a bounce.

use std::time::Instant;

use indicatif::ProgressBar;
use rand::rngs::Xoshiro256PlusPlus;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

use super::effects::{select, EffectSet, Effects, Select};
use super::light::Light;
use super::material::{material_weights, Material};
use super::math::{mis_power, Frame, Vec3};
use super::scene::Scene;
use super::shapes::{spawn, NO_LIGHT};

use crate::image::Image;
use crate::render_set::NoiseInputs;

/// One random stream per pixel, seeded from (render seed, pixel index): results do not depend on scheduling.
pub struct Sampler(Xoshiro256PlusPlus);

impl Sampler {
    pub fn for_pixel(seed: u64, pixel: u64) -> Self {
        Sampler(Xoshiro256PlusPlus::seed_from_u64(mix(
            seed ^ mix(pixel.wrapping_add(0x5851_F42D_4C95_7F2D))
        )))
    }

    /// Uniform in [0, 1) with 24 bits.
    #[inline]
    pub fn next_f32(&mut self) -> f32 {
        (self.0.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }
}

/// SplitMix64 (the walks' own): spreads nearby integers over the whole seed space.
pub use crate::filters::gsid::walk::rng::splitmix as mix;

/// What one camera path contributes to the six buffers.
#[derive(Clone, Copy, Debug)]
pub struct PathSample {
    pub color: Vec3,
    pub albedo: Vec3,
    pub normal: Vec3,
    pub material: Vec3,
    pub shadow: f32,
    /// Distance to the first hit; `None` for a miss.
    pub depth: Option<f32>,
}

/// Counters a render returns, to show what it simulated.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Stats {
    pub paths: u64,
    /// Refraction events sampled (glass transmissions).
    pub refractions: u64,
}

impl Stats {
    fn add(&mut self, o: &Stats) {
        self.paths += o.paths;
        self.refractions += o.refractions;
    }
}

/// The path tracer compiled for one effect set.
pub type TraceFn = fn(&Scene, f32, f32, &mut Sampler, &mut Stats) -> PathSample;

struct TraceSelect;

impl Select for TraceSelect {
    type Out = TraceFn;
    fn get<E: Effects>() -> TraceFn {
        trace::<E>
    }
}

/// The integrator specialised to `effects`.
pub fn integrator(effects: EffectSet) -> TraceFn {
    select::<TraceSelect>(effects)
}

#[inline]
fn light_pdf<E: Effects>(scene: &Scene, light: &Light, p: Vec3, wi: Vec3, t: f32) -> f32 {
    let pdf = light.pdf(&scene.geometry, p, wi, t);
    if E::SEVERAL_LIGHTS {
        pdf / scene.lights.len() as f32
    } else {
        pdf
    }
}

/// Traces one camera path through image position (`x`, `y`) (pixels, fractional).
pub fn trace<E: Effects>(
    scene: &Scene,
    x: f32,
    y: f32,
    rng: &mut Sampler,
    stats: &mut Stats,
) -> PathSample {
    stats.paths += 1;
    let lens = if E::DOF {
        (rng.next_f32(), rng.next_f32())
    } else {
        (0.0, 0.0)
    };
    let mut ray = scene.camera.ray(x, y, lens, E::DOF);
    let mut out = PathSample {
        color: Vec3::ZERO,
        albedo: Vec3::ZERO,
        normal: Vec3::ZERO,
        material: Vec3::ZERO,
        shadow: 1.0,
        depth: None,
    };
    let mut beta = Vec3::ONE;
    let mut radiance = Vec3::ZERO;
    let mut prev_pdf = 0.0f32;
    let mut prev_delta = true;
    let mut prev_p = ray.o;
    let mut eta_scale = 1.0f32;
    let mut smooth_bounce = false;
    let mut depth = 0u32;
    loop {
        let Some((prim, t)) = scene.geometry.intersect(&ray, f32::INFINITY) else {
            if E::ENVIRONMENT {
                if let Some(env) = scene.environment {
                    let light = &scene.lights[env];
                    let w = if prev_delta {
                        1.0
                    } else {
                        mis_power(
                            prev_pdf,
                            light_pdf::<E>(scene, light, prev_p, ray.d, f32::INFINITY),
                        )
                    };
                    radiance += beta * light.emitted(Vec3::ZERO, ray.d) * w;
                }
            }
            break;
        };
        let surf = scene.geometry.surface(prim, &ray, t, E::TEXTURES);
        if surf.light != NO_LIGHT {
            let light = &scene.lights[surf.light as usize];
            let le = light.emitted(surf.n, ray.d);
            if !le.is_black() {
                let w = if prev_delta {
                    1.0
                } else {
                    mis_power(prev_pdf, light_pdf::<E>(scene, light, prev_p, ray.d, t))
                };
                radiance += beta * le * w;
            }
        }
        let mat = &scene.materials[surf.material as usize];
        let albedo = match mat {
            Material::Diffuse { reflectance: tex } | Material::Plastic { base: tex, .. } => {
                tex.eval(&scene.textures, surf.uv, E::TEXTURES)
            }
            Material::Conductor { color, .. } => *color,
            Material::Dielectric { .. } => Vec3::ONE,
            Material::Black => Vec3::ZERO,
        };
        let frame = Frame::new(surf.n);
        let wo = frame.to_local(-ray.d);
        if depth == 0 {
            out.albedo = albedo;
            out.normal = surf.n;
            out.material = material_weights(mat, wo.z);
            out.depth = Some(t);
        }
        if depth + 1 >= scene.max_depth {
            break;
        }
        if E::REFRACTION
            && !scene.caustics
            && smooth_bounce
            && matches!(mat, Material::Dielectric { .. })
        {
            break;
        }

        // Next-event estimation: one light sample.
        if mat.has_smooth_lobe::<E>() && !scene.lights.is_empty() {
            let (index, select_pdf) = if E::SEVERAL_LIGHTS {
                let n = scene.lights.len();
                (
                    ((rng.next_f32() * n as f32) as usize).min(n - 1),
                    1.0 / n as f32,
                )
            } else {
                (0, 1.0)
            };
            let light = &scene.lights[index];
            let u = (rng.next_f32(), rng.next_f32());
            let mut reached = false;
            if let Some(ls) = light.sample(&scene.geometry, surf.p, u) {
                if !ls.radiance.is_black()
                    && ls.pdf > 0.0
                    && !scene
                        .geometry
                        .occluded_towards(surf.p, surf.n, ls.wi, ls.dist)
                {
                    reached = true;
                    let (f, bsdf_pdf) = mat.eval::<E>(albedo, wo, frame.to_local(ls.wi));
                    if !f.is_black() {
                        let pdf = ls.pdf * select_pdf;
                        radiance += beta * f * ls.radiance * (mis_power(pdf, bsdf_pdf) / pdf);
                    }
                }
            }
            if depth == 0 {
                out.shadow = if reached { 1.0 } else { 0.0 };
            }
        }

        let u = [rng.next_f32(), rng.next_f32(), rng.next_f32()];
        let Some(bs) = mat.sample::<E>(albedo, wo, u) else {
            break;
        };
        // Not gated on E::REFRACTION: an integrator without the effect that still refracted would show.
        if bs.eta != 1.0 {
            stats.refractions += 1;
            eta_scale *= bs.eta * bs.eta;
        }
        beta *= bs.weight;
        prev_pdf = bs.pdf;
        prev_delta = bs.delta;
        prev_p = surf.p;
        smooth_bounce |= !bs.delta;
        ray = spawn(surf.p, surf.n, frame.to_world(bs.wi));
        depth += 1;

        let beta_max = beta.max_component();
        if beta_max.is_nan() || beta_max <= 0.0 {
            break;
        }
        if depth >= scene.rr_depth {
            let q = (beta_max * eta_scale).min(0.95);
            if rng.next_f32() >= q {
                break;
            }
            beta = beta / q;
        }
    }
    out.color = radiance;
    out
}

/// The six buffers of one render, plus what it cost.
pub struct RenderResult {
    pub color: Image,
    pub albedo: Image,
    pub normal: Image,
    pub material: Image,
    pub shadow: Image,
    /// Mean distance over the pixel's samples that hit something; +inf where none did.
    pub depth: Image,
    /// The colour's measured noise: variance of the pixel mean and the two half-sample means.
    /// Both are `None` at 1 spp, where a variance is undefined and there are no halves.
    pub noise: NoiseInputs,
    /// Unbiased variance of one colour sample, s² (`None` at 1 spp): pixels are independent and
    /// box-filtered, so s² / N is the true variance of an N-spp render's pixel mean.
    pub sample_variance: Option<Image>,
    pub stats: Stats,
    pub seconds: f64,
}

const TILE: u32 = 16;
/// Values per pixel in a tile: colour, albedo, normal, material (3 each), shadow, depth, then the
/// noise: variance of the mean, sample variance, half a, half b (3 each).
const VALUES: usize = 26;

struct Tile {
    x0: u32,
    y0: u32,
    w: u32,
    h: u32,
    /// Per pixel: [`VALUES`] values.
    data: Vec<f32>,
    stats: Stats,
}

/// Renders `spp` samples per pixel with the integrator for `effects` (which must cover `scene.effects`).
pub fn render(
    scene: &Scene,
    spp: u32,
    seed: u64,
    effects: EffectSet,
    progress: &ProgressBar,
) -> RenderResult {
    assert!(
        effects.covers(&scene.effects),
        "integrator lacks effects the scene needs"
    );
    let trace = integrator(effects);
    let (w, h) = (scene.camera.width, scene.camera.height);
    let (tx, ty) = (w.div_ceil(TILE), h.div_ceil(TILE));
    progress.set_length((tx * ty) as u64);
    let start = Instant::now();
    let tiles: Vec<Tile> = (0..tx * ty)
        .into_par_iter()
        .map(|i| {
            let (x0, y0) = ((i % tx) * TILE, (i / tx) * TILE);
            let tile = render_tile(
                scene,
                trace,
                spp,
                seed,
                x0,
                y0,
                TILE.min(w - x0),
                TILE.min(h - y0),
            );
            progress.inc(1);
            tile
        })
        .collect();
    let seconds = start.elapsed().as_secs_f64();

    let (wu, hu) = (w as usize, h as usize);
    let mut color = Image::new(wu, hu, 3);
    let mut albedo = Image::new(wu, hu, 3);
    let mut normal = Image::new(wu, hu, 3);
    let mut material = Image::new(wu, hu, 3);
    let mut shadow = Image::new(wu, hu, 1);
    let mut depth = Image::new(wu, hu, 1);
    let mut noise = [(); 4].map(|_| Image::new(wu, hu, 3));
    let mut stats = Stats::default();
    for t in &tiles {
        stats.add(&t.stats);
        for ly in 0..t.h {
            for lx in 0..t.w {
                let v = &t.data[(ly * t.w + lx) as usize * VALUES..][..VALUES];
                let p = ((t.y0 + ly) * w + t.x0 + lx) as usize;
                color.pixel_mut(p).copy_from_slice(&v[0..3]);
                albedo.pixel_mut(p).copy_from_slice(&v[3..6]);
                normal.pixel_mut(p).copy_from_slice(&v[6..9]);
                material.pixel_mut(p).copy_from_slice(&v[9..12]);
                shadow.pixel_mut(p)[0] = v[12];
                depth.pixel_mut(p)[0] = v[13];
                for (k, img) in noise.iter_mut().enumerate() {
                    img.pixel_mut(p).copy_from_slice(&v[14 + 3 * k..][..3]);
                }
            }
        }
    }
    let [variance, sample_variance, a, b] = noise;
    let measured = spp >= 2;
    RenderResult {
        color,
        albedo,
        normal,
        material,
        shadow,
        depth,
        noise: NoiseInputs {
            variance: measured.then_some(variance),
            halves: measured.then_some([a, b]),
            from_stack: false,
            resampled: false,
        },
        sample_variance: measured.then_some(sample_variance),
        stats,
        seconds,
    }
}

/// Welford's running mean and sum of squared deviations per channel: exact 0 for constant samples
/// (a light seen directly), where sum and sum of squares would cancel to rounding noise.
#[derive(Default)]
struct Moments {
    n: u32,
    mean: [f64; 3],
    m2: [f64; 3],
}

impl Moments {
    fn add(&mut self, x: [f64; 3]) {
        self.n += 1;
        let n = self.n as f64;
        for ((x, mean), m2) in x.iter().zip(&mut self.mean).zip(&mut self.m2) {
            let d = x - *mean;
            *mean += d / n;
            *m2 += d * (x - *mean);
        }
    }

    /// The unbiased sample variance; 0 for fewer than two samples (the caller drops it then).
    fn sample_variance(&self) -> [f64; 3] {
        if self.n < 2 {
            return [0.0; 3];
        }
        self.m2.map(|m| m / (self.n - 1) as f64)
    }
}

#[allow(clippy::too_many_arguments)]
fn render_tile(
    scene: &Scene,
    trace: TraceFn,
    spp: u32,
    seed: u64,
    x0: u32,
    y0: u32,
    w: u32,
    h: u32,
) -> Tile {
    let mut data = Vec::with_capacity((w * h) as usize * VALUES);
    let mut stats = Stats::default();
    let width = scene.camera.width as u64;
    for y in y0..y0 + h {
        for x in x0..x0 + w {
            let mut rng = Sampler::for_pixel(seed, y as u64 * width + x as u64);
            let mut acc = [0.0f64; 12];
            let (mut shadow, mut depth, mut hits) = (0.0f64, 0.0f64, 0u32);
            let mut moments = Moments::default();
            // Samples 0..half and half..2·half make the two independent half-sample means.
            let half = spp / 2;
            let mut halves = [[0.0f64; 3]; 2];
            for i in 0..spp {
                // Every sample is jittered uniformly inside its own pixel from the pixel's own
                // stream, and lands in that pixel only (a box filter): pixels are independent.
                let (jx, jy) = (rng.next_f32(), rng.next_f32());
                let s = trace(scene, x as f32 + jx, y as f32 + jy, &mut rng, &mut stats);
                for (k, v) in [s.color, s.albedo, s.normal, s.material].iter().enumerate() {
                    acc[3 * k] += v.x as f64;
                    acc[3 * k + 1] += v.y as f64;
                    acc[3 * k + 2] += v.z as f64;
                }
                let c = [s.color.x as f64, s.color.y as f64, s.color.z as f64];
                moments.add(c);
                if i < 2 * half {
                    let h = &mut halves[(i >= half) as usize];
                    for (h, c) in h.iter_mut().zip(c) {
                        *h += c;
                    }
                }
                shadow += s.shadow as f64;
                if let Some(d) = s.depth {
                    depth += d as f64;
                    hits += 1;
                }
            }
            let inv = 1.0 / spp as f64;
            data.extend(acc.iter().map(|v| (v * inv) as f32));
            data.push((shadow * inv) as f32);
            data.push(if hits > 0 {
                (depth / hits as f64) as f32
            } else {
                f32::INFINITY
            });
            let s2 = moments.sample_variance();
            data.extend(s2.map(|v| (v * inv) as f32));
            data.extend(s2.map(|v| v as f32));
            let inv_half = 1.0 / half.max(1) as f64;
            for h in halves {
                data.extend(h.map(|v| (v * inv_half) as f32));
            }
        }
    }
    Tile {
        x0,
        y0,
        w,
        h,
        data,
        stats,
    }
}
