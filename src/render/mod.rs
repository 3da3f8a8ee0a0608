//! `gsid render`: the fixture renderer, a small path tracer that writes full render sets.
//!
//! A scene file ([`scene`]) is resolved into shapes, materials, textures and lights; the effects it calls
//! for pick an integrator compiled for exactly that set ([`effects`], [`integrator`]); the six buffers of
//! docs/ALGORITHM.md §1 are averaged over each pixel's samples and written in the docs/FORMATS.md layout ([`output`]).

pub mod camera;
pub mod effects;
pub mod integrator;
pub mod light;
pub mod material;
pub mod math;
pub mod output;
pub mod scene;
pub mod scene_file;
pub mod shapes;
pub mod texture;

use std::path::PathBuf;

use indicatif::{ProgressBar, ProgressStyle};

pub use effects::EffectSet;
pub use integrator::{render, RenderResult, Stats};
pub use scene::Scene;

use crate::error::{Error, Result};
use crate::io::PendingFolder;
use crate::run::RunContext;

#[derive(clap::Args, Debug)]
pub struct RenderArgs {
    /// Scene file (TOML, see fixtures/scenes/).
    pub scene: PathBuf,
    /// Output render-set folder.
    #[arg(long, short)]
    pub output: PathBuf,
    /// Sample counts of the noisy sets, comma-separated; each gets its own seed.
    #[arg(long, value_delimiter = ',', default_value = "1,4,16,64")]
    pub spp: Vec<u32>,
    /// Samples per pixel of reference.exr (0: no reference).
    #[arg(long, default_value_t = 4096)]
    pub reference_spp: u32,
    /// Override the scene's seed.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Worker threads, 1 to 1024 (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Use the all-effects integrator instead of the one specialised to the scene (for comparisons).
    #[arg(long)]
    pub all_effects: bool,
    /// Most memory the render may take, in MiB; a scene whose estimate (its size and its image
    /// textures, from their headers) is larger is refused before anything is decoded or written
    /// (default: three quarters of this machine's memory).
    #[arg(long, value_name = "MIB")]
    pub max_memory: Option<u64>,
}

/// The file that marks a folder `gsid render` wrote: only such a folder is replaced by a new render.
pub const RENDER_SET_MARKER: &str = ".gsid-render-set";

/// Seed of the render at `spp` samples (`reference` apart): different for every sample count.
pub fn seed_for(scene_seed: u64, spp: u32, reference: bool) -> u64 {
    integrator::mix(scene_seed ^ integrator::mix(((reference as u64) << 32) | spp as u64))
}

/// Entry point of `gsid render`.
pub fn run(args: &RenderArgs, quiet: bool) -> Result<()> {
    if args.spp.contains(&0) {
        return Err(Error::config("--spp", "sample counts must be ≥ 1"));
    }
    let text = crate::io::read_text(&args.scene, scene::MAX_SCENE_BYTES, "scene file")?;
    let limit = crate::options::memory_limit(args.max_memory);
    let scene = Scene::load_within(&args.scene, limit)?;
    let seed = args.seed.unwrap_or(scene.seed);
    let effects = if args.all_effects {
        EffectSet::ALL
    } else {
        scene.effects
    };
    let ctx = RunContext::new(args.threads, !quiet, seed)?;
    if ctx.progress {
        let names = effects.names();
        let list = if names.is_empty() {
            "diffuse only".to_string()
        } else {
            names.join(", ")
        };
        crate::progress::say_err!(
            "gsid: rendering {} with effects: {list}",
            args.scene.display()
        );
    }
    // Built under a temporary name and renamed into place: never half a render set.
    let folder = PendingFolder::create(&args.output, RENDER_SET_MARKER)?;
    let dir = folder.staging();
    output::write_scene(dir, &text)?;
    let mut jobs: Vec<(u32, bool)> = args.spp.iter().map(|&n| (n, false)).collect();
    if args.reference_spp > 0 {
        jobs.push((args.reference_spp, true));
    }
    for (spp, reference) in jobs {
        let bar = if !ctx.progress {
            ProgressBar::hidden()
        } else {
            ProgressBar::new(0)
        };
        let label = if reference {
            format!("reference {spp} spp")
        } else {
            format!("spp{spp}")
        };
        bar.set_style(
            ProgressStyle::with_template("{msg:>18} [{bar:30}] {pos}/{len} tiles {elapsed}")
                .map_err(|e| Error::Runtime(e.to_string()))?
                .progress_chars("=> "),
        );
        bar.set_message(label.clone());
        let seed = seed_for(ctx.seed, spp, reference);
        let r = ctx.install(|| render(&scene, spp, seed, effects, &bar));
        bar.finish_and_clear();
        if reference {
            output::write_reference(dir, &r)?;
        } else {
            output::write_buffers(&dir.join(format!("spp{spp}")), &r)?;
        }
        if ctx.progress {
            let samples = r.stats.paths as f64;
            crate::progress::say_err!(
                "gsid: {label}: {:.2} s, {:.2} M samples/s on {} threads",
                r.seconds,
                samples / r.seconds / 1e6,
                ctx.threads()
            );
        }
    }
    folder.commit()
}
