//! Geometry: parallelograms (rectangles and the faces of boxes, after any affine transform) and spheres.
//!
//! Scenes here have tens of primitives, so a flat list per kind beats an acceleration structure.

use super::math::{Mat4, Ray, Vec3};

/// Marks "no light attached".
pub const NO_LIGHT: u32 = u32::MAX;

/// A parallelogram `p0 + u·e1 + v·e2`, u, v ∈ [0, 1], one normal `n`.
#[derive(Clone, Debug)]
pub struct Quad {
    pub p0: Vec3,
    pub e1: Vec3,
    pub e2: Vec3,
    pub n: Vec3,
    /// `cross(e1, e2) / |cross(e1, e2)|²`, for the barycentric solve.
    w: Vec3,
    pub area: f32,
    pub material: u32,
    pub light: u32,
}

impl Quad {
    /// The image of Mitsuba's rectangle `[-1, 1]²` (normal +z) under `m`.
    pub fn rectangle(m: &Mat4, material: u32) -> Quad {
        Quad::new(
            m.point([-1.0, -1.0, 0.0]),
            m.vector([2.0, 0.0, 0.0]),
            m.vector([0.0, 2.0, 0.0]),
            m.normal([0.0, 0.0, 1.0]),
            material,
        )
    }

    /// The six outward-facing faces of the cube `[-1, 1]³` under `m`.
    pub fn cube(m: &Mat4, material: u32) -> Vec<Quad> {
        let mut faces = Vec::with_capacity(6);
        for axis in 0..3 {
            let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
            for sign in [-1.0f64, 1.0] {
                let mut corner = [-1.0; 3];
                corner[axis] = sign;
                let mut ea = [0.0; 3];
                ea[a] = 2.0;
                let mut eb = [0.0; 3];
                eb[b] = 2.0;
                let mut n = [0.0; 3];
                n[axis] = sign;
                faces.push(Quad::new(
                    m.point(corner),
                    m.vector(ea),
                    m.vector(eb),
                    m.normal(n),
                    material,
                ));
            }
        }
        faces
    }

    fn new(p0: Vec3, e1: Vec3, e2: Vec3, n: Vec3, material: u32) -> Quad {
        let c = e1.cross(e2);
        Quad {
            p0,
            e1,
            e2,
            n: n.normalize(),
            w: c / c.length_squared(),
            area: c.length(),
            material,
            light: NO_LIGHT,
        }
    }

    #[inline]
    fn intersect(&self, ray: &Ray, tmax: f32) -> Option<f32> {
        let denom = self.n.dot(ray.d);
        if denom.abs() < 1e-12 {
            return None;
        }
        let t = self.n.dot(self.p0 - ray.o) / denom;
        if !(t > 0.0 && t < tmax) {
            return None;
        }
        let q = ray.o + ray.d * t - self.p0;
        let a = self.w.dot(q.cross(self.e2));
        let b = self.w.dot(self.e1.cross(q));
        (0.0..=1.0).contains(&a).then_some(())?;
        (0.0..=1.0).contains(&b).then_some(t)
    }

    fn uv(&self, p: Vec3) -> (f32, f32) {
        let q = p - self.p0;
        (self.w.dot(q.cross(self.e2)), self.w.dot(self.e1.cross(q)))
    }
}

#[derive(Clone, Debug)]
pub struct Sphere {
    pub center: Vec3,
    pub radius: f32,
    pub material: u32,
    pub light: u32,
}

impl Sphere {
    #[inline]
    fn intersect(&self, ray: &Ray, tmax: f32) -> Option<f32> {
        let oc = ray.o - self.center;
        let b = oc.dot(ray.d);
        let c = oc.length_squared() - self.radius * self.radius;
        let disc = b * b - c;
        if disc < 0.0 {
            return None;
        }
        let s = disc.sqrt();
        // Numerically stable pair of roots.
        let q = if b > 0.0 { -b - s } else { -b + s };
        let (mut t0, mut t1) = (q, if q != 0.0 { c / q } else { q });
        if t0 > t1 {
            std::mem::swap(&mut t0, &mut t1);
        }
        if t0 > 0.0 && t0 < tmax {
            Some(t0)
        } else if t1 > 0.0 && t1 < tmax {
            Some(t1)
        } else {
            None
        }
    }
}

/// Which primitive a ray hit.
#[derive(Clone, Copy, Debug)]
pub enum Prim {
    Quad(u32),
    Sphere(u32),
}

/// A surface point: position, unit geometric (= shading) normal, texture coordinates (u along the first
/// edge, v up: on rectangles the local x and y, on spheres longitude and latitude from the south pole).
#[derive(Clone, Copy, Debug)]
pub struct Surface {
    pub p: Vec3,
    pub n: Vec3,
    pub uv: (f32, f32),
    pub t: f32,
    pub material: u32,
    pub light: u32,
    pub prim: Prim,
}

#[derive(Clone, Debug, Default)]
pub struct Geometry {
    pub quads: Vec<Quad>,
    pub spheres: Vec<Sphere>,
}

impl Geometry {
    /// Nearest hit before `tmax`.
    #[inline]
    pub fn intersect(&self, ray: &Ray, mut tmax: f32) -> Option<(Prim, f32)> {
        let mut hit = None;
        for (i, q) in self.quads.iter().enumerate() {
            if let Some(t) = q.intersect(ray, tmax) {
                tmax = t;
                hit = Some(Prim::Quad(i as u32));
            }
        }
        for (i, s) in self.spheres.iter().enumerate() {
            if let Some(t) = s.intersect(ray, tmax) {
                tmax = t;
                hit = Some(Prim::Sphere(i as u32));
            }
        }
        hit.map(|p| (p, tmax))
    }

    /// Whether anything blocks the ray before `tmax`.
    #[inline]
    pub fn occluded(&self, ray: &Ray, tmax: f32) -> bool {
        self.quads.iter().any(|q| q.intersect(ray, tmax).is_some())
            || self
                .spheres
                .iter()
                .any(|s| s.intersect(ray, tmax).is_some())
    }

    /// Whether anything lies between surface point `p` (normal `n`) and the point `dist` away along `d`
    /// (infinitely far for an infinite `dist`). The far end is aimed at from the nudged origin, so a light
    /// never shadows itself.
    #[inline]
    pub fn occluded_towards(&self, p: Vec3, n: Vec3, d: Vec3, dist: f32) -> bool {
        let ray = spawn(p, n, d);
        if !dist.is_finite() {
            return self.occluded(&ray, f32::INFINITY);
        }
        let to = p + d * dist - ray.o;
        let len = to.length();
        self.occluded(
            &Ray {
                o: ray.o,
                d: to / len,
            },
            len * (1.0 - 1e-4),
        )
    }

    /// The surface record of a hit; texture coordinates only when `with_uv` (they cost an atan2 on spheres).
    /// The integrator passes a compile-time constant, so the branch folds away.
    #[inline(always)]
    pub fn surface(&self, prim: Prim, ray: &Ray, t: f32, with_uv: bool) -> Surface {
        let p = ray.o + ray.d * t;
        match prim {
            Prim::Quad(i) => {
                let q = &self.quads[i as usize];
                let uv = if with_uv { q.uv(p) } else { (0.0, 0.0) };
                Surface {
                    p,
                    n: q.n,
                    uv,
                    t,
                    material: q.material,
                    light: q.light,
                    prim,
                }
            }
            Prim::Sphere(i) => {
                let s = &self.spheres[i as usize];
                let n = (p - s.center) / s.radius;
                let uv = if with_uv {
                    let u = (n.z.atan2(n.x) + std::f32::consts::PI) / (2.0 * std::f32::consts::PI);
                    let v = 1.0 - n.y.clamp(-1.0, 1.0).acos() / std::f32::consts::PI;
                    (u, v)
                } else {
                    (0.0, 0.0)
                };
                Surface {
                    p,
                    n,
                    uv,
                    t,
                    material: s.material,
                    light: s.light,
                    prim,
                }
            }
        }
    }
}

/// Ray leaving `p` in direction `d`, nudged off the surface with normal `n` to avoid self-hits.
#[inline]
pub fn spawn(p: Vec3, n: Vec3, d: Vec3) -> Ray {
    let eps = 1e-4 * (1.0 + p.x.abs().max(p.y.abs()).max(p.z.abs()));
    let off = if n.dot(d) >= 0.0 { n * eps } else { n * -eps };
    Ray { o: p + off, d }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cube_faces_point_outward() {
        let m = Mat4::translate([1.0, 2.0, 3.0])
            .mul(&Mat4::rotate(1, 20.0))
            .mul(&Mat4::scale([0.5, 1.0, 2.0]));
        let center = m.point([0.0, 0.0, 0.0]);
        for f in Quad::cube(&m, 0) {
            let c = f.p0 + (f.e1 + f.e2) * 0.5;
            assert!(f.n.dot(c - center) > 0.0);
        }
    }

    #[test]
    fn quad_and_sphere_hits() {
        let mut g = Geometry::default();
        g.quads.push(Quad::rectangle(&Mat4::IDENTITY, 0));
        g.spheres.push(Sphere {
            center: Vec3::new(0.0, 0.0, 2.0),
            radius: 0.5,
            material: 0,
            light: NO_LIGHT,
        });
        let ray = Ray {
            o: Vec3::new(0.2, 0.1, 5.0),
            d: Vec3::new(0.0, 0.0, -1.0),
        };
        let (prim, t) = g.intersect(&ray, f32::INFINITY).unwrap();
        assert!(matches!(prim, Prim::Sphere(0)));
        assert!((t - (3.0 - 0.2f32.sqrt())).abs() < 1e-4);
        let ray = Ray {
            o: Vec3::new(0.9, -0.9, 1.0),
            d: Vec3::new(0.0, 0.0, -1.0),
        };
        assert!(matches!(
            g.intersect(&ray, f32::INFINITY),
            Some((Prim::Quad(0), _))
        ));
        let ray = Ray {
            o: Vec3::new(1.1, 0.0, 1.0),
            d: Vec3::new(0.0, 0.0, -1.0),
        };
        assert!(g.intersect(&ray, f32::INFINITY).is_none());
    }
}
