//! What the noise and regress benchmarks share: the 4 spp `textured` fixture, sanitised as a run
//! does it, its estimated noise and a stand-in for a filtered image.

use std::path::Path;

use gsid::filters::noise;
use gsid::render_set::RenderSet;
use gsid::{condition, io, Image};

/// The 128×128 `textured` set at 4 spp, its noise estimate, and the input with half its noise's
/// standard deviation added (a stand-in for a filtered image: close to the input, not equal).
pub fn textured_4spp() -> (RenderSet, Image, Image) {
    let mut set = io::load_render_set(Path::new("fixtures/textured/spp4"))
        .unwrap()
        .set;
    condition::sanitize(Some(&mut set.color), &mut set.features);
    let variance = noise::estimate(&set.color, &set.features);
    let (w, h) = set.color.dims();
    let filtered = Image::from_fn(w, h, 3, |x, y, k| {
        let (c, v) = (set.color.at(x, y)[k], variance.at(x, y)[k]);
        c + 0.5 * v.sqrt()
    });
    (set, variance, filtered)
}
