//! Ctrl-C on the command line: the invocation's cancel token, which the first SIGINT or SIGTERM
//! sets so a denoise run ends through the library's cancel, and the fallback that removes pending
//! outputs and exits when no run holds the token or it does not end in time.

use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};
use std::time::Duration;

use crate::error::Error;
use crate::io;
use crate::options::CancelToken;

/// The invocation's cancel: every frame `gsid denoise` runs (a batch, a `--temporal` shot) holds
/// it, and the first SIGINT or SIGTERM sets it.
static CANCEL: std::sync::OnceLock<CancelToken> = std::sync::OnceLock::new();
/// Whether a run holding [`CANCEL`] has started: until then a signal ends the process at once.
static CANCELLABLE: AtomicBool = AtomicBool::new(false);
/// The signal that asked the run to stop (0: none).
static SIGNALLED: AtomicI32 = AtomicI32::new(0);
/// How long a cancelled run may take to end before the signal handler ends the process itself.
const CANCEL_GRACE: Duration = Duration::from_secs(2);

/// The token a run of this invocation stops on: from now on a signal cancels the run rather than
/// ending the process, so the run ends through its own error path (outputs dropped, one line).
pub(crate) fn cancel_token() -> CancelToken {
    let token = CANCEL.get_or_init(CancelToken::new).clone();
    CANCELLABLE.store(true, Ordering::SeqCst);
    token
}

/// On SIGINT or SIGTERM during a denoise run: cancels the run ([`cancel_token`]), which ends with
/// `Error::Cancelled`, its pending outputs dropped, and exits 128 + the signal's number (130, 143),
/// as a shell reports a process it stopped. Before such a run, in the commands that hold no token
/// (`render`, `ablate`, `sweep`), on a second signal, or when the cancelled run has not ended within
/// [`CANCEL_GRACE`]: removes the temporary files and folders of outputs not yet committed and exits
/// at once with that code.
pub(super) fn remove_outputs_on_signal() {
    use signal_hook::consts::{SIGINT, SIGTERM};
    // Without the handler (it cannot be installed) a signal still ends the run, leaving its temp files.
    let Ok(mut signals) = signal_hook::iterator::Signals::new([SIGINT, SIGTERM]) else {
        return;
    };
    std::thread::spawn(move || {
        let Some(signal) = signals.forever().next() else {
            return;
        };
        SIGNALLED.store(signal, Ordering::SeqCst);
        if CANCELLABLE.load(Ordering::SeqCst) {
            CANCEL.get_or_init(CancelToken::new).cancel();
            let waited = std::time::Instant::now();
            while waited.elapsed() < CANCEL_GRACE {
                if signals.pending().next().is_some() {
                    break;
                }
                std::thread::sleep(Duration::from_millis(20));
            }
        }
        io::remove_pending_outputs();
        std::process::exit(128 + signal);
    });
}

/// The exit code of a run ended by a cancel: 128 + the signal's number, as a shell reports a
/// process it stopped (the command line's runs are cancelled only by a signal).
pub(super) fn cancelled_exit_code() -> i32 {
    match SIGNALLED.load(Ordering::SeqCst) {
        0 => Error::Cancelled.exit_code(),
        signal => 128 + signal,
    }
}
