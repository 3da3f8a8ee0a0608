//! Printing on standard output that never panics: a reader that went away ends the run quietly,
//! any other failure is an error.

use crate::error::{Error, Result};

/// `print!` that returns an error instead of panicking (see [`write_stdout`]).
macro_rules! say {
    ($($arg:tt)*) => {
        $crate::cli::stdout::write_stdout(format_args!($($arg)*))
    };
}
pub(crate) use say;

/// Prints `value` as one line of JSON on standard output.
pub(crate) fn print_json(value: &impl serde::Serialize) -> Result<()> {
    let text = serde_json::to_string(value)
        .map_err(|e| Error::Runtime(format!("cannot write JSON: {e}")))?;
    say!("{text}\n")
}

/// Writes to standard output. A reader that went away (`gsid pipelines | head -1`) ends the run
/// quietly, as `ls | head` does; any other failure (a full disk) is an error, exit 1.
pub(crate) fn write_stdout(text: std::fmt::Arguments) -> Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    out.write_fmt(text)
        .and_then(|()| out.flush())
        .map_err(|e| match e.kind() {
            std::io::ErrorKind::BrokenPipe => Error::StdoutClosed,
            _ => Error::write("standard output", e),
        })
}
