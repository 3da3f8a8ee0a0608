//! A run watched from the caller's thread: the work runs on a thread of its own while the
//! caller's thread wakes every few milliseconds to pass progress on and to look for a reason to
//! cancel (a Python KeyboardInterrupt, a C cancel flag). Python's signal handlers and most UI
//! toolkits only work on the thread that called, which is why the bindings use it.

use std::sync::{mpsc, Arc, Mutex};
use std::time::Duration;

use crate::options::ProgressFn;

/// How often the caller's thread wakes while a run goes on.
pub const TICK: Duration = Duration::from_millis(20);

/// Runs `work` on a scoped thread and calls `tick` on this thread every [`TICK`] until it ends
/// (and once more after), then returns its result. A panic in `work` is resumed here.
pub fn run_watched<T: Send>(work: impl FnOnce() -> T + Send, mut tick: impl FnMut()) -> T {
    std::thread::scope(|s| {
        let (done, finished) = mpsc::channel::<()>();
        let handle = s.spawn(move || {
            let out = work();
            let _ = done.send(());
            out
        });
        while let Err(mpsc::RecvTimeoutError::Timeout) = finished.recv_timeout(TICK) {
            tick();
        }
        tick();
        match handle.join() {
            Ok(out) => out,
            Err(panic) => std::panic::resume_unwind(panic),
        }
    })
}

/// Progress as the run tells it, kept for the watching thread to pass on: the latest fraction
/// and stage, each handed out once.
#[derive(Clone, Default)]
pub struct ProgressRelay(Arc<Mutex<Option<(f32, String)>>>);

impl ProgressRelay {
    pub fn new() -> Self {
        Self::default()
    }

    /// The callback to put in [`crate::DenoiseOptions::progress`].
    pub fn callback(&self) -> Arc<ProgressFn> {
        let latest = self.0.clone();
        Arc::new(move |fraction, stage: &str| {
            let mut latest = latest.lock().unwrap_or_else(|e| e.into_inner());
            *latest = Some((fraction, stage.to_string()));
        })
    }

    /// The progress told since the last call, if any.
    pub fn take(&self) -> Option<(f32, String)> {
        self.0.lock().unwrap_or_else(|e| e.into_inner()).take()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_caller_ticks_while_the_work_runs_and_gets_its_result() {
        let relay = ProgressRelay::new();
        let tell = relay.callback();
        let mut seen = Vec::new();
        let out = run_watched(
            || {
                tell(0.5, "half");
                std::thread::sleep(TICK * 3);
                7
            },
            || seen.extend(relay.take()),
        );
        assert_eq!(out, 7);
        assert_eq!(seen, [(0.5, "half".to_string())]);
    }
}
