//! Materials (BSDFs) in the local shading frame: z is the surface normal, `wo` points back along the path
//! (towards the camera), `wi` is the sampled or light direction. Values returned include the cosine term.
//!
//! Opaque materials are one-sided like Mitsuba's: seen from behind (`wo.z ≤ 0`) they are black.

use std::f32::consts::{FRAC_1_PI, PI};

use super::effects::Effects;
use super::math::{cosine_hemisphere, Vec3};
use super::texture::TexRef;

#[derive(Clone, Debug)]
pub enum Material {
    /// Lambertian reflection.
    Diffuse { reflectance: TexRef },
    /// Metal: Schlick Fresnel with `color` at normal incidence; `alpha` = GGX roughness, 0 = perfect mirror.
    Conductor { color: Vec3, alpha: f32 },
    /// Smooth glass with index of refraction `ior` (outside is vacuum/air).
    Dielectric { ior: f32 },
    /// Diffuse base under a smooth clear coat of index `ior` (coat reflection by Fresnel, base gets the rest).
    Plastic { base: TexRef, ior: f32 },
    /// Absorbs everything (the default for lights without a material).
    Black,
}

/// One BSDF sample: `weight` = f·cos/pdf.
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    pub wi: Vec3,
    pub weight: Vec3,
    pub pdf: f32,
    pub delta: bool,
    /// Relative index η_t/η_i if the sample refracted, else 1.
    pub eta: f32,
}

/// Diffuse / reflective / refractive split of a surface as seen from `wo` (the `material` buffer).
pub fn material_weights(m: &Material, cos_o: f32) -> Vec3 {
    match m {
        Material::Diffuse { .. } => Vec3::new(1.0, 0.0, 0.0),
        Material::Conductor { .. } => Vec3::new(0.0, 1.0, 0.0),
        Material::Dielectric { ior } => {
            let eta = if cos_o > 0.0 { *ior } else { 1.0 / ior };
            let f = fresnel_dielectric(cos_o.abs(), eta);
            Vec3::new(0.0, f, 1.0 - f)
        }
        Material::Plastic { ior, .. } => {
            let f = fresnel_dielectric(cos_o.max(0.0), *ior);
            Vec3::new(1.0 - f, f, 0.0)
        }
        Material::Black => Vec3::ZERO,
    }
}

impl Material {
    /// Whether next-event estimation can help: the material has a non-delta lobe.
    pub fn has_smooth_lobe<E: Effects>(&self) -> bool {
        match self {
            Material::Diffuse { .. } | Material::Plastic { .. } => true,
            Material::Conductor { alpha, .. } => E::ROUGH && *alpha > 0.0,
            Material::Dielectric { .. } | Material::Black => false,
        }
    }

    /// Samples `wi` given `wo`; `albedo` is the evaluated base colour, `u` three uniform numbers.
    #[inline]
    pub fn sample<E: Effects>(&self, albedo: Vec3, wo: Vec3, u: [f32; 3]) -> Option<BsdfSample> {
        match self {
            Material::Diffuse { .. } => {
                if wo.z <= 0.0 {
                    return None;
                }
                let wi = cosine_hemisphere(u[0], u[1]);
                (wi.z > 0.0).then_some(BsdfSample {
                    wi,
                    weight: albedo,
                    pdf: wi.z * FRAC_1_PI,
                    delta: false,
                    eta: 1.0,
                })
            }
            Material::Conductor { color, alpha } if E::ROUGH && *alpha > 0.0 => {
                sample_ggx(*color, *alpha, wo, u)
            }
            Material::Conductor { color, .. } if E::REFLECTION => {
                if wo.z <= 0.0 {
                    return None;
                }
                let wi = Vec3::new(-wo.x, -wo.y, wo.z);
                Some(BsdfSample {
                    wi,
                    weight: schlick(*color, wo.z),
                    pdf: 1.0,
                    delta: true,
                    eta: 1.0,
                })
            }
            Material::Dielectric { ior } if E::REFRACTION => Some(sample_glass(*ior, wo, u[2])),
            Material::Dielectric { ior } if E::REFLECTION => {
                // Refraction switched off: the glass keeps only its Fresnel reflection.
                let eta = if wo.z > 0.0 { *ior } else { 1.0 / ior };
                let f = fresnel_dielectric(wo.z.abs(), eta);
                let wi = Vec3::new(-wo.x, -wo.y, wo.z);
                Some(BsdfSample {
                    wi,
                    weight: Vec3::splat(f),
                    pdf: 1.0,
                    delta: true,
                    eta: 1.0,
                })
            }
            Material::Plastic { ior, .. } => {
                if wo.z <= 0.0 {
                    return None;
                }
                let fo = fresnel_dielectric(wo.z, *ior);
                let ps = if E::REFLECTION {
                    plastic_coat_prob(fo, albedo)
                } else {
                    0.0
                };
                if u[2] < ps {
                    let wi = Vec3::new(-wo.x, -wo.y, wo.z);
                    return Some(BsdfSample {
                        wi,
                        weight: Vec3::splat(fo / ps),
                        pdf: ps,
                        delta: true,
                        eta: 1.0,
                    });
                }
                let wi = cosine_hemisphere(u[0], u[1]);
                if wi.z <= 0.0 {
                    return None;
                }
                let fi = fresnel_dielectric(wi.z, *ior);
                let weight = albedo * ((1.0 - fo) * (1.0 - fi) / (1.0 - ps));
                Some(BsdfSample {
                    wi,
                    weight,
                    pdf: (1.0 - ps) * wi.z * FRAC_1_PI,
                    delta: false,
                    eta: 1.0,
                })
            }
            _ => None,
        }
    }

    /// f·cos and the sampling pdf of `wi` for the non-delta lobes.
    #[inline]
    pub fn eval<E: Effects>(&self, albedo: Vec3, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return (Vec3::ZERO, 0.0);
        }
        match self {
            Material::Diffuse { .. } => (albedo * (wi.z * FRAC_1_PI), wi.z * FRAC_1_PI),
            Material::Conductor { color, alpha } if E::ROUGH && *alpha > 0.0 => {
                eval_ggx(*color, *alpha, wo, wi)
            }
            Material::Plastic { ior, .. } => {
                let fo = fresnel_dielectric(wo.z, *ior);
                let fi = fresnel_dielectric(wi.z, *ior);
                let ps = if E::REFLECTION {
                    plastic_coat_prob(fo, albedo)
                } else {
                    0.0
                };
                let f = albedo * ((1.0 - fo) * (1.0 - fi) * wi.z * FRAC_1_PI);
                (f, (1.0 - ps) * wi.z * FRAC_1_PI)
            }
            _ => (Vec3::ZERO, 0.0),
        }
    }
}

/// Probability of sampling a plastic's coat: its Fresnel share of the reflected energy, kept off 0 and 1.
fn plastic_coat_prob(fo: f32, base: Vec3) -> f32 {
    let d = (1.0 - fo) * base.mean();
    (fo / (fo + d).max(1e-6)).clamp(0.05, 0.95)
}

fn schlick(f0: Vec3, cos: f32) -> Vec3 {
    let m = (1.0 - cos).clamp(0.0, 1.0);
    let m5 = m * m * m * m * m;
    f0 + (Vec3::ONE - f0) * m5
}

/// Unpolarised Fresnel reflectance of a smooth dielectric boundary; `eta` = η_t/η_i, `cos_i` ≥ 0.
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> f32 {
    let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    let rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    0.5 * (rs * rs + rp * rp)
}

fn sample_glass(ior: f32, wo: Vec3, u: f32) -> BsdfSample {
    let entering = wo.z > 0.0;
    let eta = if entering { ior } else { 1.0 / ior };
    let cos_i = wo.z.abs();
    let f = fresnel_dielectric(cos_i, eta);
    if u < f {
        return BsdfSample {
            wi: Vec3::new(-wo.x, -wo.y, wo.z),
            weight: Vec3::ONE,
            pdf: f,
            delta: true,
            eta: 1.0,
        };
    }
    let sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    let cos_t = (1.0 - sin2_t).max(0.0).sqrt();
    let n_sign = if entering { 1.0 } else { -1.0 };
    let wi = -wo / eta + Vec3::new(0.0, 0.0, n_sign * (cos_i / eta - cos_t));
    // Radiance is compressed by 1/η² entering a denser medium (pbrt's radiance-mode scaling).
    BsdfSample {
        wi,
        weight: Vec3::splat(1.0 / (eta * eta)),
        pdf: 1.0 - f,
        delta: true,
        eta,
    }
}

fn ggx_d(alpha: f32, h: Vec3) -> f32 {
    let a2 = alpha * alpha;
    let d = h.z * h.z * (a2 - 1.0) + 1.0;
    a2 / (PI * d * d)
}

fn ggx_g1(alpha: f32, v: Vec3) -> f32 {
    let cos2 = v.z * v.z;
    let tan2 = (1.0 - cos2).max(0.0) / cos2;
    2.0 / (1.0 + (1.0 + alpha * alpha * tan2).sqrt())
}

fn sample_ggx(color: Vec3, alpha: f32, wo: Vec3, u: [f32; 3]) -> Option<BsdfSample> {
    if wo.z <= 0.0 {
        return None;
    }
    let tan2 = alpha * alpha * u[0] / (1.0 - u[0]).max(1e-7);
    let cos_h = 1.0 / (1.0 + tan2).sqrt();
    let sin_h = (1.0 - cos_h * cos_h).max(0.0).sqrt();
    let phi = 2.0 * PI * u[1];
    let h = Vec3::new(sin_h * phi.cos(), sin_h * phi.sin(), cos_h);
    let oh = wo.dot(h);
    if oh <= 0.0 {
        return None;
    }
    let wi = h * (2.0 * oh) - wo;
    if wi.z <= 0.0 {
        return None;
    }
    let pdf = ggx_d(alpha, h) * cos_h / (4.0 * oh);
    let weight = schlick(color, oh) * (ggx_g1(alpha, wo) * ggx_g1(alpha, wi) * oh / (wo.z * cos_h));
    Some(BsdfSample {
        wi,
        weight,
        pdf,
        delta: false,
        eta: 1.0,
    })
}

fn eval_ggx(color: Vec3, alpha: f32, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
    let h = (wo + wi).normalize();
    let oh = wo.dot(h);
    if oh <= 0.0 {
        return (Vec3::ZERO, 0.0);
    }
    let d = ggx_d(alpha, h);
    let f = schlick(color, oh) * (d * ggx_g1(alpha, wo) * ggx_g1(alpha, wi) / (4.0 * wo.z));
    (f, d * h.z / (4.0 * oh))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::effects::{EffectSet, Effects, Select};

    fn hash01(i: u32, k: u32) -> f32 {
        let mut x = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (k as u64).wrapping_mul(0xD1B5_4A32_D192_ED03);
        x ^= x >> 31;
        x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        x ^= x >> 29;
        (x >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Estimated albedo by sampling, and by integrating `eval` against uniform hemisphere directions.
    struct Albedo;

    impl Select for Albedo {
        type Out = fn(&Material, Vec3) -> (f32, f32);
        fn get<E: Effects>() -> Self::Out {
            |m, wo| {
                let n = 200_000;
                let mut sampled = 0.0f64;
                let mut integrated = 0.0f64;
                for i in 0..n {
                    let u = [hash01(i, 0), hash01(i, 1), hash01(i, 2)];
                    if let Some(s) = m.sample::<E>(Vec3::splat(0.8), wo, u) {
                        if !s.delta {
                            sampled += s.weight.x as f64;
                            let (f, pdf) = m.eval::<E>(Vec3::splat(0.8), wo, s.wi);
                            assert!(
                                (pdf - s.pdf).abs() <= 1e-3 * pdf.max(1.0),
                                "pdf {pdf} vs {}",
                                s.pdf
                            );
                            assert!((f.x / pdf - s.weight.x).abs() <= 1e-2 * s.weight.x.max(1.0));
                        }
                    }
                    let z = u[0];
                    let r = (1.0 - z * z).sqrt();
                    let wi = Vec3::new(r * (2.0 * PI * u[1]).cos(), r * (2.0 * PI * u[1]).sin(), z);
                    integrated += (m.eval::<E>(Vec3::splat(0.8), wo, wi).0.x * 2.0 * PI) as f64;
                }
                ((sampled / n as f64) as f32, (integrated / n as f64) as f32)
            }
        }
    }

    #[test]
    fn sampling_agrees_with_evaluation() {
        let f = crate::render::effects::select::<Albedo>(EffectSet::ALL);
        let wo = Vec3::new(0.5, 0.1, 0.86).normalize();
        let diffuse = Material::Diffuse {
            reflectance: TexRef::constant(Vec3::splat(0.8)),
        };
        let (s, i) = f(&diffuse, wo);
        assert!((s - 0.8).abs() < 1e-3 && (i - 0.8).abs() < 0.01, "{s} {i}");
        let rough = Material::Conductor {
            color: Vec3::splat(0.9),
            alpha: 0.3,
        };
        let (s, i) = f(&rough, wo);
        assert!((s - i).abs() < 0.02 && s < 1.0, "{s} {i}");
        let plastic = Material::Plastic {
            base: TexRef::constant(Vec3::splat(0.8)),
            ior: 1.5,
        };
        let (s, i) = f(&plastic, wo);
        assert!((s - i).abs() < 0.02, "{s} {i}");
    }

    #[test]
    fn glass_fresnel_is_sane() {
        assert!((fresnel_dielectric(1.0, 1.5) - 0.04).abs() < 1e-4);
        assert_eq!(fresnel_dielectric(0.1, 1.0 / 1.5), 1.0);
        let s = sample_glass(1.5, Vec3::new(0.0, 0.6, 0.8), 0.99);
        assert!(s.wi.z < 0.0 && (s.wi.length() - 1.0).abs() < 1e-5);
    }
}
