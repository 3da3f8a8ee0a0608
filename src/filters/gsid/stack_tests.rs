//! `stack_color_guide`: the colour guide's k on a `--temporal` frame (a variance measured from the
//! shot's frames), `color_guide`'s everywhere else.

use super::GsidStage;
use crate::buffers::Buffers;
use crate::filters::stage::{Context, Stage, StageIo};
use crate::image::Image;
use crate::render_set::RenderSet;

/// A 24×24 colour edge (0.2 | 0.8) with noise of σ 0.05 and flat features (a mirror's reflection):
/// only the colour tells the sides apart, so the guide changes what the walks average.
fn reflected_edge(from_stack: bool) -> RenderSet {
    let (w, h) = (24, 24);
    let mut state = 99u64;
    let color = Image::from_fn(w, h, 3, |x, _, _| {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let u = (state >> 40) as f32 / (1u64 << 24) as f32;
        let level = if x < w / 2 { 0.2 } else { 0.8 };
        level + 0.05 * (u * 3.46 - 1.73)
    });
    let mut set = RenderSet::new(color);
    set.noise.variance = Some(Image::filled(w, h, 3, 0.0025));
    set.noise.from_stack = from_stack;
    set
}

/// The `gsid` stage (keys `table`, its `noise` the set's variance) on [`reflected_edge`].
fn denoised(table: &str, from_stack: bool) -> Image {
    let mut buffers = Buffers::from(reflected_edge(from_stack));
    buffers.insert_same("noise", "variance").unwrap();
    let io = StageIo {
        input: "color".into(),
        output: "out".into(),
    };
    let table = format!("noise = \"noise\"\nwalks = 4\n{table}");
    let stage = GsidStage::from_table("gsid", io, toml::from_str(&table).unwrap()).unwrap();
    stage
        .execute(&mut buffers, &mut Context::new(0, false))
        .unwrap();
    buffers.get("out").unwrap().clone()
}

#[test]
fn the_stack_guide_counts_on_a_temporal_frame_only() {
    let plain = denoised("", false);
    let guided = denoised("color_guide = 1.0", false);
    assert_ne!(plain, guided, "the case must show the guide");
    // On a single frame the stack's key is left alone, whatever it says.
    assert_eq!(denoised("stack_color_guide = 1.0", false), plain);
    // On a `--temporal` frame it replaces `color_guide`: on with it alone, off without it.
    assert_eq!(denoised("stack_color_guide = 1.0", true), guided);
    assert_eq!(denoised("color_guide = 1.0", true), plain);
}
