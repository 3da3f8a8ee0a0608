//! Builds a large render set by tiling a small one N×N times, for timing at realistic sizes.
//!
//! `cargo run --release --example tile_set -- fixtures/mitsuba-cornell/spp4 /tmp/tiled 8`
//! writes a 1024×1024 set (8×8 copies of the 128×128 fixture) with every buffer the source has.

use std::path::PathBuf;

use gsid::{io, Image};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() != 3 {
        eprintln!("usage: tile_set SRC_DIR DST_DIR N");
        std::process::exit(2);
    }
    let (src, dst) = (PathBuf::from(&args[0]), PathBuf::from(&args[1]));
    let n: usize = args[2].parse().expect("N must be a number");
    let set = io::load_render_set(&src).unwrap_or_else(|e| {
        eprintln!("tile_set: {e}");
        std::process::exit(2);
    });
    std::fs::create_dir_all(&dst).expect("create destination");
    for (name, img) in set.set.buffers() {
        let (w, h) = img.dims();
        let tiled = Image::from_fn(w * n, h * n, img.channels(), |x, y, c| {
            img.at(x % w, y % h)[c]
        });
        io::write_exr(&dst.join(format!("{name}.exr")), &tiled).expect("write");
    }
    if let Some(reference) = &set.reference {
        let img = io::read_image(reference, 3).expect("reference");
        let (w, h) = img.dims();
        let tiled = Image::from_fn(w * n, h * n, 3, |x, y, c| img.at(x % w, y % h)[c]);
        io::write_exr(&dst.join("reference.exr"), &tiled).expect("write");
    }
}
