//! How a run goes, apart from its inputs and its pipeline: the seed, the threads, progress and
//! cancellation. One struct for the library call and the command line, so neither grows
//! positional flags.

use std::fmt;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use crate::error::{Error, Result};

/// Most worker threads accepted: far beyond any machine gsid runs on, so a larger count is a typo.
pub const MAX_THREADS: usize = 1024;

/// Told how far a run is: the fraction done (0 to 1, never decreasing) and the id of the
/// pipeline stage running (`done` at the end, with 1). Called as each stage begins and, within the
/// heavy stages, every few thousandths as rows finish; calls never overlap, but they may come from
/// any of the run's threads, so keep it short (store the numbers, wake a UI).
pub type ProgressFn = dyn Fn(f32, &str) + Send + Sync;

/// Stops a run from another thread (a user pressing Esc): the run checks it before and after
/// every stage, at every pyramid level and between the rows of its heavy kernels (walks,
/// prefilter, noise estimate, regression), and ends with [`Error::Cancelled`], returning no image
/// and writing no output.
#[derive(Clone, Debug, Default)]
pub struct CancelToken(Arc<AtomicBool>);

impl CancelToken {
    pub fn new() -> Self {
        Self::default()
    }

    /// Asks every run holding this token (or a clone of it) to stop.
    pub fn cancel(&self) {
        self.0.store(true, Ordering::Relaxed);
    }

    pub fn is_cancelled(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }
}

/// Everything about a run but its inputs and its pipeline. `Default` is seed 0, all cores, no
/// progress and no way to cancel.
#[derive(Clone, Default)]
pub struct DenoiseOptions {
    /// Seed of every random choice: the same inputs, pipeline and seed give the same bits on any
    /// number of threads.
    pub seed: u64,
    /// Worker threads, 1 to [`MAX_THREADS`]; `None` runs on the caller's rayon pool (all cores
    /// unless the caller set up another).
    pub threads: Option<usize>,
    /// Draw progress bars on stderr when it is a terminal (the command line's choice).
    pub progress_bar: bool,
    /// Called as the run goes (see [`ProgressFn`]).
    pub progress: Option<Arc<ProgressFn>>,
    /// Checked between stages and rows (see [`CancelToken`]).
    pub cancel: Option<CancelToken>,
    /// Bytes the run may take at most: a run whose estimate
    /// ([`crate::Pipeline::peak_bytes`]) is larger is refused before any stage runs. `None`: no
    /// limit (the command line sets [`default_max_memory`]).
    pub max_memory: Option<u64>,
}

impl DenoiseOptions {
    /// The defaults with this seed.
    pub fn seeded(seed: u64) -> Self {
        DenoiseOptions {
            seed,
            ..Self::default()
        }
    }

    /// Runs `f` on a pool of `threads` workers, or on the caller's pool when none is asked for or
    /// it already has that many.
    pub(crate) fn install<T: Send>(&self, f: impl FnOnce() -> T + Send) -> Result<T> {
        match self.threads {
            Some(n) if n != rayon::current_num_threads() => Ok(thread_pool(n)?.install(f)),
            _ => Ok(f()),
        }
    }
}

impl fmt::Debug for DenoiseOptions {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("DenoiseOptions")
            .field("seed", &self.seed)
            .field("threads", &self.threads)
            .field("progress_bar", &self.progress_bar)
            .field("progress", &self.progress.as_ref().map(|_| "callback"))
            .field("cancel", &self.cancel)
            .field("max_memory", &self.max_memory)
            .finish()
    }
}

/// The limit `--max-memory MIB` sets, in bytes: `mib` MiB, else [`default_max_memory`].
pub fn memory_limit(mib: Option<u64>) -> u64 {
    mib.map_or_else(default_max_memory, |mib| mib.saturating_mul(1 << 20))
}

/// Refuses work whose estimate `need` is above `limit` bytes, in one line: `what` says what needs
/// how much, given the estimate in MiB ("a 64x64 image needs about 40 MiB …").
pub fn check_memory(need: u64, limit: u64, what: impl FnOnce(u64) -> String) -> Result<()> {
    const MIB: u64 = 1 << 20;
    if need > limit {
        return Err(Error::config(
            "--max-memory",
            format!(
                "{}, more than the {} MiB allowed (default: three quarters of this machine's memory)",
                what(need / MIB),
                limit / MIB
            ),
        ));
    }
    Ok(())
}

/// Three quarters of this machine's memory: what a run may take unless told otherwise (OIDN's
/// `maxMemoryMB` plays the same part), leaving room for the rest of the machine.
pub fn default_max_memory() -> u64 {
    // SAFETY: sysconf only reads system values.
    let (pages, size) = unsafe {
        (
            libc::sysconf(libc::_SC_PHYS_PAGES),
            libc::sysconf(libc::_SC_PAGESIZE),
        )
    };
    if pages <= 0 || size <= 0 {
        return u64::MAX;
    }
    (pages as u64).saturating_mul(size as u64) / 4 * 3
}

/// A pool of `n` worker threads, `n` checked to be 1 to [`MAX_THREADS`].
pub(crate) fn thread_pool(n: usize) -> Result<rayon::ThreadPool> {
    if !(1..=MAX_THREADS).contains(&n) {
        return Err(Error::range("--threads", n, &format!("1 to {MAX_THREADS}")));
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .map_err(|e| Error::Runtime(format!("cannot start {n} threads: {e}")))
}
