//! The supervisor of one run's processes: starts the curriculum service, the learner
//! and the actors, restarts an actor that dies (within a budget), prints the progress
//! line from the heartbeats, and stops everything in order.
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
use pednav_runtime::messages::{Heartbeat, process_kind};
use pednav_runtime::{Ipc, RunConfig, RunDir, StopFlag, run_prefix};

/// An actor that dies this many times within [`RESTART_WINDOW`] ends the run.
const MAX_RESTARTS: usize = 5;
/// The window of [`MAX_RESTARTS`].
const RESTART_WINDOW: Duration = Duration::from_secs(120);

/// One supervised child.
struct Proc {
    name: String,
    args: Vec<String>,
    binary: PathBuf,
    log: PathBuf,
    child: Option<Child>,
    restarts: VecDeque<Instant>,
    total_restarts: u32,
}

impl Proc {
    fn start(&mut self) -> Result<()> {
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

    fn log_tail(&self) -> String {
        let text = std::fs::read_to_string(&self.log).unwrap_or_default();
        let lines: Vec<&str> = text.lines().collect();
        lines[lines.len().saturating_sub(8)..].join("\n")
    }
}

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
                p.signal(libc::SIGKILL);
                if let Some(c) = p.child.as_mut() {
                    let _ = c.wait();
                }
                p.child = None;
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
    latest: BTreeMap<(u32, u32), Heartbeat>,
    started: Instant,
    last_line: Instant,
    tty: bool,
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
        let mk = |name: String, bin: &str, args: Vec<String>| Proc {
            log: dir.logs().join(format!("{name}.log")),
            name,
            binary: plan.bins.join(bin),
            args,
            child: None,
            restarts: VecDeque::new(),
            total_restarts: 0,
        };
        let mut curriculum =
            mk("curriculum".into(), "pednav-curriculum", vec!["serve".into(), "--run-dir".into(), rd.clone()]);
        let mut learner_args = vec!["--run-dir".into(), rd.clone(), "--device".into(), plan.learner_device.to_string()];
        if let Some(t) = plan.learner_threads {
            learner_args.extend(["--threads".into(), t.to_string()]);
        }
        let mut learner = mk("learner".into(), "pednav-learner", learner_args);
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
                mk(format!("actor-{k}"), "pednav-actor", args)
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
            started: Instant::now(),
            last_line: Instant::now(),
            tty: std::io::stderr().is_terminal(),
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

    /// One look at the processes: heartbeats, dead actors restarted, the learner and
    /// the curriculum service alive, the budget marker, the progress line. `false`
    /// when the run is over; an error when it failed.
    pub fn step(&mut self) -> Result<bool> {
        while let Ok(Some(h)) = self.heartbeats.receive() {
            self.latest.insert((h.kind, h.id), *h);
        }
        for a in self.actors.iter_mut() {
            let Some(status) = a.exited() else { continue };
            if self.stop.is_set() {
                return Ok(false);
            }
            a.restarts.push_back(Instant::now());
            while a.restarts.front().is_some_and(|t| t.elapsed() > RESTART_WINDOW) {
                a.restarts.pop_front();
            }
            if a.restarts.len() > MAX_RESTARTS {
                bail!(
                    "{} died {} times within {} s ({status}); last log lines:\n{}",
                    a.name,
                    MAX_RESTARTS + 1,
                    RESTART_WINDOW.as_secs(),
                    a.log_tail()
                );
            }
            a.total_restarts += 1;
            eprintln!("\npednav: {} exited ({status}); restarting it (restart {})", a.name, a.total_restarts);
            self.ipc.cleanup_dead_nodes();
            a.start()?;
        }
        for p in [&mut self.learner, &mut self.curriculum] {
            if let Some(status) = p.exited() {
                bail!("{} exited ({status}); last log lines:\n{}", p.name, p.log_tail());
            }
        }
        if let Ok(reason) = std::fs::read_to_string(self.dir.done_marker()) {
            eprintln!("\npednav: the learner reached its budget ({reason})");
            return Ok(false);
        }
        let every = if self.tty { Duration::from_secs(1) } else { Duration::from_secs(30) };
        if self.last_line.elapsed() >= every {
            self.last_line = Instant::now();
            let line = progress_line(self.started.elapsed(), &self.latest, &self.actors);
            if self.tty {
                eprint!("\r\x1b[2K{line}");
            } else {
                eprintln!("{line}");
            }
            let _ = std::io::stderr().flush();
        }
        Ok(true)
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

fn progress_line(elapsed: Duration, latest: &BTreeMap<(u32, u32), Heartbeat>, actors: &[Proc]) -> String {
    let s = elapsed.as_secs();
    let learner = latest.get(&(process_kind::LEARNER, 0));
    let curriculum = latest.get(&(process_kind::CURRICULUM, 0));
    let actor_rate: f32 = latest.iter().filter(|(k, _)| k.0 == process_kind::ACTOR).map(|(_, h)| h.rate).sum();
    let alive = actors.iter().filter(|a| a.running()).count();
    let restarts: u32 = actors.iter().map(|a| a.total_restarts).sum();
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
