//! What a `gsid denoise` run shows on stderr while it works, and how much it says.
//!
//! On a terminal: one bar over the whole run (every frame's read, pipeline stages and write) with the
//! frame, the stage and an ETA. Without one (a render farm capturing stderr): a plain line every few
//! seconds and at each frame's end, in a fixed form a farm's progress regex can parse:
//!
//! ```text
//! gsid: frame 1003: 40 % (frame 3 of 8, run 29 %, stage gsid, ETA 0:00:12)
//! gsid: 40 % (run 40 %, stage gsid, ETA 0:00:12)          one render set
//! ```
//!
//! [`LINE_REGEX`] matches both; farm/README.md documents the fields.

use std::io::IsTerminal;
use std::sync::mpsc;
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};

use crate::options::ProgressFn;
use crate::progress::say;

/// A progress line's form (Python and .NET syntax alike): 1 the frame, 2 the frame's percent, 3 the
/// frame's place and 4 the frame count (absent for one render set), 5 the whole run's percent,
/// 6 the stage, 7 the ETA (`H:MM:SS`, or `?` before there is a rate to go by).
pub const LINE_REGEX: &str = r"^gsid: (?:frame (\S+): )?(\d+) % \((?:frame (\d+) of (\d+), )?run (\d+) %, stage (\S+), ETA (\S+)\)$";

/// Seconds between progress lines without a terminal (`--progress-every`).
pub const DEFAULT_EVERY: f64 = 5.0;

/// How much a run says on stderr. Each level says everything the one before it says.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Verbosity {
    /// `-q`: errors only.
    Quiet,
    /// The default: notes, progress, one summary line a frame.
    Normal,
    /// `-v`: also the run's setup, each frame's inputs and its stages' times.
    Verbose,
    /// `-vv`: also every progress step as it happens, with the time since the start.
    Debug,
}

impl Verbosity {
    pub fn of(quiet: bool, verbose: u8) -> Self {
        match (quiet, verbose) {
            (true, _) => Verbosity::Quiet,
            (false, 0) => Verbosity::Normal,
            (false, 1) => Verbosity::Verbose,
            _ => Verbosity::Debug,
        }
    }
}

/// The share of a frame's progress reading takes, and where writing starts; the pipeline's
/// fractions fill the span between (progress is work done, not time).
const READ_END: f64 = 0.05;
const WRITE_START: f64 = 0.95;

/// How often a terminal's bar is redrawn while the callback is silent (for the ETA and elapsed time).
const BAR_TICK: Duration = Duration::from_millis(500);

struct State {
    frames: usize,
    /// Frames finished (denoised, skipped or failed); the current frame is the next one.
    finished: usize,
    /// The current frame's label (a frame number or a render set's name); `None` for one render set.
    label: Option<String>,
    /// Progress within the current frame, 0 to 1; `None` between frames.
    fraction: Option<f64>,
    stage: String,
    start: Instant,
    last_line: Option<Instant>,
}

impl State {
    fn run_fraction(&self) -> f64 {
        let frame = self.fraction.unwrap_or(0.0);
        ((self.finished as f64 + frame) / self.frames.max(1) as f64).clamp(0.0, 1.0)
    }

    /// The time left at the rate so far, once there is one.
    fn eta(&self) -> Option<Duration> {
        let done = self.run_fraction();
        let elapsed = self.start.elapsed().as_secs_f64();
        (done >= 0.01 && elapsed > 0.0)
            .then(|| Duration::from_secs_f64(elapsed * (1.0 - done) / done))
    }

    fn eta_text(&self) -> String {
        self.eta().map_or_else(|| "?".to_string(), clock)
    }

    /// The plain progress line (see the module's doc).
    fn line(&self) -> String {
        let frame = percent(self.fraction.unwrap_or(0.0));
        let (run, stage, eta) = (percent(self.run_fraction()), &self.stage, self.eta_text());
        match &self.label {
            Some(label) => format!(
                "gsid: frame {label}: {frame} % (frame {} of {}, run {run} %, stage {stage}, ETA {eta})",
                (self.finished + 1).min(self.frames),
                self.frames
            ),
            None => format!("gsid: {frame} % (run {run} %, stage {stage}, ETA {eta})"),
        }
    }

    /// The bar's message on a terminal.
    fn message(&self) -> String {
        let frame = match &self.label {
            Some(label) => format!(
                "frame {label} ({} of {}) · ",
                (self.finished + 1).min(self.frames),
                self.frames
            ),
            None => String::new(),
        };
        format!("{frame}{} · ETA {}", self.stage, self.eta_text())
    }
}

/// Whole percent, rounded down: 100 only once the work is done.
fn percent(fraction: f64) -> u32 {
    (fraction.clamp(0.0, 1.0) * 100.0).floor() as u32
}

/// `H:MM:SS`.
fn clock(d: Duration) -> String {
    let s = d.as_secs();
    format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
}

/// How progress is shown.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Shown {
    Nothing,
    Bar,
    Lines,
}

struct Inner {
    state: Mutex<State>,
    shown: Shown,
    bar: Option<ProgressBar>,
    /// Least time between two plain lines (zero: one at every step).
    every: Duration,
    verbosity: Verbosity,
}

impl Inner {
    fn state(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Moves the current frame to `fraction` (never back) at `stage`, and shows it.
    fn set(&self, fraction: f64, stage: &str) {
        let mut s = self.state();
        let before = s.fraction;
        let fraction = fraction.clamp(before.unwrap_or(0.0), 1.0);
        if before == Some(fraction) && s.stage == stage {
            return;
        }
        s.fraction = Some(fraction);
        s.stage = stage.to_string();
        if self.verbosity >= Verbosity::Debug {
            let elapsed = s.start.elapsed().as_secs_f64();
            self.print(&format!(
                "gsid: debug: {elapsed:.3} s: {} % of {}, stage {stage}",
                percent(fraction),
                s.label.as_deref().unwrap_or("the render set"),
            ));
        }
        self.show(&mut s, false);
    }

    /// Draws the bar, or prints a line when one is due (`force`: at a frame's end).
    fn show(&self, s: &mut State, force: bool) {
        match self.shown {
            Shown::Nothing => {}
            Shown::Bar => {
                if let Some(bar) = &self.bar {
                    bar.set_position((s.run_fraction() * 1000.0) as u64);
                    bar.set_message(s.message());
                }
            }
            Shown::Lines => {
                // The first line comes one interval into the run: a run that fails at once (bad
                // input) prints its one error line and nothing else.
                let since = s.last_line.unwrap_or(s.start).elapsed();
                let due = self.every.is_zero() || since >= self.every;
                if force || due {
                    self.print(&s.line());
                    s.last_line = Some(Instant::now());
                }
            }
        }
    }

    fn print(&self, line: &str) {
        match &self.bar {
            Some(bar) => bar.suspend(|| say(line)),
            None => say(line),
        }
    }
}

/// A run's progress and the lines it prints, shared by the frames of a batch.
pub struct Meter {
    inner: Arc<Inner>,
    /// Wakes every few seconds while a frame runs, so the bar's ETA moves and a farm gets its line
    /// even during a long stage; stopped by dropping the sender.
    ticker: Mutex<Option<(mpsc::Sender<()>, JoinHandle<()>)>>,
}

impl Meter {
    /// A meter over `frames` frames, printing lines at most every `every` seconds without a terminal.
    pub fn new(verbosity: Verbosity, frames: usize, every: f64) -> Self {
        let shown = match verbosity {
            Verbosity::Quiet => Shown::Nothing,
            _ if std::io::stderr().is_terminal() => Shown::Bar,
            _ => Shown::Lines,
        };
        let bar = (shown == Shown::Bar).then(|| {
            let bar = ProgressBar::new(1000);
            let style =
                ProgressStyle::with_template("{prefix} [{bar:24}] {percent:>3}% {wide_msg}")
                    .unwrap_or_else(|_| ProgressStyle::default_bar())
                    .progress_chars("=> ");
            bar.set_style(style);
            bar.set_prefix("gsid");
            bar
        });
        let every = Duration::from_secs_f64(every.max(0.0));
        let inner = Arc::new(Inner {
            state: Mutex::new(State {
                frames: frames.max(1),
                finished: 0,
                label: None,
                fraction: None,
                stage: "read".to_string(),
                start: Instant::now(),
                last_line: None,
            }),
            shown,
            bar,
            every,
            verbosity,
        });
        let tick = match shown {
            Shown::Bar => Some(BAR_TICK),
            Shown::Lines if !every.is_zero() => Some(every),
            _ => None,
        };
        let ticker = tick.map(|period| {
            let (stop, wait) = mpsc::channel::<()>();
            let inner = Arc::clone(&inner);
            let handle = std::thread::spawn(move || {
                while let Err(mpsc::RecvTimeoutError::Timeout) = wait.recv_timeout(period) {
                    let mut s = inner.state();
                    if s.fraction.is_some() {
                        inner.show(&mut s, false);
                    }
                }
            });
            (stop, handle)
        });
        Meter {
            inner,
            ticker: Mutex::new(ticker),
        }
    }

    pub fn verbosity(&self) -> Verbosity {
        self.inner.verbosity
    }

    /// Whether notes and summaries are printed (all but `-q`).
    pub fn talks(&self) -> bool {
        self.inner.verbosity >= Verbosity::Normal
    }

    /// Prints `line` on stderr above the bar, when the verbosity is at least `level`.
    pub fn say_at(&self, level: Verbosity, line: &str) {
        if self.inner.verbosity >= level && level > Verbosity::Quiet {
            self.inner.print(line);
        }
    }

    /// Prints an error line, whatever the verbosity.
    pub fn error(&self, line: &str) {
        self.inner.print(line);
    }

    /// Starts the next frame (`label`: its number or name; `None` for one render set), reading.
    pub fn start_frame(&self, label: Option<&str>) {
        {
            let mut s = self.inner.state();
            s.label = label.map(str::to_string);
            s.fraction = None;
        }
        self.inner.set(0.0, "read");
    }

    /// The callback the pipeline reports to: its fractions fill the frame between reading and writing.
    pub fn pipeline_progress(&self) -> Arc<ProgressFn> {
        let inner = Arc::clone(&self.inner);
        Arc::new(move |fraction: f32, stage: &str| {
            let f = READ_END + (WRITE_START - READ_END) * f64::from(fraction.clamp(0.0, 1.0));
            // The pipeline's last call (`done`) is where writing starts.
            let stage = if stage == "done" { "write" } else { stage };
            inner.set(f, stage);
        })
    }

    /// The current frame has reached its write.
    pub fn writing(&self) {
        self.inner.set(WRITE_START, "write");
    }

    /// Ends the current frame as `how` (`done`, `skipped`, `failed`): its line is printed whatever
    /// the time since the last one.
    pub fn end_frame(&self, how: &str) {
        let mut s = self.inner.state();
        if how != "failed" {
            s.fraction = Some(1.0);
        }
        s.stage = how.to_string();
        // The frame's line counts it as the current one; the run's share then moves on.
        let line = s.line();
        s.finished = (s.finished + 1).min(s.frames);
        s.fraction = None;
        match self.inner.shown {
            // A failed frame's line is its error, printed by the caller.
            Shown::Lines if how == "failed" => {}
            Shown::Lines => {
                self.inner.print(&line);
                s.last_line = Some(Instant::now());
            }
            Shown::Bar => self.inner.show(&mut s, true),
            Shown::Nothing => {}
        }
        if self.inner.verbosity >= Verbosity::Debug {
            let elapsed = s.start.elapsed().as_secs_f64();
            self.inner
                .print(&format!("gsid: debug: {elapsed:.3} s: frame {how}"));
        }
    }

    /// Stops the ticker and clears the bar.
    pub fn finish(&self) {
        let ticker = self.ticker.lock().unwrap_or_else(|e| e.into_inner()).take();
        if let Some((stop, handle)) = ticker {
            drop(stop);
            let _ = handle.join();
        }
        if let Some(bar) = &self.inner.bar {
            bar.finish_and_clear();
        }
    }
}

impl Drop for Meter {
    fn drop(&mut self) {
        self.finish();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(frames: usize, label: Option<&str>) -> State {
        State {
            frames,
            finished: 0,
            label: label.map(str::to_string),
            fraction: Some(0.0),
            stage: "read".into(),
            start: Instant::now(),
            last_line: None,
        }
    }

    #[test]
    fn a_line_names_the_frame_its_place_the_run_and_the_stage() {
        let mut s = state(8, Some("1003"));
        s.finished = 2;
        s.fraction = Some(0.4);
        s.stage = "gsid".into();
        let line = s.line();
        assert!(
            line.starts_with("gsid: frame 1003: 40 % (frame 3 of 8, run 30 %, stage gsid, ETA "),
            "{line}"
        );
        let one = state(1, None).line();
        assert_eq!(one, "gsid: 0 % (run 0 %, stage read, ETA ?)");
    }

    #[test]
    fn percents_round_down_and_clocks_pad() {
        assert_eq!(percent(0.999), 99);
        assert_eq!(percent(1.0), 100);
        assert_eq!(percent(-1.0), 0);
        assert_eq!(clock(Duration::from_secs(3725)), "1:02:05");
        assert_eq!(clock(Duration::from_secs(9)), "0:00:09");
    }

    #[test]
    fn verbosity_levels_grow_with_v_and_q_wins() {
        assert_eq!(Verbosity::of(true, 2), Verbosity::Quiet);
        assert_eq!(Verbosity::of(false, 0), Verbosity::Normal);
        assert_eq!(Verbosity::of(false, 1), Verbosity::Verbose);
        assert_eq!(Verbosity::of(false, 5), Verbosity::Debug);
    }
}
