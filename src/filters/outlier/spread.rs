//! The `spread` stage: the light the outlier clamp took from its fireflies is given back to their
//! surfaces, so a caustic or a highlight keeps its brightness while the spike is gone.
//!
//! A firefly is one lucky path's estimate of light that belongs, on average, to the pixels around
//! it on the same surface. The clamp (`action = "clamp"` with `light = "…"`) writes what it removed;
//! this stage shares each flagged pixel's removed light over its `(2·radius+1)²` window as a
//! Gaussian bump (σ = radius / 2), weighted by how much each pixel shares its surface (albedo and
//! normal, the outlier stage's tolerances), and adds it to the filtered image. No pixel takes more than `cap` of its own noise's standard
//! deviation: the light comes back as a rise below the noise, never as a new spot or a blotch, and
//! what would exceed that (the energy of a truly huge spike) stays removed. Each receiver sums its
//! sources in a fixed order, so any thread count gives the same bits.
//!
//! ```toml
//! [[stage]]
//! kind = "spread"
//! input = "out"            # the filtered image
//! light = "outlier_light"  # what the outlier clamp removed (its `light` key)
//! noise = "noise"          # the colour's variance (a `noise` stage's output)
//! output = "out"
//! radius = 15
//! cap = 0.5
//! highlights = 0.01        # significance level of the highlight test (`highlight`; 0: off)
//! stack_highlights = 0.0   # the same on a `--temporal` frame (variance measured from the stack)
//! conserve = false         # each spike's light over its own surface's pixels, none lost to others
//! ```
//!
//! With `highlights` above 0, a flagged pixel the `highlight` test calls a highlight (it touches
//! another flagged pixel, where chance would rarely make one) gets its own light back in full, in
//! place: it was structure the clamp took, not a spike.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::highlight::highlights;
use super::params::Guides;
use crate::buffers::Buffers;
use crate::error::{Error, Result};
use crate::filters::noise::measured::clean;
use crate::filters::stage::{parse_params, Context, Stage, StageIo};
use crate::image::Image;
use crate::meter::Meter;
use crate::render_set::Feature;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SpreadParams {
    /// The removed light, 3 channels (the outlier stage's `light` buffer).
    pub light: String,
    /// The colour's noise variance, 3 channels.
    pub noise: String,
    /// Half the window's side: the light of a flagged pixel is shared among `(2r+1)²` pixels.
    pub radius: u32,
    /// Most light a pixel takes, in its own noise standard deviations.
    pub cap: f64,
    /// Largest albedo difference (RGB distance) of "the same surface", as in the outlier stage.
    pub albedo_tol: f32,
    /// Largest normal difference (1 − n·n′)/2 of "the same surface", as in the outlier stage.
    pub normal_tol: f32,
    /// Significance level of the highlight test: flagged pixels that touch, where the image's share
    /// of flagged pixels makes that rarer than this by chance, get their light back in place. 0: off.
    pub highlights: f64,
    /// `highlights` on a frame merged from a shot's frames (`--temporal`): a pair the test passes
    /// on one frame and not the next is given back on one and clamped on the other, which a
    /// shot shows as flicker. 0: off.
    pub stack_highlights: f64,
    /// Each spike's light shared over its own surface's pixels in its window (its shares sum to
    /// one), not at a flat surface's density with what falls on other surfaces lost; the cap still
    /// bounds what any pixel takes.
    pub conserve: bool,
}

impl Default for SpreadParams {
    fn default() -> Self {
        SpreadParams {
            light: "outlier_light".into(),
            noise: "noise".into(),
            radius: 15,
            cap: 0.5,
            albedo_tol: 0.1,
            normal_tol: 0.05,
            highlights: 0.0,
            stack_highlights: 0.0,
            conserve: false,
        }
    }
}

impl SpreadParams {
    /// Checks every key against its allowed range; the error names the key.
    pub fn validate(&self) -> Result<()> {
        if !(1..=32).contains(&self.radius) {
            return Err(Error::range("radius", self.radius, "1 to 32"));
        }
        if !(self.cap > 0.0 && self.cap <= 1e6) {
            return Err(Error::range("cap", self.cap, "above 0, at most 1e6"));
        }
        for (key, value, hi, range) in [
            ("albedo_tol", self.albedo_tol, 2.0, "above 0, at most 2"),
            ("normal_tol", self.normal_tol, 1.0, "above 0, at most 1"),
        ] {
            if !(value > 0.0 && value <= hi) {
                return Err(Error::range(key, value, range));
            }
        }
        for (key, value) in [
            ("highlights", self.highlights),
            ("stack_highlights", self.stack_highlights),
        ] {
            if !(0.0..=0.5).contains(&value) {
                return Err(Error::range(key, value, "0 (off) to 0.5"));
            }
        }
        for (key, name) in [("light", &self.light), ("noise", &self.noise)] {
            if name.is_empty() {
                return Err(Error::config(key, "must name a buffer"));
            }
        }
        Ok(())
    }
}

pub struct SpreadStage {
    id: String,
    io: StageIo,
    pub params: SpreadParams,
}

impl SpreadStage {
    pub fn from_table(id: &str, io: StageIo, table: toml::Table) -> Result<Self> {
        let params: SpreadParams = parse_params(id, table)?;
        params.validate().map_err(|e| e.in_context(id))?;
        Ok(SpreadStage {
            id: id.to_string(),
            io,
            params,
        })
    }
}

impl Stage for SpreadStage {
    fn id(&self) -> &str {
        &self.id
    }

    fn requires(&self) -> Vec<String> {
        vec![
            self.io.input.clone(),
            self.params.light.clone(),
            self.params.noise.clone(),
        ]
    }

    fn writes(&self) -> Vec<String> {
        vec![self.io.output.clone()]
    }

    fn execute_impl(&self, buffers: &mut Buffers, ctx: &mut Context) -> Result<u64> {
        let (filtered, light, variance) = crate::filters::stage::filtered_original_noise(
            buffers,
            &self.io.input,
            &self.params.light,
            &self.params.noise,
        )?;
        let guides = Guides {
            albedo: buffers.features().get(Feature::Albedo),
            normal: buffers.features().get(Feature::Normal),
        };
        let mut out = filtered.par_clone();
        let mut params = self.params.clone();
        if buffers.variance_from_stack() {
            params.highlights = params.stack_highlights;
        }
        let given = spread_light(&mut out, light, variance, &guides, &params, &ctx.meter);
        ctx.meter.check()?;
        if given.removed > 0.0 {
            ctx.note(format!(
                "{}: {:.0} % of the light the clamp removed given back to its surfaces",
                self.id,
                100.0 * given.returned / given.removed
            ));
        }
        buffers.insert(self.io.output.clone(), out)?;
        Ok(0)
    }
}

/// How much light a spread had to give (the sum of the removed light over pixels and channels)
/// and how much it gave back under the cap.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Given {
    pub removed: f64,
    pub returned: f64,
}

/// A pixel that lost light: where, and how much each pixel of its window takes at most.
struct Source {
    x: usize,
    light: [f64; 3],
    /// The light it lost, summed over channels.
    total: f64,
}

/// Adds to `out` the light of `light` (nonzero where the clamp took some), shared among each
/// source's window by surface weight and capped per pixel at `cap` noise σ of `variance`.
pub fn spread_light(
    out: &mut Image,
    light: &Image,
    variance: &Image,
    guides: &Guides,
    params: &SpreadParams,
    meter: &Meter,
) -> Given {
    let (w, h) = out.dims();
    let r = params.radius as usize;
    let (ka, kn) = (
        0.5 / (params.albedo_tol * params.albedo_tol),
        0.5 / (params.normal_tol * params.normal_tol),
    );
    // Each source shares its light as a Gaussian bump (σ half the radius: a smooth rise, no
    // square), at the density it would have on a flat surface filling the window, not over the
    // pixels of its own surface alone: a firefly on a sliver of surface would otherwise pour it all
    // into a few pixels and make a new spot. What would fall on other surfaces is lost.
    let side = 2 * r + 1;
    let s2 = 2.0 * (r as f32 / 2.0).powi(2);
    // −ln of the bump, by offset in the window.
    let far: Vec<f32> = (0..side * side)
        .map(|k| {
            let (dx, dy) = ((k % side) as f32 - r as f32, (k / side) as f32 - r as f32);
            (dx * dx + dy * dy) / s2
        })
        .collect();
    let bump: Vec<f64> = far.iter().map(|&e| (-e as f64).exp()).collect();
    let area: f64 = bump.iter().sum::<f64>() - 1.0;
    // A highlight's light goes back where it was taken, whole, and is no source of the bumps.
    let kept = highlights(light, params.highlights);
    let mut in_place = 0.0f64;
    for (i, px) in out.data_mut().chunks_exact_mut(3).enumerate() {
        if kept[i] {
            for (v, &l) in px.iter_mut().zip(light.pixel(i)) {
                let add = positive(l);
                *v = (*v as f64 + add).min(f32::MAX as f64) as f32;
                in_place += add;
            }
        }
    }
    let sources: Vec<Vec<Source>> = (0..h)
        .into_par_iter()
        .map(|y| {
            let mut unlike = Vec::new();
            (0..w)
                .filter(|&x| !kept[y * w + x])
                .filter_map(|x| {
                    let l = light.pixel(y * w + x);
                    let lost: [f64; 3] = std::array::from_fn(|k| positive(l[k]));
                    if lost == [0.0; 3] {
                        return None;
                    }
                    let share = if params.conserve {
                        let window = ((x, y), (w, h), r);
                        own_surface(guides, (ka, kn), window, (&far, &bump), &mut unlike)
                    } else {
                        area
                    };
                    let light = lost.map(|v| v / share);
                    (share > 0.0 && light != [0.0; 3]).then_some(Source {
                        x,
                        light,
                        total: lost.iter().sum(),
                    })
                })
                .collect()
        })
        .collect();
    let removed: f64 = sources.iter().flatten().map(|s| s.total).sum::<f64>();
    if removed == 0.0 {
        return Given {
            removed: in_place,
            returned: in_place,
        };
    }
    meter.pass(h);
    let v = variance.data();
    let returned: f64 = out
        .data_mut()
        .par_chunks_mut(3 * w.max(1))
        .enumerate()
        .map_init(
            || (Vec::new(), Vec::new()),
            |(gained, unlike), (y, row)| {
                if meter.cancelled() {
                    return 0.0;
                }
                meter.rows(1);
                gained.clear();
                gained.resize(w, [0.0f64; 3]);
                unlike.resize(side, 0.0f32);
                let rows = y.saturating_sub(r)..(y + r + 1).min(h);
                for (sy, row_sources) in rows.clone().zip(&sources[rows]) {
                    for s in row_sources {
                        let x0 = s.x.saturating_sub(r);
                        let x1 = (s.x + r + 1).min(w);
                        let unlike = &mut unlike[..x1 - x0];
                        row_unlike(guides, (ka, kn), sy * w + s.x, y * w + x0, unlike);
                        // The window's row this receiving row is, from x0 on.
                        let at = (y + r - sy) * side + (x0 + r - s.x);
                        let (far, bump) =
                            (&far[at..at + unlike.len()], &bump[at..at + unlike.len()]);
                        // The spike itself takes nothing back.
                        let spike = if sy == y { s.x - x0 } else { usize::MAX };
                        let cells = gained[x0..x1]
                            .iter_mut()
                            .zip(unlike.iter())
                            .zip(far.iter().zip(bump));
                        for (t, ((gain, &u), (&far, &bump))) in cells.enumerate() {
                            let Some(share) = share_of(far, bump, u).filter(|_| t != spike) else {
                                continue;
                            };
                            for (g, l) in gain.iter_mut().zip(s.light) {
                                *g += share * l;
                            }
                        }
                    }
                }
                let mut returned = 0.0;
                for (x, (px, gain)) in row.chunks_exact_mut(3).zip(gained.iter()).enumerate() {
                    let j = y * w + x;
                    for k in 0..3 {
                        let sd = clean(v[3 * j + k]).sqrt();
                        let add = gain[k].min(params.cap * sd);
                        if add > 0.0 {
                            px[k] = (px[k] as f64 + add).min(f32::MAX as f64) as f32;
                            returned += add;
                        }
                    }
                }
                returned
            },
        )
        .sum::<f64>();
    Given {
        removed: removed + in_place,
        returned: returned + in_place,
    }
}

/// The sum of the shares source (x, y) gives its window's pixels (the bump times the surface
/// weight, the spike itself and the cells the receiving loop skips left out), so that light
/// divided by it is given back whole before the cap. `unlike` is scratch space.
fn own_surface(
    guides: &Guides,
    k: (f32, f32),
    ((x, y), (w, h), r): ((usize, usize), (usize, usize), usize),
    (far, bump): (&[f32], &[f64]),
    unlike: &mut Vec<f32>,
) -> f64 {
    let side = 2 * r + 1;
    let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(w));
    unlike.resize(side, 0.0);
    let unlike = &mut unlike[..x1 - x0];
    let mut mass = 0.0f64;
    for ry in y.saturating_sub(r)..(y + r + 1).min(h) {
        row_unlike(guides, k, y * w + x, ry * w + x0, unlike);
        let at = (ry + r - y) * side + (x0 + r - x);
        for (t, &u) in unlike.iter().enumerate() {
            if ry == y && x0 + t == x {
                continue;
            }
            mass += share_of(far[at + t], bump[at + t], u).unwrap_or(0.0);
        }
    }
    mass
}

/// The share of a source's light one cell takes: the bump there (−ln `far`, value `bump`) times
/// the surface weight exp(−`u`). None below exp(−18), a share worth no exponential, and where a
/// feature is not a number (it shares nothing); one surface (`u` 0) needs no exponential.
#[inline(always)]
fn share_of(far: f32, bump: f64, u: f32) -> Option<f64> {
    let e = far + u;
    if e.is_nan() || e > 18.0 {
        return None;
    }
    Some(if u > 0.0 {
        bump * (-u).exp() as f64
    } else {
        bump
    })
}

/// −ln of the surface weight exp(−½(Δalbedo/tol)² − ½(Δnormal/tol)²) of source pixel `i` to each
/// of the pixels from `j` on along its row, into `out`: [`Guides::squared_distances`]'
/// operations with the source's features read once, not at every pair.
fn row_unlike(guides: &Guides, (ka, kn): (f32, f32), i: usize, j: usize, out: &mut [f32]) {
    // The albedo's squared distance first (0 without one), then u = ka·da² + kn·dn² as for a pair.
    if let Some(a) = guides.albedo {
        let p = first3(a.pixel(i));
        let squared = |o: &mut f32, q: [f32; 3]| {
            *o = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2);
        };
        for_row(a, j, out, squared);
    } else {
        out.fill(0.0);
    }
    let Some(m) = guides.normal else {
        for o in out.iter_mut() {
            *o = ka * *o + kn * 0.0 * 0.0;
        }
        return;
    };
    let p = first3(m.pixel(i));
    let known = p[0] != 0.0 || p[1] != 0.0 || p[2] != 0.0;
    let unlike = |o: &mut f32, q: [f32; 3]| {
        let dot = p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
        let dn = if known && (q[0] != 0.0 || q[1] != 0.0 || q[2] != 0.0) {
            ((1.0 - dot) * 0.5).clamp(0.0, 1.0)
        } else {
            0.0
        };
        *o = ka * *o + kn * dn * dn;
    };
    for_row(m, j, out, unlike);
}

/// A pixel's first three channels.
fn first3(px: &[f32]) -> [f32; 3] {
    [px[0], px[1], px[2]]
}

/// `f` on each cell of `out` and the first three channels of its pixel of `img`, the pixels from
/// `j` on: read as whole arrays when the image has three channels (the common case, which the
/// loop then vectorises).
#[inline(always)]
fn for_row(img: &Image, j: usize, out: &mut [f32], f: impl Fn(&mut f32, [f32; 3])) {
    let c = img.channels();
    let data = &img.data()[j * c..(j + out.len()) * c];
    if c == 3 {
        for (o, q) in out.iter_mut().zip(data.as_chunks::<3>().0) {
            f(o, *q);
        }
    } else {
        for (o, q) in out.iter_mut().zip(data.chunks_exact(c)) {
            f(o, first3(q));
        }
    }
}

/// A removed light's value as spread: finite and positive, else nothing.
fn positive(v: f32) -> f64 {
    if v.is_finite() && v > 0.0 {
        v as f64
    } else {
        0.0
    }
}

#[cfg(test)]
#[path = "spread_tests.rs"]
mod tests;
