//! How far a run is and whether it must stop, as the stages' row loops see it: one [`Meter`] a
//! run, handed to the heavy kernels (walks, prefilter, noise estimate, regression, pyramid
//! blending) so a cancel stops them between rows and progress moves within a stage.
//!
//! Progress within a stage is told in passes: each kernel run over the image's rows (a pass)
//! moves the fraction up to half of what is left of the stage's share, so the fraction never
//! decreases and never reaches the next stage's start before that stage begins. The callback is
//! called one call at a time (a lock), from whichever thread finished the rows.

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use crate::error::{Error, Result};
use crate::options::{CancelToken, DenoiseOptions, ProgressFn};

/// Smallest rise of the fraction worth a callback within a stage: at most a few hundred calls a
/// run, whatever the image size.
const STEP: f32 = 0.002;

/// A run's cancellation and progress; cheap to clone and to ask. [`Meter::default`] has neither.
#[derive(Clone, Default)]
pub struct Meter(Option<Arc<Inner>>);

struct Inner {
    cancel: Option<CancelToken>,
    progress: Option<Arc<ProgressFn>>,
    /// The current pass: its fractions at start and end (f32 bits), rows done and rows in all.
    from: AtomicU32,
    to: AtomicU32,
    done: AtomicU64,
    total: AtomicU64,
    /// What was last told; held while the callback runs, so calls never overlap or go back.
    told: Mutex<Told>,
}

struct Told {
    fraction: f32,
    stage: String,
    /// Where the current stage's share ends.
    stage_end: f32,
}

impl Meter {
    /// The meter of a run with these options (none when they ask for neither progress nor cancel).
    pub fn new(options: &DenoiseOptions) -> Self {
        if options.cancel.is_none() && options.progress.is_none() {
            return Meter(None);
        }
        Meter(Some(Arc::new(Inner {
            cancel: options.cancel.clone(),
            progress: options.progress.clone(),
            from: AtomicU32::new(0),
            to: AtomicU32::new(0),
            done: AtomicU64::new(0),
            total: AtomicU64::new(1),
            told: Mutex::new(Told {
                fraction: 0.0,
                stage: String::new(),
                stage_end: 0.0,
            }),
        })))
    }

    /// Whether the run was asked to stop: a row loop that sees it skips its remaining rows.
    #[inline]
    pub fn cancelled(&self) -> bool {
        self.0
            .as_ref()
            .and_then(|m| m.cancel.as_ref())
            .is_some_and(CancelToken::is_cancelled)
    }

    /// `Err(Cancelled)` once the run was asked to stop.
    pub fn check(&self) -> Result<()> {
        if self.cancelled() {
            return Err(Error::Cancelled);
        }
        Ok(())
    }

    /// A stage begins whose share of the run is `from..to`: told at once (blocking), with its id.
    pub fn stage(&self, from: f32, to: f32, id: &str) {
        let Some(m) = &self.0 else { return };
        let mut told = m.told.lock().unwrap_or_else(|e| e.into_inner());
        told.stage = id.to_string();
        told.stage_end = to;
        m.from.store(from.to_bits(), Ordering::Relaxed);
        m.to.store(from.to_bits(), Ordering::Relaxed);
        m.done.store(0, Ordering::Relaxed);
        told.fraction = told.fraction.max(from);
        if let Some(progress) = &m.progress {
            progress(told.fraction.clamp(0.0, 1.0), id);
        }
    }

    /// A pass over `rows` rows begins within the current stage: as its rows finish, the fraction
    /// moves up to half of what is left of the stage's share.
    pub fn pass(&self, rows: usize) {
        let Some(m) = &self.0 else { return };
        let told = m.told.lock().unwrap_or_else(|e| e.into_inner());
        let from = told.fraction;
        let to = from + (told.stage_end - from) / 2.0;
        m.done.store(0, Ordering::Relaxed);
        m.total.store(rows.max(1) as u64, Ordering::Relaxed);
        m.from.store(from.to_bits(), Ordering::Relaxed);
        m.to.store(to.to_bits(), Ordering::Relaxed);
    }

    /// `n` rows of the current pass are done; tells the callback when the fraction rose enough
    /// (skipped while another thread is telling it).
    #[inline]
    pub fn rows(&self, n: usize) {
        let Some(m) = &self.0 else { return };
        let Some(progress) = &m.progress else { return };
        let done = m.done.fetch_add(n as u64, Ordering::Relaxed) + n as u64;
        let total = m.total.load(Ordering::Relaxed);
        let from = f32::from_bits(m.from.load(Ordering::Relaxed));
        let to = f32::from_bits(m.to.load(Ordering::Relaxed));
        let fraction = from + (to - from) * (done.min(total) as f32 / total as f32);
        let Ok(mut told) = m.told.try_lock() else {
            return;
        };
        if fraction >= told.fraction + STEP && fraction < told.stage_end {
            told.fraction = fraction;
            progress(fraction.clamp(0.0, 1.0), &told.stage);
        }
    }

    /// One more of a stage's short passes is done (those with no row loop worth telling): the
    /// fraction moves as for a whole pass, then `Err(Cancelled)` once the run was asked to stop.
    pub fn step(&self) -> Result<()> {
        if self.0.is_some() {
            self.pass(1);
            self.rows(1);
        }
        self.check()
    }

    /// The end of the run: fraction 1, stage `done`.
    pub fn finish(&self) {
        let Some(m) = &self.0 else { return };
        let mut told = m.told.lock().unwrap_or_else(|e| e.into_inner());
        told.fraction = 1.0;
        if let Some(progress) = &m.progress {
            progress(1.0, "done");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    type Calls = Arc<Mutex<Vec<(f32, String)>>>;

    fn recorded() -> (Meter, Calls) {
        let seen = Arc::new(Mutex::new(Vec::new()));
        let sink = seen.clone();
        let options = DenoiseOptions {
            progress: Some(Arc::new(move |f, s: &str| {
                sink.lock().unwrap().push((f, s.to_string()))
            })),
            ..DenoiseOptions::default()
        };
        (Meter::new(&options), seen)
    }

    #[test]
    fn passes_move_within_the_stage_share_and_never_back() {
        let (meter, seen) = recorded();
        meter.stage(0.0, 0.5, "a");
        for rows in [100, 10, 1000] {
            meter.pass(rows);
            for _ in 0..rows {
                meter.rows(1);
            }
        }
        meter.stage(0.5, 1.0, "b");
        meter.finish();
        let seen = seen.lock().unwrap();
        assert!(seen.len() > 10, "{seen:?}");
        assert!(seen.windows(2).all(|w| w[0].0 <= w[1].0), "{seen:?}");
        let in_a: Vec<_> = seen.iter().filter(|(_, s)| s == "a").collect();
        assert!(in_a.iter().all(|(f, _)| *f < 0.5), "{in_a:?}");
        assert_eq!(seen[seen.len() - 2], (0.5, "b".to_string()));
        assert_eq!(*seen.last().unwrap(), (1.0, "done".to_string()));
    }

    #[test]
    fn a_meter_without_options_is_never_cancelled() {
        let meter = Meter::default();
        meter.pass(3);
        meter.rows(3);
        assert!(!meter.cancelled());
        let cancel = CancelToken::new();
        let meter = Meter::new(&DenoiseOptions {
            cancel: Some(cancel.clone()),
            ..DenoiseOptions::default()
        });
        assert!(meter.check().is_ok());
        cancel.cancel();
        assert!(matches!(meter.check(), Err(Error::Cancelled)));
    }
}
