//! The levels of a pyramid: REDUCE and EXPAND, and how each buffer is reduced (colour by a
//! masked Gaussian, depth by the nearest surface, normals renormalised) (docs/ALGORITHM.md §4).
//!
//! REDUCE is a sum-1 Gaussian (σ = 1 source pixel, close to the 5-tap binomial) followed by halving
//! (odd sizes round up); EXPAND interpolates back to a stored size with the same Gaussian in coarse
//! pixels. Both are convolution resamplings by `fast_image_resize` with a custom filter, which
//! renormalises the kernel at borders, so energy is kept there too.

use fast_image_resize as fr;

use crate::buffers::Buffers;
use crate::error::{Error, Result};
use crate::image::Image;
use crate::render_set::Feature;

/// Levels stop before either side would drop below this many pixels.
pub const MIN_LEVEL_SIZE: usize = 4;

/// The Gaussian used by REDUCE and EXPAND, in destination pixels when downscaling (σ = 0.5 there is
/// σ = 1 source pixel) and in source pixels when upscaling.
pub(super) fn gaussian(x: f64) -> f64 {
    (-2.0 * x * x).exp()
}

fn filter() -> fr::FilterType {
    // Support 1.5 = 3σ; the constructor only fails for a non-positive support.
    fr::FilterType::Custom(
        fr::Filter::new("gaussian-0.5", gaussian, 1.5).expect("positive support"),
    )
}

/// Resamples `img` to `w × h` with the pyramid Gaussian.
pub fn resample(img: &Image, w: usize, h: usize) -> Result<Image> {
    if img.dims() == (w, h) {
        return Ok(img.clone());
    }
    // One typed instance per channel count: `Resizer::resize` dispatches on the pixel type at run
    // time and so compiles every pixel type the crate knows (u8, u16, i32 …), most of this crate's
    // generated code for four types it uses. `resize` calls `resize_typed` itself: the same bits.
    let mut data = vec![0.0f32; w * h * img.channels()];
    match img.channels() {
        1 => resample_typed::<fr::pixels::F32>(img, w, h, &mut data)?,
        2 => resample_typed::<fr::pixels::F32x2>(img, w, h, &mut data)?,
        3 => resample_typed::<fr::pixels::F32x3>(img, w, h, &mut data)?,
        4 => resample_typed::<fr::pixels::F32x4>(img, w, h, &mut data)?,
        c => return Err(Error::Usage(format!("cannot resample a {c}-channel image"))),
    }
    Image::from_vec(w, h, img.channels(), data)
}

fn resample_typed<P: fr::PixelTrait>(
    img: &Image,
    w: usize,
    h: usize,
    out: &mut [f32],
) -> Result<()> {
    let fail = |e: &dyn std::fmt::Display| Error::Runtime(format!("resample: {e}"));
    let src = fr::images::TypedImageRef::<P>::from_buffer(
        img.width() as u32,
        img.height() as u32,
        bytemuck::cast_slice(img.data()),
    )
    .map_err(|e| fail(&e))?;
    let mut dst =
        fr::images::TypedImage::<P>::from_buffer(w as u32, h as u32, bytemuck::cast_slice_mut(out))
            .map_err(|e| fail(&e))?;
    let options = fr::ResizeOptions::new().resize_alg(fr::ResizeAlg::Convolution(filter()));
    fr::Resizer::new()
        .resize_typed(&src, &mut dst, &options)
        .map_err(|e| fail(&e))
}

/// Size of the next coarser level.
pub fn half(w: usize, h: usize) -> (usize, usize) {
    (w.div_ceil(2), h.div_ceil(2))
}

/// REDUCE: blur and halve.
pub fn reduce(img: &Image) -> Result<Image> {
    let (w, h) = half(img.width(), img.height());
    resample(img, w, h)
}

/// EXPAND: interpolate up to the stored finer size.
pub fn expand(img: &Image, w: usize, h: usize) -> Result<Image> {
    resample(img, w, h)
}

/// How many levels an image of `w × h` allows, up to `wanted`.
pub fn allowed_levels(w: usize, h: usize, wanted: usize) -> usize {
    let (mut w, mut h) = (w, h);
    let mut levels = 1;
    while levels < wanted {
        let (nw, nh) = half(w, h);
        if nw < MIN_LEVEL_SIZE || nh < MIN_LEVEL_SIZE {
            break;
        }
        (w, h) = (nw, nh);
        levels += 1;
    }
    levels
}

/// Depth REDUCE: the nearest surface of each 2×2 block, so no phantom depths between surfaces appear.
pub fn reduce_min(img: &Image) -> Image {
    let (w, h) = img.dims();
    let (nw, nh) = half(w, h);
    let c = img.channels();
    Image::from_fn(nw, nh, c, |x, y, ch| {
        let mut m = f32::INFINITY;
        for yy in 2 * y..(2 * y + 2).min(h) {
            for xx in 2 * x..(2 * x + 2).min(w) {
                m = m.min(img.at(xx, yy)[ch]);
            }
        }
        m
    })
}

/// Scales every non-zero 3-vector back to unit length (zero stays "unknown").
pub fn renormalize(img: &mut Image) {
    for n in img.data_mut().chunks_exact_mut(3) {
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        if len > 1e-6 {
            n.iter_mut().for_each(|v| *v /= len);
        } else {
            n.fill(0.0);
        }
    }
}

/// REDUCE of colour that ignores masked pixels (normalised convolution), so a masked firefly does not
/// spread into coarse levels. Returns the colour and the coarse mask (set where no valid pixel fed it).
pub fn reduce_masked(color: &Image, mask: &Image) -> Result<(Image, Image)> {
    let (w, h) = color.dims();
    let valid = Image::from_fn(
        w,
        h,
        1,
        |x, y, _| if mask.at(x, y)[0] > 0.5 { 0.0 } else { 1.0 },
    );
    let weighted = Image::from_fn(w, h, 3, |x, y, c| color.at(x, y)[c] * valid.at(x, y)[0]);
    let (nw, nh) = half(w, h);
    let num = resample(&weighted, nw, nh)?;
    let den = resample(&valid, nw, nh)?;
    let plain = resample(color, nw, nh)?;
    let mut out = Image::new(nw, nh, 3);
    let mut coarse_mask = Image::new(nw, nh, 1);
    for i in 0..nw * nh {
        let d = den.pixel(i)[0];
        if d > 1e-3 {
            for c in 0..3 {
                out.pixel_mut(i)[c] = (num.pixel(i)[c] / d).max(0.0);
            }
        } else {
            out.pixel_mut(i).copy_from_slice(plain.pixel(i));
            coarse_mask.pixel_mut(i)[0] = 1.0;
        }
    }
    Ok((out, coarse_mask))
}

/// The next coarser level of every buffer: colour-like buffers by REDUCE, normals renormalised,
/// depth by nearest surface, the colour `input` masked by `mask` when one is given.
pub fn reduce_buffers(buffers: &Buffers, input: &str, mask: Option<&str>) -> Result<Buffers> {
    let masked = match (mask, buffers.get(input)) {
        (Some(m), Some(color)) => match buffers.get(m) {
            Some(mask_img) => Some(reduce_masked(color, mask_img)?),
            None => None,
        },
        _ => None,
    };
    let mut out = Buffers::new();
    for (name, img) in buffers.iter() {
        let reduced = match &masked {
            Some((color, _)) if name == input => color.clone(),
            Some((_, m)) if Some(name) == mask => m.clone(),
            _ => match Feature::from_name(name) {
                Some(feature) => reduce_feature(feature, img)?,
                None => reduce(img)?,
            },
        };
        out.insert(name, reduced)?;
    }
    out.inherit_origin(buffers);
    Ok(out)
}

/// REDUCE of one feature buffer: depth by nearest surface (no phantom depths between two
/// surfaces), normals renormalised, the rest as colour.
pub fn reduce_feature(feature: Feature, img: &Image) -> Result<Image> {
    Ok(match feature {
        Feature::Depth => reduce_min(img),
        Feature::Normal => {
            let mut n = reduce(img)?;
            renormalize(&mut n);
            n
        }
        Feature::Albedo | Feature::Material | Feature::Shadow => reduce(img)?,
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn ramp(w: usize, h: usize) -> Image {
        Image::from_fn(w, h, 3, |x, y, c| {
            ((x * 13 + y * 7 + c * 5) % 17) as f32 / 4.0 + 0.01
        })
    }

    #[test]
    fn a_coarser_level_keeps_a_stack_frames_origin() {
        // A `--temporal` frame's variance was measured from the shot's frames; its coarser levels'
        // stages (a `gsid` stage's `stack_color_guide`) must know it too.
        for from_stack in [false, true] {
            let mut set = crate::render_set::RenderSet::new(ramp(8, 6));
            set.noise.variance = Some(Image::filled(8, 6, 3, 0.01));
            set.noise.from_stack = from_stack;
            set.noise.resampled = from_stack;
            let coarse = reduce_buffers(&Buffers::from(set), "color", None).unwrap();
            assert_eq!(coarse.variance_from_stack(), from_stack);
            assert_eq!(coarse.resampled(), from_stack);
        }
    }

    #[test]
    fn reduce_keeps_the_mean() {
        let img = ramp(40, 30);
        let small = reduce(&img).unwrap();
        assert_eq!(small.dims(), (20, 15));
        for (a, b) in img.channel_means().iter().zip(small.channel_means()) {
            assert!((a - b).abs() < 0.02 * a, "{a} vs {b}");
        }
    }

    #[test]
    fn every_channel_count_resamples_each_channel_on_its_own() {
        // Channel k of every pixel is constant k + 1: a pixel type mapped to the wrong channel
        // count would mix channels or fail. Sizes from 1×1 and odd, up and down.
        for c in 1..=4 {
            for (w, h, nw, nh) in [(1, 1, 3, 2), (7, 5, 4, 3), (9, 4, 17, 8)] {
                let img = Image::from_fn(w, h, c, |_, _, k| k as f32 + 1.0);
                let out = resample(&img, nw, nh).unwrap();
                assert_eq!((out.dims(), out.channels()), ((nw, nh), c));
                for px in out.data().chunks_exact(c) {
                    for (k, &v) in px.iter().enumerate() {
                        assert!((v - (k as f32 + 1.0)).abs() < 1e-5, "{c} channels: {px:?}");
                    }
                }
            }
        }
        let five = Image::new(4, 4, 5);
        let err = resample(&five, 2, 2).unwrap_err().to_string();
        assert!(err.contains("5-channel"), "{err}");
    }

    #[test]
    fn depth_reduce_picks_the_nearest_surface() {
        let d = Image::from_vec(3, 1, 1, vec![5.0, 1.0, 9.0]).unwrap();
        assert_eq!(reduce_min(&d).data(), &[1.0, 9.0]);
    }

    #[test]
    fn masked_reduce_ignores_fireflies() {
        let mut color = Image::filled(8, 8, 3, 0.5);
        color.pixel_mut(27).copy_from_slice(&[1e6; 3]);
        let mut mask = Image::new(8, 8, 1);
        mask.pixel_mut(27)[0] = 1.0;
        let (small, coarse_mask) = reduce_masked(&color, &mask).unwrap();
        assert!(small.data().iter().all(|&v| (v - 0.5).abs() < 1e-5));
        assert!(coarse_mask.data().iter().all(|&v| v == 0.0));
    }

    #[test]
    fn level_count_is_clipped_for_small_images() {
        assert_eq!(allowed_levels(1, 1, 4), 1);
        assert_eq!(allowed_levels(37, 23, 4), 3);
        assert_eq!(allowed_levels(128, 128, 4), 4);
    }
}
