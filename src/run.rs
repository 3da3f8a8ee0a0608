//! The context every computing command runs in: its thread pool, whether progress is shown, and the
//! seed. `denoise`, `sweep`, `ablate` and `render` all make it the same way, so `--threads` means and
//! checks the same everywhere.

use crate::error::Result;
pub use crate::options::MAX_THREADS;
use crate::options::{thread_pool, DenoiseOptions};

/// A thread pool (rayon's global one unless a count was asked for), progress on or off, and a seed.
pub struct RunContext {
    pool: Option<rayon::ThreadPool>,
    /// Show progress bars and notes.
    pub progress: bool,
    /// Seed for every random choice of the run.
    pub seed: u64,
}

impl RunContext {
    /// Checks `threads` (1 to [`MAX_THREADS`]; `None`: all cores) and starts the pool.
    pub fn new(threads: Option<usize>, progress: bool, seed: u64) -> Result<Self> {
        let pool = threads.map(thread_pool).transpose()?;
        Ok(RunContext {
            pool,
            progress,
            seed,
        })
    }

    /// Runs `f` on the context's pool, so every parallel step inside it uses that many threads.
    pub fn install<T: Send>(&self, f: impl FnOnce() -> T + Send) -> T {
        match &self.pool {
            Some(pool) => pool.install(f),
            None => f(),
        }
    }

    /// The options of one pipeline run inside this context's pool, with or without progress bars.
    pub fn denoise_options(&self, progress_bar: bool) -> DenoiseOptions {
        DenoiseOptions {
            seed: self.seed,
            progress_bar,
            ..DenoiseOptions::default()
        }
    }

    /// Worker threads of the pool.
    pub fn threads(&self) -> usize {
        self.pool
            .as_ref()
            .map_or_else(rayon::current_num_threads, |p| p.current_num_threads())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thread_counts_outside_1_to_1024_are_refused_naming_the_flag() {
        for bad in [0, MAX_THREADS + 1] {
            let err = RunContext::new(Some(bad), false, 0).err().unwrap();
            assert_eq!(err.exit_code(), 2);
            assert!(err.to_string().starts_with("--threads: is "), "{err}");
        }
        let ctx = RunContext::new(Some(2), false, 7).unwrap();
        assert_eq!(ctx.install(rayon::current_num_threads), 2);
        assert_eq!(ctx.threads(), 2);
        assert!(RunContext::new(None, true, 0).is_ok());
    }
}
