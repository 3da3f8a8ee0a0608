//! The scene file's format (TOML) as written: serde types with the format's defaults, each
//! table's keys checked by name (`deny_unknown_fields`). `scene` resolves them into a `Scene`.

use std::collections::BTreeMap;

use serde::Deserialize;

use super::math::Vec3;

#[derive(Deserialize, Debug)]
#[serde(deny_unknown_fields)]
pub struct SceneSpec {
    pub render: RenderSpec,
    pub camera: CameraSpec,
    pub environment: Option<EnvironmentSpec>,
    #[serde(default)]
    pub effects: EffectsSpec,
    #[serde(default)]
    pub textures: BTreeMap<String, TextureSpec>,
    #[serde(default)]
    pub materials: BTreeMap<String, MaterialSpec>,
    pub shapes: Vec<ShapeSpec>,
}

#[derive(Deserialize, Debug)]
#[serde(deny_unknown_fields)]
pub struct RenderSpec {
    pub width: u32,
    pub height: u32,
    /// Mitsuba's convention: 1 = lights seen directly, 2 = plus direct lighting, ….
    #[serde(default = "default_max_depth")]
    pub max_depth: u32,
    /// Bounce count from which Russian roulette may end paths.
    #[serde(default = "default_rr_depth")]
    pub rr_depth: u32,
    #[serde(default)]
    pub seed: u64,
}

fn default_max_depth() -> u32 {
    8
}

fn default_rr_depth() -> u32 {
    5
}

#[derive(Deserialize, Debug)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    pub eye: [f32; 3],
    pub target: [f32; 3],
    #[serde(default = "default_up")]
    pub up: [f32; 3],
    /// Vertical field of view, degrees.
    pub fov: f32,
    /// Lens radius in scene units; 0 = pinhole.
    #[serde(default)]
    pub aperture: f32,
    /// Distance of the plane in focus; default: eye to target.
    pub focus_distance: Option<f32>,
}

fn default_up() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}

#[derive(Deserialize, Debug)]
#[serde(deny_unknown_fields)]
pub struct EnvironmentSpec {
    pub radiance: Color,
}

/// Switches for effects; `false` turns an effect off even if the scene calls for it.
#[derive(Deserialize, Debug, Default)]
#[serde(deny_unknown_fields)]
pub struct EffectsSpec {
    /// `false`: a path that has bounced off a non-specular surface ends when it meets glass (no caustics).
    pub caustics: Option<bool>,
    /// `false`: glass only reflects.
    pub refraction: Option<bool>,
    /// `false`: mirrors and glass go black, plastic loses its coat.
    pub reflection: Option<bool>,
    /// `false`: rough conductors become smooth mirrors.
    pub rough_reflection: Option<bool>,
    /// `false`: every texture is replaced by its mean colour.
    pub textures: Option<bool>,
    /// `false`: the environment is black.
    pub environment: Option<bool>,
    /// `false`: pinhole camera whatever the aperture.
    pub depth_of_field: Option<bool>,
}

/// A colour: one grey value or `[r, g, b]` (linear).
#[derive(Deserialize, Debug, Clone, Copy)]
#[serde(untagged)]
pub enum Color {
    Grey(f32),
    Rgb([f32; 3]),
}

impl Color {
    pub(super) fn vec(self) -> Vec3 {
        match self {
            Color::Grey(g) => Vec3::splat(g),
            Color::Rgb(c) => Vec3::from_array(c),
        }
    }
}

/// A material's colour slot: a grey value, `[r, g, b]`, or the name of a texture.
#[derive(Deserialize, Debug, Clone)]
#[serde(untagged)]
pub enum ColorOrTexture {
    Grey(f32),
    Rgb([f32; 3]),
    Texture(String),
}

#[derive(Deserialize, Debug)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
pub enum TextureSpec {
    Constant {
        color: Color,
    },
    Checker {
        color1: Color,
        color2: Color,
        /// Squares across u and v.
        #[serde(default = "default_checks")]
        scale: [f32; 2],
    },
    Bricks {
        brick: Color,
        mortar: Color,
        /// Bricks across u, rows across v.
        #[serde(default = "default_bricks")]
        scale: [f32; 2],
        /// Joint width as a fraction of a row's height.
        #[serde(default = "default_mortar_width")]
        mortar_width: f32,
    },
    Image {
        /// Linear EXR or sRGB PNG/JPEG, relative to the scene file.
        path: String,
    },
}

fn default_checks() -> [f32; 2] {
    [8.0, 8.0]
}

fn default_bricks() -> [f32; 2] {
    [4.0, 8.0]
}

fn default_mortar_width() -> f32 {
    0.1
}

#[derive(Deserialize, Debug)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
pub enum MaterialSpec {
    Diffuse {
        reflectance: ColorOrTexture,
    },
    #[serde(alias = "mirror")]
    Conductor {
        #[serde(default = "default_white")]
        color: Color,
        /// GGX α; 0 = perfect mirror.
        #[serde(default)]
        roughness: f32,
    },
    #[serde(alias = "glass")]
    Dielectric {
        #[serde(default = "default_ior")]
        ior: f32,
    },
    Plastic {
        reflectance: ColorOrTexture,
        #[serde(default = "default_ior")]
        ior: f32,
    },
}

fn default_white() -> Color {
    Color::Grey(1.0)
}

fn default_ior() -> f32 {
    1.5
}

#[derive(Deserialize, Debug, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum ShapeKind {
    /// Unit sphere at the origin.
    Sphere,
    /// `[-1, 1]²` in the z = 0 plane, normal +z.
    Rectangle,
    /// `[-1, 1]³`, normals outward.
    #[serde(alias = "box")]
    Cube,
}

#[derive(Deserialize, Debug)]
#[serde(deny_unknown_fields)]
pub struct ShapeSpec {
    #[serde(rename = "type")]
    pub kind: ShapeKind,
    /// Material name; optional for lights (default: black).
    pub material: Option<String>,
    /// Makes the shape an area light with this radiance, emitted on the side its normals face.
    pub emission: Option<Color>,
    /// Row-major 4×4 to-world matrix; excludes translate/rotate/scale.
    pub matrix: Option<[[f64; 4]; 4]>,
    pub translate: Option<[f64; 3]>,
    /// Degrees about x, then y, then z.
    pub rotate: Option<[f64; 3]>,
    pub scale: Option<Scale>,
}

#[derive(Deserialize, Debug, Clone, Copy)]
#[serde(untagged)]
pub enum Scale {
    Uniform(f64),
    Axes([f64; 3]),
}
