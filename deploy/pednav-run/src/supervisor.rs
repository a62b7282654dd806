//! The supervisor of one host's processes of a run: starts the curriculum service, the
//! learner and the actors (the learner host), or the actors alone (an actor host), and
//! the bridge when the run spans hosts; restarts any of them that dies — the learner
//! from its last checkpoint (refilling its replay as on a resume), the curriculum
//! service from its saved state, an actor or a bridge afresh — within a budget of
//! [`pednav_runtime::MAX_RESTARTS`] per [`pednav_runtime::RESTART_WINDOW`] each; a
//! learner or curriculum service that stops sending heartbeats for
//! `runtime.hang_secs` is treated as dead. It prints the
//! progress line from the heartbeats (an actor host sees the learner's through its
//! bridge) and stops everything in order.
//!
//! Invariant: the actors are always stopped first, then the bridge, then the learner
//! and the curriculum service, so the learner drains a stream nobody writes any more
//! before its final checkpoint, and the curriculum service has every report before it
//! saves.

use std::collections::{BTreeMap, VecDeque};
use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use pednav_bridge::HostTable;
use pednav_nets::DeviceSpec;
use pednav_runtime::ipc::HeartbeatSubscriber;
use pednav_runtime::messages::{Heartbeat, ProcessKind};
use pednav_runtime::{Ipc, RestartRecord, RunConfig, RunDir, StopFlag, run_prefix};

use crate::child::{Proc, stop_all};

/// A remote actor whose heartbeats stopped this long ago counts as dead on the progress line.
const REMOTE_SILENCE: Duration = Duration::from_secs(10);

/// Which of a run's processes this host runs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum HostRole {
    /// The learner, the curriculum service and the local actors; with `listen`
    /// endpoints, a bridge that lets actor hosts join (`launch --listen`).
    Learner {
        /// Endpoints the bridge listens on (none: a run on one machine).
        listen: Vec<String>,
        /// Mutual TLS on the link (endpoints `tls/…`).
        tls: Option<pednav_bridge::TlsFiles>,
    },
    /// Actors and a bridge to the learner host (`join`).
    Actors {
        /// The learner host's endpoints.
        connect: Vec<String>,
        /// The run's name on the link.
        run: String,
        /// This host's name on the link.
        host: String,
        /// Mutual TLS on the link (endpoints `tls/…`).
        tls: Option<pednav_bridge::TlsFiles>,
    },
}

/// What to start: the binaries and how many of which, with their flags.
pub struct ProcessPlan {
    /// Folder of pednav-actor, pednav-learner and pednav-curriculum.
    pub bins: PathBuf,
    /// Actor processes.
    pub actors: u32,
    /// The global id of the first of them (0 on the learner host; an actor host's
    /// join grants its range).
    pub first_actor: u32,
    /// The processes this host runs.
    pub role: HostRole,
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
    /// The curriculum service and the learner (the learner host), none on an actor host.
    services: Vec<Proc>,
    /// The bridge, when the run spans hosts.
    bridge: Option<Proc>,
    actors: Vec<Proc>,
    /// The local actors' global ids.
    local_ids: std::ops::Range<u32>,
    /// The host table of a learner host that lets actor hosts join.
    hosts_file: Option<PathBuf>,
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
        let mk = |name: String, binary: PathBuf, args: Vec<String>, heartbeat: (ProcessKind, u32)| Proc {
            log: dir.logs().join(format!("{name}.log")),
            name,
            binary,
            args,
            child: None,
            restarts: VecDeque::new(),
            total_restarts: 0,
            heartbeat,
            watch_hang: heartbeat.0 == ProcessKind::LEARNER || heartbeat.0 == ProcessKind::CURRICULUM,
            last_cause: None,
            restart_at: None,
            log_start: 0,
            started: None,
        };
        let local_ids = plan.first_actor..plan.first_actor + plan.actors;
        let launcher = std::env::current_exe().context("locating pednav-run (it runs the bridge)")?;
        let bridge_args =
            |role_args: Vec<String>| [vec!["bridge".into(), "--run-dir".into(), rd.clone()], role_args].concat();
        let (mut services, mut bridge) = (Vec::new(), None);
        match &plan.role {
            HostRole::Learner { listen, tls } => {
                services.push(mk(
                    "curriculum".into(),
                    plan.bins.join("pednav-curriculum"),
                    vec!["serve".into(), "--run-dir".into(), rd.clone()],
                    (ProcessKind::CURRICULUM, 0),
                ));
                let mut learner_args =
                    vec!["--run-dir".into(), rd.clone(), "--device".into(), plan.learner_device.to_string()];
                if let Some(t) = plan.learner_threads {
                    learner_args.extend(["--threads".into(), t.to_string()]);
                }
                services.push(mk(
                    "learner".into(),
                    plan.bins.join("pednav-learner"),
                    learner_args,
                    (ProcessKind::LEARNER, 0),
                ));
                if !listen.is_empty() {
                    let mut args = vec!["--local-actors".to_string(), plan.actors.to_string()];
                    for e in listen {
                        args.extend(["--listen".into(), e.clone()]);
                    }
                    args.extend(crate::tls::tls_flags(tls.as_ref()));
                    bridge = Some(mk("bridge".into(), launcher, bridge_args(args), (ProcessKind::BRIDGE, 0)));
                }
            }
            HostRole::Actors { connect, run, host, tls } => {
                let mut args = vec!["--run".to_string(), run.clone(), "--host".into(), host.clone()];
                for e in connect {
                    args.extend(["--connect".into(), e.clone()]);
                }
                args.extend(crate::tls::tls_flags(tls.as_ref()));
                bridge = Some(mk("bridge".into(), launcher, bridge_args(args), (ProcessKind::BRIDGE, 0)));
            }
        }
        let mut actors: Vec<Proc> = local_ids
            .clone()
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
                mk(format!("actor-{k}"), plan.bins.join("pednav-actor"), args, (ProcessKind::ACTOR, k))
            })
            .collect();
        for p in services.iter_mut().chain(bridge.iter_mut()).chain(actors.iter_mut()) {
            p.start()?;
        }
        Ok(Supervisor {
            dir: dir.clone(),
            stop,
            ipc,
            heartbeats,
            services,
            bridge,
            actors,
            local_ids,
            hosts_file: matches!(&plan.role, HostRole::Learner { listen, .. } if !listen.is_empty())
                .then(|| dir.root().join(pednav_bridge::HOSTS_FILE)),
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
        let Supervisor { services, bridge, actors, last_beat, ipc, stop, hang, dir, .. } = self;
        for p in services.iter_mut().chain(bridge.iter_mut()).chain(actors.iter_mut()) {
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
            eprintln!("\npednav: the learner reached its budget ({})", reason.trim());
            return Ok(false);
        }
        let every = if self.tty { Duration::from_secs(1) } else { Duration::from_secs(30) };
        if self.last_line.elapsed() >= every {
            self.last_line = Instant::now();
            let restarts: u32 = self.services.iter().chain(self.bridge.iter()).map(|p| p.total_restarts).sum();
            let mut line = progress_line(self.started.elapsed(), &self.latest, &self.actors, restarts);
            let extras = [
                self.remote_actors_line(),
                self.budget_progress(),
                self.faults_line(),
                self.backoff_line(),
                self.learner_host_line(),
            ];
            for extra in extras.into_iter().flatten() {
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
        let waiting: Vec<String> = self
            .services
            .iter()
            .chain(self.bridge.iter())
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

    /// On an actor host, when the learner's heartbeats stopped coming across the link
    /// (the learner host is away or unreachable): how long, and what the actors do.
    fn learner_host_line(&self) -> Option<String> {
        if !self.services.is_empty() {
            return None;
        }
        let silent = self.last_beat.get(&(ProcessKind::LEARNER, 0)).map_or(self.started.elapsed(), Instant::elapsed);
        (silent >= REMOTE_SILENCE).then(|| {
            format!("learner host silent {} s: actors wait (records held) and go on when it is back", silent.as_secs())
        })
    }

    /// On a learner host that lets actor hosts join: the joined hosts' actors heard
    /// within the last [`REMOTE_SILENCE`], of the ids granted to them (`hosts.json`).
    fn remote_actors_line(&self) -> Option<String> {
        let table = match HostTable::load(self.hosts_file.as_ref()?) {
            Ok(table) => table?,
            Err(e) => return Some(format!("remote actors unknown ({e})")),
        };
        let heard = |id: u32| {
            !self.local_ids.contains(&id)
                && self.last_beat.get(&(ProcessKind::ACTOR, id)).is_some_and(|t| t.elapsed() < REMOTE_SILENCE)
        };
        remote_actors_summary(&table, heard)
    }

    /// Actors first, then the bridge, then the learner (final checkpoint) and the
    /// curriculum service (state).
    fn stop_in_order(&mut self) {
        if self.services.is_empty() {
            eprintln!("\npednav: stopping — actors first, then the bridge");
        } else {
            eprintln!(
                "\npednav: stopping — actors first, then the learner (final checkpoint) and the curriculum service"
            );
        }
        let mut refs: Vec<&mut Proc> = self.actors.iter_mut().collect();
        stop_all(&mut refs, Duration::from_secs(30));
        if let Some(b) = self.bridge.as_mut() {
            stop_all(&mut [b], Duration::from_secs(15));
        }
        let mut refs: Vec<&mut Proc> = self.services.iter_mut().collect();
        stop_all(&mut refs, Duration::from_secs(300));
        self.ipc.cleanup_dead_nodes();
    }
}

/// `remote actors 14/16 (silent: gpu-b)`: of the actor ids granted to joined hosts,
/// those `heard`, and the hosts none of whose actors is heard. A host that left the
/// link counts as its actors dead, as a dead local actor does; `None` before any host
/// joined.
fn remote_actors_summary(table: &HostTable, heard: impl Fn(u32) -> bool) -> Option<String> {
    let (mut granted, mut alive, mut silent) = (0, 0, Vec::new());
    for host in table.remote() {
        let n = host.ids().filter(|&id| heard(id)).count();
        granted += host.actors as usize;
        alive += n;
        if n == 0 {
            silent.push(host.name.as_str());
        }
    }
    (granted > 0).then(|| {
        let mut line = format!("remote actors {alive}/{granted}");
        if !silent.is_empty() {
            line.push_str(&format!(" (silent: {})", silent.join(", ")));
        }
        line
    })
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

    #[test]
    fn remote_actors_count_against_the_granted_ids_and_silent_hosts_are_named() {
        let mut table = HostTable::new(2, 256).unwrap();
        assert_eq!(remote_actors_summary(&table, |_| true), None, "no host joined yet");
        table.join("gpu-a", 3).unwrap(); // ids 2..5
        table.join("gpu-b", 2).unwrap(); // ids 5..7
        // The local actors (0, 1) are not counted, whether heard or not.
        assert_eq!(remote_actors_summary(&table, |id| id != 3).as_deref(), Some("remote actors 4/5"));
        assert_eq!(remote_actors_summary(&table, |id| id < 5).as_deref(), Some("remote actors 3/5 (silent: gpu-b)"));
        assert_eq!(
            remote_actors_summary(&table, |_| false).as_deref(),
            Some("remote actors 0/5 (silent: gpu-a, gpu-b)")
        );
    }
}
