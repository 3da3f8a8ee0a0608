//! Textures: colour as a function of the surface's (u, v) coordinates.

use super::math::Vec3;
use crate::image::Image;

/// Marks "constant colour, no texture lookup".
pub const NO_TEXTURE: u32 = u32::MAX;

#[derive(Clone, Debug)]
pub enum Texture {
    Constant(Vec3),
    /// Alternating squares; `scale` = number of squares across u and v.
    Checker {
        a: Vec3,
        b: Vec3,
        scale: (f32, f32),
    },
    /// Running-bond bricks; `scale` = bricks across u and rows across v, `mortar` = joint width as a fraction of a brick.
    Bricks {
        brick: Vec3,
        mortar_color: Vec3,
        scale: (f32, f32),
        mortar: f32,
    },
    /// A linear RGB image stretched over [0, 1]², nearest pixel, repeating; v = 1 is the image's top row
    /// (v grows upwards on rectangles and spheres, so images appear upright).
    Image(Image),
}

impl Texture {
    pub fn eval(&self, (u, v): (f32, f32)) -> Vec3 {
        match self {
            Texture::Constant(c) => *c,
            Texture::Checker { a, b, scale } => {
                let (i, j) = ((u * scale.0).floor() as i64, (v * scale.1).floor() as i64);
                if (i + j).rem_euclid(2) == 0 {
                    *a
                } else {
                    *b
                }
            }
            Texture::Bricks {
                brick,
                mortar_color,
                scale,
                mortar,
            } => {
                let (x, y) = (u * scale.0, v * scale.1);
                let row = y.floor();
                let x = if (row as i64).rem_euclid(2) == 1 {
                    x + 0.5
                } else {
                    x
                };
                let (fx, fy) = (x - x.floor(), y - row);
                let half = mortar * 0.5;
                let aspect = scale.0 / scale.1.max(1e-6);
                // Joints have the same width in both directions in (u, v) space.
                let half_x = half * aspect;
                if fx < half_x || fx > 1.0 - half_x || fy < half || fy > 1.0 - half {
                    *mortar_color
                } else {
                    *brick
                }
            }
            Texture::Image(img) => {
                let (w, h) = (img.width(), img.height());
                let x = ((u - u.floor()) * w as f32) as usize;
                let y = ((1.0 - (v - v.floor())) * h as f32) as usize;
                let p = img.at(x.min(w - 1), y.min(h - 1));
                Vec3::new(p[0], p[1], p[2])
            }
        }
    }

    /// Mean colour over [0, 1]², used where textures are switched off.
    pub fn mean(&self) -> Vec3 {
        if let Texture::Constant(c) = self {
            return *c;
        }
        let n = 256;
        let mut sum = Vec3::ZERO;
        for j in 0..n {
            for i in 0..n {
                sum += self.eval(((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32));
            }
        }
        sum / (n * n) as f32
    }
}

/// A material's colour slot: a constant, or a texture with its mean as the constant fallback.
#[derive(Clone, Copy, Debug)]
pub struct TexRef {
    pub value: Vec3,
    pub id: u32,
}

impl TexRef {
    pub fn constant(value: Vec3) -> Self {
        TexRef {
            value,
            id: NO_TEXTURE,
        }
    }

    /// Colour at `uv`; with `textures_on` false (a compile-time constant in the integrator) the constant.
    #[inline(always)]
    pub fn eval(&self, textures: &[Texture], uv: (f32, f32), textures_on: bool) -> Vec3 {
        if textures_on && self.id != NO_TEXTURE {
            textures[self.id as usize].eval(uv)
        } else {
            self.value
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checker_alternates_and_has_the_mean_of_its_colours() {
        let t = Texture::Checker {
            a: Vec3::ONE,
            b: Vec3::ZERO,
            scale: (4.0, 4.0),
        };
        assert_eq!(t.eval((0.1, 0.1)), Vec3::ONE);
        assert_eq!(t.eval((0.3, 0.1)), Vec3::ZERO);
        assert!((t.mean().x - 0.5).abs() < 1e-3);
    }

    #[test]
    fn bricks_have_mortar_lines() {
        let t = Texture::Bricks {
            brick: Vec3::ONE,
            mortar_color: Vec3::ZERO,
            scale: (4.0, 8.0),
            mortar: 0.1,
        };
        assert_eq!(t.eval((0.1, 0.0625)), Vec3::ONE);
        assert_eq!(t.eval((0.1, 0.001)), Vec3::ZERO);
        let m = t.mean().x;
        assert!(m > 0.6 && m < 0.95, "{m}");
    }
}
