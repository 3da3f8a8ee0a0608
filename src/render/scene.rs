//! Scene files (TOML): the raw spec as written, checked key by key, then resolved into a `Scene`.
//!
//! Every error names the key at fault (e.g. `shapes[3].material`), so a typo is a one-line fix.

use std::collections::BTreeMap;
use std::path::Path;

use super::camera::Camera;
use super::effects::EffectSet;
use super::light::Light;
use super::material::Material;
use super::math::{Mat4, Vec3};
use super::scene_file::{
    Color, ColorOrTexture, MaterialSpec, Scale, SceneSpec, ShapeKind, ShapeSpec, TextureSpec,
};
use super::shapes::{Geometry, Quad, Sphere};
use super::texture::{TexRef, Texture};
use crate::error::{Error, Result};

/// Largest scene file read (a scene's shapes and materials, not its textures, which are files of
/// their own).
pub const MAX_SCENE_BYTES: u64 = 4 << 20;

/// A scene resolved for rendering.
#[derive(Debug)]
pub struct Scene {
    pub camera: Camera,
    pub geometry: Geometry,
    pub materials: Vec<Material>,
    pub textures: Vec<Texture>,
    pub lights: Vec<Light>,
    /// Index of the environment in `lights`, if any.
    pub environment: Option<usize>,
    pub max_depth: u32,
    pub rr_depth: u32,
    pub seed: u64,
    /// See `EffectsSpec::caustics`.
    pub caustics: bool,
    /// The effects this scene calls for (after the scene's own switches).
    pub effects: EffectSet,
}

impl Scene {
    /// Reads and resolves a scene file; image textures are found relative to it.
    pub fn load(path: &Path) -> Result<Scene> {
        Scene::load_within(path, u64::MAX)
    }

    /// [`Scene::load`], refusing before any texture is decoded a scene whose render would take
    /// more than `limit` bytes ([`SceneSpec::peak_bytes`]), naming the estimate.
    pub fn load_within(path: &Path, limit: u64) -> Result<Scene> {
        let text = crate::io::read_text(path, MAX_SCENE_BYTES, "scene file")?;
        let base = path.parent().unwrap_or(Path::new("."));
        let in_file = |e| match e {
            Error::Config { key, msg } => Error::config(format!("{}: {key}", path.display()), msg),
            other => other,
        };
        let spec = SceneSpec::parse(&text).map_err(in_file)?;
        spec.check_memory(base, limit)?;
        spec.build(base).map_err(in_file)
    }

    /// Parses scene TOML text; `base` resolves relative texture paths.
    pub fn parse(text: &str, base: &Path) -> Result<Scene> {
        SceneSpec::parse(text)?.build(base)
    }
}

/// Bytes a rendered pixel takes at most: the tiles' 26 accumulated values and the images they
/// are gathered into (measured: 208 at 1–4 spp, 1 to 4 MP), with a quarter's margin.
const RENDER_BYTES_PER_PIXEL: u64 = 256;
/// What a render takes whatever its size: the program, the scene, the thread pool.
const RENDER_BASE_BYTES: u64 = 32 << 20;

impl SceneSpec {
    /// Parses scene TOML text, keys checked by name; nothing is resolved or read.
    pub fn parse(text: &str) -> Result<SceneSpec> {
        let table: toml::Table = text.parse().map_err(|e: toml::de::Error| {
            Error::config("scene", e.to_string().lines().collect::<Vec<_>>().join(" "))
        })?;
        serde_path_to_error::deserialize(toml::Value::Table(table)).map_err(|e| {
            let path = e.path().to_string();
            let key = if path == "." {
                "scene".to_string()
            } else {
                path
            };
            Error::config(key, e.inner().message().to_string())
        })
    }

    /// Bytes a render of this scene takes at most: its buffers at the render's size, and every
    /// image texture as its reader decodes it (sized from the file's header; an unreadable one
    /// counts nothing here and is named when it is read).
    pub fn peak_bytes(&self, base: &Path) -> u64 {
        let pixels = self.render.width as u64 * self.render.height as u64;
        let textures = self.textures.values().filter_map(|t| match t {
            TextureSpec::Image { path } => crate::io::read_bytes(&base.join(path)),
            _ => None,
        });
        textures.fold(
            RENDER_BASE_BYTES.saturating_add(pixels.saturating_mul(RENDER_BYTES_PER_PIXEL)),
            u64::saturating_add,
        )
    }

    /// Refuses a scene whose [`SceneSpec::peak_bytes`] is above `limit`, naming both.
    pub fn check_memory(&self, base: &Path, limit: u64) -> Result<()> {
        let (w, h) = (self.render.width, self.render.height);
        crate::options::check_memory(self.peak_bytes(base), limit, |mib| {
            format!("rendering this {w}x{h} scene and its textures needs about {mib} MiB")
        })
    }

    pub fn build(&self, base: &Path) -> Result<Scene> {
        let r = &self.render;
        if r.width == 0 || r.height == 0 || r.width > 16384 || r.height > 16384 {
            return Err(Error::config(
                "render.width",
                "width and height must be in 1..=16384",
            ));
        }
        if r.max_depth == 0 {
            return Err(Error::config("render.max_depth", "must be at least 1"));
        }
        let fx = &self.effects;
        let on = |o: Option<bool>| o.unwrap_or(true);

        let mut textures = Vec::new();
        let mut texture_ids = BTreeMap::new();
        for (name, t) in &self.textures {
            let key = format!("textures.{name}");
            let tex = match t {
                TextureSpec::Constant { color } => {
                    Texture::Constant(color_checked(*color, &key, "color")?)
                }
                TextureSpec::Checker {
                    color1,
                    color2,
                    scale,
                } => Texture::Checker {
                    a: color_checked(*color1, &key, "color1")?,
                    b: color_checked(*color2, &key, "color2")?,
                    scale: positive_pair(*scale, &key)?,
                },
                TextureSpec::Bricks {
                    brick,
                    mortar,
                    scale,
                    mortar_width,
                } => {
                    if !(0.0..0.5).contains(mortar_width) {
                        return Err(Error::config(
                            format!("{key}.mortar_width"),
                            "must be in [0, 0.5)",
                        ));
                    }
                    Texture::Bricks {
                        brick: color_checked(*brick, &key, "brick")?,
                        mortar_color: color_checked(*mortar, &key, "mortar")?,
                        scale: positive_pair(*scale, &key)?,
                        mortar: *mortar_width,
                    }
                }
                TextureSpec::Image { path } => {
                    let full = base.join(path);
                    let img = crate::io::read_image(&full, 3)
                        .map_err(|e| Error::config(format!("{key}.path"), e.to_string()))?;
                    Texture::Image(img)
                }
            };
            texture_ids.insert(name.clone(), textures.len() as u32);
            textures.push(tex);
        }
        let tex_ref = |c: &ColorOrTexture, key: String| -> Result<TexRef> {
            match c {
                ColorOrTexture::Grey(g) => {
                    Ok(TexRef::constant(color_checked(Color::Grey(*g), &key, "")?))
                }
                ColorOrTexture::Rgb(v) => {
                    Ok(TexRef::constant(color_checked(Color::Rgb(*v), &key, "")?))
                }
                ColorOrTexture::Texture(name) => {
                    let id = *texture_ids
                        .get(name)
                        .ok_or_else(|| Error::config(key, format!("no texture named `{name}`")))?;
                    let tex = &textures[id as usize];
                    let value = tex.mean();
                    let textured = on(fx.textures) && !matches!(tex, Texture::Constant(_));
                    Ok(if textured {
                        TexRef { value, id }
                    } else {
                        TexRef::constant(value)
                    })
                }
            }
        };

        let mut materials = vec![Material::Black];
        let mut material_ids = BTreeMap::new();
        for (name, m) in &self.materials {
            let key = format!("materials.{name}");
            let mat = match m {
                MaterialSpec::Diffuse { reflectance } => Material::Diffuse {
                    reflectance: tex_ref(reflectance, format!("{key}.reflectance"))?,
                },
                MaterialSpec::Conductor { color, roughness } => {
                    if !(0.0..=1.0).contains(roughness) {
                        return Err(Error::config(
                            format!("{key}.roughness"),
                            "must be in [0, 1]",
                        ));
                    }
                    let alpha = if on(fx.rough_reflection) {
                        *roughness
                    } else {
                        0.0
                    };
                    Material::Conductor {
                        color: color_checked(*color, &key, "color")?,
                        alpha,
                    }
                }
                MaterialSpec::Dielectric { ior } => Material::Dielectric {
                    ior: ior_checked(*ior, &key)?,
                },
                MaterialSpec::Plastic { reflectance, ior } => Material::Plastic {
                    base: tex_ref(reflectance, format!("{key}.reflectance"))?,
                    ior: ior_checked(*ior, &key)?,
                },
            };
            material_ids.insert(name.clone(), materials.len() as u32);
            materials.push(mat);
        }

        let mut geometry = Geometry::default();
        let mut lights = Vec::new();
        let mut used = vec![false; materials.len()];
        for (i, s) in self.shapes.iter().enumerate() {
            let key = format!("shapes[{i}]");
            let material = match &s.material {
                Some(name) => *material_ids.get(name).ok_or_else(|| {
                    Error::config(
                        format!("{key}.material"),
                        format!("no material named `{name}`"),
                    )
                })?,
                None if s.emission.is_some() => 0,
                None => {
                    return Err(Error::config(
                        format!("{key}.material"),
                        "missing (only lights may omit it)",
                    ))
                }
            };
            used[material as usize] = true;
            let m = shape_matrix(s, &key)?;
            if m.det3().abs() < 1e-12 {
                return Err(Error::config(key, "transform is singular"));
            }
            let emission = s
                .emission
                .map(|e| color_checked(e, &key, "emission"))
                .transpose()?;
            let radiance = emission.filter(|e| !e.is_black());
            match s.kind {
                ShapeKind::Rectangle | ShapeKind::Cube => {
                    let quads = match s.kind {
                        ShapeKind::Rectangle => vec![Quad::rectangle(&m, material)],
                        _ => Quad::cube(&m, material),
                    };
                    for mut q in quads {
                        if let Some(radiance) = radiance {
                            q.light = lights.len() as u32;
                            lights.push(Light::Quad {
                                index: geometry.quads.len() as u32,
                                radiance,
                            });
                        }
                        geometry.quads.push(q);
                    }
                }
                ShapeKind::Sphere => {
                    let center = m.point([0.0, 0.0, 0.0]);
                    let axes = [
                        m.vector([1.0, 0.0, 0.0]),
                        m.vector([0.0, 1.0, 0.0]),
                        m.vector([0.0, 0.0, 1.0]),
                    ];
                    let radius = axes[0].length();
                    let uniform = axes
                        .iter()
                        .all(|a| (a.length() - radius).abs() <= 1e-4 * radius)
                        && axes[0].dot(axes[1]).abs() <= 1e-4 * radius * radius
                        && axes[1].dot(axes[2]).abs() <= 1e-4 * radius * radius
                        && axes[0].dot(axes[2]).abs() <= 1e-4 * radius * radius;
                    if !uniform {
                        return Err(Error::config(
                            format!("{key}.scale"),
                            "spheres need a uniform scale",
                        ));
                    }
                    let mut sphere = Sphere {
                        center,
                        radius,
                        material,
                        light: super::shapes::NO_LIGHT,
                    };
                    if let Some(radiance) = radiance {
                        sphere.light = lights.len() as u32;
                        lights.push(Light::Sphere {
                            index: geometry.spheres.len() as u32,
                            radiance,
                        });
                    }
                    geometry.spheres.push(sphere);
                }
            }
        }

        let mut environment = None;
        if let Some(env) = &self.environment {
            let radiance = color_checked(env.radiance, "environment", "radiance")?;
            if !radiance.is_black() && on(fx.environment) {
                environment = Some(lights.len());
                lights.push(Light::Environment { radiance });
            }
        }

        let c = &self.camera;
        let (eye, target, up) = (
            Vec3::from_array(c.eye),
            Vec3::from_array(c.target),
            Vec3::from_array(c.up),
        );
        if (target - eye).length() == 0.0 {
            return Err(Error::config(
                "camera.target",
                "must differ from camera.eye",
            ));
        }
        if (target - eye).normalize().cross(up).length() < 1e-6 {
            return Err(Error::config(
                "camera.up",
                "must not be parallel to the view direction",
            ));
        }
        if !(0.0..180.0).contains(&c.fov) || c.fov == 0.0 {
            return Err(Error::config("camera.fov", "must be in (0, 180) degrees"));
        }
        if c.aperture.is_nan() || c.aperture < 0.0 {
            return Err(Error::config("camera.aperture", "must be ≥ 0"));
        }
        let focus = c.focus_distance.unwrap_or((target - eye).length());
        if focus.is_nan() || focus <= 0.0 {
            return Err(Error::config("camera.focus_distance", "must be > 0"));
        }
        let aperture = if on(fx.depth_of_field) {
            c.aperture
        } else {
            0.0
        };
        let camera = Camera::new(eye, target, up, c.fov, (r.width, r.height), aperture, focus);

        let mut effects = EffectSet {
            several_lights: lights.len() > 1,
            environment: environment.is_some(),
            depth_of_field: aperture > 0.0,
            ..EffectSet::default()
        };
        for (m, _) in materials.iter().zip(&used).filter(|(_, u)| **u) {
            match m {
                Material::Diffuse { reflectance } => {
                    effects.textures |= reflectance.id != super::texture::NO_TEXTURE
                }
                Material::Plastic { base, .. } => {
                    effects.textures |= base.id != super::texture::NO_TEXTURE;
                    effects.reflection |= on(fx.reflection);
                }
                Material::Conductor { alpha, .. } => {
                    effects.reflection |= on(fx.reflection);
                    effects.rough_reflection |= *alpha > 0.0;
                }
                Material::Dielectric { .. } => {
                    effects.refraction |= on(fx.refraction);
                    effects.reflection |= on(fx.reflection);
                }
                Material::Black => {}
            }
        }

        Ok(Scene {
            camera,
            geometry,
            materials,
            textures,
            lights,
            environment,
            max_depth: r.max_depth,
            rr_depth: r.rr_depth,
            seed: r.seed,
            caustics: fx.caustics.unwrap_or(true),
            effects,
        })
    }
}

fn color_checked(c: Color, key: &str, field: &str) -> Result<Vec3> {
    let v = c.vec();
    if [v.x, v.y, v.z].iter().all(|x| x.is_finite() && *x >= 0.0) {
        Ok(v)
    } else {
        let key = if field.is_empty() {
            key.to_string()
        } else {
            format!("{key}.{field}")
        };
        Err(Error::config(key, "colour values must be finite and ≥ 0"))
    }
}

fn positive_pair(s: [f32; 2], key: &str) -> Result<(f32, f32)> {
    if s.iter().all(|v| v.is_finite() && *v > 0.0) {
        Ok((s[0], s[1]))
    } else {
        Err(Error::config(
            format!("{key}.scale"),
            "must be two positive numbers",
        ))
    }
}

fn ior_checked(ior: f32, key: &str) -> Result<f32> {
    if ior.is_finite() && ior > 1.0 {
        Ok(ior)
    } else {
        Err(Error::config(
            format!("{key}.ior"),
            "must be a finite number > 1",
        ))
    }
}

/// The shape's to-world matrix: `matrix`, or translate · rotate(z·y·x) · scale.
fn shape_matrix(s: &ShapeSpec, key: &str) -> Result<Mat4> {
    if let Some(m) = s.matrix {
        if s.translate.is_some() || s.rotate.is_some() || s.scale.is_some() {
            return Err(Error::config(
                format!("{key}.matrix"),
                "give either `matrix` or translate/rotate/scale",
            ));
        }
        if m.iter().flatten().any(|v| !v.is_finite()) || m[3] != [0.0, 0.0, 0.0, 1.0] {
            return Err(Error::config(
                format!("{key}.matrix"),
                "must be finite and affine (last row 0 0 0 1)",
            ));
        }
        return Ok(Mat4(m));
    }
    // A NaN or infinite placement would make the shape miss every ray without a word.
    let parts = [("translate", s.translate), ("rotate", s.rotate)];
    for (name, value) in parts {
        if value.is_some_and(|v| v.iter().any(|x| !x.is_finite())) {
            return Err(Error::config(
                format!("{key}.{name}"),
                "must be finite numbers",
            ));
        }
    }
    let mut m = Mat4::translate(s.translate.unwrap_or([0.0; 3]));
    if let Some(r) = s.rotate {
        m = m
            .mul(&Mat4::rotate(2, r[2]))
            .mul(&Mat4::rotate(1, r[1]))
            .mul(&Mat4::rotate(0, r[0]));
    }
    let scale = match s.scale {
        None => [1.0; 3],
        Some(Scale::Uniform(v)) => [v; 3],
        Some(Scale::Axes(v)) => v,
    };
    if scale.iter().any(|x| !x.is_finite()) {
        return Err(Error::config(
            format!("{key}.scale"),
            "must be finite numbers",
        ));
    }
    Ok(m.mul(&Mat4::scale(scale)))
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = r#"
[render]
width = 8
height = 8
[camera]
eye = [0, 0, 3]
target = [0, 0, 0]
fov = 40
[materials.white]
type = "diffuse"
reflectance = 0.5
[[shapes]]
type = "sphere"
material = "white"
"#;

    #[test]
    fn minimal_scene_parses_with_no_effects() {
        let s = Scene::parse(MINIMAL, Path::new(".")).unwrap();
        assert_eq!(s.effects, EffectSet::default());
        assert_eq!(s.geometry.spheres.len(), 1);
    }

    #[test]
    fn errors_name_the_key() {
        let bad = MINIMAL.replace("reflectance = 0.5", "reflectanse = 0.5");
        let e = Scene::parse(&bad, Path::new(".")).unwrap_err().to_string();
        assert!(e.contains("reflectanse"), "{e}");
        let bad = MINIMAL.replace("material = \"white\"", "material = \"whte\"");
        let e = Scene::parse(&bad, Path::new(".")).unwrap_err().to_string();
        assert!(e.starts_with("shapes[0].material"), "{e}");
        let bad = MINIMAL.replace("fov = 40", "fov = \"wide\"");
        let e = Scene::parse(&bad, Path::new(".")).unwrap_err().to_string();
        assert!(e.contains("camera.fov"), "{e}");
    }
}
