//! The `blend` stage: never worse than the input where the input is good. Mixes a filtered image
//! with the colour it came from, per pixel, by the Wiener weight of `keep_weights` (in `weights`;
//! the error estimate it rests on in `error_estimate`; the image's noise-level function that caps
//! the tested noise where the local estimate reads structure in `noise_level`).
//!
//! ```toml
//! [[stage]]
//! kind = "blend"
//! input = "out"          # the filtered image
//! original = "color"     # what it was filtered from
//! noise = "noise"        # the original's variance (a `noise` stage's output)
//! output = "out"
//! tolerance = 1.5        # slack for the error of both estimates (the presets use 2)
//! stack_tolerance = 1.0  # the same for a variance measured from a shot's frames (`--temporal`)
//! leak = 4.0             # a rise beyond √leak noise σ is light leaked from a neighbour
//! noise_level = 0.0      # quantile of the image's noise-level function capping the test (0: off)
//! stack_noise_level = 0.0 # the same for a variance measured from a shot's frames (`--temporal`)
//! leak_level = 0.0       # quantile of the noise-level function capping the leak test (0: off)
//! stack_leak_level = 0.0 # the same for a variance measured from a shot's frames (`--temporal`)
//! ```

#[cfg(test)]
mod cap_tests;
mod error_estimate;
#[cfg(test)]
mod leak_tests;
mod noise_level;
mod weights;

use serde::{Deserialize, Serialize};

use crate::buffers::{Buffers, COLOR};
use crate::error::{Error, Result};
use crate::filters::reliability::reliability_name;
use crate::filters::stage::{parse_params, Context, Stage, StageIo};
use crate::render_set::Feature;

pub use weights::{keep_weights, keep_weights_metered};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BlendParams {
    pub original: String,
    pub noise: String,
    /// How far the filter's measured change may exceed the noise before the input comes back:
    /// slack for the error of both estimates.
    pub tolerance: f64,
    /// The same where the render set's variance was measured from a shot's frames (`--temporal`):
    /// pooled over the window's samples and same-surface neighbours, it needs less slack than the
    /// image's estimate or a renderer's variance of each pixel's own samples (docs/ALGORITHM.md §10).
    pub stack_tolerance: f64,
    /// How many noise variances above its input a pixel's filtered value may rise before it
    /// counts as light leaked from a neighbour the features cannot tell apart.
    pub leak: f64,
    /// Above 0: the quantile (at most 1) of the image's noise-level function (the local
    /// estimates of pixels as bright, across the image) that caps the variance a pixel's change is
    /// tested against, where the filter took light from a pixel that is no spike and its output
    /// still shows structure there: a highlight or rim the estimate read as noise comes back. 0
    /// tests against the local estimate alone. Costs a sort of the image's pixels.
    pub noise_level: f64,
    /// The same where the variance was measured from a shot's frames (`--temporal`): pooled over
    /// the window's samples, it does not read structure as the image's estimate does, and the cap
    /// measured a loss there (docs/RESULTS.md "Keeping what the input has right").
    pub stack_noise_level: f64,
    /// Above 0: the quantile (at most 1) of the image's noise-level function that caps the
    /// variance the leak test holds a rise against, where the filter brightened a pixel whose
    /// noise by that level is small against its brightness (nearly symmetric): the local estimate
    /// reads a reflection's structure as noise and would let a highlight's light into the dark
    /// pixels beside it. 0: the local estimate alone.
    pub leak_level: f64,
    /// The same where the variance was measured from a shot's frames (`--temporal`): a moving
    /// reflection's light reaches a pixel through the merge as through a filter.
    pub stack_leak_level: f64,
}

impl Default for BlendParams {
    fn default() -> Self {
        BlendParams {
            original: COLOR.to_string(),
            noise: "noise".to_string(),
            tolerance: 1.5,
            stack_tolerance: 1.0,
            leak: 4.0,
            noise_level: 0.0,
            stack_noise_level: 0.0,
            leak_level: 0.0,
            stack_leak_level: 0.0,
        }
    }
}

impl BlendParams {
    /// Checks every key against its allowed range; the error names the key. Both factors scale a
    /// variance, so 0 or less would hand back the input everywhere or push past it.
    pub fn validate(&self) -> Result<()> {
        for (key, value) in [
            ("tolerance", self.tolerance),
            ("stack_tolerance", self.stack_tolerance),
            ("leak", self.leak),
        ] {
            if !(value > 0.0 && value <= 1e6) {
                return Err(Error::range(key, value, "above 0, at most 1e6"));
            }
        }
        for (key, value) in [
            ("noise_level", self.noise_level),
            ("stack_noise_level", self.stack_noise_level),
            ("leak_level", self.leak_level),
            ("stack_leak_level", self.stack_leak_level),
        ] {
            if !(0.0..=1.0).contains(&value) {
                return Err(Error::range(key, value, "0 (off) to 1"));
            }
        }
        Ok(())
    }
}

pub struct BlendStage {
    id: String,
    io: StageIo,
    pub params: BlendParams,
}

impl BlendStage {
    pub fn from_table(id: &str, io: StageIo, table: toml::Table) -> Result<Self> {
        let params: BlendParams = parse_params(id, table)?;
        params.validate().map_err(|e| e.in_context(id))?;
        Ok(BlendStage {
            id: id.to_string(),
            io,
            params,
        })
    }
}

impl Stage for BlendStage {
    fn id(&self) -> &str {
        &self.id
    }

    fn requires(&self) -> Vec<String> {
        vec![
            self.io.input.clone(),
            self.params.original.clone(),
            self.params.noise.clone(),
        ]
    }

    fn writes(&self) -> Vec<String> {
        vec![self.io.output.clone()]
    }

    fn execute_impl(&self, buffers: &mut Buffers, ctx: &mut Context) -> Result<u64> {
        let (filtered, original, variance) = crate::filters::stage::filtered_original_noise(
            buffers,
            &self.io.input,
            &self.params.original,
            &self.params.noise,
        )?;
        let (tolerance, noise_level, leak_level) = if buffers.variance_from_stack() {
            (
                self.params.stack_tolerance,
                self.params.stack_noise_level,
                self.params.stack_leak_level,
            )
        } else {
            (
                self.params.tolerance,
                self.params.noise_level,
                self.params.leak_level,
            )
        };
        let keep = keep_weights_metered(
            crate::kernels::simd::Kernel::detect(),
            (original, filtered, variance),
            buffers.features(),
            (tolerance, self.params.leak, noise_level, leak_level),
            buffers
                .get_sized(&reliability_name(Feature::Normal), 1, original.dims())?
                .map(|r| r.data()),
            &ctx.meter,
        );
        ctx.meter.check()?;
        let mut out = filtered.par_clone();
        for (i, px) in out.data_mut().chunks_exact_mut(3).enumerate() {
            let o = original.pixel(i);
            for k in 0..3 {
                px[k] = o[k] + keep[i] * (px[k] - o[k]);
            }
        }
        buffers.insert(self.io.output.clone(), out)?;
        Ok(0)
    }
}

#[cfg(test)]
mod tests {
    use super::weights::tests::{blend_case, blend_case_keep};
    use super::*;
    use crate::image::Image;
    use crate::render_set::RenderSet;

    /// The blend stage (keys `table`) of `filtered` against `color` with noise `variance`, the
    /// variance from a renderer or a stack.
    fn staged(
        table: &str,
        (color, filtered, variance): (Image, Image, Image),
        from_stack: bool,
    ) -> Image {
        let mut set = RenderSet::new(color);
        set.noise.variance = Some(variance);
        set.noise.from_stack = from_stack;
        let mut buffers = Buffers::from(set);
        buffers.insert("out", filtered).unwrap();
        buffers.insert_same("noise", "variance").unwrap();
        let io = StageIo {
            input: "out".into(),
            output: "out".into(),
        };
        let stage = BlendStage::from_table("blend", io, toml::from_str(table).unwrap()).unwrap();
        let mut ctx = Context::new(0, false);
        stage.execute(&mut buffers, &mut ctx).unwrap();
        buffers.get("out").unwrap().clone()
    }

    /// The blend of `full` (tolerance 2) over a flat colour of noise variance 0.01 whose filtered
    /// value moved every pixel by 1.5 noise σ, with the variance from a renderer or a stack.
    fn blended(from_stack: bool) -> Image {
        let (w, h) = (9, 9);
        let case = (
            Image::filled(w, h, 3, 1.0),
            Image::filled(w, h, 3, 1.15),
            Image::filled(w, h, 3, 0.01),
        );
        staged("tolerance = 2.0", case, from_stack)
    }

    #[test]
    fn a_stack_measured_variance_takes_the_colour_back_without_the_slack() {
        // The filter's change is more than its noise explains, so part of the colour comes back
        // under either; against a stack's measured variance, with tolerance 1 instead of 2, twice
        // as much of the change is given back.
        let renderer = blended(false).at(4, 4)[0] as f64 - 1.0;
        let stack = blended(true).at(4, 4)[0] as f64 - 1.0;
        assert!(renderer < 0.9 * 0.15, "kept {renderer} of 0.15");
        assert!(
            (stack / renderer - 0.5).abs() < 1e-3,
            "{stack} against {renderer}"
        );
    }

    /// The blend stage of `full` (noise level 0.75, none for a stack) over the noise-level
    /// module's blurred band, with its variance from a renderer or a stack, `noise_level` `q`.
    fn band_blended(from_stack: bool, q: f64) -> Image {
        let table = format!("tolerance = 2.0\nnoise_level = {q}\nstack_noise_level = 0.0");
        staged(&table, super::cap_tests::blurred_band(), from_stack)
    }

    #[test]
    fn the_noise_level_cap_is_off_for_a_stack_measured_variance() {
        // A renderer's (or the image's) variance: the band's edge comes back towards the input.
        let (single, plain) = (band_blended(false, 0.75), band_blended(false, 0.0));
        assert!(single.at(22, 10)[0] > plain.at(22, 10)[0] + 0.1);
        // A stack's: `stack_noise_level` 0, the blend as without the cap.
        assert_eq!(
            band_blended(true, 0.75).data(),
            band_blended(true, 0.0).data()
        );
    }

    #[test]
    fn the_leak_level_follows_its_own_key_on_a_stack_frame() {
        // The leak tests' lit dark columns beside a highlight, as a `--temporal` frame: taken back
        // under `stack_leak_level`, whatever `leak_level` says, and kept without it.
        let lit = |table: &str| {
            let case = super::leak_tests::lit_beside_highlight(0.3);
            staged(&format!("tolerance = 2.0\n{table}"), case, true).at(20, 24)[0]
        };
        assert!(lit("stack_leak_level = 0.5") < 0.31);
        assert_eq!(lit("leak_level = 0.5"), 0.5);
        assert_eq!(
            lit("stack_leak_level = 0.5\nleak_level = 0.5"),
            lit("stack_leak_level = 0.5")
        );
    }

    #[test]
    fn a_rise_beyond_two_sigma_is_taken_back() {
        let (color, _, _) = blend_case();
        let leak = BlendParams::default().leak;
        // One pixel 3σ brighter than its input, one 3σ darker (a firefly removed).
        let mut filtered = color.clone();
        let (up, down) = (2 * 9 + 2, 6 * 9 + 7);
        filtered.pixel_mut(up).fill(1.3);
        filtered.pixel_mut(down).fill(0.7);
        let keep = blend_case_keep(&filtered, leak);
        // κ = λ·v / gain²: a rise of exactly 2σ would be kept whole, a larger one shrinks as 1/gain.
        let rise = keep[up] * 0.3;
        assert!(rise <= 0.2, "kept a rise of {rise}, above 2σ = 0.2");
        assert!(
            (keep[up] - 4.0 * 0.01 / 0.09).abs() < 1e-4,
            "keep {}",
            keep[up]
        );
        assert_eq!(keep[down], 1.0, "a darker pixel is a firefly removed");
    }
}
