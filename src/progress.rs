//! Progress reporting: an indicatif bar on stderr when it is a terminal, nothing otherwise (and
//! nothing at all without the `cli` feature, so a library build does not pull in indicatif).

use std::io::IsTerminal;

#[cfg(feature = "cli")]
use indicatif::ProgressBar as Bar;

/// A progress bar that may be switched off; cheap to tick from many threads.
#[derive(Clone)]
pub struct Progress {
    bar: Option<Bar>,
}

impl Progress {
    /// A bar of `len` units labelled `label`, shown only if `enabled` and stderr is a terminal.
    pub fn new(enabled: bool, label: &str, len: u64) -> Self {
        if !enabled || !std::io::stderr().is_terminal() {
            return Self::hidden();
        }
        Progress {
            bar: styled_bar(label, len),
        }
    }

    pub fn hidden() -> Self {
        Progress { bar: None }
    }

    #[inline]
    pub fn inc(&self, n: u64) {
        if let Some(b) = &self.bar {
            b.inc(n);
        }
    }

    /// Prints a line on stderr above the bar, so the bar is not torn by it.
    pub fn println(&self, line: &str) {
        match &self.bar {
            Some(b) => b.suspend(|| say(line)),
            None => say(line),
        }
    }

    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

/// Writes `line` to stderr. A full or closed stderr (`2>/dev/full`, a reader that went away) loses
/// the line but never stops the run: `eprintln!` would panic there.
pub fn say(line: &str) {
    use std::io::Write;
    let mut err = std::io::stderr().lock();
    let _ = writeln!(err, "{line}");
}

/// [`say`] with `format!` arguments.
#[cfg(feature = "cli")]
macro_rules! say_err {
    ($($arg:tt)*) => {
        $crate::progress::say(&format!($($arg)*))
    };
}
#[cfg(feature = "cli")]
pub(crate) use say_err;

/// The styled bar.
#[cfg(feature = "cli")]
fn styled_bar(label: &str, len: u64) -> Option<Bar> {
    use indicatif::ProgressStyle;
    let bar = Bar::new(len);
    let style =
        ProgressStyle::with_template("{prefix:>12} [{bar:30}] {pos}/{len} {elapsed_precise}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> ");
    bar.set_style(style);
    bar.set_prefix(label.to_string());
    Some(bar)
}

#[cfg(not(feature = "cli"))]
fn styled_bar(_: &str, _: u64) -> Option<Bar> {
    None
}

/// Without the `cli` feature there is no bar: a type with no values stands in for indicatif's.
#[cfg(not(feature = "cli"))]
#[derive(Clone)]
enum Bar {}

#[cfg(not(feature = "cli"))]
impl Bar {
    fn inc(&self, _: u64) {
        match *self {}
    }
    fn suspend(&self, _: impl FnOnce()) {
        match *self {}
    }
    fn finish_and_clear(&self) {
        match *self {}
    }
}
