//! The packed feature records ([`Features`]) and the recipe that builds them, or their planes,
//! from the buffers ([`Recipe`]). The tests of d's kernels are here too, as they build records.

use rayon::prelude::*;

use super::distance::{distance, FEATURE_LANES, USED_LANES};
use super::planes::FeaturePlanes;
use super::weights::{Tone, Weights, WEIGHT_BUFFER};
use crate::error::{Error, Result};
use crate::image::Image;
use crate::render_set::{Feature, FeatureSet};

/// Record lanes of the material weights (diffuse, reflective, refractive) and the shadow.
const MATERIAL_LANES: std::ops::Range<usize> = 9..13;

/// Packed per-pixel features, ready for `distance`.
#[derive(Clone, Debug)]
pub struct Features {
    width: usize,
    height: usize,
    records: Vec<[f32; FEATURE_LANES]>,
    depth_weight: f32,
    /// Whether the material and shadow lanes ([`MATERIAL_LANES`]) hold anything; when not they are 0 in every
    /// record, and d's kernels leave their terms out (adding them would add +0).
    material: bool,
}

impl Features {
    /// Packs the features of `color` and the feature buffers `features`, weighted by `weights`.
    ///
    /// Returns the features and the names of weighted features switched off because their buffer is missing.
    pub fn build(
        color: &Image,
        features: &FeatureSet,
        weights: &Weights,
        tone: Tone,
        exposure: f32,
    ) -> Result<(Features, Vec<&'static str>)> {
        Features::build_rows(color, features, weights, tone, exposure, 0..color.height())
    }

    /// [`Features::build`] for image rows `rows` only: a Features `rows.len()` rows high whose row 0
    /// is image row `rows.start`. Lets a filter hold one band's features instead of the image's
    /// (64 bytes a pixel).
    pub fn build_rows(
        color: &Image,
        features: &FeatureSet,
        weights: &Weights,
        tone: Tone,
        exposure: f32,
        rows: std::ops::Range<usize>,
    ) -> Result<(Features, Vec<&'static str>)> {
        let recipe = Recipe::new(color, features, weights, tone, exposure, None)?;
        Ok((recipe.records(rows), recipe.off().to_vec()))
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    pub fn depth_weight(&self) -> f32 {
        self.depth_weight
    }

    /// Rows `rows` of the records as one plane per lane (structure of arrays), each row padded with
    /// `pad` zero columns on both sides, so 8 horizontally adjacent pixels are one vector load.
    pub fn planes(&self, rows: std::ops::Range<usize>, pad: usize) -> FeaturePlanes {
        let lanes: Vec<usize> = (0..USED_LANES)
            .filter(|lane| self.material || !MATERIAL_LANES.contains(lane))
            .collect();
        let mut planes =
            FeaturePlanes::build_lanes(self.width, rows, pad, USED_LANES, &lanes, |i, lane| {
                self.records[i][lane]
            });
        planes.material = self.material;
        planes
    }

    #[inline]
    pub fn record(&self, i: usize) -> &[f32; FEATURE_LANES] {
        &self.records[i]
    }

    /// d(i, j) of docs/ALGORITHM.md §2 between pixels `i` and `j` (row-major indices).
    #[inline]
    pub fn distance(&self, i: usize, j: usize) -> f32 {
        distance(&self.records[i], &self.records[j], self.depth_weight)
    }
}

/// How the buffers become feature lanes: the weights with those of missing buffers set to 0, and
/// every feature in use with its first lane and per-channel scale. Made once per image; it builds
/// the records of any band of rows ([`Recipe::records`]) or their planes straight from the buffers
/// ([`Recipe::planes`]), the same bits either way.
pub struct Recipe<'a> {
    color: &'a Image,
    weights: Weights,
    tone: Tone,
    exposure: f32,
    color_scale: Option<&'a [f32]>,
    /// (buffer, first lane, per-channel scale).
    packs: Vec<(&'a Image, usize, Vec<f32>)>,
    /// Whether a material or shadow lane is in use.
    material: bool,
    /// Names of the features switched off because their buffer is missing.
    off: Vec<&'static str>,
}

impl<'a> Recipe<'a> {
    /// The recipe for `color` and the feature buffers `features`, weighted by `weights`, the
    /// tone-mapped colour of every pixel multiplied by its `color_scale` when given (one factor per
    /// image pixel: colour differences in units of the local noise, `crate::filters::noise::color_scales`).
    pub fn new(
        color: &'a Image,
        features: &'a FeatureSet,
        weights: &Weights,
        tone: Tone,
        exposure: f32,
        color_scale: Option<&'a [f32]>,
    ) -> Result<Self> {
        let mut effective = *weights;
        let mut off = Vec::new();
        for (i, buffer) in WEIGHT_BUFFER.iter().enumerate() {
            if weights.as_array()[i] > 0.0 && buffer.is_some_and(|f| !features.contains(f)) {
                effective.set(i, 0.0);
                off.push(Weights::NAMES[i]);
            }
        }
        let wt = effective;
        let fetch = |feature: Feature, weight: f32| -> Result<Option<&'a Image>> {
            if weight <= 0.0 {
                return Ok(None);
            }
            let img = features.get(feature);
            if let Some(img) = img {
                if img.dims() != color.dims() {
                    return Err(Error::buffer(
                        feature.name(),
                        "does not match the colour buffer's size",
                    ));
                }
            }
            Ok(img)
        };
        let mut packs: Vec<(&Image, usize, Vec<f32>)> = Vec::new();
        if let Some(a) = fetch(Feature::Albedo, wt.albedo)? {
            packs.push((a, 3, vec![wt.albedo; 3]));
        }
        if let Some(nm) = fetch(Feature::Normal, wt.normal)? {
            packs.push((nm, 6, vec![wt.normal.sqrt() * 0.5; 3]));
        }
        let material = wt.diffuse.max(wt.reflective).max(wt.refractive);
        if let Some(m) = fetch(Feature::Material, material)? {
            packs.push((m, 9, vec![wt.diffuse, wt.reflective, wt.refractive]));
        }
        if let Some(sh) = fetch(Feature::Shadow, wt.shadow)? {
            packs.push((sh, 12, vec![wt.shadow]));
        }
        let material = packs
            .iter()
            .any(|&(_, lane, _)| MATERIAL_LANES.contains(&lane));
        if let Some(z) = fetch(Feature::Depth, wt.depth)? {
            packs.push((z, 13, vec![1.0]));
        }
        Ok(Recipe {
            color,
            weights: wt,
            tone,
            exposure,
            color_scale,
            packs,
            material,
            off,
        })
    }

    /// Names of the weighted features switched off because their buffer is missing.
    pub fn off(&self) -> &[&'static str] {
        &self.off
    }

    /// The records of image rows `rows`: a [`Features`] `rows.len()` rows high whose row 0 is image
    /// row `rows.start`. Lets a filter hold one band's features instead of the image's (64 bytes a
    /// pixel).
    pub fn records(&self, rows: std::ops::Range<usize>) -> Features {
        let w = self.color.width();
        let h = rows.len();
        let base = rows.start * w;
        let n = w * h;
        let mut records = vec![[0.0f32; FEATURE_LANES]; n];
        // Every record depends on its own pixel only: fill them in parallel chunks.
        const CHUNK: usize = 4096;
        records
            .par_chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(chunk, records)| {
                let first = base + chunk * CHUNK;
                for (i, r) in records.iter_mut().enumerate() {
                    r[..3].copy_from_slice(&self.color(first + i));
                    for (img, lane, scales) in &self.packs {
                        for (k, (&v, &scale)) in img.pixel(first + i).iter().zip(scales).enumerate()
                        {
                            r[lane + k] = scale * v;
                        }
                    }
                }
            });
        Features {
            width: w,
            height: h,
            records,
            depth_weight: self.weights.depth,
            material: self.material,
        }
    }

    /// [`Recipe::records`]`(rows)`'s [`Features::planes`]`(0..rows.len(), pad)`, bit for bit, and the
    /// depth weight, built straight from the buffers without the records: for a filter that reads
    /// only planes, half the copying.
    pub fn planes(&self, rows: std::ops::Range<usize>, pad: usize) -> (FeaturePlanes, f32) {
        let w = self.color.width();
        // Row 0 is image row `rows.start`, as in the band's own records.
        let mut planes = FeaturePlanes::zeroed(w, 0..rows.len(), pad, USED_LANES, self.material);
        let (stride, plane_len, data) = (planes.stride, planes.plane_len, &mut planes.data);
        // Row by row: the colour pixel by pixel into its three lanes, then each buffer lane by lane,
        // reading with a fixed stride and writing one contiguous run.
        for (r, y) in rows.enumerate() {
            let at = r * stride + pad;
            for x in 0..w {
                for (k, v) in self.color(y * w + x).into_iter().enumerate() {
                    data[k * plane_len + at + x] = v;
                }
            }
            for (img, lane, scales) in &self.packs {
                let c = img.channels();
                let src = &img.data()[y * w * c..(y + 1) * w * c];
                for (k, &scale) in scales.iter().enumerate().take(c) {
                    let out = &mut data[(lane + k) * plane_len + at..][..w];
                    for (o, px) in out.iter_mut().zip(src.chunks_exact(c)) {
                        *o = scale * px[k];
                    }
                }
            }
        }
        (planes, self.weights.depth)
    }

    /// The colour lanes of pixel `i` (an image index).
    #[inline(always)]
    fn color(&self, i: usize) -> [f32; 3] {
        let scale = self.color_scale.map_or(1.0, |s| s[i]);
        let c = self.color.pixel(i);
        std::array::from_fn(|k| self.weights.color * scale * self.tone.apply(self.exposure * c[k]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::buffers::Buffers;
    use crate::features::distance::distance_row;
    use crate::kernels::simd::Kernel;

    fn set_with(color: Vec<f32>, w: usize, h: usize) -> (Image, Buffers) {
        let img = Image::from_vec(w, h, 3, color).unwrap();
        let mut b = Buffers::new();
        b.insert("color", img.clone()).unwrap();
        (img, b)
    }

    #[test]
    fn distance_matches_the_formula() {
        let (color, mut b) = set_with(vec![0.0, 0.0, 0.0, 1.0, 1.0, 1.0], 2, 1);
        b.insert(
            "albedo",
            Image::from_vec(2, 1, 3, vec![0.1, 0.2, 0.3, 0.4, 0.2, 0.3]).unwrap(),
        )
        .unwrap();
        b.insert(
            "normal",
            Image::from_vec(2, 1, 3, vec![0.0, 0.0, 1.0, 0.0, 1.0, 0.0]).unwrap(),
        )
        .unwrap();
        b.insert(
            "material",
            Image::from_vec(2, 1, 3, vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0]).unwrap(),
        )
        .unwrap();
        b.insert("shadow", Image::from_vec(2, 1, 1, vec![0.0, 1.0]).unwrap())
            .unwrap();
        b.insert("depth", Image::from_vec(2, 1, 1, vec![1.0, 4.0]).unwrap())
            .unwrap();
        let wts = Weights::default();
        let (f, off) = Features::build(&color, b.features(), &wts, Tone::Reinhard, 1.0).unwrap();
        assert!(off.is_empty());
        let f1 = (3.0f32 * 0.25).sqrt(); // T(1) = 0.5 in each channel
        let f2 = 0.3f32;
        let f3 = 0.5f32; // (1 - 0) / 2
        let expected =
            2.0 * f1 + 2.0 * f2 + 3.0 * f3 + 1.0 + 2.0 + 0.0 + 0.5 * 1.0 + 2.0 * 3.0 / 4.0;
        assert!(
            (f.distance(0, 1) - expected).abs() < 1e-5,
            "{} vs {expected}",
            f.distance(0, 1)
        );
        assert_eq!(f.distance(0, 1), f.distance(1, 0));
        assert_eq!(f.distance(1, 1), 0.0);
    }

    /// Features of a `w`×`h` render with random colour, albedo, normal and depth, and material
    /// and shadow buffers when `material`.
    fn random_features(w: usize, h: usize, material: bool, seed: u64) -> Features {
        let (color, b) = random_set(w, h, material, seed);
        let wts = Weights::default();
        Features::build(&color, b.features(), &wts, Tone::Reinhard, 1.0)
            .unwrap()
            .0
    }

    /// A colour buffer and a set of random albedo, normal and depth (and material and shadow).
    fn random_set(w: usize, h: usize, material: bool, seed: u64) -> (Image, Buffers) {
        let mut next = crate::kernels::trim::tests::xorshift(seed);
        let mut random = |c: usize| {
            let v = (0..w * h * c).map(|_| (next() >> 40) as f32 / (1u64 << 24) as f32);
            Image::from_vec(w, h, c, v.collect()).unwrap()
        };
        let (color, mut b) = set_with(random(3).data().to_vec(), w, h);
        let mut names = vec![("albedo", 3), ("normal", 3), ("depth", 1)];
        if material {
            names.extend([("material", 3), ("shadow", 1)]);
        }
        for (name, c) in names {
            b.insert(name, random(c)).unwrap();
        }
        (color, b)
    }

    #[test]
    fn planes_built_without_records_hold_the_records_bits() {
        let (w, h) = (13, 9);
        let scale: Vec<f32> = (0..w * h).map(|i| 0.5 + (i % 5) as f32 * 0.25).collect();
        let wts = Weights {
            reflective: 0.7,
            ..Weights::default()
        };
        for material in [false, true] {
            let (color, b) = random_set(w, h, material, 11);
            for scale in [None, Some(scale.as_slice())] {
                for (rows, pad) in [(0..h, 0), (2..7, 3), (8..9, 1)] {
                    let recipe =
                        Recipe::new(&color, b.features(), &wts, Tone::Reinhard, 1.5, scale)
                            .unwrap();
                    let records = recipe.records(rows.clone());
                    let want = records.planes(0..rows.len(), pad);
                    let (got, depth_weight) = recipe.planes(rows.clone(), pad);
                    let bits = |p: &FeaturePlanes| p.data.iter().map(|v| v.to_bits()).collect();
                    let bits: (Vec<u32>, Vec<u32>) = (bits(&got), bits(&want));
                    assert!(bits.0 == bits.1, "material {material}, rows {rows:?}");
                    assert_eq!(
                        (got.first_row, got.stride, got.plane_len, got.material),
                        (want.first_row, want.stride, want.plane_len, want.material)
                    );
                    assert_eq!(depth_weight.to_bits(), records.depth_weight().to_bits());
                }
            }
        }
    }

    #[test]
    fn distance_rows_give_the_pairs_distance_bits_with_either_kernel() {
        // 37 wide: four whole groups of 8 and a tail. Without material and shadow buffers their
        // lanes are left out of the planes and of d's vector kernel; with them they count.
        let (w, h, pad) = (37, 4, 3);
        for material in [false, true] {
            let f = random_features(w, h, material, 7 + material as u64);
            let planes = f.planes(0..h, pad);
            for (dx, dy) in [(1, 0), (-2, 1), (0, 1), (3, 1)] {
                for y in 0..h - 1 {
                    let center = planes.offset(0, y);
                    let other = planes.offset(dx, y + dy);
                    for kernel in [Kernel::detect(), Kernel::Scalar] {
                        let mut out = vec![0.0f32; w];
                        distance_row(kernel, &planes, f.depth_weight(), center, other, &mut out);
                        for (x, &d) in out.iter().enumerate() {
                            let nx = x as isize + dx;
                            if nx < 0 || nx >= w as isize {
                                continue;
                            }
                            let want = f.distance(y * w + x, (y + dy) * w + nx as usize);
                            assert_eq!(
                                d.to_bits(),
                                want.to_bits(),
                                "{kernel:?} ({x}, {y}) + ({dx}, {dy}), material {material}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    #[should_panic]
    fn a_distance_run_beyond_the_planes_is_refused() {
        let (w, h) = (16, 2);
        let f = random_features(w, h, false, 3);
        let planes = f.planes(0..h, 0);
        // Row 1 and 8 pixels past its end: beyond the last plane for the vector kernel's loads.
        let mut out = vec![0.0f32; w + 8];
        let center = planes.offset(0, 1);
        distance_row(
            Kernel::detect(),
            &planes,
            f.depth_weight(),
            center,
            center,
            &mut out,
        );
    }

    #[test]
    fn missing_buffers_switch_features_off() {
        let (color, b) = set_with(vec![0.0; 12], 2, 2);
        let (_, off) = Features::build(
            &color,
            b.features(),
            &Weights::default(),
            Tone::Reinhard,
            1.0,
        )
        .unwrap();
        assert_eq!(
            off,
            vec![
                "albedo",
                "normal",
                "diffuse",
                "reflective",
                "refractive",
                "shadow",
                "depth"
            ]
        );
        let (_, off) = Features::build(
            &color,
            b.features(),
            &Weights::color_only(),
            Tone::Reinhard,
            1.0,
        )
        .unwrap();
        assert!(off.is_empty());
    }
}
