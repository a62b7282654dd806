//! What a process could not write, and when it last said so.
//!
//! A process whose checkpoint, saved state, metrics or stats cannot be written (a
//! full disk, a folder made read-only) keeps its work in memory and goes on; the
//! owner of each write retries it at its next interval. [`WriteHealth`] is the one
//! place that records such failures: it logs a failure when it starts and then at
//! most once per interval (not at every attempt), logs the recovery, and gives the
//! heartbeat the [`Faults`] that the launcher's progress line shows.
//!
//! Invariant: a kind of write is failing from its first failed attempt to its next
//! successful one, and [`WriteHealth::faults`] is exactly the union of the failing
//! kinds' faults and the process log's ([`crate::log_health`]).

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use crate::messages::Faults;
use crate::metrics::{Metrics, MetricsFailure};

struct Failing {
    fault: Faults,
    warned: Instant,
}

/// The failing writes of one process.
pub struct WriteHealth {
    every: Duration,
    failing: BTreeMap<&'static str, Failing>,
    warnings: u64,
}

impl WriteHealth {
    /// Failures are logged when they start and then at most once per `warn_every`.
    pub fn new(warn_every: Duration) -> WriteHealth {
        WriteHealth { every: warn_every, failing: BTreeMap::new(), warnings: 0 }
    }

    /// A write of `what` (e.g. `"checkpoint"`) failed with `message` (naming the file
    /// and the error); `fault` is its heartbeat bit, `disk_full` whether the disk (or
    /// quota) is full, `meanwhile` what the process does about it (logged with it).
    pub fn failed(&mut self, what: &'static str, fault: Faults, disk_full: bool, message: &str, meanwhile: &str) {
        let fault = if disk_full { fault.with(Faults::DISK_FULL) } else { fault };
        let now = Instant::now();
        let due = self.failing.get(what).is_none_or(|f| f.warned.elapsed() >= self.every);
        if due {
            self.warnings += 1;
            tracing::warn!("{what} FAILED{}: {message}; {meanwhile}", if disk_full { " (disk full)" } else { "" });
        }
        let warned = if due { now } else { self.failing[what].warned };
        self.failing.insert(what, Failing { fault, warned });
    }

    /// A write of `what` succeeded: if it was failing, say that it recovered.
    pub fn succeeded(&mut self, what: &'static str) {
        if self.failing.remove(what).is_some() {
            tracing::info!("{what} written again: the fault has cleared");
        }
    }

    /// Record how `metrics`' last write went (its rows wait in memory while failing).
    pub fn metrics(&mut self, metrics: &Metrics) {
        self.rows("metrics", metrics.failing());
    }

    /// Record how the last write of a log of rows (`what`, e.g. `"episode log"`) went.
    pub fn rows(&mut self, what: &'static str, failing: Option<MetricsFailure<'_>>) {
        match failing {
            Some(f) => self.failed(
                what,
                Faults::METRICS,
                crate::generations::is_disk_full(f.error),
                &format!("{}: {}", f.path.display(), f.error),
                &match f.dropped {
                    0 => format!("{} rows wait in memory and are written once the disk takes them", f.waiting),
                    d => format!("{} rows wait in memory (the most kept; {d} newer rows were dropped)", f.waiting),
                },
            ),
            None => self.succeeded(what),
        }
    }

    /// The faults of every failing write, and of the process's log
    /// ([`crate::log_health::STDERR_LOG`]).
    pub fn faults(&self) -> Faults {
        self.failing.values().fold(crate::log_health::STDERR_LOG.faults(), |acc, f| acc.with(f.fault))
    }

    /// Failure warnings logged so far (what the once-per-interval throttle let through).
    pub fn warnings_logged(&self) -> u64 {
        self.warnings
    }

    /// Whether `what` is failing.
    pub fn is_failing(&self, what: &str) -> bool {
        self.failing.contains_key(what)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn faults_are_the_union_of_what_is_failing_until_it_succeeds() {
        let mut h = WriteHealth::new(Duration::from_secs(60));
        assert_eq!(h.faults(), Faults::NONE);
        h.failed("checkpoint", Faults::CHECKPOINT, true, "x: No space left on device", "training goes on");
        h.failed("stats", Faults::METRICS, false, "y: Read-only file system", "kept in memory");
        let f = h.faults();
        assert!(f.contains(Faults::CHECKPOINT) && f.contains(Faults::METRICS) && f.contains(Faults::DISK_FULL));
        h.succeeded("checkpoint");
        assert_eq!(h.faults(), Faults::METRICS);
        assert!(!h.is_failing("checkpoint") && h.is_failing("stats"));
        assert_eq!(
            Faults::CHECKPOINT.with(Faults::DISK_FULL).describe(1200, "update").as_deref(),
            Some("checkpoint FAILED: disk full, last good at update 1200")
        );
        assert_eq!(
            Faults::STATE.describe(0, "episode").as_deref(),
            Some("curriculum state FAILED: cannot write, last saved none yet")
        );
        assert_eq!(Faults::DISK_FULL.describe(5, "update"), None);
        assert_eq!(Faults::NONE.describe(5, "update"), None);
    }

    #[test]
    fn a_failing_write_is_logged_when_it_starts_and_then_once_per_interval() {
        let mut h = WriteHealth::new(Duration::from_secs(3600));
        for _ in 0..5 {
            h.failed("metrics", Faults::METRICS, false, "m: Read-only file system", "kept");
        }
        assert_eq!(h.warnings_logged(), 1, "five failures in a row within the interval: one warning");
        h.failed("stats", Faults::METRICS, false, "s: Read-only file system", "kept");
        assert_eq!(h.warnings_logged(), 2, "another kind of write is throttled on its own");
        h.succeeded("metrics");
        h.failed("metrics", Faults::METRICS, false, "m: Read-only file system", "kept");
        assert_eq!(h.warnings_logged(), 3, "a failure after a recovery starts a new run of failures");
        let mut every_time = WriteHealth::new(Duration::ZERO);
        for _ in 0..3 {
            every_time.failed("stats", Faults::METRICS, false, "s", "kept");
        }
        assert_eq!(every_time.warnings_logged(), 3);
    }
}
