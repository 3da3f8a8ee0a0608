//! Running the settings: timing (median of the repeats), scoring, and the rows' notes.

use std::time::Instant;

use super::grid::Setting;
use super::pareto::mark_front;
use super::row::Row;
use crate::buffers::Buffers;
use crate::error::Result;
use crate::image::Image;
use crate::metrics;
use crate::options::DenoiseOptions;

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
            let result = s.pipeline.run(&mut b, &DenoiseOptions::seeded(seed))?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::study::sweep::row::test_row as row;

    #[test]
    fn median_of_odd_and_even_counts() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), 2.5);
        assert_eq!(median(&[7.0]), 7.0);
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
}
