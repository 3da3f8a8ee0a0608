//! One error type for the library; the CLI maps it to an exit code and one line of text.

use std::path::{Path, PathBuf};

/// Everything that can go wrong, split by who can fix it: bad input (exit 2) or a runtime failure (exit 1).
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file that cannot be read, decoded, or does not fit the render set.
    #[error("{}: {msg}", path.display())]
    File { path: PathBuf, msg: String },
    /// A buffer a stage needs is missing or has the wrong shape.
    #[error("buffer `{name}`: {msg}")]
    Buffer { name: String, msg: String },
    /// A pipeline file, a stage parameter, or a `--set` override is wrong; `key` names it.
    #[error("{key}: {msg}")]
    Config { key: String, msg: String },
    /// The output cannot be written where the user asked.
    #[error("cannot write {}: {msg}", path.display())]
    Output { path: PathBuf, msg: String },
    /// Writing an output failed part way (disk full, an I/O error): a runtime failure.
    #[error("cannot write {}: {msg}", path.display())]
    Write { path: PathBuf, msg: String },
    /// Standard output was closed by its reader: the run ends quietly, exit 0.
    #[error("standard output closed")]
    StdoutClosed,
    /// One frame of a sequence or batch failed; `frame` is its number or render set's name.
    #[error("frame {frame}: {source}")]
    Frame { frame: String, source: Box<Error> },
    /// Frames of a `--keep-going` run failed (each was reported as it failed).
    #[error("{} of {total} frames failed: {}", failed.len(), failed.join(", "))]
    Frames {
        failed: Vec<String>,
        total: usize,
        /// 1 if any frame failed at run time (a retry may succeed), else 2 (bad input).
        code: i32,
    },
    /// Any other bad usage (e.g. mismatched image sizes given to `eval`).
    #[error("{0}")]
    Usage(String),
    /// The run was stopped through its [`crate::CancelToken`]; no image was produced.
    #[error("cancelled")]
    Cancelled,
    /// Something failed that is not the user's input (I/O error mid-run, ...).
    #[error("{0}")]
    Runtime(String),
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    pub fn file(path: impl AsRef<Path>, msg: impl std::fmt::Display) -> Self {
        Error::File {
            path: path.as_ref().to_path_buf(),
            msg: msg.to_string(),
        }
    }

    pub fn buffer(name: impl Into<String>, msg: impl std::fmt::Display) -> Self {
        Error::Buffer {
            name: name.into(),
            msg: msg.to_string(),
        }
    }

    pub fn config(key: impl Into<String>, msg: impl std::fmt::Display) -> Self {
        Error::Config {
            key: key.into(),
            msg: msg.to_string(),
        }
    }

    pub fn output(path: impl AsRef<Path>, msg: impl std::fmt::Display) -> Self {
        Error::Output {
            path: path.as_ref().to_path_buf(),
            msg: msg.to_string(),
        }
    }

    pub fn write(path: impl AsRef<Path>, msg: impl std::fmt::Display) -> Self {
        Error::Write {
            path: path.as_ref().to_path_buf(),
            msg: msg.to_string(),
        }
    }

    /// A value outside its allowed range: `KEY: is VALUE, allowed range is RANGE`.
    pub fn range(key: &str, value: impl std::fmt::Display, range: &str) -> Self {
        Error::config(key, format!("is {value}, allowed range is {range}"))
    }

    /// Process exit code, as docs/FORMATS.md fixes it: 2 for bad usage or input, 1 for runtime failures.
    pub fn exit_code(&self) -> i32 {
        match self {
            Error::StdoutClosed => 0,
            Error::Runtime(_) | Error::Write { .. } | Error::Cancelled => 1,
            Error::Frame { source, .. } => source.exit_code(),
            Error::Frames { code, .. } => *code,
            _ => 2,
        }
    }

    /// Prefix a config error's key with its context (e.g. the stage id), keeping other errors as they are.
    pub fn in_context(self, prefix: &str) -> Self {
        self.map_key(|key| format!("{prefix}.{key}"))
    }

    /// Prefix a config error's key with the file it came from (`x.toml: KEY`).
    pub fn in_file(self, origin: &str) -> Self {
        self.map_key(|key| format!("{origin}: {key}"))
    }

    fn map_key(self, f: impl FnOnce(&str) -> String) -> Self {
        match self {
            Error::Config { key, msg } => Error::Config { key: f(&key), msg },
            other => other,
        }
    }
}
