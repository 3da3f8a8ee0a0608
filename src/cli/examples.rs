//! The examples every `--help` ends with. Each line starting `gsid ` runs as it is from the
//! repository root on the bundled fixtures (`tests/it/examples.rs` runs them all).

pub(super) const TOP: &str = "\
Examples:
  gsid denoise fixtures/mitsuba-cornell/spp4 -o denoised.exr
  gsid denoise fixtures/cycles-studio/spp4.exr -o denoised.exr --save-buffer out=preview.png
  gsid pipelines

Every command has its own examples: gsid denoise --help, gsid sweep --help, ...";

pub(super) const DENOISE: &str = "\
Examples:
  gsid denoise fixtures/mitsuba-cornell/spp4 -o denoised.exr
  gsid denoise fixtures/cycles-studio/spp4.exr -p fast -o denoised.exr
  gsid denoise fixtures/blender-passes/two-view-layers.exr --layer ViewLayer -o denoised.exr
  gsid denoise --hdr fixtures/mitsuba-cornell/spp4/color.exr --alb fixtures/mitsuba-cornell/spp4/albedo.exr --nrm fixtures/mitsuba-cornell/spp4/normal.exr -o denoised.pfm
  gsid denoise fixtures/mitsuba-cornell/spp4 -o denoised.exr --set gsid.walks=40 --set gsid.weights.depth=0
  gsid denoise 'fixtures/cycles-static-small/spp4/frame.####.exr' -o 'denoised/frame.####.exr' --frames 1-2 --skip-existing";

pub(super) const EVAL: &str = "\
Examples:
  gsid eval fixtures/mitsuba-cornell/spp64/color.exr --reference fixtures/mitsuba-cornell/reference.exr
  gsid eval fixtures/mitsuba-cornell/spp64/color.exr --reference fixtures/mitsuba-cornell/reference.exr --json";

pub(super) const PIPELINES: &str = "\
Examples:
  gsid pipelines";

pub(super) const RENDER: &str = "\
Examples:
  gsid render fixtures/scenes/cornell.toml -o rendered --spp 1,4 --reference-spp 16";

pub(super) const ABLATE: &str = "\
Examples:
  gsid ablate fixtures/mitsuba-cornell/spp4 -p fast --out ablate.csv";

pub(super) const SWEEP: &str = "\
Examples:
  gsid sweep fixtures/mitsuba-cornell/spp4 --vary gsid.walks=2,8 --repeat 1
  gsid sweep fixtures/mitsuba-cornell/spp4 -p fast --vary gsid.walks=1,4 --vary atrous.iterations=1,2 --repeat 1 --out sweep-fast";
