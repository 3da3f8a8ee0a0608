//! The SSIM-vs-seconds scatter plot, as SVG and PNG: every setting labelled, the front joined.

use std::sync::Once;

use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::coord::Shift;
use plotters::prelude::*;

use super::glyphs::GlyphBitmap;
use super::row::Row;
use crate::error::{Error, Result};

/// DejaVu Sans (license in `assets/DejaVuSans-LICENSE.txt`), compiled in so the plots have text on any
/// machine: plotters' default `ttf` feature would look fonts up through fontconfig and FreeType,
/// system libraries a fresh machine or CI may not have.
static FONT: &[u8] = include_bytes!("../../../assets/DejaVuSans.ttf");
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
        let root = GlyphBitmap::new(BitMapBackend::with_buffer(&mut rgb, PLOT_SIZE), FONT)?
            .into_drawing_area();
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::study::sweep::row::test_row as row;

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
