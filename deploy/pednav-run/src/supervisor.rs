//! The supervisor of one run's processes: starts the curriculum service, the learner
//! and the actors, restarts any of them that dies — the learner from its last
//! checkpoint (refilling its replay as on a resume), the curriculum service from its
//! saved state, an actor afresh — within a budget of [`MAX_RESTARTS`] per
//! [`RESTART_WINDOW`] each; a learner or curriculum service that stops sending
//! heartbeats for `runtime.hang_secs` is treated as dead. It prints the progress line
//! from the heartbeats and stops everything in order.
//!
//! Invariant: the actors are always stopped before the learner and the curriculum
//! service, so the learner drains a stream nobody writes any more before its final
//! checkpoint, and the curriculum service has every report before it saves.

use std::collections::{BTreeMap, VecDeque};
use std::fs::OpenOptions;
use std::io::{IsTerminal, Write};
use std::os::unix::process::CommandExt;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use pednav_nets::DeviceSpec;
use pednav_runtime::ipc::HeartbeatSubscriber;
use pednav_runtime::messages::{Heartbeat, ProcessKind};
use pednav_runtime::{Ipc, RestartRecord, RunConfig, RunDir, StopFlag, run_prefix};

use crate::exit_cause::ExitCause;

/// A process that dies more than this many times within [`RESTART_WINDOW`] ends the run.
pub(crate) const MAX_RESTARTS: usize = 5;
/// The window of [`MAX_RESTARTS`].
pub(crate) const RESTART_WINDOW: Duration = Duration::from_secs(120);

/// One supervised child.
struct Proc {
    name: String,
    args: Vec<String>,
    binary: PathBuf,
    log: PathBuf,
    child: Option<Child>,
    restarts: VecDeque<Instant>,
    total_restarts: u32,
    /// Its heartbeats' (kind, id).
    heartbeat: (ProcessKind, u32),
    /// Whether silence means a hang (the learner and the curriculum service; an actor
    /// legitimately stays silent while it waits for a restarting learner).
    watch_hang: bool,
    /// The headline of its last death's cause, and how many deaths in a row had it.
    last_cause: Option<(String, u32)>,
    /// When a process that died of the same cause again is started (back-off).
    restart_at: Option<Instant>,
    /// Where its log ended when it was last started: its death's cause is read from
    /// there on (the log holds every run of the process).
    log_start: u64,
    /// When it was last started.
    started: Option<Instant>,
}

impl Proc {
    /// Count a death against the restart budget; an error naming the cause (from the
    /// log) when the budget is spent.
    fn count_restart(&mut self, status: &str, cause: &ExitCause) -> Result<()> {
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
    fn backoff(&mut self, headline: &str) -> (Duration, u32) {
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

    fn start(&mut self) -> Result<()> {
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

    fn signal(&self, sig: libc::c_int) {
        if let Some(c) = &self.child {
            // SAFETY: kill(2) on our own child's pid.
            unsafe { libc::kill(c.id() as libc::pid_t, sig) };
        }
    }

    /// SIGKILL it and reap it.
    fn kill(&mut self) {
        self.signal(libc::SIGKILL);
        if let Some(c) = self.child.as_mut() {
            let _ = c.wait();
        }
        self.child = None;
    }

    /// Exit status if it has exited (and forget the child).
    fn exited(&mut self) -> Option<std::process::ExitStatus> {
        let status = self.child.as_mut().and_then(|c| c.try_wait().ok().flatten());
        if status.is_some() {
            self.child = None;
        }
        status
    }

    fn running(&self) -> bool {
        self.child.is_some()
    }

    /// Why the process ended, from what its last run wrote to its log ([`ExitCause`]).
    fn exit_cause(&self) -> ExitCause {
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
fn stop_all(procs: &mut [&mut Proc], grace: Duration) {
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

/// What to start: the binaries and how many of which, with their flags.
pub struct ProcessPlan {
    /// Folder of pednav-actor, pednav-learner and pednav-curriculum.
    pub bins: PathBuf,
    /// Actor processes.
    pub actors: u32,
    /// Simulator instances per actor (default: the config's).
    pub envs: Option<usize>,
    /// Learner compute threads (default: all cores).
    pub learner_threads: Option<usize>,
    /// The learner's device.
    pub learner_device: DeviceSpec,
    /// The actors' inference device.
    pub actor_device: DeviceSpec,
}

/// The running processes of one run and what the supervisor knows of them.
pub struct Supervisor {
    dir: RunDir,
    stop: StopFlag,
    ipc: Ipc,
    heartbeats: HeartbeatSubscriber,
    curriculum: Proc,
    learner: Proc,
    actors: Vec<Proc>,
    /// The newest heartbeat of each (kind, id).
    latest: BTreeMap<(ProcessKind, u32), Heartbeat>,
    /// When each (kind, id) last sent one (cleared when its process restarts).
    last_beat: BTreeMap<(ProcessKind, u32), Instant>,
    /// `runtime.hang_secs`.
    hang: Duration,
    started: Instant,
    last_line: Instant,
    tty: bool,
    /// `runtime.max_env_steps` and `max_updates` (0: none).
    budget: (u64, u64),
    /// The learner's (time, env steps, updates) over the last two minutes, for the ETA.
    pace: VecDeque<(Instant, u64, u64)>,
}

impl Supervisor {
    /// Remove stale resources of this run (a previous launcher killed hard), then start
    /// the curriculum service, the learner and the actors of `plan`.
    pub fn start(dir: &RunDir, cfg: &RunConfig, plan: &ProcessPlan, stop: StopFlag) -> Result<Supervisor> {
        let ipc = Ipc::new(
            &run_prefix(dir.root()),
            "launcher",
            cfg.runtime.step_buffer,
            Duration::from_secs(5),
            stop.clone(),
        )?;
        let heartbeats = ipc.heartbeat_subscriber()?;
        let rd = dir.root().display().to_string();
        let mk = |name: String, bin: &str, args: Vec<String>, heartbeat: (ProcessKind, u32)| Proc {
            log: dir.logs().join(format!("{name}.log")),
            name,
            binary: plan.bins.join(bin),
            args,
            child: None,
            restarts: VecDeque::new(),
            total_restarts: 0,
            heartbeat,
            watch_hang: heartbeat.0 != ProcessKind::ACTOR,
            last_cause: None,
            restart_at: None,
            log_start: 0,
            started: None,
        };
        let mut curriculum = mk(
            "curriculum".into(),
            "pednav-curriculum",
            vec!["serve".into(), "--run-dir".into(), rd.clone()],
            (ProcessKind::CURRICULUM, 0),
        );
        let mut learner_args = vec!["--run-dir".into(), rd.clone(), "--device".into(), plan.learner_device.to_string()];
        if let Some(t) = plan.learner_threads {
            learner_args.extend(["--threads".into(), t.to_string()]);
        }
        let mut learner = mk("learner".into(), "pednav-learner", learner_args, (ProcessKind::LEARNER, 0));
        let mut actors: Vec<Proc> = (0..plan.actors)
            .map(|k| {
                let mut args = vec![
                    "--run-dir".into(),
                    rd.clone(),
                    "--actor".into(),
                    k.to_string(),
                    "--device".into(),
                    plan.actor_device.to_string(),
                ];
                if let Some(m) = plan.envs {
                    args.extend(["--envs".into(), m.to_string()]);
                }
                mk(format!("actor-{k}"), "pednav-actor", args, (ProcessKind::ACTOR, k))
            })
            .collect();
        curriculum.start()?;
        learner.start()?;
        for a in actors.iter_mut() {
            a.start()?;
        }
        Ok(Supervisor {
            dir: dir.clone(),
            stop,
            ipc,
            heartbeats,
            curriculum,
            learner,
            actors,
            latest: BTreeMap::new(),
            last_beat: BTreeMap::new(),
            hang: Duration::from_secs_f64(cfg.runtime.hang_secs),
            started: Instant::now(),
            last_line: Instant::now(),
            tty: std::io::stderr().is_terminal(),
            budget: (cfg.runtime.max_env_steps, cfg.runtime.max_updates),
            pace: VecDeque::new(),
        })
    }

    /// Supervise until Ctrl-C / SIGTERM, the learner's budget or a failure, then stop
    /// everything in order; a failure is the error.
    pub fn run(mut self) -> Result<()> {
        let mut failure = None;
        while !self.stop.is_set() {
            std::thread::sleep(Duration::from_millis(100));
            match self.step() {
                Ok(true) => {}
                Ok(false) => break,
                Err(e) => {
                    failure = Some(e);
                    break;
                }
            }
        }
        self.stop_in_order();
        match failure {
            Some(f) => Err(f.context("the run stopped")),
            None => Ok(()),
        }
    }

    /// One look at the processes: heartbeats, dead or hung processes restarted, the
    /// budget marker, the progress line. `false` when the run is over; an error when it
    /// failed (a process out of restarts).
    pub fn step(&mut self) -> Result<bool> {
        while let Ok(Some(h)) = self.heartbeats.receive() {
            self.latest.insert((h.kind, h.id), *h);
            self.last_beat.insert((h.kind, h.id), Instant::now());
        }
        let Supervisor { learner, curriculum, actors, last_beat, ipc, stop, hang, dir, .. } = self;
        for p in [learner, curriculum].into_iter().chain(actors.iter_mut()) {
            if let Some(at) = p.restart_at {
                if Instant::now() >= at && !stop.is_set() {
                    p.restart_at = None;
                    ipc.cleanup_dead_nodes();
                    p.start()?;
                }
                continue;
            }
            let status = match p.exited() {
                Some(status) => status.to_string(),
                None if p.watch_hang && last_beat.get(&p.heartbeat).is_some_and(|t| t.elapsed() > *hang) => {
                    eprintln!("\npednav: {} sent no heartbeat for {} s: killing it", p.name, hang.as_secs());
                    p.kill();
                    format!("hung: no heartbeat for {} s", hang.as_secs())
                }
                None => continue,
            };
            if stop.is_set() {
                return Ok(false);
            }
            let cause = p.exit_cause();
            p.count_restart(&status, &cause)?;
            let from = match p.heartbeat.0 {
                ProcessKind::LEARNER => " from its last checkpoint",
                ProcessKind::CURRICULUM => " from its saved state",
                _ => "",
            };
            let headline = cause.headline();
            let (delay, repeats) = p.backoff(&headline);
            last_beat.remove(&p.heartbeat);
            let record = RestartRecord {
                unix_time: std::time::SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .map_or(0.0, |d| d.as_secs_f64()),
                process: p.name.clone(),
                status: status.clone(),
                cause: headline.clone(),
                restart: p.total_restarts,
                delay_secs: delay.as_secs_f64(),
            };
            if let Err(e) = dir.append_restart(&record) {
                tracing::warn!("the restart could not be recorded: {e}");
            }
            if delay.is_zero() {
                eprintln!(
                    "\npednav: {} exited ({status}): {headline}; restarting it{from} (restart {})",
                    p.name, p.total_restarts
                );
                ipc.cleanup_dead_nodes();
                p.start()?;
            } else {
                eprintln!(
                    "\npednav: {} exited ({status}): {headline} — the same error {repeats} times in a row: \
                     restarting it{from} in {} s (restart {})",
                    p.name,
                    delay.as_secs(),
                    p.total_restarts
                );
                p.restart_at = Some(Instant::now() + delay);
            }
        }
        if let Ok(reason) = std::fs::read_to_string(self.dir.done_marker()) {
            eprintln!("\npednav: the learner reached its budget ({reason})");
            return Ok(false);
        }
        let every = if self.tty { Duration::from_secs(1) } else { Duration::from_secs(30) };
        if self.last_line.elapsed() >= every {
            self.last_line = Instant::now();
            let restarts = self.learner.total_restarts + self.curriculum.total_restarts;
            let mut line = progress_line(self.started.elapsed(), &self.latest, &self.actors, restarts);
            for extra in [self.budget_progress(), self.faults_line(), self.backoff_line()].into_iter().flatten() {
                line.push_str(" | ");
                line.push_str(&extra);
            }
            if self.tty {
                eprint!("\r\x1b[2K{line}");
            } else {
                eprintln!("{line}");
            }
            let _ = std::io::stderr().flush();
        }
        Ok(true)
    }

    /// `37 % ETA 00:21:13` when the run has a budget (env steps or updates): the share
    /// done and the time left at the pace of the last two minutes.
    fn budget_progress(&mut self) -> Option<String> {
        let (max_steps, max_updates) = self.budget;
        let h = self.latest.get(&(ProcessKind::LEARNER, 0))?;
        let now = Instant::now();
        self.pace.push_back((now, h.env_steps, h.updates));
        while self.pace.front().is_some_and(|p| now.duration_since(p.0) > Duration::from_secs(120)) {
            self.pace.pop_front();
        }
        let (t0, s0, u0) = *self.pace.front()?;
        let secs = now.duration_since(t0).as_secs_f64();
        // The budget that ends the run first, as (done, total, rate per second).
        // (A learner resumed from a checkpoint may report fewer steps than before it died.)
        let steps = (max_steps > 0).then(|| (h.env_steps, max_steps, h.env_steps.saturating_sub(s0) as f64 / secs));
        let updates = (max_updates > 0).then(|| (h.updates, max_updates, h.updates.saturating_sub(u0) as f64 / secs));
        let left = |(done, total, rate): (u64, u64, f64)| total.saturating_sub(done) as f64 / rate.max(1e-9);
        let (done, total, rate) =
            [steps, updates].into_iter().flatten().min_by(|a, b| left(*a).total_cmp(&left(*b)))?;
        let share = 100.0 * done as f64 / total as f64;
        if secs < 5.0 || rate <= 0.0 {
            return Some(format!("{share:.0} %"));
        }
        let eta = left((done, total, rate)) as u64;
        Some(format!("{share:.0} % ETA {:02}:{:02}:{:02}", eta / 3600, (eta / 60) % 60, eta % 60))
    }

    /// What the learner and the curriculum service could not write, from their heartbeats.
    fn faults_line(&self) -> Option<String> {
        let parts: Vec<String> = [(ProcessKind::LEARNER, "update"), (ProcessKind::CURRICULUM, "episodes")]
            .into_iter()
            .filter_map(|(kind, unit)| self.latest.get(&(kind, 0)).and_then(|h| h.faults.describe(h.last_good, unit)))
            .chain(
                self.latest
                    .iter()
                    .filter(|(k, h)| k.0 == ProcessKind::ACTOR && h.faults.any())
                    .map(|(k, h)| format!("actor-{}: {}", k.1, h.faults.describe(0, "").unwrap_or_default())),
            )
            .collect();
        (!parts.is_empty()).then(|| parts.join("; "))
    }

    /// Processes waiting out a back-off before their restart.
    fn backoff_line(&self) -> Option<String> {
        let waiting: Vec<String> = [&self.learner, &self.curriculum]
            .into_iter()
            .chain(self.actors.iter())
            .filter_map(|p| {
                let at = p.restart_at?;
                let (_, repeats) = p.last_cause.as_ref()?;
                let secs = at.saturating_duration_since(Instant::now()).as_secs();
                Some(format!("{} restarting in {secs} s (same error {repeats}×)", p.name))
            })
            .collect();
        (!waiting.is_empty()).then(|| waiting.join(", "))
    }

    /// Actors first, then the learner (final checkpoint) and the curriculum service (state).
    fn stop_in_order(&mut self) {
        eprintln!("\npednav: stopping — actors first, then the learner (final checkpoint) and the curriculum service");
        let mut refs: Vec<&mut Proc> = self.actors.iter_mut().collect();
        stop_all(&mut refs, Duration::from_secs(30));
        stop_all(&mut [&mut self.learner, &mut self.curriculum], Duration::from_secs(300));
        self.ipc.cleanup_dead_nodes();
    }
}

/// The launcher's progress line; `service_restarts` counts the learner's and the
/// curriculum service's restarts, added to the actors'.
fn progress_line(
    elapsed: Duration,
    latest: &BTreeMap<(ProcessKind, u32), Heartbeat>,
    actors: &[Proc],
    service_restarts: u32,
) -> String {
    let s = elapsed.as_secs();
    let learner = latest.get(&(ProcessKind::LEARNER, 0));
    let curriculum = latest.get(&(ProcessKind::CURRICULUM, 0));
    let actor_rate: f32 = latest.iter().filter(|(k, _)| k.0 == ProcessKind::ACTOR).map(|(_, h)| h.rate).sum();
    let alive = actors.iter().filter(|a| a.running()).count();
    let restarts: u32 = actors.iter().map(|a| a.total_restarts).sum::<u32>() + service_restarts;
    format!(
        "[{:02}:{:02}:{:02}] steps {} ({:.0}/s) | updates {} | episodes {} return {:.1} | {} t_c {} | actors {}/{} restarts {}",
        s / 3600,
        (s / 60) % 60,
        s % 60,
        learner.map_or(0, |h| h.env_steps),
        actor_rate,
        learner.map_or(0, |h| h.updates),
        curriculum.map_or(0, |h| h.episodes),
        curriculum.map_or(f32::NAN, |h| h.recent_return),
        if curriculum.is_some_and(|h| h.phase == 1) { "ACL" } else { "first-task" },
        curriculum.map_or(0, |h| h.acl_steps),
        alive,
        actors.len(),
        restarts
    )
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
