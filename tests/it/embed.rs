//! The embedding call: borrowed strided views in, the caller's buffer out. It gives the bits of
//! the owned (`Vec`) path whatever the layout, names the buffer at fault, and leaves the caller's
//! buffer untouched when the run fails or is cancelled.

use crate::common;
use gsid::{
    Buffers, CancelToken, DenoiseOptions, Error, Feature, Image, ImageView, ImageViewMut, Inputs,
    Layout, PipelineSpec, RenderSet,
};

const W: usize = 37;
const H: usize = 23;

fn colour() -> Image {
    Image::from_fn(W, H, 3, |x, y, c| {
        let i = (y * W + x) * 3 + c;
        0.1 + (x as f32 / W as f32) * 0.5 + 0.3 * ((i * 7919 % 23) as f32 / 23.0)
    })
}

fn albedo() -> Image {
    Image::from_fn(
        W,
        H,
        3,
        |x, _, c| if x < W / 2 { 0.8 } else { 0.2 + 0.1 * c as f32 },
    )
}

fn normal() -> Image {
    Image::from_fn(W, H, 3, |x, _, c| match (c, x < W / 3) {
        (2, _) => 0.8,
        (0, true) => 0.6,
        _ => 0.0,
    })
}

fn depth() -> Image {
    Image::from_fn(W, H, 1, |x, y, _| 2.0 + (x + y) as f32 * 0.01)
}

/// `img` laid out as an RGBA (or 2-channel for one) framebuffer, rows padded by 5 elements and
/// stored bottom row first, columns right to left: the layout a renderer might hand over.
fn scrambled(img: &Image) -> (Vec<f32>, Layout) {
    let c = img.channels();
    let pixel = c + 1;
    let row = W * pixel + 5;
    let mut data = vec![f32::NAN; row * H];
    for y in 0..H {
        for x in 0..W {
            let at = (H - 1 - y) * row + (W - 1 - x) * pixel;
            data[at..at + c].copy_from_slice(img.at(x, y));
        }
    }
    let layout = Layout {
        width: W,
        height: H,
        channels: c,
        origin: (H - 1) * row + (W - 1) * pixel,
        row_stride: -(row as isize),
        pixel_stride: -(pixel as isize),
        channel_stride: 1,
    };
    (data, layout)
}

/// The owned path: a render set of `Vec`s through `Pipeline::run`.
fn owned(pipeline: &str) -> Image {
    let set = RenderSet::new(colour())
        .with(Feature::Albedo, albedo())
        .unwrap()
        .with(Feature::Normal, normal())
        .unwrap()
        .with(Feature::Depth, depth())
        .unwrap();
    let pipeline = PipelineSpec::builtin(pipeline).unwrap().build().unwrap();
    let options = DenoiseOptions::seeded(5);
    pipeline.run(&mut Buffers::from(set), &options).unwrap().0
}

#[test]
fn strided_views_give_the_bits_of_the_owned_path() {
    let images = [colour(), albedo(), normal(), depth()];
    let laid: Vec<(Vec<f32>, Layout)> = images.iter().map(scrambled).collect();
    let view = |k: usize| ImageView::new(&laid[k].0, laid[k].1);
    let inputs = Inputs::new(view(0))
        .with(Feature::Albedo, view(1))
        .with(Feature::Normal, view(2))
        .with(Feature::Depth, view(3));
    for name in ["full", "fast"] {
        let want = owned(name);
        let pipeline = PipelineSpec::builtin(name).unwrap().build().unwrap();
        // Into an RGBA framebuffer whose alpha must survive.
        let mut fb = vec![0.5f32; W * H * 4];
        let mut out = ImageViewMut::new(&mut fb, Layout::strided(W, H, 3, W * 4, 4));
        pipeline
            .denoise_into(&inputs, &mut out, &DenoiseOptions::seeded(5))
            .unwrap();
        for (px, want) in fb.chunks_exact(4).zip(want.data().chunks_exact(3)) {
            assert_eq!(
                px[..3].iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                want.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                "{name}"
            );
            assert_eq!(px[3], 0.5);
        }
    }
}

#[test]
fn a_failed_or_cancelled_run_leaves_the_callers_buffer_untouched() {
    let (c, a) = (colour(), albedo());
    let pipeline = PipelineSpec::builtin("full").unwrap().build().unwrap();
    let mut fb = vec![-7.0f32; W * H * 3];
    // Cancelled once the pyramid is under way.
    let cancel = CancelToken::new();
    let trigger = cancel.clone();
    let options = DenoiseOptions {
        progress: Some(std::sync::Arc::new(move |_, stage: &str| {
            if stage == "pyramid" {
                trigger.cancel();
            }
        })),
        cancel: Some(cancel),
        ..DenoiseOptions::default()
    };
    let inputs = Inputs::new(ImageView::packed(c.data(), W, H, 3))
        .with(Feature::Albedo, ImageView::packed(a.data(), W, H, 3));
    let mut out = ImageViewMut::packed(&mut fb, W, H, 3);
    let err = pipeline.denoise_into(&inputs, &mut out, &options).err();
    assert!(matches!(err, Some(Error::Cancelled)), "{err:?}");
    assert!(fb.iter().all(|&v| v == -7.0));
    // A colour of nothing but NaN: refused, naming it.
    let nan = vec![f32::NAN; W * H * 3];
    let inputs = Inputs::new(ImageView::packed(&nan, W, H, 3));
    let mut out = ImageViewMut::packed(&mut fb, W, H, 3);
    let err = pipeline
        .denoise_into(&inputs, &mut out, &DenoiseOptions::default())
        .unwrap_err();
    assert!(err.to_string().starts_with("buffer `color`: "), "{err}");
    assert_eq!(err.exit_code(), 2);
    assert!(fb.iter().all(|&v| v == -7.0));
}

#[test]
fn wrong_shapes_and_sizes_name_the_buffer() {
    let pipeline = PipelineSpec::builtin("fast").unwrap().build().unwrap();
    let (c, a) = (colour(), albedo());
    let mut fb = vec![0.0f32; W * H * 3];
    let mut run = |inputs: Inputs| {
        let mut out = ImageViewMut::packed(&mut fb, W, H, 3);
        pipeline
            .denoise_into(&inputs, &mut out, &DenoiseOptions::default())
            .unwrap_err()
            .to_string()
    };
    let color = ImageView::packed(c.data(), W, H, 3);
    // An albedo of another size.
    let small = ImageView::packed(&a.data()[..(W - 1) * H * 3], W - 1, H, 3);
    let err = run(Inputs::new(color).with(Feature::Albedo, small));
    assert!(
        err.starts_with("buffer `albedo`: is 36x23 but colour is 37x23"),
        "{err}"
    );
    // A depth of three channels.
    let err = run(Inputs::new(color).with(Feature::Depth, ImageView::packed(a.data(), W, H, 3)));
    assert!(err.starts_with("buffer `depth`: has 3 channels"), "{err}");
    // A normal view that runs off its slice.
    let short = ImageView::packed(&a.data()[..W * H], W, H, 3);
    let err = run(Inputs::new(color).with(Feature::Normal, short));
    assert!(err.starts_with("buffer `normal`: "), "{err}");
    // A colour of one channel.
    let err = run(Inputs::new(ImageView::packed(&c.data()[..W * H], W, H, 1)));
    assert!(
        err.starts_with("buffer `color`: has 1 channels, expected 3"),
        "{err}"
    );
    // An output of the wrong size, before any work.
    let inputs = Inputs::new(color);
    let mut out = ImageViewMut::packed(&mut fb[..W * (H - 1) * 3], W, H - 1, 3);
    let err = pipeline
        .denoise_into(&inputs, &mut out, &DenoiseOptions::default())
        .unwrap_err()
        .to_string();
    assert!(err.starts_with("buffer `out`: is 37x22"), "{err}");
}

#[test]
fn the_command_line_refuses_a_pass_of_nothing_but_nan_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let set = RenderSet::new(colour())
        .with(Feature::Albedo, Image::filled(W, H, 3, f32::NAN))
        .unwrap();
    common::write_set(&dir.path().join("set"), &Buffers::from(set));
    let out = dir.path().join("out.exr");
    let run = common::gsid(&[
        "denoise",
        "-q",
        dir.path().join("set").to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    common::assert_bad_input(&run, "buffer `albedo`: every sample is NaN");
    assert!(!out.exists());
}
