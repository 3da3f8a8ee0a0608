//! One row of the sweep table: a setting's time, scores and notes, as run, plotted and written.

use serde::Serialize;

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
    /// On the Pareto front of (seconds, SSIM); filled in by [`super::pareto::mark_front`].
    pub pareto: bool,
    /// What the sweep left out of this setting and the pipeline's notes from its first run.
    #[serde(skip)]
    pub notes: Vec<String>,
}

/// A row with the given label, time, SSIM and front flag (the other fields fixed), for tests.
#[cfg(test)]
pub(super) fn test_row(label: &str, seconds: f64, ssim: f64, pareto: bool) -> Row {
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
