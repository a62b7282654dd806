//! One supervised child process: how it is started (its own process group, SIGTERM
//! when the launcher dies, its output appended to its log), signalled, reaped, and how
//! its deaths count against the restart budget and back off.
//!
//! Invariant: a child's death is read from the part of its log its last run wrote, so
//! a cause is never an earlier run's.

use std::collections::VecDeque;
use std::fs::OpenOptions;
use std::os::unix::process::CommandExt;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use pednav_runtime::messages::ProcessKind;

use crate::exit_cause::ExitCause;

use pednav_runtime::{MAX_RESTARTS, RESTART_WINDOW};

/// One supervised child.
pub(crate) struct Proc {
    pub(crate) name: String,
    pub(crate) args: Vec<String>,
    pub(crate) binary: PathBuf,
    pub(crate) log: PathBuf,
    pub(crate) child: Option<Child>,
    pub(crate) restarts: VecDeque<Instant>,
    pub(crate) total_restarts: u32,
    /// Its heartbeats' (kind, id).
    pub(crate) heartbeat: (ProcessKind, u32),
    /// Whether silence means a hang (the learner and the curriculum service; an actor
    /// legitimately stays silent while it waits for a restarting learner).
    pub(crate) watch_hang: bool,
    /// The headline of its last death's cause, and how many deaths in a row had it.
    pub(crate) last_cause: Option<(String, u32)>,
    /// When a process that died of the same cause again is started (back-off).
    pub(crate) restart_at: Option<Instant>,
    /// Where its log ended when it was last started: its death's cause is read from
    /// there on (the log holds every run of the process).
    pub(crate) log_start: u64,
    /// When it was last started.
    pub(crate) started: Option<Instant>,
}

impl Proc {
    /// Count a death against the restart budget; an error naming the cause (from the
    /// log) when the budget is spent.
    pub(crate) fn count_restart(&mut self, status: &str, cause: &ExitCause) -> Result<()> {
        self.restarts.push_back(Instant::now());
        while self.restarts.front().is_some_and(|t| t.elapsed() > RESTART_WINDOW) {
            self.restarts.pop_front();
        }
        if self.restarts.len() > MAX_RESTARTS {
            bail!(
                "{} died {} times within {} s ({status}): {}\nfrom its log ({}):\n{}",
                self.name,
                MAX_RESTARTS + 1,
                RESTART_WINDOW.as_secs(),
                cause.headline(),
                self.log.display(),
                cause.report()
            );
        }
        self.total_restarts += 1;
        Ok(())
    }

    /// How long to wait before restarting it after a death with `headline`: nothing the
    /// first time, then 2, 4, 8 … up to [`MAX_BACKOFF`] seconds while the same error
    /// repeats (a fault that a restart alone does not fix); returns the delay and the
    /// number of deaths in a row with that error.
    pub(crate) fn backoff(&mut self, headline: &str) -> (Duration, u32) {
        // A run that lasted longer than the restart window was healthy: start counting afresh.
        if self.started.is_some_and(|t| t.elapsed() > RESTART_WINDOW) {
            self.last_cause = None;
        }
        let repeats = match &self.last_cause {
            Some((h, n)) if h == headline => n + 1,
            _ => 1,
        };
        self.last_cause = Some((headline.to_string(), repeats));
        let delay = if repeats < 2 {
            Duration::ZERO
        } else {
            (Duration::from_secs(1) * 2u32.pow((repeats - 1).min(6))).min(MAX_BACKOFF)
        };
        (delay, repeats)
    }

    pub(crate) fn start(&mut self) -> Result<()> {
        self.log_start = std::fs::metadata(&self.log).map_or(0, |m| m.len());
        self.started = Some(Instant::now());
        let log = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&self.log)
            .with_context(|| format!("opening {}", self.log.display()))?;
        let mut cmd = Command::new(&self.binary);
        cmd.args(&self.args).stdin(Stdio::null()).stdout(log.try_clone()?).stderr(log).process_group(0);
        // SAFETY: only async-signal-safe calls between fork and exec.
        unsafe {
            cmd.pre_exec(|| {
                libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM);
                Ok(())
            });
        }
        let child = cmd.spawn().with_context(|| format!("starting {} ({})", self.name, self.binary.display()))?;
        tracing::info!(process = %self.name, pid = child.id(), "started");
        self.child = Some(child);
        Ok(())
    }

    pub(crate) fn signal(&self, sig: libc::c_int) {
        if let Some(c) = &self.child {
            // SAFETY: kill(2) on our own child's pid.
            unsafe { libc::kill(c.id() as libc::pid_t, sig) };
        }
    }

    /// SIGKILL it and reap it.
    pub(crate) fn kill(&mut self) {
        self.signal(libc::SIGKILL);
        if let Some(c) = self.child.as_mut() {
            let _ = c.wait();
        }
        self.child = None;
    }

    /// Exit status if it has exited (and forget the child).
    pub(crate) fn exited(&mut self) -> Option<std::process::ExitStatus> {
        let status = self.child.as_mut().and_then(|c| c.try_wait().ok().flatten());
        if status.is_some() {
            self.child = None;
        }
        status
    }

    pub(crate) fn running(&self) -> bool {
        self.child.is_some()
    }

    /// Why the process ended, from what its last run wrote to its log ([`ExitCause`]).
    pub(crate) fn exit_cause(&self) -> ExitCause {
        use std::io::{Read, Seek, SeekFrom};
        let mut text = String::new();
        if let Ok(mut f) = std::fs::File::open(&self.log) {
            let _ = f.seek(SeekFrom::Start(self.log_start)).and_then(|_| f.read_to_string(&mut text));
        }
        ExitCause::parse(&text)
    }
}

/// The longest wait before restarting a process that keeps dying of the same error.
pub(crate) const MAX_BACKOFF: Duration = Duration::from_secs(60);

/// Stop processes with SIGTERM, SIGKILL after `grace`.
pub(crate) fn stop_all(procs: &mut [&mut Proc], grace: Duration) {
    for p in procs.iter() {
        p.signal(libc::SIGTERM);
    }
    let start = Instant::now();
    while procs.iter().any(|p| p.running()) {
        for p in procs.iter_mut() {
            if let Some(s) = p.exited() {
                tracing::info!(process = %p.name, status = %s, "stopped");
            }
        }
        if start.elapsed() > grace {
            for p in procs.iter_mut().filter(|p| p.running()) {
                tracing::warn!(process = %p.name, "did not stop within {grace:?}; killing it");
                p.kill();
            }
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn proc_named(name: &str) -> Proc {
        Proc {
            name: name.into(),
            args: Vec::new(),
            binary: PathBuf::from("/nonexistent"),
            log: PathBuf::from("/nonexistent.log"),
            child: None,
            restarts: VecDeque::new(),
            total_restarts: 0,
            heartbeat: (ProcessKind::LEARNER, 0),
            watch_hang: true,
            last_cause: None,
            restart_at: None,
            log_start: 0,
            started: None,
        }
    }

    /// A death of a new cause restarts at once; the same cause again waits 2, 4, 8 …
    /// seconds, at most a minute, so a fault a restart cannot fix does not spend the
    /// restart budget in seconds.
    #[test]
    fn the_same_error_in_a_row_backs_off_and_a_new_one_does_not() {
        let mut p = proc_named("learner");
        let disk = "the final checkpoint could not be written — No space left on device (os error 28)";
        let delays: Vec<(u64, u32)> = (0..9).map(|_| p.backoff(disk)).map(|(d, n)| (d.as_secs(), n)).collect();
        assert_eq!(delays, [(0, 1), (2, 2), (4, 3), (8, 4), (16, 5), (32, 6), (60, 7), (60, 8), (60, 9)]);
        assert_eq!(p.backoff("killed by SIGKILL"), (Duration::ZERO, 1), "another cause starts over");
    }
}
