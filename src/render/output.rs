//! Writes a render set in the docs/FORMATS.md layout: `scene.toml`, `reference.exr`, `spp<N>/<buffer>.exr`.

use std::path::Path;

use super::integrator::RenderResult;
use crate::error::{Error, Result};
use crate::io::{write_exr, PendingOutput};

/// Writes the six buffers of `r` into `dir` (created if missing), and its noise buffers
/// (`variance`, `color_a`, `color_b`) when it has them (not at 1 spp).
pub fn write_buffers(dir: &Path, r: &RenderResult) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::output(dir, e))?;
    let buffers = [
        ("color", &r.color),
        ("albedo", &r.albedo),
        ("normal", &r.normal),
        ("material", &r.material),
        ("shadow", &r.shadow),
        ("depth", &r.depth),
    ];
    for (name, img) in buffers.into_iter().chain(r.noise.buffers()) {
        write_exr(&dir.join(format!("{name}.exr")), img)?;
    }
    Ok(())
}

/// Writes the colour of `r` as `dir/reference.exr`, and its per-sample colour variance as
/// `dir/sample_variance.exr` (an N-spp set's true noise is it divided by N).
pub fn write_reference(dir: &Path, r: &RenderResult) -> Result<()> {
    write_exr(&dir.join("reference.exr"), &r.color)?;
    match &r.sample_variance {
        Some(s2) => write_exr(&dir.join("sample_variance.exr"), s2),
        None => Ok(()),
    }
}

/// Copies the scene file's text into `dir/scene.toml`.
pub fn write_scene(dir: &Path, text: &str) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::output(dir, e))?;
    PendingOutput::create(&dir.join("scene.toml"))?.write_bytes(text.as_bytes())
}
