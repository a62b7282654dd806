//! The process's own log lines, and what happens when they cannot be written.
//!
//! A process logs to stderr, which the launcher points at `logs/<process>.log`. On a
//! full disk that file refuses the lines, and `tracing`'s writer would drop them
//! without a trace — the very warnings that say the disk is full among them.
//! [`LoggedWriter`] is the writer `tracing` uses instead: a line the log refuses is
//! counted, the failure shows in the process's heartbeat ([`LogHealth::faults`], the
//! launcher's progress line says `log lines lost: disk full`), and the first line
//! the log takes again is preceded by one that says how many were lost.
//!
//! Invariant: the log is failing from its first refused line to its next accepted
//! one; a refused line is never half-counted (each refused write adds one to the
//! count of lost lines, whatever part of it the file took).

use std::io::{self, Write};
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};

use crate::messages::Faults;

const OK: u32 = 0;
const FAILING: u32 = 1;
const FAILING_DISK_FULL: u32 = 2;

/// Whether a log is being written, and how many lines it has refused since it last
/// took one.
#[derive(Debug, Default)]
pub struct LogHealth {
    state: AtomicU32,
    lost: AtomicU64,
}

impl LogHealth {
    /// A log that has refused nothing.
    pub const fn new() -> LogHealth {
        LogHealth { state: AtomicU32::new(OK), lost: AtomicU64::new(0) }
    }

    /// Write one formatted line (`tracing` hands over a whole event at a time) to `out`.
    /// A refusal is counted and remembered, never returned: the caller has nowhere
    /// else to say it.
    pub fn write_line(&self, out: &mut impl Write, line: &[u8]) {
        if self.state.load(Ordering::Relaxed) != OK {
            let lost = self.lost.load(Ordering::Relaxed);
            let notice = format!("WARN {lost} log line(s) were lost while this log could not be written\n");
            if out.write_all(notice.as_bytes()).is_err() {
                self.lost.fetch_add(1, Ordering::Relaxed);
                return;
            }
            self.lost.fetch_sub(lost, Ordering::Relaxed);
            self.state.store(OK, Ordering::Relaxed);
        }
        if let Err(e) = out.write_all(line).and_then(|()| out.flush()) {
            self.lost.fetch_add(1, Ordering::Relaxed);
            let state = if crate::generations::is_disk_full(&e) { FAILING_DISK_FULL } else { FAILING };
            self.state.store(state, Ordering::Relaxed);
        }
    }

    /// The heartbeat's bits for this log: [`Faults::LOG`] (and [`Faults::DISK_FULL`])
    /// while it refuses lines.
    pub fn faults(&self) -> Faults {
        match self.state.load(Ordering::Relaxed) {
            OK => Faults::NONE,
            FAILING => Faults::LOG,
            _ => Faults::LOG.with(Faults::DISK_FULL),
        }
    }

    /// Lines refused since the log last took one.
    pub fn lost(&self) -> u64 {
        self.lost.load(Ordering::Relaxed)
    }
}

/// The health of this process's stderr log.
pub static STDERR_LOG: LogHealth = LogHealth::new();

/// The writer [`crate::init_logging`] gives `tracing`: stderr through [`STDERR_LOG`].
#[derive(Debug, Clone, Copy, Default)]
pub struct LoggedWriter;

impl Write for LoggedWriter {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        STDERR_LOG.write_line(&mut io::stderr().lock(), buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A file that refuses every write while `full` is set, as a full disk does.
    struct Disk {
        full: bool,
        written: Vec<u8>,
    }

    impl Write for Disk {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            if self.full {
                return Err(io::Error::from_raw_os_error(libc::ENOSPC));
            }
            self.written.extend_from_slice(buf);
            Ok(buf.len())
        }

        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn refused_lines_are_counted_shown_as_a_fault_and_reported_when_the_log_takes_lines_again() {
        let health = LogHealth::new();
        let mut disk = Disk { full: false, written: Vec::new() };
        health.write_line(&mut disk, b"first\n");
        assert_eq!(health.faults(), Faults::NONE);

        disk.full = true;
        for line in [&b"second\n"[..], b"third\n", b"fourth\n"] {
            health.write_line(&mut disk, line);
        }
        assert_eq!(health.lost(), 3);
        assert!(health.faults().contains(Faults::LOG) && health.faults().contains(Faults::DISK_FULL));
        assert_eq!(
            health.faults().describe(0, "update").as_deref(),
            Some("log lines lost: disk full"),
            "the progress line says so"
        );

        disk.full = false;
        health.write_line(&mut disk, b"fifth\n");
        assert_eq!(
            String::from_utf8(disk.written).unwrap(),
            "first\nWARN 3 log line(s) were lost while this log could not be written\nfifth\n"
        );
        assert_eq!((health.lost(), health.faults()), (0, Faults::NONE));
    }

    #[test]
    fn a_log_that_is_not_full_but_refuses_is_a_fault_without_the_disk_full_bit() {
        struct ReadOnly;
        impl Write for ReadOnly {
            fn write(&mut self, _: &[u8]) -> io::Result<usize> {
                Err(io::Error::from_raw_os_error(libc::EROFS))
            }
            fn flush(&mut self) -> io::Result<()> {
                Ok(())
            }
        }
        let health = LogHealth::new();
        health.write_line(&mut ReadOnly, b"line\n");
        assert_eq!(health.faults(), Faults::LOG);
        assert_eq!(health.faults().describe(0, "").as_deref(), Some("log lines lost: cannot write"));
    }
}
