//! The `pyramid` composite stage: run a sub-list of stages at every level of a Gaussian pyramid,
//! then recombine the results by Laplacian blending (docs/ALGORITHM.md §4).
//!
//! ```toml
//! [[stage]]
//! kind = "pyramid"
//! levels = 3                 # including full size
//! blend = [1.0, 1.0]         # detail-band weights, fine to coarse (missing = 1)
//! mask = "outlier_mask"      # optional: pixels left out of REDUCE
//! gsid = { walks = 16 }      # override a sub-stage at every level (by its id)
//! level1 = { gsid = { sigma = 1.5 } }   # override a sub-stage at one level
//! [[stage.stages]]           # the sub-list, run at each level
//! kind = "gsid"
//! sigma = 1.0
//! ```
//!
//! `--set pyramid.levels=4`, `--set pyramid.gsid.walks=10` and `--set pyramid.level2.gsid.sigma=2`
//! all address these keys.

pub mod blend;
pub mod levels;

use serde::{Deserialize, Serialize};

use crate::buffers::Buffers;
use crate::error::{Error, Result};
use crate::filters::stage::{parse_params, Context, Stage, StageBuilder, StageIo};
use crate::spec::StageSpec;
use blend::BlendDomain;

/// The pyramid's own parameters (its sub-stages and their overrides are parts of its [`StageSpec`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PyramidParams {
    /// Levels including full size: more reaches lower frequencies; each adds about ¼ of the previous cost.
    pub levels: u32,
    /// Detail-band blend weights, fine to coarse (missing entries are 1): below 1 smooths that band.
    pub blend: Vec<f32>,
    /// One-channel buffer of pixels to leave out of REDUCE, so masked fireflies do not spread.
    pub mask: Option<String>,
    /// Domain of the Laplacian bands: `log` avoids halos at bright HDR edges, `linear` is the textbook form.
    pub domain: BlendDomain,
    /// Expand coarse corrections guided by the finer level (joint bilateral), so they stop at edges.
    pub guided: bool,
    /// Keep each blended pixel within the range of its finer level's (2r+1)² neighbourhood; 0 = off.
    pub clamp_radius: u32,
}

impl Default for PyramidParams {
    fn default() -> Self {
        PyramidParams {
            levels: 3,
            blend: Vec::new(),
            mask: None,
            domain: BlendDomain::Log,
            guided: true,
            clamp_radius: 1,
        }
    }
}

/// Most levels accepted; a 2^12 reduction leaves nothing of any real render.
const MAX_LEVELS: u32 = 12;

/// Largest `clamp_radius`: the clamp costs (2r+1)² reads a pixel, and a neighbourhood wider than
/// a few pixels no longer guards against halos.
const MAX_CLAMP_RADIUS: u32 = 8;

impl PyramidParams {
    pub fn validate(&self) -> Result<()> {
        if !(1..=MAX_LEVELS).contains(&self.levels) {
            return Err(Error::range(
                "levels",
                self.levels,
                &format!("1 to {MAX_LEVELS}"),
            ));
        }
        for (i, b) in self.blend.iter().enumerate() {
            if !(0.0..=4.0).contains(b) {
                return Err(Error::range(&format!("blend[{i}]"), b, "0 to 4"));
            }
        }
        if self.clamp_radius > MAX_CLAMP_RADIUS {
            return Err(Error::range(
                "clamp_radius",
                self.clamp_radius,
                &format!("0 to {MAX_CLAMP_RADIUS}"),
            ));
        }
        Ok(())
    }
}

pub struct PyramidStage {
    id: String,
    io: StageIo,
    pub params: PyramidParams,
    /// The sub-stages as written: their buffers are what the pyramid reads and writes.
    children: Vec<StageSpec>,
    /// Built sub-stages per level.
    levels: Vec<Vec<Box<dyn Stage>>>,
}

impl PyramidStage {
    /// Builds the sub-stages of every level: each child with its every-level overrides, then those
    /// of its level, merged into its parameters; `build` makes each sub-stage (the registry's
    /// `filters::build`, handed in so this room does not reach back to it).
    pub fn from_spec(spec: &StageSpec, build: StageBuilder) -> Result<Self> {
        let id = spec.id.as_str();
        let params: PyramidParams = parse_params(id, spec.params.clone())?;
        params.validate().map_err(|e| e.in_context(id))?;
        let names_child = |k: &String| spec.children.iter().any(|c| &c.id == k);
        if let Some(bad) = spec.overrides.every_level.keys().find(|k| !names_child(k)) {
            return Err(Error::config(
                format!("{id}.{bad}"),
                "names no sub-stage of this pyramid",
            ));
        }
        for (key, o) in &spec.overrides.levels {
            if o.level >= params.levels as usize {
                return Err(Error::config(
                    format!("{id}.{key}"),
                    format!(
                        "level {} does not exist (levels = {}; level0 is full size)",
                        o.level, params.levels
                    ),
                ));
            }
            if let Some(bad) = o.stages.keys().find(|k| !names_child(k)) {
                return Err(Error::config(
                    format!("{id}.{key}.{bad}"),
                    "names no sub-stage of this pyramid",
                ));
            }
        }
        let mut levels = Vec::new();
        for l in 0..params.levels as usize {
            let mut built: Vec<Box<dyn Stage>> = Vec::new();
            for child in &spec.children {
                let mut sub = child.clone();
                let mut context = id.to_string();
                if let Some(o) = spec.overrides.every_level.get(&child.id) {
                    sub.merge(o).map_err(|e| e.in_context(&context))?;
                }
                for (key, o) in spec.overrides.levels.iter().filter(|(_, o)| o.level == l) {
                    if let Some(t) = o.stages.get(&child.id) {
                        context = format!("{id}.{key}");
                        sub.merge(t).map_err(|e| e.in_context(&context))?;
                    }
                }
                built.push(build(&sub).map_err(|e| e.in_context(&context))?);
            }
            levels.push(built);
        }
        Ok(PyramidStage {
            id: id.to_string(),
            io: spec.io.clone(),
            params,
            children: spec.children.clone(),
            levels,
        })
    }

    /// The buffer a level's result is read from: the last sub-stage's output, or the input colour.
    fn level_output(&self) -> String {
        self.children
            .last()
            .map_or_else(|| self.io.input.clone(), |s| s.io.output.clone())
    }
}

impl Stage for PyramidStage {
    fn id(&self) -> &str {
        &self.id
    }

    fn nesting(&self) -> usize {
        let inner = self.levels.iter().flatten().map(|s| s.nesting()).max();
        1 + inner.unwrap_or(0)
    }

    /// Level l holds a quarter of level l − 1's pixels, so its walks count a quarter as much.
    fn steps_per_pixel(&self) -> f64 {
        let mut share = 1.0;
        let mut total = 0.0;
        for level in &self.levels {
            total += share * level.iter().map(|s| s.steps_per_pixel()).sum::<f64>();
            share /= 4.0;
        }
        total
    }

    fn requires(&self) -> Vec<String> {
        vec![self.io.input.clone()]
    }

    fn writes(&self) -> Vec<String> {
        // Level 0 runs in place, so its sub-stages' buffers remain afterwards.
        let mut w: Vec<String> = self.children.iter().map(|s| s.io.output.clone()).collect();
        w.push(self.io.output.clone());
        w
    }

    fn exposure_power(&self, buffer: &str) -> i32 {
        // What is left of a sub-stage's buffer is level 0's: the last of its stages that wrote it.
        self.levels
            .first()
            .and_then(|stages| {
                stages
                    .iter()
                    .rev()
                    .find(|s| s.writes().iter().any(|w| w == buffer))
            })
            .map_or(1, |s| s.exposure_power(buffer))
    }

    fn execute_impl(&self, buffers: &mut Buffers, ctx: &mut Context) -> Result<u64> {
        let (w, h) = buffers.require(&self.io.input)?.dims();
        if self.children.is_empty() {
            // Allowed (it checks that splitting and blending give the input back), but never
            // what a user means: say so rather than pass it silently.
            ctx.note(format!(
                "{}: no sub-stages ([[stage.stages]]): the levels are only split and put back together",
                self.id
            ));
        }
        let wanted = self.params.levels as usize;
        let n = levels::allowed_levels(w, h, wanted);
        if n < wanted {
            ctx.note(format!(
                "{}: a {w}x{h} image allows {n} of the {wanted} levels asked for",
                self.id
            ));
        }
        let mask = self.params.mask.as_deref().filter(|m| buffers.contains(m));
        if let (Some(m), None) = (&self.params.mask, mask) {
            ctx.note(format!(
                "{}: mask buffer `{m}` not present; REDUCE uses every pixel",
                self.id
            ));
        }
        // Coarse levels are built from the untouched input before level 0 is denoised in place.
        let mut coarse: Vec<Buffers> = Vec::with_capacity(n.saturating_sub(1));
        for l in 1..n {
            let finer = if l == 1 { &*buffers } else { &coarse[l - 2] };
            ctx.meter.check()?;
            let next = levels::reduce_buffers(finer, &self.io.input, mask)?;
            coarse.push(next);
        }
        let out_name = self.level_output();
        let saved_level = ctx.level;
        // Coarsest level first: each coarse level's buffers are dropped once its result is taken,
        // so level 0, whose walks hold the most, runs beside none of them. No level reads
        // another's results (each draws its own random numbers), so the order changes no bit.
        let mut denoised = Vec::with_capacity(n);
        for l in (0..n).rev() {
            ctx.level = saved_level + l as u32;
            let mut own = (l > 0).then(|| coarse.pop().expect("one coarse set per level"));
            let level_buffers: &mut Buffers = own.as_mut().unwrap_or(&mut *buffers);
            for stage in &self.levels[l] {
                stage.execute(level_buffers, ctx)?;
            }
            level_buffers.require(&out_name)?;
            // A coarse level's buffers are dropped after this, and level 0's result is replaced
            // by the blend when it is the stage's output: take it instead of copying it.
            let last_use = l > 0 || (out_name == self.io.output && out_name != self.io.input);
            denoised.push(if last_use {
                level_buffers.remove(&out_name).expect("required above")
            } else {
                level_buffers.require(&out_name)?.clone()
            });
        }
        denoised.reverse();
        ctx.level = saved_level;
        ctx.meter.check()?;
        let out = blend::blend_metered(
            denoised,
            &self.params.blend,
            self.params.domain,
            self.params.guided,
            (self.params.clamp_radius > 0).then_some(self.params.clamp_radius as usize),
            &ctx.meter,
        )?;
        buffers.insert(self.io.output.clone(), out)?;
        Ok(0)
    }
}
