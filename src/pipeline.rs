//! Pipelines: a [`PipelineSpec`] (the file as a data tree, see `spec`) built into a [`Pipeline`] of
//! validated stages, and the run of those stages over a render set.

use std::time::Instant;

use serde::Serialize;

use crate::buffers::{Buffers, COLOR};
use crate::condition::{check_recorded, scale_image_f64, Conditioning, SanitizeReport};
use crate::error::{Error, Result};
use crate::filters::stage::{steps_per_pixel_allowed, MAX_STEPS_PER_PIXEL};
use crate::filters::{self, Context, Stage, StageReport};
use crate::image::Image;
use crate::meter::Meter;
use crate::options::DenoiseOptions;
pub use crate::spec::{PipelineSpec, StageSpec, BUILTIN, OUTPUT_BUFFER};

/// Bytes a pixel of the heaviest preset takes at its peak, with a quarter's margin.
const BYTES_PER_PIXEL: u64 = 200;
/// Bytes a run takes whatever its size: the binary, thread stacks, tables.
const BASE_BYTES: u64 = 32 << 20;

/// The pipeline `gsid denoise` runs without `--pipeline`.
pub const DEFAULT_PIPELINE: &str = "full";

impl PipelineSpec {
    /// Builds and validates every stage ([`Pipeline::from_spec`]).
    pub fn build(&self) -> Result<Pipeline> {
        Pipeline::from_spec(self)
    }
}

/// A built pipeline: stages in order.
pub struct Pipeline {
    pub name: String,
    pub description: String,
    pub stages: Vec<Box<dyn Stage>>,
    /// The pipeline file's `temporal` key: frames each side a sequence is merged over.
    pub temporal: Option<usize>,
}

/// What a run did: sanitisation, notices, per-stage timings.
#[derive(Clone, Debug, Serialize)]
pub struct RunReport {
    pub pipeline: String,
    pub sanitized: SanitizeReport,
    pub notes: Vec<String>,
    pub stages: Vec<StageReport>,
    pub seconds: f64,
    /// The factor the colour was brought to the stages' brightness by: the buffers the run leaves
    /// (but the colour and the result, brought back) are at that exposure; see
    /// [`Pipeline::at_input_exposure`].
    #[serde(skip)]
    pub exposure_scale: f32,
}

impl RunReport {
    pub fn walk_steps(&self) -> u64 {
        self.stages.iter().map(|s| s.walk_steps).sum()
    }
}

impl Pipeline {
    /// Builds and validates every stage of `spec`; errors name the file.
    pub fn from_spec(spec: &PipelineSpec) -> Result<Self> {
        let stages = spec
            .stages
            .iter()
            .map(|s| filters::build(s).map_err(|e| e.in_file(&spec.origin)))
            .collect::<Result<Vec<_>>>()?;
        let pipeline = Pipeline {
            name: spec.name.clone(),
            description: spec.description.clone(),
            stages,
            temporal: spec.temporal,
        };
        let steps = pipeline.steps_per_pixel();
        if steps > MAX_STEPS_PER_PIXEL {
            return Err(Error::config(
                format!("{}: walks", spec.origin),
                format!(
                    "the pipeline's walks may take {steps:.0} steps per pixel (walks × max_steps over its gsid stages, pyramid levels counted by their size), more than the {MAX_STEPS_PER_PIXEL:.0} allowed"
                ),
            ));
        }
        Ok(pipeline)
    }

    /// Conditions the inputs (sanitising, brightness: [`Conditioning`]), runs every stage, and
    /// takes the `out` buffer out of `buffers` (back at the input's scale, as is `color`) with a
    /// report. `options` gives the seed, the threads, progress and cancellation.
    pub fn run(
        &self,
        buffers: &mut Buffers,
        options: &DenoiseOptions,
    ) -> Result<(Image, RunReport)> {
        options.install(|| self.run_here(buffers, options))?
    }

    /// [`Pipeline::run`] on the current thread pool.
    fn run_here(
        &self,
        buffers: &mut Buffers,
        options: &DenoiseOptions,
    ) -> Result<(Image, RunReport)> {
        let start = Instant::now();
        check_recorded(buffers)?;
        let conditioning = Conditioning::apply(buffers);
        let mut ctx = Context::new(options.seed, options.progress_bar);
        ctx.meter = Meter::new(options);
        for line in conditioning.notes() {
            ctx.note(line);
        }
        self.check_buffers(buffers)?;
        self.check_steps(buffers)?;
        if let (Some(limit), Some(color)) = (options.max_memory, buffers.get(COLOR)) {
            let (w, h) = color.dims();
            self.check_memory(w, h, limit)?;
        }
        let count = self.stages.len().max(1) as f32;
        for (done, stage) in self.stages.iter().enumerate() {
            let share = (done as f32 / count, (done + 1) as f32 / count);
            ctx.meter.stage(share.0, share.1, stage.id());
            stage.execute(buffers, &mut ctx)?;
        }
        if let Some(color) = buffers.get_mut(COLOR) {
            conditioning.undo(color);
        }
        let mut out = buffers.remove(OUTPUT_BUFFER).ok_or_else(|| {
            Error::buffer(
                OUTPUT_BUFFER,
                format!("pipeline {} never writes it", self.name),
            )
        })?;
        conditioning.undo(&mut out);
        ctx.meter.finish();
        let report = RunReport {
            pipeline: self.name.clone(),
            sanitized: conditioning.sanitized,
            notes: ctx.notes,
            stages: ctx.reports,
            seconds: start.elapsed().as_secs_f64(),
            exposure_scale: conditioning.scale,
        };
        Ok((out, report))
    }

    /// Buffer `name` as a run left it, brought back to the input's exposure (the run's
    /// `report.exposure_scale`): light scales with it, a variance with its square, features and masks
    /// not at all; the colour and the result are back already.
    pub fn at_input_exposure<'a>(
        &self,
        name: &str,
        buffer: &'a Image,
        report: &RunReport,
    ) -> std::borrow::Cow<'a, Image> {
        use crate::render_set::NoiseInputs;
        let writer = || {
            self.stages
                .iter()
                .rev()
                .find(|s| s.writes().iter().any(|w| w == name))
        };
        let power = if name == COLOR || name == crate::spec::OUTPUT_BUFFER {
            0
        } else if let Some(stage) = writer() {
            stage.exposure_power(name)
        } else if name == NoiseInputs::VARIANCE {
            2
        } else {
            i32::from(NoiseInputs::HALVES.contains(&name))
        };
        let factor = (report.exposure_scale as f64).powi(-power);
        if power == 0 || !factor.is_finite() || factor == 1.0 {
            return std::borrow::Cow::Borrowed(buffer);
        }
        let mut out = buffer.clone();
        scale_image_f64(&mut out, factor);
        std::borrow::Cow::Owned(out)
    }

    /// Bytes a run of this pipeline takes at most on a `w`×`h` colour, the inputs included: the
    /// presets' measured peaks (140–160 bytes a pixel at 1 and 4 MP, with the binary and the
    /// decoded inputs) with a quarter's margin, doubled for a pyramid nested in another.
    pub fn peak_bytes(&self, w: usize, h: usize) -> u64 {
        let nesting = self.stages.iter().map(|s| s.nesting()).max().unwrap_or(0);
        let per_pixel = BYTES_PER_PIXEL << nesting.saturating_sub(1);
        BASE_BYTES.saturating_add(
            (w as u64)
                .saturating_mul(h as u64)
                .saturating_mul(per_pixel),
        )
    }

    /// Refuses, before any work, a `w`×`h` run whose estimate ([`Pipeline::peak_bytes`]) is above
    /// `limit` bytes, naming both.
    pub fn check_memory(&self, w: usize, h: usize, limit: u64) -> Result<()> {
        crate::options::check_memory(self.peak_bytes(w, h), limit, |mib| {
            format!(
                "a {w}x{h} image needs about {mib} MiB with pipeline {}",
                self.name
            )
        })
    }

    /// The most walk steps a pixel may take, over every stage.
    pub fn steps_per_pixel(&self) -> f64 {
        self.stages.iter().map(|s| s.steps_per_pixel()).sum()
    }

    /// Checks, before any work, that the walks fit the time budget of an image this size.
    fn check_steps(&self, buffers: &Buffers) -> Result<()> {
        let Some((w, h)) = buffers.get(COLOR).map(Image::dims) else {
            return Ok(());
        };
        let (steps, allowed) = (self.steps_per_pixel(), steps_per_pixel_allowed(w * h));
        if steps > allowed {
            return Err(Error::config(
                "walks",
                format!(
                    "pipeline {} may take {steps:.0} walk steps a pixel, {:.1} G on this {w}x{h} image; at most {allowed:.0} a pixel at this size (walks × max_steps over its gsid stages)",
                    self.name,
                    steps * (w * h) as f64 / 1e9
                ),
            ));
        }
        Ok(())
    }

    /// Checks, before any work, that every stage's inputs exist or are written by an earlier stage.
    fn check_buffers(&self, buffers: &Buffers) -> Result<()> {
        let mut available: Vec<String> = buffers.names().map(String::from).collect();
        for stage in &self.stages {
            for need in stage.requires() {
                if !available.contains(&need) {
                    return Err(Error::buffer(
                        &need,
                        format!("is required by stage `{}` but neither the input nor an earlier stage provides it", stage.id()),
                    ));
                }
            }
            available.extend(stage.writes());
        }
        if !available.iter().any(|b| b == OUTPUT_BUFFER) {
            return Err(Error::buffer(
                OUTPUT_BUFFER,
                format!("pipeline {} never writes it", self.name),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_builtin_pipeline_parses_builds_and_matches_its_file_name() {
        for (name, text) in BUILTIN {
            let spec = PipelineSpec::parse(text, name).unwrap();
            assert_eq!(&spec.name, name);
            assert!(!spec.description.is_empty());
            spec.build().unwrap();
        }
    }

    #[test]
    fn misspelled_keys_are_named() {
        let err = PipelineSpec::parse(
            "name = \"x\"\n[[stage]]\nkind = \"gsid\"\nwalsk = 3\n",
            "x.toml",
        )
        .unwrap()
        .build()
        .err()
        .unwrap()
        .to_string();
        assert!(err.contains("x.toml") && err.contains("walsk"), "{err}");
        let err = PipelineSpec::parse("name = \"x\"\nstages = 1\n", "x.toml")
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("stages"), "{err}");
        let err = PipelineSpec::parse("name = \"x\"\n[[stage]]\nkind = \"blur\"\n", "x.toml")
            .unwrap()
            .build()
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("blur") && err.contains("kind"), "{err}");
    }

    #[test]
    fn out_of_range_values_name_key_and_range() {
        let mut spec = PipelineSpec::resolve("gsid").unwrap();
        spec.apply_set("gsid.p_min=2").unwrap();
        let err = spec.build().err().unwrap().to_string();
        assert!(
            err.contains("gsid.p_min") && err.contains("between 0 and 1"),
            "{err}"
        );
        let mut spec = PipelineSpec::resolve("gsid").unwrap();
        spec.apply_set("gsid.weights.normal=-1").unwrap();
        let err = spec.build().err().unwrap().to_string();
        assert!(err.contains("gsid.weights.normal"), "{err}");
    }

    #[test]
    fn overrides_parse_toml_values_and_bare_words() {
        let mut spec = PipelineSpec::resolve("gsid").unwrap();
        spec.apply_set("gsid.walks=40").unwrap();
        spec.apply_set("gsid.tone=log1p").unwrap();
        spec.apply_set("gsid.weights.depth=0.5").unwrap();
        let p = &spec.stages[0].params;
        assert_eq!(p["walks"].as_integer(), Some(40));
        assert_eq!(p["tone"].as_str(), Some("log1p"));
        assert_eq!(p["weights"]["depth"].as_float(), Some(0.5));
        spec.build().unwrap();
        assert!(spec.apply_set("walks=4").is_err());
        assert!(spec.apply_set("gsid.walks").is_err());
    }
}
