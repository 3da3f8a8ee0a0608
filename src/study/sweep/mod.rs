//! `gsid sweep`: what does a pipeline parameter cost in time, and what does it buy in quality?
//!
//! Every `--vary KEY=V1,V2,...` is one axis; the sweep runs the Cartesian product of the axes (the first
//! axis varies slowest), each setting `repeat` times, and keeps the median time and the score of the
//! output. The settings no other setting beats on both time and SSIM form the Pareto front: those are
//! the only ones worth choosing, and the plot joins them.
//!
//! Everything here is library code (parsing the axes, building and validating the settings, running,
//! the Pareto front, the CSV, the table and the plots), so it is unit-tested; `cli.rs` only wires files.
//! [`grid`]: axes and settings; [`run`]: timing and scores; [`row`]: one setting's results;
//! [`pareto`]: the front; [`plot`] and [`glyphs`]: the plots.

pub mod glyphs;
pub mod grid;
pub mod pareto;
pub mod plot;
pub mod row;
pub mod run;

pub use grid::{parse_axes, parse_axis, settings, short_names, Axis, Setting};
pub use pareto::{dominates, mark_front, pareto_front};
pub use plot::{plot_png, plot_svg, PLOT_SIZE};
pub use row::Row;
pub use run::{median, notes, run};

use super::table;
use crate::error::Result;

/// The rows as CSV: `label`, one column per varied key (headed by the key), then `seconds` (median),
/// `seconds_min`, `seconds_max`, `ssim`, `psnr`, `relmse`, `walk_steps`, `pareto`.
pub fn csv(axes: &[Axis], rows: &[Row]) -> Result<String> {
    let mut header = vec!["label".to_string()];
    header.extend(axes.iter().map(|a| a.key.clone()));
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
    let fields: Vec<Vec<String>> = rows
        .iter()
        .map(|r| {
            let mut f = vec![r.label.clone()];
            f.extend(r.values.iter().cloned());
            f.extend([
                r.seconds.to_string(),
                r.seconds_min.to_string(),
                r.seconds_max.to_string(),
                r.ssim.to_string(),
                r.psnr.to_string(),
                r.relmse.to_string(),
                r.walk_steps.to_string(),
                r.pareto.to_string(),
            ]);
            f
        })
        .collect();
    table::csv(&header, &fields)
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

#[cfg(test)]
mod tests {
    use super::*;
    use row::test_row as row;

    #[test]
    fn csv_has_key_columns_and_quotes_only_where_needed() {
        let axes = [parse_axis("gsid.walks=5,10").unwrap()];
        let mut rows = [
            row("walks=5", 0.1, 0.8, true),
            row("walks=10", 0.2, 0.7, false),
        ];
        rows[1].label = "walks=10 tone=a,b".into();
        let text = csv(&axes, &rows).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(
            lines[0],
            "label,gsid.walks,seconds,seconds_min,seconds_max,ssim,psnr,relmse,walk_steps,pareto"
        );
        assert_eq!(lines[1], "walks=5,5,0.1,0.1,0.1,0.8,30,0.01,100,true");
        assert!(
            lines[2].starts_with("\"walks=10 tone=a,b\",10,"),
            "{}",
            lines[2]
        );
        assert!(table(&rows)
            .lines()
            .nth(1)
            .unwrap()
            .trim_end()
            .ends_with('*'));
    }
}
