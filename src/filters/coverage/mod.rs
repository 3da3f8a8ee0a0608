//! The `coverage` stage: an edge pixel's value is the mix of the sides its area covers, not of the
//! sides its few samples landed on.
//!
//! At a few samples a pixel (and more with a wide pixel filter, such as Cycles' 1.5-pixel
//! Blackman-Harris, whose samples land up to a pixel and a half away), the pixels along an edge each
//! show one side or the other at random, in their features and their colour alike. Every filter
//! that follows the features keeps that staircase, while the reference's edge is a smooth mix. This
//! stage finds each pixel's edge direction from the features (`orient`), and moves the pixel towards
//! the mean of the pixels along its edge by how much the features jump along it, as far as the
//! colour's noise covers the change (`along`). A clean anti-aliased edge, flat surfaces, and
//! stripes or fine texture (another edge within three pixels) pass unchanged; without albedo or
//! normal the stage passes the image through with a note. Each pixel reads only its inputs, so any
//! thread count gives the same bits (docs/ALGORITHM.md §8, "Edges at few samples"). Then, where the
//! renderer's pixel filter is wider than a box (read from the features' edges, `across`), each edge
//! pixel takes its share of the pixels across its edge, as far as its noise covers. Last, the same
//! along-edge step on the edges only the colour shows (`colour`): a light's rim, a hard shadow.
//!
//! ```toml
//! [[stage]]
//! kind = "coverage"
//! input = "out"        # the filtered image
//! noise = "noise"      # the colour's variance (a `noise` stage's output)
//! output = "out"
//! reach = 1            # pixels read each way along the edge
//! tolerance = 1.0      # slack on the noise, as `blend`'s
//! across = true        # spread across edges as the renderer's filter does (estimated)
//! stack_across = false # and on a `--temporal` frame that moved (its merge already spreads edges)
//! colour = true        # the along-edge step on edges only the colour shows
//! stack_colour = false # and on a `--temporal` frame (its colour holds the shot's samples)
//! ```

mod across;
mod along;
mod colour;
mod orient;

use serde::{Deserialize, Serialize};

use crate::buffers::Buffers;
use crate::error::{Error, Result};
use crate::filters::stage::{parse_params, Context, Stage, StageIo};

pub use across::{across_edges, spread, Spread};
pub use along::{along_edges, Gate};
pub use colour::{along_colour_edges, colour_guide};
pub use orient::{normals, Guide};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CoverageParams {
    /// The colour's noise variance, 3 channels.
    pub noise: String,
    /// Pixels read each way along an edge: the mean of `2·reach + 1` points.
    pub reach: usize,
    /// How far the change may exceed the noise before it is scaled down, as `blend`'s tolerance.
    pub tolerance: f64,
    /// Then spread each edge pixel's colour across its edge by as much as the renderer's pixel
    /// filter spreads the features' edges (estimated per image; none for a box filter). Costs a
    /// pass over the edge pixels.
    pub across: bool,
    /// The across-edge spread on a `--temporal` frame whose neighbours were resampled between
    /// pixels (the shot moved) too. Off by default: that merged colour is a mean of bilinear reads
    /// whose edges already carry the resampling's spread, and spreading them again by the
    /// renderer's filter softens them twice. A still shot merges whole pixels and keeps the step.
    pub stack_across: bool,
    /// Then the along-edge step again on the edges the tone-mapped colour shows and the features
    /// do not (a light's rim on a ceiling of its albedo, a hard shadow), gated by the larger of the
    /// noise and the colour's scatter along the edge. Needs no features.
    pub colour: bool,
    /// The colour-edge step on a `--temporal` frame too. Off by default: the merged colour holds
    /// the shot's samples, so its rims scatter by far less than one frame's, and what the step
    /// still finds there is the edges' own detail (it added flicker and error on both Blender shots).
    pub stack_colour: bool,
}

impl Default for CoverageParams {
    fn default() -> Self {
        CoverageParams {
            noise: "noise".into(),
            reach: 1,
            tolerance: 1.0,
            across: true,
            stack_across: false,
            colour: true,
            stack_colour: false,
        }
    }
}

impl CoverageParams {
    /// Checks every key against its allowed range; the error names the key.
    pub fn validate(&self) -> Result<()> {
        if !(1..=4).contains(&self.reach) {
            return Err(Error::range("reach", self.reach, "1 to 4"));
        }
        if !(self.tolerance > 0.0 && self.tolerance <= 1e6) {
            return Err(Error::range(
                "tolerance",
                self.tolerance,
                "above 0, at most 1e6",
            ));
        }
        if self.noise.is_empty() {
            return Err(Error::config("noise", "must name a buffer"));
        }
        Ok(())
    }
}

pub struct CoverageStage {
    id: String,
    io: StageIo,
    pub params: CoverageParams,
}

impl CoverageStage {
    pub fn from_table(id: &str, io: StageIo, table: toml::Table) -> Result<Self> {
        let params: CoverageParams = parse_params(id, table)?;
        params.validate().map_err(|e| e.in_context(id))?;
        Ok(CoverageStage {
            id: id.to_string(),
            io,
            params,
        })
    }
}

impl Stage for CoverageStage {
    fn id(&self) -> &str {
        &self.id
    }

    fn requires(&self) -> Vec<String> {
        vec![self.io.input.clone(), self.params.noise.clone()]
    }

    fn writes(&self) -> Vec<String> {
        vec![self.io.output.clone()]
    }

    fn execute_impl(&self, buffers: &mut Buffers, ctx: &mut Context) -> Result<u64> {
        let color = buffers.require_channels(&self.io.input, 3)?;
        let variance = buffers.require_channels(&self.params.noise, 3)?;
        if variance.dims() != color.dims() {
            return Err(Error::buffer(
                &self.params.noise,
                "does not match the filtered image's size",
            ));
        }
        let p = &self.params;
        // The feature steps' result; none without features (the colour step, if on, reads the input).
        let edged = match Guide::new(buffers.features(), color.dims()) {
            Some(guide) => {
                let dirs = normals(&guide);
                let out = along_edges(
                    color,
                    variance,
                    &guide,
                    &dirs,
                    (p.reach, p.tolerance, Gate::Noise),
                    &ctx.meter,
                );
                ctx.meter.check()?;
                Some(if p.across && (p.stack_across || !buffers.resampled()) {
                    let share = spread(&guide, &dirs).share();
                    across_edges(
                        &out,
                        variance,
                        &guide,
                        &dirs,
                        (share, p.tolerance),
                        &ctx.meter,
                    )
                } else {
                    out
                })
            }
            None => {
                let rest = if p.colour {
                    "only the colour's own edges are used"
                } else {
                    "the image passes unchanged"
                };
                ctx.note(format!(
                    "{}: no albedo or normal to find edges by; {rest}",
                    self.id
                ));
                None
            }
        };
        ctx.meter.check()?;
        let out = if p.colour && (p.stack_colour || !buffers.variance_from_stack()) {
            let input = edged.as_ref().unwrap_or(color);
            along_colour_edges(input, variance, (p.reach, p.tolerance), &ctx.meter)
        } else {
            edged.unwrap_or_else(|| color.par_clone())
        };
        ctx.meter.check()?;
        buffers.insert(self.io.output.clone(), out)?;
        Ok(0)
    }
}

#[cfg(test)]
mod tests;
