//! Lights: emitting rectangles and spheres (one-sided, emitting on the side their normal faces) and a
//! constant environment. Each can be sampled from a point and report the solid-angle pdf of that choice.

use std::f32::consts::PI;

use super::math::{uniform_sphere, Frame, Vec3};
use super::shapes::Geometry;

#[derive(Clone, Debug)]
pub enum Light {
    Quad { index: u32, radiance: Vec3 },
    Sphere { index: u32, radiance: Vec3 },
    Environment { radiance: Vec3 },
}

/// A sampled direction towards a light.
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    pub wi: Vec3,
    /// Distance to the sampled point (infinite for the environment).
    pub dist: f32,
    /// Radiance arriving along `-wi` if unoccluded (zero when the light faces away).
    pub radiance: Vec3,
    /// Solid-angle pdf of this direction for this light.
    pub pdf: f32,
}

impl Light {
    pub fn sample(&self, geo: &Geometry, p: Vec3, u: (f32, f32)) -> Option<LightSample> {
        match self {
            Light::Quad { index, radiance } => {
                let q = &geo.quads[*index as usize];
                let x = q.p0 + q.e1 * u.0 + q.e2 * u.1;
                let d = x - p;
                let dist2 = d.length_squared();
                let dist = dist2.sqrt();
                let wi = d / dist;
                let cos_l = -q.n.dot(wi);
                if cos_l <= 0.0 {
                    return Some(LightSample {
                        wi,
                        dist,
                        radiance: Vec3::ZERO,
                        pdf: 0.0,
                    });
                }
                Some(LightSample {
                    wi,
                    dist,
                    radiance: *radiance,
                    pdf: dist2 / (q.area * cos_l),
                })
            }
            Light::Sphere { index, radiance } => {
                let s = &geo.spheres[*index as usize];
                let to_c = s.center - p;
                let dc2 = to_c.length_squared();
                let r2 = s.radius * s.radius;
                if dc2 <= r2 {
                    return None;
                }
                let dc = dc2.sqrt();
                let sin2_max = r2 / dc2;
                let cos_max = (1.0 - sin2_max).max(0.0).sqrt();
                let one_minus = sin2_max / (1.0 + cos_max);
                let cos = 1.0 - u.0 * one_minus;
                let sin = (1.0 - cos * cos).max(0.0).sqrt();
                let phi = 2.0 * PI * u.1;
                let frame = Frame::new(to_c / dc);
                let wi = frame.to_world(Vec3::new(sin * phi.cos(), sin * phi.sin(), cos));
                // Distance to the sphere along wi (the near root; tangent point if rounding misses).
                let b = wi.dot(to_c);
                let disc = (b * b - (dc2 - r2)).max(0.0);
                let dist = b - disc.sqrt();
                Some(LightSample {
                    wi,
                    dist,
                    radiance: *radiance,
                    pdf: 1.0 / (2.0 * PI * one_minus),
                })
            }
            Light::Environment { radiance } => {
                let wi = uniform_sphere(u.0, u.1);
                Some(LightSample {
                    wi,
                    dist: f32::INFINITY,
                    radiance: *radiance,
                    pdf: 1.0 / (4.0 * PI),
                })
            }
        }
    }

    /// Solid-angle pdf that `sample` from `p` returns the direction `wi`, which hits this light at distance `t`.
    pub fn pdf(&self, geo: &Geometry, p: Vec3, wi: Vec3, t: f32) -> f32 {
        match self {
            Light::Quad { index, .. } => {
                let q = &geo.quads[*index as usize];
                let cos_l = -q.n.dot(wi);
                if cos_l <= 0.0 {
                    0.0
                } else {
                    t * t / (q.area * cos_l)
                }
            }
            Light::Sphere { index, .. } => {
                let s = &geo.spheres[*index as usize];
                let dc2 = (s.center - p).length_squared();
                let r2 = s.radius * s.radius;
                if dc2 <= r2 {
                    return 0.0;
                }
                let sin2_max = r2 / dc2;
                let cos_max = (1.0 - sin2_max).max(0.0).sqrt();
                1.0 / (2.0 * PI * sin2_max / (1.0 + cos_max))
            }
            Light::Environment { .. } => 1.0 / (4.0 * PI),
        }
    }

    /// Radiance leaving the light's surface towards `-d` (a ray travelling along `d`) at normal `n`.
    pub fn emitted(&self, n: Vec3, d: Vec3) -> Vec3 {
        match self {
            Light::Quad { radiance, .. } | Light::Sphere { radiance, .. } => {
                if n.dot(d) < 0.0 {
                    *radiance
                } else {
                    Vec3::ZERO
                }
            }
            Light::Environment { radiance } => *radiance,
        }
    }
}
