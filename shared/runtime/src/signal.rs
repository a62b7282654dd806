//! Ctrl-C / SIGTERM handling: a process-wide flag every loop polls.
//!
//! Invariant: the handler only stores to an atomic (async-signal-safe); all
//! clean-up (final checkpoint, closing files) happens in the loops that see it.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    STOP.store(true, Ordering::SeqCst);
}

/// A handle on the process's stop flag.
#[derive(Clone, Debug, Default)]
pub struct StopFlag {
    _private: Arc<()>,
}

impl StopFlag {
    /// Install SIGINT and SIGTERM handlers that set the flag.
    pub fn install() -> StopFlag {
        // SAFETY: `on_signal` only stores to an atomic, which is async-signal-safe.
        unsafe {
            libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
            libc::signal(libc::SIGTERM, on_signal as *const () as libc::sighandler_t);
        }
        StopFlag::default()
    }

    /// Was a stop requested?
    pub fn is_set(&self) -> bool {
        STOP.load(Ordering::SeqCst)
    }

    /// Request a stop from inside the process (a fatal error in one thread, say).
    pub fn set(&self) {
        STOP.store(true, Ordering::SeqCst);
    }
}
