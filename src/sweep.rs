//! `gsid sweep`: what does a pipeline parameter cost in time, and what does it buy in quality?
//!
//! Every `--vary KEY=V1,V2,...` is one axis; the sweep runs the Cartesian product of the axes (the first
//! axis varies slowest), each setting `repeat` times, and keeps the median time and the score of the
//! output. The settings no other setting beats on both time and SSIM form the Pareto front: those are
//! the only ones worth choosing, and the plot joins them.
//!
//! Everything here is library code (parsing the axes, building and validating the settings, running,
//! the Pareto front, the CSV, the table and the plots), so it is unit-tested; `cli.rs` only wires files.

use std::sync::Once;
use std::time::Instant;

use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters_backend as pb;
use plotters_backend::text_anchor::{HPos, VPos};
use serde::Serialize;

use crate::buffers::Buffers;
use crate::error::{Error, Result};
use crate::image::Image;
use crate::metrics;
use crate::pipeline::{Pipeline, PipelineSpec};

/// One `--vary` axis: a pipeline key (the syntax `--set` takes) and the values it takes, in order.
#[derive(Clone, Debug, PartialEq)]
pub struct Axis {
    pub key: String,
    pub values: Vec<String>,
}

/// Parses one `--vary KEY=V1,V2,...`. Values are split on commas and trimmed; each is later read as
/// TOML by [`PipelineSpec::apply_set`], so a value cannot itself contain a comma (no TOML arrays).
pub fn parse_axis(arg: &str) -> Result<Axis> {
    let (key, list) = arg.split_once('=').ok_or_else(|| {
        Error::config(
            format!("--vary {arg}"),
            "needs KEY=V1,V2,..., e.g. --vary gsid.walks=5,10,20",
        )
    })?;
    let key = key.trim();
    if key.is_empty() {
        return Err(Error::config(
            format!("--vary {arg}"),
            "the key is empty; give STAGE.PARAM, e.g. gsid.walks",
        ));
    }
    if list.trim().is_empty() {
        return Err(Error::config(
            format!("--vary {key}"),
            "has no values; give V1,V2,... after the `=`",
        ));
    }
    let values: Vec<String> = list.split(',').map(|v| v.trim().to_string()).collect();
    if values.iter().any(|v| v.is_empty()) {
        return Err(Error::config(
            format!("--vary {key}"),
            format!("`{list}` has an empty value (two commas in a row, or one at an end)"),
        ));
    }
    for (i, v) in values.iter().enumerate() {
        if values[..i].contains(v) {
            return Err(Error::config(
                format!("--vary {key}"),
                format!("value `{v}` is listed twice"),
            ));
        }
    }
    Ok(Axis {
        key: key.to_string(),
        values,
    })
}

/// Parses every `--vary`, rejecting a key given twice or also fixed by `--set` (which one would win
/// is not obvious, so neither does).
pub fn parse_axes(varies: &[String], sets: &[String]) -> Result<Vec<Axis>> {
    if varies.is_empty() {
        return Err(Error::config(
            "--vary",
            "give at least one, e.g. --vary gsid.walks=5,10,20",
        ));
    }
    let mut axes: Vec<Axis> = Vec::new();
    for arg in varies {
        let axis = parse_axis(arg)?;
        if axes.iter().any(|a| a.key == axis.key) {
            return Err(Error::config(
                format!("--vary {}", axis.key),
                "is given twice; list all its values in one --vary",
            ));
        }
        let fixed = sets
            .iter()
            .filter_map(|s| s.split_once('=').map(|(k, _)| k.trim()))
            .any(|k| k == axis.key);
        if fixed {
            return Err(Error::config(
                format!("--vary {}", axis.key),
                "is also fixed by --set; drop one of them",
            ));
        }
        axes.push(axis);
    }
    Ok(axes)
}

/// Short names for the axes in labels and the plot: the last segment of each key (`gsid.walks` →
/// `walks`), lengthened from the end only where two keys would otherwise share a name
/// (`level1.gsid.sigma` and `level2.gsid.sigma`).
pub fn short_names(keys: &[String]) -> Vec<String> {
    let parts: Vec<Vec<&str>> = keys.iter().map(|k| k.split('.').collect()).collect();
    let mut take = vec![1usize; keys.len()];
    let name = |i: usize, n: usize| parts[i][parts[i].len().saturating_sub(n)..].join(".");
    loop {
        let names: Vec<String> = (0..keys.len()).map(|i| name(i, take[i])).collect();
        let mut grew = false;
        let mut clash = false;
        for i in 0..keys.len() {
            if (0..keys.len()).any(|j| j != i && names[j] == names[i]) {
                clash = true;
                if take[i] < parts[i].len() {
                    take[i] += 1;
                    grew = true;
                }
            }
        }
        // Distinct keys always separate once written in full; the second test only guards the loop.
        if !clash || !grew {
            return names;
        }
    }
}

/// One point of the sweep: a value for every axis, and the pipeline those values give.
pub struct Setting {
    /// `walks=5 levels=2`: the axes' short names and values.
    pub label: String,
    /// The value of each axis, in axis order.
    pub values: Vec<String>,
    pub spec: PipelineSpec,
    pub pipeline: Pipeline,
    /// What the sweep changed beyond the axes' values (per-level overrides left out), for the user.
    pub notes: Vec<String>,
}

/// Every combination of the axes' values (first axis slowest), each applied to `base` and built.
///
/// All validation happens here, before any denoising. A combination that does not build is reported
/// with the `--vary` value at fault when that value also fails on its own (a bad value, an unknown
/// key), else as a clash of the combination (values fine alone can clash: `pyramid.level2.gsid.sigma`
/// needs `pyramid.levels` of 3 or more). A value is not checked alone first, since a value that needs
/// another axis (that same `level2`) would then be rejected although every combination is valid.
pub fn settings(base: &PipelineSpec, axes: &[Axis]) -> Result<Vec<Setting>> {
    let names = short_names(&axes.iter().map(|a| a.key.clone()).collect::<Vec<_>>());
    let count: usize = axes.iter().map(|a| a.values.len()).product();
    let mut out = Vec::with_capacity(count);
    for n in 0..count {
        // Mixed-radix digits of n, the last axis fastest.
        let mut digits = vec![0usize; axes.len()];
        let mut rest = n;
        for (d, axis) in digits.iter_mut().zip(axes).rev() {
            *d = rest % axis.values.len();
            rest /= axis.values.len();
        }
        let values: Vec<String> = digits
            .iter()
            .zip(axes)
            .map(|(&d, a)| a.values[d].clone())
            .collect();
        let label = names
            .iter()
            .zip(&values)
            .map(|(k, v)| format!("{k}={v}"))
            .collect::<Vec<_>>()
            .join(" ");
        let assignments: Vec<String> = axes
            .iter()
            .zip(&values)
            .map(|(a, v)| format!("{}={v}", a.key))
            .collect();
        let mut spec = base.clone();
        let mut notes = Vec::new();
        let built = assignments
            .iter()
            .try_for_each(|a| spec.apply_set(a))
            .and_then(|()| {
                notes = drop_missing_levels(&mut spec, axes);
                spec.build()
            });
        let pipeline = match built {
            Ok(p) => p,
            Err(e) => return Err(combination_error(base, axes, &assignments, &label, e)),
        };
        out.push(Setting {
            label,
            values,
            spec,
            pipeline,
            notes,
        });
    }
    Ok(out)
}

/// When `--vary` sets a pyramid's `levels`, drops the pipeline's own per-level overrides (`levelN`)
/// for levels the setting does not have, and says so.
///
/// Without this, `--vary pyramid.levels=1,2,3` on `full` (whose file tunes `level1`) fails at
/// levels=1, since a pyramid rejects overrides of missing levels to catch typos. Overrides that a
/// `--vary` itself gives are kept, so a clash between two axes is still an error.
fn drop_missing_levels(spec: &mut PipelineSpec, axes: &[Axis]) -> Vec<String> {
    let mut notes = Vec::new();
    for axis in axes {
        let Some(id) = axis.key.strip_suffix(".levels") else {
            continue;
        };
        let Some(stage) = spec
            .stages
            .iter_mut()
            .find(|s| s.id == id && s.kind == "pyramid")
        else {
            continue;
        };
        let Some(levels) = stage.params.get("levels").and_then(|v| v.as_integer()) else {
            continue;
        };
        let varied = |key: &str| {
            let prefix = format!("{id}.{key}.");
            axes.iter().any(|a| a.key.starts_with(&prefix))
        };
        let missing: Vec<String> = stage
            .overrides
            .levels
            .iter()
            .filter(|(k, o)| o.level as i64 >= levels && !varied(k))
            .map(|(k, _)| k.clone())
            .collect();
        for key in missing {
            stage.overrides.levels.remove(&key);
            notes.push(format!(
                "{id}.{key} of pipeline {} left out: levels = {levels}",
                spec.name
            ));
        }
    }
    notes
}

/// The one-line error for a combination that does not build, naming the `--vary` value at fault:
/// the first that also fails as the only axis (with the same treatment of missing levels).
fn combination_error(
    base: &PipelineSpec,
    axes: &[Axis],
    assignments: &[String],
    label: &str,
    e: Error,
) -> Error {
    let fails_alone = |(axis, a): &(&Axis, &String)| {
        let mut spec = base.clone();
        spec.apply_set(a)
            .and_then(|()| {
                drop_missing_levels(&mut spec, std::slice::from_ref(*axis));
                spec.build()
            })
            .is_err()
    };
    let culprit = axes.iter().zip(assignments).find(fails_alone);
    let key = match (culprit, assignments.len()) {
        (Some((_, a)), 1) => format!("--vary {a}"),
        (Some((_, a)), _) => format!("--vary {a} (in {label})"),
        (None, _) => format!("--vary combination {label}"),
    };
    Error::config(key, e)
}

/// One row of the sweep table.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub label: String,
    pub values: Vec<String>,
    /// Median over the repeats of the in-process `Pipeline::run` time (files excluded).
    pub seconds: f64,
    pub seconds_min: f64,
    pub seconds_max: f64,
    pub ssim: f64,
    pub psnr: f64,
    pub relmse: f64,
    /// Walk steps of one run (the same on every repeat: the run is deterministic).
    pub walk_steps: u64,
    /// On the Pareto front of (seconds, SSIM); filled in by [`mark_front`].
    pub pareto: bool,
    /// What the sweep left out of this setting and the pipeline's notes from its first run.
    #[serde(skip)]
    pub notes: Vec<String>,
}

/// The rows' notes, each once: a note every setting shares as it is, any other followed by the
/// settings it belongs to (so 16 settings with the same notice print one line, not 16).
pub fn notes(rows: &[Row]) -> Vec<String> {
    let mut seen: Vec<(&str, Vec<&str>)> = Vec::new();
    for r in rows {
        for n in &r.notes {
            match seen.iter_mut().find(|(t, _)| t == n) {
                Some((_, labels)) => labels.push(&r.label),
                None => seen.push((n, vec![&r.label])),
            }
        }
    }
    seen.into_iter()
        .map(|(note, labels)| {
            if labels.len() == rows.len() {
                note.to_string()
            } else {
                format!("{note} ({})", labels.join("; "))
            }
        })
        .collect()
}

/// The median of a non-empty list (mean of the middle two for an even count).
pub fn median(xs: &[f64]) -> f64 {
    let mut v = xs.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

/// Runs every setting `repeat` times on a fresh copy of `buffers` and scores it against `reference`.
///
/// Only the `Pipeline::run` call is timed (sanitising, the stages and the result copy: the
/// in-process denoise); loading files, copying the input and scoring are not. The output of a seed is
/// deterministic, so the first run's output is the one scored. `on_run` is called after each run.
pub fn run(
    settings: &[Setting],
    buffers: &Buffers,
    reference: &Image,
    seed: u64,
    repeat: usize,
    on_run: &dyn Fn(),
) -> Result<Vec<Row>> {
    let repeat = repeat.max(1);
    let mut rows = Vec::with_capacity(settings.len());
    for s in settings {
        let mut times = Vec::with_capacity(repeat);
        let mut first = None;
        for _ in 0..repeat {
            let mut b = buffers.clone();
            let start = Instant::now();
            let result = s.pipeline.run(&mut b, seed, false)?;
            times.push(start.elapsed().as_secs_f64());
            first.get_or_insert(result);
            on_run();
        }
        let (out, report) = first.expect("repeat is at least 1");
        let score = metrics::score(&out, reference)?;
        rows.push(Row {
            label: s.label.clone(),
            values: s.values.clone(),
            seconds: median(&times),
            seconds_min: times.iter().copied().fold(f64::INFINITY, f64::min),
            seconds_max: times.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            ssim: score.ssim,
            psnr: score.psnr,
            relmse: score.relmse,
            walk_steps: report.walk_steps(),
            pareto: false,
            notes: s.notes.iter().cloned().chain(report.notes).collect(),
        });
    }
    mark_front(&mut rows);
    Ok(rows)
}

/// Sets `pareto` on every row from its (seconds, SSIM).
pub fn mark_front(rows: &mut [Row]) {
    let points: Vec<(f64, f64)> = rows.iter().map(|r| (r.seconds, r.ssim)).collect();
    for (r, on) in rows.iter_mut().zip(pareto_front(&points)) {
        r.pareto = on;
    }
}

/// Whether `a` dominates `b` in (seconds, SSIM): no slower, no worse, and strictly better in one.
/// False whenever a coordinate is NaN (every comparison with NaN is false).
pub fn dominates(a: (f64, f64), b: (f64, f64)) -> bool {
    a.0 <= b.0 && a.1 >= b.1 && (a.0 < b.0 || a.1 > b.1)
}

/// The Pareto front of `(seconds, ssim)` points: `true` for each point that no other point dominates
/// (fewer or equal seconds and higher or equal SSIM, strictly better in at least one).
///
/// Identical points do not dominate each other, so tied settings are on the front together. A point
/// with a NaN coordinate cannot be compared: it is never on the front and dominates nothing. Quadratic,
/// which is nothing next to one denoise per point.
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<bool> {
    points
        .iter()
        .map(|&p| !(p.0.is_nan() || p.1.is_nan() || points.iter().any(|&q| dominates(q, p))))
        .collect()
}

/// Quotes a CSV field when it needs it (comma, quote, space or newline).
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', ' ']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// The rows as CSV: `label`, one column per varied key (headed by the key), then `seconds` (median),
/// `seconds_min`, `seconds_max`, `ssim`, `psnr`, `relmse`, `walk_steps`, `pareto`.
pub fn csv(axes: &[Axis], rows: &[Row]) -> String {
    let mut header = vec!["label".to_string()];
    header.extend(axes.iter().map(|a| csv_field(&a.key)));
    header.extend(
        [
            "seconds",
            "seconds_min",
            "seconds_max",
            "ssim",
            "psnr",
            "relmse",
            "walk_steps",
            "pareto",
        ]
        .map(String::from),
    );
    let mut t = header.join(",") + "\n";
    for r in rows {
        let mut fields = vec![csv_field(&r.label)];
        fields.extend(r.values.iter().map(|v| csv_field(v)));
        fields.extend([
            r.seconds.to_string(),
            r.seconds_min.to_string(),
            r.seconds_max.to_string(),
            r.ssim.to_string(),
            r.psnr.to_string(),
            r.relmse.to_string(),
            r.walk_steps.to_string(),
            r.pareto.to_string(),
        ]);
        t += &(fields.join(",") + "\n");
    }
    t
}

/// The table printed at the end: one row per setting, `*` marking the Pareto front.
pub fn table(rows: &[Row]) -> String {
    let w = rows
        .iter()
        .map(|r| r.label.chars().count())
        .max()
        .unwrap_or(0)
        .max("setting".len());
    let mut t = format!(
        "{:<w$} {:>8} {:>7} {:>9} {:>6}\n",
        "setting", "seconds", "SSIM", "relMSE", "front"
    );
    for r in rows {
        t += &format!(
            "{:<w$} {:>8.3} {:>7.4} {:>9.5} {:>6}\n",
            r.label,
            r.seconds,
            r.ssim,
            r.relmse,
            if r.pareto { "*" } else { "" }
        );
    }
    t
}

/// DejaVu Sans (license in `assets/DejaVuSans-LICENSE.txt`), compiled in so the plots have text on any
/// machine: plotters' default `ttf` feature would look fonts up through fontconfig and FreeType,
/// system libraries a fresh machine or CI may not have.
static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
const FAMILY: &str = "sans-serif";

fn register_font() -> Result<()> {
    static ONCE: Once = Once::new();
    let mut ok = true;
    ONCE.call_once(|| {
        ok = plotters::style::register_font(FAMILY, FontStyle::Normal, FONT).is_ok();
    });
    if ok {
        Ok(())
    } else {
        Err(Error::Runtime(
            "the embedded plot font does not load".into(),
        ))
    }
}

/// Plot size in pixels (PNG) or user units (SVG).
pub const PLOT_SIZE: (u32, u32) = (1000, 680);

/// The scatter plot as an SVG document.
pub fn plot_svg(rows: &[Row], title: &str) -> Result<String> {
    register_font()?;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, PLOT_SIZE).into_drawing_area();
        draw(&root, rows, title)?;
        root.present().map_err(plot_error)?;
    }
    Ok(svg)
}

/// The scatter plot as PNG bytes (drawn by plotters into an RGB buffer, encoded by `image`).
pub fn plot_png(rows: &[Row], title: &str) -> Result<Vec<u8>> {
    register_font()?;
    let (w, h) = PLOT_SIZE;
    let mut rgb = vec![0u8; w as usize * h as usize * 3];
    {
        let root =
            GlyphBitmap::new(BitMapBackend::with_buffer(&mut rgb, PLOT_SIZE))?.into_drawing_area();
        draw(&root, rows, title)?;
        root.present().map_err(plot_error)?;
    }
    let mut png = Vec::new();
    image::ImageEncoder::write_image(
        image::codecs::png::PngEncoder::new(&mut png),
        &rgb,
        w,
        h,
        image::ExtendedColorType::Rgb8,
    )
    .map_err(|e| Error::Runtime(format!("cannot encode the plot as PNG: {e}")))?;
    Ok(png)
}

fn plot_error(e: impl std::fmt::Display) -> Error {
    Error::Runtime(format!("cannot draw the plot: {e}"))
}

/// The axis ranges: seconds and SSIM of all rows, padded so no marker sits on the frame, and whether
/// the time axis is logarithmic (when the times span more than a factor 10).
fn ranges(rows: &[Row]) -> ((f64, f64), (f64, f64), bool) {
    let finite = |f: fn(&Row) -> f64| rows.iter().map(f).filter(|v| v.is_finite());
    let (mut t0, mut t1) =
        finite(|r| r.seconds).fold((f64::INFINITY, 0.0f64), |(a, b), v| (a.min(v), b.max(v)));
    if !t0.is_finite() || t0 <= 0.0 {
        t0 = 1e-3;
    }
    if t1 < t0 {
        t1 = t0;
    }
    let log = t1 / t0 > 10.0;
    let (t0, t1) = if log {
        (t0 / 1.3, t1 * 1.3)
    } else {
        let pad = ((t1 - t0) * 0.08).max(t0 * 0.05).max(1e-4);
        ((t0 - pad).max(0.0), t1 + pad)
    };
    let (mut s0, mut s1) = finite(|r| r.ssim)
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    if !s0.is_finite() {
        (s0, s1) = (0.0, 1.0);
    }
    let pad = ((s1 - s0) * 0.1).max(0.005);
    ((t0, t1), (s0 - pad, s1 + pad), log)
}

/// A tick label: three significant digits, trailing zeros dropped (`0.30000000000000004` → `0.3`).
fn short_number(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let decimals = (2 - v.abs().log10().floor() as i32).max(0) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    rows: &[Row],
    title: &str,
) -> Result<()> {
    let (x, y, log) = ranges(rows);
    if log {
        chart(root, rows, title, (x.0..x.1).log_scale(), y)
    } else {
        chart(root, rows, title, x.0..x.1, y)
    }
}

/// Draws the chart: every setting as a grey dot with its label, the Pareto front as red dots joined
/// in order of time.
fn chart<DB, X>(
    root: &DrawingArea<DB, Shift>,
    rows: &[Row],
    title: &str,
    x: X,
    y: (f64, f64),
) -> Result<()>
where
    DB: DrawingBackend,
    X: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
{
    let e = plot_error;
    root.fill(&WHITE).map_err(e)?;
    let mut chart = ChartBuilder::on(root)
        .caption(title, (FAMILY, 20))
        .margin(16)
        .x_label_area_size(44)
        .y_label_area_size(64)
        .build_cartesian_2d(x, y.0..y.1)
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc("seconds (median in-process denoise time)")
        .y_desc("SSIM")
        .x_labels(10)
        .x_label_formatter(&|v| short_number(*v))
        .label_style((FAMILY, 14))
        .axis_desc_style((FAMILY, 15))
        .max_light_lines(0)
        .draw()
        .map_err(e)?;
    let front_colour = RGBColor(200, 30, 30);
    let mut front: Vec<(f64, f64)> = rows
        .iter()
        .filter(|r| r.pareto)
        .map(|r| (r.seconds, r.ssim))
        .collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
    chart
        .draw_series(LineSeries::new(front.clone(), front_colour.stroke_width(2)))
        .map_err(e)?
        .label("Pareto front")
        .legend(move |(lx, ly)| {
            PathElement::new(vec![(lx, ly), (lx + 20, ly)], front_colour.stroke_width(2))
        });
    let points = rows
        .iter()
        .filter(|r| r.seconds.is_finite() && r.ssim.is_finite());
    chart
        .draw_series(points.clone().map(|r| {
            let (colour, size) = if r.pareto {
                (front_colour, 5)
            } else {
                (RGBColor(110, 110, 110), 4)
            };
            Circle::new((r.seconds, r.ssim), size, colour.filled())
        }))
        .map_err(e)?;
    // Labels go where they hide no marker, no line and no other label (front points first, as
    // they are the ones worth reading); the table and CSV carry every value anyway.
    let label_style = TextStyle::from((FAMILY, 13).into_font()).color(&RGBColor(40, 40, 40));
    let (xr, yr) = chart.plotting_area().get_pixel_range();
    let area = Rect::new(xr.start, yr.start, xr.end, yr.end);
    let mut taken: Vec<Rect> = Vec::new();
    let pixel = |r: &Row| chart.backend_coord(&(r.seconds, r.ssim));
    let drawn: Vec<&Row> = points.clone().collect();
    for r in &drawn {
        let (px, py) = pixel(r);
        taken.push(Rect::new(px - 6, py - 6, px + 6, py + 6));
    }
    for pair in front.windows(2) {
        let (a, b) = (chart.backend_coord(&pair[0]), chart.backend_coord(&pair[1]));
        let steps = ((b.0 - a.0).abs().max((b.1 - a.1).abs()) / 3).max(1);
        for k in 0..=steps {
            let x = a.0 + (b.0 - a.0) * k / steps;
            let y = a.1 + (b.1 - a.1) * k / steps;
            taken.push(Rect::new(x - 2, y - 2, x + 2, y + 2));
        }
    }
    let mut order: Vec<&Row> = drawn.iter().copied().filter(|r| r.pareto).collect();
    order.extend(drawn.iter().copied().filter(|r| !r.pareto));
    for r in order {
        let (w, h) = root.estimate_text_size(&r.label, &label_style).map_err(e)?;
        let at = place_label(pixel(r), (w as i32, h as i32), area, &taken);
        taken.push(at);
        root.draw(&Text::new(
            r.label.clone(),
            (at.x0, at.y0),
            label_style.clone(),
        ))
        .map_err(e)?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .label_font((FAMILY, 13))
        .background_style(WHITE.mix(0.8))
        .border_style(RGBColor(180, 180, 180))
        .draw()
        .map_err(e)?;
    Ok(())
}

/// A pixel rectangle, `x1`/`y1` exclusive.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Rect {
    x0: i32,
    y0: i32,
    x1: i32,
    y1: i32,
}

impl Rect {
    fn new(x0: i32, y0: i32, x1: i32, y1: i32) -> Self {
        Rect { x0, y0, x1, y1 }
    }

    fn overlap(&self, o: &Rect) -> i64 {
        let w = (self.x1.min(o.x1) - self.x0.max(o.x0)).max(0) as i64;
        let h = (self.y1.min(o.y1) - self.y0.max(o.y0)).max(0) as i64;
        w * h
    }

    fn inside(&self, o: &Rect) -> bool {
        self.x0 >= o.x0 && self.y0 >= o.y0 && self.x1 <= o.x1 && self.y1 <= o.y1
    }
}

/// Where a `size` label of the marker at `p` goes: the first of eight spots around the marker that is
/// inside `area` and overlaps nothing `taken`; failing that, the spot inside `area` (else anywhere)
/// that overlaps least.
fn place_label(p: (i32, i32), size: (i32, i32), area: Rect, taken: &[Rect]) -> Rect {
    let ((px, py), (w, h)) = (p, size);
    let spots = [
        (px + 8, py - h - 2),
        (px + 8, py + 2),
        (px - 8 - w, py - h - 2),
        (px - 8 - w, py + 2),
        (px + 9, py - h / 2),
        (px - 9 - w, py - h / 2),
        (px - w / 2, py - h - 8),
        (px - w / 2, py + 8),
    ]
    .map(|(x, y)| Rect::new(x, y, x + w, y + h));
    let cost = |r: &Rect| -> (bool, i64) {
        (
            !r.inside(&area),
            taken.iter().map(|t| t.overlap(r)).sum::<i64>(),
        )
    };
    spots.iter().copied().min_by_key(cost).expect("eight spots")
}

/// plotters' bitmap backend with its text drawn correctly.
///
/// plotters 0.3.7 draws ab_glyph text without each glyph's left side bearing (`walks=10` comes out as
/// `walks=1 0`), and only the bitmap is affected: the SVG backend writes `<text>` for the viewer to
/// set. This wrapper passes everything to the bitmap backend except text, which it lays out and
/// rasterises itself with ab_glyph from the embedded font (kerning, bearings, anchors, rotations).
struct GlyphBitmap<'a> {
    inner: BitMapBackend<'a>,
    font: ab_glyph::FontRef<'static>,
}

type BitmapError<'a> = pb::DrawingErrorKind<<BitMapBackend<'a> as DrawingBackend>::ErrorType>;

impl<'a> GlyphBitmap<'a> {
    fn new(inner: BitMapBackend<'a>) -> Result<Self> {
        let font = ab_glyph::FontRef::try_from_slice(FONT)
            .map_err(|e| Error::Runtime(format!("the embedded plot font does not load: {e}")))?;
        Ok(GlyphBitmap { inner, font })
    }

    /// Calls `f(x, y, coverage)` for every pixel of `text` at `size` px, with the layout box's top left
    /// at (0, 0) and the baseline at the font's ascent; returns the box's width and height.
    fn layout(&self, text: &str, size: f64, mut f: impl FnMut(i32, i32, f32)) -> (f32, f32) {
        use ab_glyph::{Font, ScaleFont};
        let font = self.font.as_scaled(size as f32);
        let mut pen = 0.0f32;
        let mut prev = None;
        for c in text.chars() {
            let id = font.glyph_id(c);
            if let Some(p) = prev {
                pen += font.kern(p, id);
            }
            prev = Some(id);
            let glyph =
                id.with_scale_and_position(size as f32, ab_glyph::point(pen, font.ascent()));
            if let Some(outline) = font.outline_glyph(glyph) {
                let b = outline.px_bounds();
                outline.draw(|x, y, c| f(b.min.x as i32 + x as i32, b.min.y as i32 + y as i32, c));
            }
            pen += font.h_advance(id);
        }
        (pen, font.ascent() - font.descent())
    }
}

impl<'a> DrawingBackend for GlyphBitmap<'a> {
    type ErrorType = <BitMapBackend<'a> as DrawingBackend>::ErrorType;

    fn get_size(&self) -> (u32, u32) {
        self.inner.get_size()
    }

    fn ensure_prepared(&mut self) -> std::result::Result<(), BitmapError<'a>> {
        self.inner.ensure_prepared()
    }

    fn present(&mut self) -> std::result::Result<(), BitmapError<'a>> {
        self.inner.present()
    }

    fn draw_pixel(
        &mut self,
        point: pb::BackendCoord,
        color: pb::BackendColor,
    ) -> std::result::Result<(), BitmapError<'a>> {
        self.inner.draw_pixel(point, color)
    }

    fn draw_line<S: pb::BackendStyle>(
        &mut self,
        from: pb::BackendCoord,
        to: pb::BackendCoord,
        style: &S,
    ) -> std::result::Result<(), BitmapError<'a>> {
        self.inner.draw_line(from, to, style)
    }

    fn draw_rect<S: pb::BackendStyle>(
        &mut self,
        upper_left: pb::BackendCoord,
        bottom_right: pb::BackendCoord,
        style: &S,
        fill: bool,
    ) -> std::result::Result<(), BitmapError<'a>> {
        self.inner.draw_rect(upper_left, bottom_right, style, fill)
    }

    fn draw_path<S: pb::BackendStyle, I: IntoIterator<Item = pb::BackendCoord>>(
        &mut self,
        path: I,
        style: &S,
    ) -> std::result::Result<(), BitmapError<'a>> {
        self.inner.draw_path(path, style)
    }

    fn draw_circle<S: pb::BackendStyle>(
        &mut self,
        center: pb::BackendCoord,
        radius: u32,
        style: &S,
        fill: bool,
    ) -> std::result::Result<(), BitmapError<'a>> {
        self.inner.draw_circle(center, radius, style, fill)
    }

    fn fill_polygon<S: pb::BackendStyle, I: IntoIterator<Item = pb::BackendCoord>>(
        &mut self,
        vert: I,
        style: &S,
    ) -> std::result::Result<(), BitmapError<'a>> {
        self.inner.fill_polygon(vert, style)
    }

    fn blit_bitmap(
        &mut self,
        pos: pb::BackendCoord,
        size: (u32, u32),
        src: &[u8],
    ) -> std::result::Result<(), BitmapError<'a>> {
        self.inner.blit_bitmap(pos, size, src)
    }

    fn draw_text<S: pb::BackendTextStyle>(
        &mut self,
        text: &str,
        style: &S,
        pos: pb::BackendCoord,
    ) -> std::result::Result<(), BitmapError<'a>> {
        let colour = style.color();
        if colour.alpha == 0.0 {
            return Ok(());
        }
        let (w, h) = self.layout(text, style.size(), |_, _, _| {});
        let (w, h) = (w.ceil() as i32, h.ceil() as i32);
        let dx = match style.anchor().h_pos {
            HPos::Left => 0,
            HPos::Center => -w / 2,
            HPos::Right => -w,
        };
        let dy = match style.anchor().v_pos {
            VPos::Top => 0,
            VPos::Center => -h / 2,
            VPos::Bottom => -h,
        };
        let transform = style.transform();
        let (width, height) = self.get_size();
        let mut pixels = Vec::new();
        self.layout(text, style.size(), |x, y, c| {
            let (x, y) = transform.transform(x + dx, y + dy);
            let (x, y) = (pos.0 + x, pos.1 + y);
            if c > 0.0 && x >= 0 && y >= 0 && x < width as i32 && y < height as i32 {
                pixels.push(((x, y), c.min(1.0)));
            }
        });
        for (p, c) in pixels {
            let alpha = colour.alpha * c as f64;
            self.inner
                .draw_pixel(p, pb::BackendColor { alpha, ..colour })?;
        }
        Ok(())
    }

    fn estimate_text_size<S: pb::BackendTextStyle>(
        &self,
        text: &str,
        style: &S,
    ) -> std::result::Result<(u32, u32), BitmapError<'a>> {
        let (w, h) = self.layout(text, style.size(), |_, _, _| {});
        Ok((w.ceil() as u32, h.ceil() as u32))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axes_parse_and_reject_bad_forms() {
        let a = parse_axis("gsid.walks= 5, 10 ,20").unwrap();
        assert_eq!(a.key, "gsid.walks");
        assert_eq!(a.values, ["5", "10", "20"]);
        for bad in [
            "gsid.walks",
            "gsid.walks=",
            "=5",
            "gsid.walks=5,,10",
            "gsid.walks=5,",
            "gsid.walks=5,5",
        ] {
            let err = parse_axis(bad).err().unwrap().to_string();
            assert!(err.contains("--vary"), "{bad}: {err}");
            assert_eq!(err.lines().count(), 1);
        }
        let varies = ["gsid.walks=1,2".to_string(), "gsid.walks=3".to_string()];
        let err = parse_axes(&varies, &[]).err().unwrap().to_string();
        assert!(err.contains("gsid.walks") && err.contains("twice"), "{err}");
        let err = parse_axes(&varies[..1], &["gsid.walks=4".to_string()])
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("--set"), "{err}");
        assert!(parse_axes(&[], &[]).is_err());
    }

    #[test]
    fn short_names_lengthen_only_on_a_clash() {
        let keys = |k: &[&str]| k.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert_eq!(
            short_names(&keys(&["gsid.walks", "pyramid.levels"])),
            ["walks", "levels"]
        );
        assert_eq!(
            short_names(&keys(&[
                "pyramid.level1.gsid.sigma",
                "pyramid.level2.gsid.sigma",
                "pyramid.levels"
            ])),
            ["level1.gsid.sigma", "level2.gsid.sigma", "levels"]
        );
        assert_eq!(
            short_names(&keys(&["gsid.walks", "pyramid.gsid.walks"])),
            ["gsid.walks", "pyramid.gsid.walks"]
        );
    }

    #[test]
    fn settings_are_the_product_first_axis_slowest() {
        let base = PipelineSpec::resolve("full").unwrap();
        let axes = vec![
            parse_axis("pyramid.gsid.walks=4,8").unwrap(),
            parse_axis("pyramid.levels=1,2,3").unwrap(),
        ];
        let s = settings(&base, &axes).unwrap();
        let labels: Vec<&str> = s.iter().map(|s| s.label.as_str()).collect();
        assert_eq!(
            labels,
            [
                "walks=4 levels=1",
                "walks=4 levels=2",
                "walks=4 levels=3",
                "walks=8 levels=1",
                "walks=8 levels=2",
                "walks=8 levels=3"
            ]
        );
        assert_eq!(s[4].values, ["8", "2"]);
        let pyramid = s[4].spec.stages.iter().find(|s| s.id == "pyramid").unwrap();
        assert_eq!(pyramid.params["levels"].as_integer(), Some(2));
        assert_eq!(
            pyramid.overrides.every_level["gsid"]["walks"].as_integer(),
            Some(8)
        );
    }

    #[test]
    fn bad_keys_values_and_combinations_are_named_before_any_work() {
        let base = PipelineSpec::resolve("gsid").unwrap();
        for (vary, culprit) in [
            ("gsid.walkz=1,2", "gsid.walkz"),
            ("gsid.walks=4,-1", "gsid.walks=-1"),
            ("gsid.walks=abc", "gsid.walks=abc"),
            ("blur.radius=1", "blur.radius"),
        ] {
            let err = settings(&base, &[parse_axis(vary).unwrap()])
                .err()
                .unwrap()
                .to_string();
            assert!(err.contains(culprit), "{vary}: {err}");
            assert_eq!(err.lines().count(), 1, "{err}");
        }
        // `level2` needs three levels: invalid against the base (two levels) but fine with levels=3 ...
        let full = PipelineSpec::resolve("full").unwrap();
        let mut axes = vec![
            parse_axis("pyramid.levels=3,4").unwrap(),
            parse_axis("pyramid.level2.gsid.sigma=0.5").unwrap(),
        ];
        assert_eq!(settings(&full, &axes).unwrap().len(), 2);
        // ... and named, with the combination, when one combination has two levels.
        axes[0] = parse_axis("pyramid.levels=3,2").unwrap();
        let err = settings(&full, &axes).err().unwrap().to_string();
        assert!(
            err.contains("--vary pyramid.level2.gsid.sigma=0.5 (in levels=2 sigma=0.5)"),
            "{err}"
        );
        // Fine alone, clashing together: named as a combination.
        let axes = [
            parse_axis("pyramid.levels=1,3").unwrap(),
            parse_axis("pyramid.level1.gsid.sigma=0.5").unwrap(),
        ];
        let err = settings(&full, &axes).err().unwrap().to_string();
        assert!(err.contains("combination levels=1 sigma=0.5"), "{err}");
    }

    #[test]
    fn varying_levels_drops_the_files_overrides_of_missing_levels() {
        // `full` tunes level1 (σ 0.25); with one level that override has nothing to apply to.
        let full = PipelineSpec::resolve("full").unwrap();
        let s = settings(&full, &[parse_axis("pyramid.levels=1,2").unwrap()]).unwrap();
        let pyramid = |i: usize| s[i].spec.stages.iter().find(|s| s.id == "pyramid").unwrap();
        assert!(!pyramid(0).overrides.levels.contains_key("level1"));
        assert_eq!(s[0].notes.len(), 1, "{:?}", s[0].notes);
        assert!(s[0].notes[0].contains("pyramid.level1"), "{:?}", s[0].notes);
        assert_eq!(
            pyramid(1).overrides.levels["level1"].stages["gsid"]["sigma"].as_float(),
            Some(0.25)
        );
        assert!(s[1].notes.is_empty());
    }

    #[test]
    fn median_of_odd_and_even_counts() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), 2.5);
        assert_eq!(median(&[7.0]), 7.0);
    }

    #[test]
    fn pareto_front_examples() {
        // (1, .8) and (2, .9) trade off; (3, .85) is beaten by (2, .9); (1, .7) by (1, .8).
        let pts = [(1.0, 0.8), (2.0, 0.9), (3.0, 0.85), (1.0, 0.7)];
        assert_eq!(pareto_front(&pts), [true, true, false, false]);
        // Identical points are both on the front.
        assert_eq!(
            pareto_front(&[(1.0, 0.9), (1.0, 0.9), (2.0, 0.9)]),
            [true, true, false]
        );
        // Same time, better SSIM wins; same SSIM, faster wins.
        assert_eq!(pareto_front(&[(1.0, 0.9), (1.0, 0.8)]), [true, false]);
        assert_eq!(pareto_front(&[(2.0, 0.9), (1.0, 0.9)]), [false, true]);
        assert_eq!(pareto_front(&[(f64::NAN, 0.9), (1.0, 0.5)]), [false, true]);
        assert!(pareto_front(&[]).is_empty());
        assert_eq!(pareto_front(&[(0.5, 0.1)]), [true]);
        // Property tests of the front are in tests/sweep.rs.
    }

    fn row(label: &str, seconds: f64, ssim: f64, pareto: bool) -> Row {
        Row {
            label: label.into(),
            values: vec![label.trim_start_matches("walks=").into()],
            seconds,
            seconds_min: seconds,
            seconds_max: seconds,
            ssim,
            psnr: 30.0,
            relmse: 0.01,
            walk_steps: 100,
            pareto,
            notes: vec![],
        }
    }

    #[test]
    fn csv_has_key_columns_and_quoted_labels() {
        let axes = [parse_axis("gsid.walks=5,10").unwrap()];
        let rows = [
            row("walks=5", 0.1, 0.8, true),
            row("walks=10", 0.2, 0.7, false),
        ];
        let text = csv(&axes, &rows);
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(
            lines[0],
            "label,gsid.walks,seconds,seconds_min,seconds_max,ssim,psnr,relmse,walk_steps,pareto"
        );
        assert_eq!(lines[1], "walks=5,5,0.1,0.1,0.1,0.8,30,0.01,100,true");
        assert_eq!(csv_field("walks=5 levels=2"), "\"walks=5 levels=2\"");
        assert!(table(&rows)
            .lines()
            .nth(1)
            .unwrap()
            .trim_end()
            .ends_with('*'));
    }

    #[test]
    fn notes_are_printed_once() {
        let mut rows = [
            row("walks=5", 0.1, 0.8, true),
            row("walks=10", 0.2, 0.7, false),
        ];
        rows[0].notes = vec!["a".into(), "b".into()];
        rows[1].notes = vec!["a".into()];
        assert_eq!(notes(&rows), ["a", "b (walks=5)"]);
    }

    #[test]
    fn plots_render_linear_and_log_axes() {
        let linear = [
            row("walks=5", 0.1, 0.8, true),
            row("walks=10", 0.2, 0.9, true),
        ];
        let log = [
            row("walks=5", 0.01, 0.8, true),
            row("walks=500", 1.0, 0.9, true),
        ];
        for rows in [&linear[..], &log[..], &linear[..1]] {
            let svg = plot_svg(rows, "SSIM vs seconds — test — pipeline gsid").unwrap();
            assert!(svg.contains("<svg") && svg.contains("walks=5"), "{svg}");
            let png = plot_png(rows, "t").unwrap();
            assert_eq!(&png[1..4], b"PNG");
        }
        assert!(ranges(&log).2 && !ranges(&linear).2);
        assert_eq!(short_number(0.30000000000000004), "0.3");
        assert_eq!(short_number(0.125), "0.125");
        assert_eq!(short_number(12.5), "12.5");
        assert_eq!(short_number(1.0), "1");
        assert_eq!(short_number(0.0004567), "0.000457");
    }
}
