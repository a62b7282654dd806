//! `pednav-run bench soak`: a long run (the smoke config, 30 minutes by default;
//! not in CI) whose learner, curriculum service and actors are SIGKILLed at seeded
//! random times. It reports what the launcher restarted, whether training went on
//! after every kill, and whether any step an actor sent went missing at the learner.
//!
//! - **Schedule** ([`kill_schedule`]): one ChaCha8 RNG seeded with `--seed` draws the
//!   whole schedule before the run starts — intervals uniform in [0.5, 1.5] × the mean,
//!   victims in shuffled rounds over the three kinds (learner, curriculum service, an
//!   actor drawn among `--actors`), never the same kind twice in a row — so every kind
//!   is killed at least once. The last [`schedule::recovery_secs`] of the run have no kill (time
//!   to see training continue). A schedule too short to cover every kind, or one that
//!   kills one process more than [`MAX_PLANNED_KILLS_PER_WINDOW`] times within the
//!   supervisor's restart window, is refused before anything starts. A kill comes due
//!   no earlier than the learner's first update.
//! - **The run**: `pednav-run launch` on a fresh run directory named by its absolute
//!   path, from a snapshot of this build's binaries (`<run>/bin`, so a concurrent
//!   `cargo build` cannot swap them under a restart); stopped at the end with SIGINT
//!   (Ctrl-C: actors first, then the learner's final checkpoint) and waited for.
//! - **Victims' pids** ([`find_victim`]): from `/proc` — a child of this soak's
//!   launcher (`PPid`), running the victim's binary (`argv[0]`'s file name), whose
//!   `--run-dir` argument is exactly this run's directory, and `--actor K` for an
//!   actor; anything else (another run on the machine, a zombie, two candidates) is
//!   never signalled. The pid is opened as a pidfd, checked again, then signalled
//!   through the pidfd, so a pid reused in between cannot be hit. (The stats files'
//!   `pid` lag a restart by up to a metrics interval, so they are not used for this.)
//! - **Restarts**: the launcher's records of them (`<run>/restarts.jsonl`, one
//!   [`pednav_runtime::RestartRecord`] each, read as the soak polls), matched to the
//!   kills; the rest are unplanned deaths. Its stderr is kept in
//!   `<run>/soak-launcher.log`.
//! - **Training continued** after a kill when the learner's stats (`stats/learner.json`,
//!   polled every 250 ms, tagged by pid) show more updates *and* more env steps than
//!   `metrics/learner.csv` showed at the kill, written after the launcher restarted the
//!   victim (after a learner kill: by the new learner process).
//! - **Steps lost** ([`account`]), the end-to-end test's accounting (`tests/tests/
//!   runtime.rs`) per actor incarnation: what it sent (`stats/actor-K.I.json`, written
//!   on a clean stop: exact; a killed incarnation's last `actor-K.live.json`: a lower
//!   bound) against what every learner process counted for it (`streams` of
//!   `stats/learner.json`: the first sequence number, records and CRC-32 sum of one
//!   contiguous run; the final learner's exact, a killed learner's as last written).
//!   A stream that did not cross a learner restart must arrive whole — count and
//!   checksum equal — and anything missing is **lost on the learner's side** (must be
//!   0). Across a learner restart the actors send the new learner again what the killed
//!   one took without acknowledging (its intake queue included), so what a crossing
//!   stream may miss is only what the killed learner took *and acknowledged* after its
//!   last stats write (into the replay, which is not checkpointed; the learner resumes
//!   from its last checkpoint and refills `dsac.warmup` steps before updating again).
//!   That is allowed up to [`died_allowance`] per killed learner (1.5 × its intake rate
//!   over the time since its last stats write); anything beyond counts as lost.
//!   The report gives it separately, with each learner restart's rollback to its
//!   checkpoint.
//!
//! - **Across hosts** (`--across-hosts`): the same run split over two hosts on this
//!   machine — a learner host with no actors of its own (`launch --actors 0 --listen
//!   tcp/127.0.0.1:P`, run directory `<run>/learner-host`) and an actor host with the
//!   actors (`join`, `<run>/actor-host`), whose link goes through a TCP relay on
//!   loopback ([`crate::relay`]). The kinds of victim add each host's bridge (SIGKILL;
//!   its launcher restarts it) and the link (every connection closed and new ones
//!   refused for `--link-cut-secs`). The accounting is the same, with the actors'
//!   stats from the actor host's directory and the learner's from the learner host's;
//!   a learner that jumps over records (a dead learner's last acknowledgement can reach
//!   an actor across the link after its replacement took older records) is allowed
//!   only on a stream that crossed a learner restart, and what it jumped over counts
//!   against the same allowance. The actor host is stopped first, then the learner host.
//!
//! The report is a Markdown table on stdout and `soak.json` in the run directory; the
//! command fails (after reporting) when a kind was not killed, the launcher did not
//! restart a victim, training did not continue, a step was lost, or the run did not
//! stop cleanly. The default (temporary) run directory is removed after a passing
//! soak; a given `--run-dir` is kept.

use std::collections::BTreeMap;
use std::ffi::OsStr;
use std::io::{BufRead, BufReader, Read, Seek, SeekFrom, Write};
use std::os::fd::{FromRawFd, OwnedFd};
use std::os::unix::ffi::OsStrExt;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args;
use pednav_runtime::stats::{self, ActorStats, LearnerStats, ProcessStatus};
use pednav_runtime::{RunConfig, RunDir, StopFlag, columns};
use rand_chacha::ChaCha8Rng;
use rand_chacha::rand_core::{RngCore, SeedableRng};
use serde_json::{Value, json};

mod accounting;
mod hosts;
mod observe;
mod procfs;
mod report;
mod schedule;

use accounting::intake_before;
pub use accounting::{Received, Sent, account, died_allowance};
use hosts::HostRun;
use observe::{LearnerPoint, Observer, Sample, read_stats};
use procfs::sigkill_verified;
pub use procfs::{find_victim, is_victim};
use report::Report;
pub use schedule::{Host, PlannedKill, Victim, kill_schedule, victim_kinds};

/// The supervisor's restart budget: a process that dies more than this many times
/// within [`SUPERVISOR_RESTART_WINDOW_SECS`] ends the run.
const SUPERVISOR_MAX_RESTARTS: usize = pednav_runtime::MAX_RESTARTS;
/// The window of [`SUPERVISOR_MAX_RESTARTS`], in seconds.
const SUPERVISOR_RESTART_WINDOW_SECS: f64 = pednav_runtime::RESTART_WINDOW.as_secs_f64();
/// Kills the schedule may plan for one process within the supervisor's window: one
/// below its budget, leaving room for a death the soak did not cause.
pub const MAX_PLANNED_KILLS_PER_WINDOW: usize = SUPERVISOR_MAX_RESTARTS - 1;
/// The least kill-free time at the end of the run (to see training continue).
const MIN_RECOVERY_SECS: f64 = 30.0;
/// How long a due kill waits for its victim (starting or restarting) before it is skipped.
const VICTIM_WAIT_SECS: f64 = 60.0;
/// How long the launcher may take to stop after SIGINT (its learner's grace is 300 s).
const STOP_WAIT: Duration = Duration::from_secs(420);
/// Slack around a learner restart within which an actor stream counts as crossing it.
const LEARNER_RESTART_SLACK_SECS: f64 = 5.0;
/// How often the run's stats and metrics are read.
const POLL: Duration = Duration::from_millis(250);
/// The binaries of a run, snapshotted into `<run>/bin`.
const BINARIES: [&str; 4] = ["pednav-run", "pednav-learner", "pednav-curriculum", "pednav-actor"];

/// Arguments of `bench soak`.
#[derive(Args, Debug)]
pub struct Soak {
    /// Length of the run in minutes, from the launch to the Ctrl-C (SIGINT) that ends it.
    #[arg(long, default_value_t = 30.0)]
    minutes: f64,
    /// Seed of the one RNG (ChaCha8) that draws every kill time and victim: the same
    /// seed gives the same schedule.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Actor processes of the run (an actor victim is drawn among them).
    #[arg(long, default_value_t = 2)]
    actors: u32,
    /// Config of the run (TOML); a relative path is looked up in the current folder,
    /// then in the repository.
    #[arg(long, default_value = "deploy/configs/smoke.toml")]
    config: PathBuf,
    /// Run directory: must not exist or be empty; kept afterwards. Default: a new
    /// temporary folder, removed after a passing soak (kept when it fails).
    #[arg(long)]
    run_dir: Option<PathBuf>,
    /// Mean time between two kills, seconds; each interval is drawn uniformly from
    /// [0.5, 1.5] × this. The first kill waits for the learner's first update.
    #[arg(long, default_value_t = 120.0)]
    mean_kill_interval_secs: f64,
    /// Run the soak across two hosts on this machine: a learner host with no actors
    /// of its own and an actor host with the --actors, each with its run directory
    /// under the soak's (`learner-host/`, `actor-host/`), joined over a TCP relay on
    /// loopback that the soak can cut. The victims then also include each host's
    /// bridge and the link.
    #[arg(long)]
    across_hosts: bool,
    /// How long each cut of the link lasts, seconds (--across-hosts); less than half
    /// the mean kill interval, so the link is back before the next kill.
    #[arg(long, default_value_t = 15.0)]
    link_cut_secs: f64,
}

/// A restart the launcher announced.
#[derive(Clone, Debug, PartialEq)]
pub struct Restart {
    /// Seconds after the launch the line arrived.
    pub at: f64,
    /// The supervisor's process name (`learner`, `curriculum`, `actor-K`; across hosts
    /// a bridge's with its host, `learner-host/bridge` or `actor-host/bridge`).
    pub process: String,
    /// How it ended (`signal: 9 (SIGKILL)`, `hung: …`).
    pub status: String,
    /// The process's restart count.
    pub number: u32,
}

/// Seconds since the Unix epoch.
fn unix_now() -> f64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64())
}

/// Take the restarts `host`'s launcher recorded since the last look (`restarts.jsonl`
/// of its run directory, [`pednav_runtime::RestartRecord`]) into the log, timed from
/// the soak's start. Across hosts both launchers have a `bridge`: its name gets the
/// host's ([`Victim::process`]).
fn take_restarts(dir: &RunDir, host: Host, across_hosts: bool, started_unix: f64, log: &Mutex<LauncherLog>) {
    let records = dir.read_restarts();
    let mut l = log.lock().unwrap();
    let seen = l.taken.get(&host).copied().unwrap_or(0);
    l.taken.insert(host, records.len().max(seen));
    for r in records.into_iter().skip(seen) {
        let process =
            if across_hosts && r.process == "bridge" { format!("{}/bridge", host.label()) } else { r.process };
        l.restarts.push(Restart { at: r.unix_time - started_unix, process, status: r.status, number: r.restart });
    }
}

/// What the launchers' stderr and restart records told.
#[derive(Default)]
struct LauncherLog {
    restarts: Vec<Restart>,
    /// Restart records taken so far, per host.
    taken: BTreeMap<Host, usize>,
    /// The `restarts N` of the learner host's last progress line.
    progress_restarts: Option<u32>,
    lines: Vec<String>,
}

/// A kill as it happened.
struct KillRecord {
    plan: PlannedKill,
    at: f64,
    pid: u32,
    /// The learner's figures (metrics/learner.csv) just before the kill.
    before: Option<Sample>,
    /// An actor victim's incarnation (its live stats).
    incarnation: Option<u64>,
}

/// The config file: `path` as given, else relative to the repository.
fn resolve_config(path: &Path) -> Result<PathBuf> {
    if path.exists() {
        return Ok(std::path::absolute(path)?);
    }
    let mut tried = vec![path.to_path_buf()];
    if path.is_relative() {
        let mut roots = vec![Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")];
        if let Ok(exe) = std::env::current_exe()
            && let Some(root) = exe.parent().and_then(Path::parent).and_then(Path::parent)
        {
            roots.push(root.to_path_buf());
        }
        for root in roots {
            let candidate = root.join(path);
            if candidate.exists() {
                return Ok(candidate.canonicalize()?);
            }
            tried.push(candidate);
        }
    }
    bail!(
        "config {} not found (tried {}): pass --config with an existing file",
        path.display(),
        tried.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
    )
}

/// Hard-link (or copy) this build's binaries into `bin`, so the run keeps them.
fn snapshot_binaries(bin: &Path) -> Result<()> {
    let exe = std::env::current_exe().context("locating pednav-bench")?;
    let from = exe.parent().context("pednav-bench has no folder")?;
    std::fs::create_dir_all(bin)?;
    for b in BINARIES {
        let (src, dst) = (from.join(b), bin.join(b));
        if !src.exists() {
            bail!(
                "{} not found (build it: cargo build --release -p pednav-run -p pednav-actor -p pednav-learner -p pednav-curriculum)",
                src.display()
            );
        }
        if std::fs::hard_link(&src, &dst).is_err() {
            std::fs::copy(&src, &dst).with_context(|| format!("copying {} to {}", src.display(), dst.display()))?;
        }
    }
    Ok(())
}

fn secs(x: Option<f64>) -> String {
    x.map_or("—".into(), |s| format!("{s:.1} s"))
}

/// Run the soak of `args` (see the module doc).
pub fn run(args: Soak) -> Result<()> {
    let Soak { minutes, seed, actors, config, run_dir, mean_kill_interval_secs: mean, across_hosts, link_cut_secs } =
        args;
    let duration = minutes * 60.0;
    let schedule = kill_schedule(seed, duration, mean, actors, across_hosts)?;
    if across_hosts && !(link_cut_secs.is_finite() && link_cut_secs > 0.0 && link_cut_secs < 0.5 * mean) {
        bail!(
            "--link-cut-secs must be positive and less than half of --mean-kill-interval-secs ({mean} s), so the link \
             is back before the next kill; got {link_cut_secs}"
        );
    }
    let config = resolve_config(&config)?;
    let cfg = RunConfig::load(&config)?;
    let (run_dir, given) = match run_dir {
        Some(d) => (std::path::absolute(&d)?, true),
        None => (std::env::temp_dir().join(format!("pednav-soak-s{seed}-{}", std::process::id())), false),
    };
    if run_dir.exists() && std::fs::read_dir(&run_dir)?.next().is_some() {
        bail!("{} exists and is not empty: the soak needs a fresh run directory", run_dir.display());
    }
    std::fs::create_dir_all(&run_dir)?;
    let bin = run_dir.join("bin");
    snapshot_binaries(&bin)?;
    // One host: the run is the soak's directory. Across hosts: one run directory each.
    let (learner_dir, actor_dir) = if across_hosts {
        (run_dir.join(Host::Learner.label()), run_dir.join(Host::Actors.label()))
    } else {
        (run_dir.clone(), run_dir.clone())
    };
    eprintln!(
        "soak: {minutes} min, seed {seed}, {actors} actor(s){}, {}, run directory {}\nsoak: schedule (s after the \
         launch; the first kill waits for the learner's first update): {}",
        if across_hosts { format!(" on an actor host, link cuts of {link_cut_secs} s") } else { String::new() },
        config.display(),
        run_dir.display(),
        schedule.iter().map(|k| format!("{:.1} {}", k.at_secs, k.victim.process())).collect::<Vec<_>>().join(", ")
    );

    let stop = StopFlag::install();
    let start = Instant::now();
    let started_unix = unix_now();
    let now = move || start.elapsed().as_secs_f64();
    let log = Arc::new(Mutex::new(LauncherLog::default()));
    let launcher_bin = bin.join("pednav-run");
    let strings = |v: &[&str]| v.iter().map(|a| a.to_string()).collect::<Vec<_>>();
    let common =
        |dir: &Path| strings(&["--run-dir", &dir.display().to_string(), "--bin-dir", &bin.display().to_string()]);
    let mut relay = None;
    let mut hosts = Vec::new();
    if across_hosts {
        let (learner_port, relay_port) = (crate::relay::free_port()?, crate::relay::free_port()?);
        // Bound at once (nothing else can take the port); until the learner host listens
        // it drops what it cannot forward.
        relay = Some(crate::relay::Relay::start(relay_port, learner_port)?);
        let learner_args = [
            strings(&["launch", "--actors", "0", "--listen", &format!("tcp/127.0.0.1:{learner_port}"), "--config"]),
            vec![config.display().to_string()],
            common(&learner_dir),
        ]
        .concat();
        let learner_log = run_dir.join("soak-learner-host.log");
        hosts.push(HostRun::start(
            Host::Learner,
            &learner_dir,
            &launcher_bin,
            &learner_args,
            &learner_log,
            "learner host",
            &log,
        )?);
        // The actor host joins once the learner host's bridge listens (a join gives up
        // after 30 s).
        let listening = Instant::now();
        while std::net::TcpStream::connect(("127.0.0.1", learner_port)).is_err() {
            if let Some(status) = hosts[0].launcher.try_wait()? {
                bail!("the learner host ended ({status}) before it listened (see {})", learner_log.display());
            }
            if stop.is_set() {
                bail!("interrupted before the learner host listened");
            }
            if listening.elapsed() > Duration::from_secs(120) {
                bail!(
                    "the learner host did not listen on port {learner_port} within 120 s (see {})",
                    learner_log.display()
                );
            }
            std::thread::sleep(Duration::from_millis(200));
        }
        let actor_args = [
            strings(&[
                "join",
                "--connect",
                &format!("tcp/127.0.0.1:{relay_port}"),
                "--actors",
                &actors.to_string(),
                "--host",
                "soak-actors",
            ]),
            common(&actor_dir),
        ]
        .concat();
        let actor_log = run_dir.join("soak-actor-host.log");
        hosts.push(HostRun::start(
            Host::Actors,
            &actor_dir,
            &launcher_bin,
            &actor_args,
            &actor_log,
            "actor host",
            &log,
        )?);
    } else {
        let args = [
            strings(&["launch", "--actors", &actors.to_string(), "--config"]),
            vec![config.display().to_string()],
            common(&run_dir),
        ]
        .concat();
        hosts.push(HostRun::start(
            Host::Learner,
            &run_dir,
            &launcher_bin,
            &args,
            &run_dir.join("soak-launcher.log"),
            "launcher",
            &log,
        )?);
    }

    let mut obs = Observer::new(RunDir::new(&learner_dir), RunDir::new(&actor_dir), actors);
    let (mut kills, mut skipped) = (Vec::<KillRecord>::new(), Vec::<PlannedKill>::new());
    let (mut next, mut training_started, mut early_exit) = (0, None::<f64>, None::<(Host, ExitStatus)>);
    let proc_root = Path::new("/proc");
    'soak: while now() < duration && !stop.is_set() {
        std::thread::sleep(POLL);
        let t = now();
        obs.poll(t);
        for h in &mut hosts {
            take_restarts(&RunDir::new(&h.dir), h.host, across_hosts, started_unix, &log);
            if let Some(status) = h.launcher.try_wait()? {
                early_exit = Some((h.host, status));
                break 'soak;
            }
        }
        if training_started.is_none() && obs.samples.iter().any(|s| s.updates > 0) {
            training_started = Some(t);
            eprintln!("soak: [{t:.1} s] the learner is updating; kills may start");
        }
        let (Some(&plan), Some(started)) = (schedule.get(next), training_started) else { continue };
        let due = plan.at_secs.max(started);
        if t < due {
            continue;
        }
        obs.poll(now());
        let before = obs.last_sample();
        if plan.victim == Victim::Link {
            let relay = relay.as_ref().expect("a link victim only across hosts");
            relay.cut_later(Duration::ZERO, Duration::from_secs_f64(link_cut_secs));
            let at = now();
            eprintln!(
                "soak: [{at:.1} s] link cut for {link_cut_secs} s at env steps {}, updates {}",
                before.map_or(0, |s| s.env_steps),
                before.map_or(0, |s| s.updates)
            );
            kills.push(KillRecord { plan, at, pid: 0, before, incarnation: None });
            next += 1;
            continue;
        }
        let victim_host = hosts.iter().find(|r| r.host == plan.victim.host()).unwrap_or(&hosts[0]);
        let (launcher_pid, victim_dir) = (victim_host.pid, victim_host.dir.clone());
        let Some(pid) = find_victim(proc_root, launcher_pid, &victim_dir, plan.victim) else {
            if t - due > VICTIM_WAIT_SECS {
                eprintln!(
                    "soak: [{t:.1} s] no {} process for {VICTIM_WAIT_SECS} s: kill skipped",
                    plan.victim.process()
                );
                skipped.push(plan);
                next += 1;
            }
            continue;
        };
        let incarnation = match plan.victim {
            Victim::Actor(k) => read_stats::<ActorStats>(&RunDir::new(&actor_dir), &stats::actor_live(k))
                .filter(|v| v.pid as u64 == pid as u64)
                .map(|v| v.incarnation as u64),
            _ => None,
        };
        match sigkill_verified(pid, || is_victim(proc_root, pid, launcher_pid, &victim_dir, plan.victim)) {
            Ok(()) => {
                let at = now();
                eprintln!(
                    "soak: [{at:.1} s] SIGKILL {} (pid {pid}) at env steps {}, updates {}",
                    plan.victim.process(),
                    before.map_or(0, |s| s.env_steps),
                    before.map_or(0, |s| s.updates)
                );
                kills.push(KillRecord { plan, at, pid, before, incarnation });
                next += 1;
            }
            Err(e) => eprintln!("soak: [{t:.1} s] {} not killed, retrying: {e:#}", plan.victim.process()),
        }
    }
    let stopped_at = now();
    // The actor host first (its actors stop, its bridge hands on what they sent), then
    // the learner host (the learner drains and writes its final checkpoint).
    let mut exits = Vec::new();
    for h in hosts.iter_mut().rev() {
        exits.push((h.host, h.stop(now())?));
    }
    exits.reverse();
    // The restarts each launcher recorded after the last poll.
    for h in hosts {
        let _ = h.reader.join();
        take_restarts(&RunDir::new(&h.dir), h.host, across_hosts, started_unix, &log);
    }
    let end = now();
    obs.poll(end);
    let log = std::mem::take(&mut *log.lock().unwrap());

    let report = Report {
        cfg: &cfg,
        config: &config,
        seed,
        actors,
        minutes,
        mean,
        across_hosts,
        link_cut_secs,
        run_dir: &run_dir,
        learner_dir: &learner_dir,
        actor_dir: &actor_dir,
        schedule: &schedule,
        kills: &kills,
        skipped: &skipped,
        obs: &obs,
        log: &log,
        training_started,
        stopped_at,
        end,
        exits: &exits,
        early: early_exit,
        interrupted: stop.is_set(),
    };
    let (markdown, json, failures) = report.build();
    println!("{markdown}");
    let json_path = run_dir.join("soak.json");
    std::fs::write(&json_path, serde_json::to_string_pretty(&json)?)?;
    if failures.is_empty() && !given {
        std::fs::remove_dir_all(&run_dir)?;
        eprintln!("soak: passed; the temporary run directory was removed (pass --run-dir to keep one)");
    } else {
        eprintln!("soak: run directory kept: {} (report: {})", run_dir.display(), json_path.display());
    }
    if !failures.is_empty() {
        bail!("the soak failed:\n- {}", failures.join("\n- "));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::accounting::Verdict;
    use super::schedule::recovery_secs;
    use super::*;

    fn kinds(s: &[PlannedKill]) -> Vec<&'static str> {
        s.iter().map(|k| k.victim.kind()).collect()
    }

    /// The same seed gives the same schedule, another seed another one; every kind
    /// is killed, intervals lie in [0.5, 1.5] × the mean, the end is left for
    /// recovery, no kind is killed twice in a row, and no process is killed often
    /// enough to spend its restart budget — for the default soak and the short one.
    #[test]
    fn the_kill_schedule_is_seeded_covers_every_kind_and_keeps_its_intervals() {
        let a = kill_schedule(1, 1800.0, 120.0, 2, false).unwrap();
        assert_eq!(a, kill_schedule(1, 1800.0, 120.0, 2, false).unwrap());
        assert_ne!(a, kill_schedule(2, 1800.0, 120.0, 2, false).unwrap());
        // One host: the three kinds only. Across hosts: the bridges and the link too.
        assert!(a.iter().all(|k| k.victim.is_process() && victim_kinds(false).contains(&k.victim.kind())));
        for (duration, mean, actors, across) in [
            (1800.0, 120.0, 2, false),
            (1800.0, 120.0, 5, false),
            (180.0, 40.0, 2, false),
            (1800.0, 120.0, 2, true),
            (720.0, 60.0, 2, true),
        ] {
            let mut actors_hit = std::collections::BTreeSet::new();
            let mut refused = 0;
            for seed in 0..200 {
                let Ok(s) = kill_schedule(seed, duration, mean, actors, across) else {
                    refused += 1;
                    continue;
                };
                for kind in victim_kinds(across) {
                    assert!(kinds(&s).contains(kind), "seed {seed}: no {kind} in {s:?}");
                }
                let mut t = 0.0;
                for k in &s {
                    let dt = k.at_secs - t;
                    assert!((0.5 * mean..=1.5 * mean).contains(&dt), "seed {seed}: interval {dt}");
                    t = k.at_secs;
                    if let Victim::Actor(i) = k.victim {
                        assert!(i < actors);
                        actors_hit.insert(i);
                    }
                }
                assert!(t <= duration - recovery_secs(mean));
                for w in s.windows(2) {
                    assert_ne!(w[0].victim.kind(), w[1].victim.kind(), "seed {seed}: the same kind twice in a row");
                }
                for k in &s {
                    let n = s
                        .iter()
                        .filter(|b| b.victim == k.victim && (0.0..120.0).contains(&(b.at_secs - k.at_secs)))
                        .count();
                    assert!(n <= MAX_PLANNED_KILLS_PER_WINDOW);
                }
            }
            assert_eq!(actors_hit.len() as u32, actors, "every actor is drawn by some seed");
            if duration >= 720.0 {
                assert_eq!(refused, 0, "{duration} s, mean {mean} s, across hosts {across}");
            } else {
                assert!(refused < 40, "{refused} of 200 short schedules refused");
            }
        }
        // The short validation soak of the README covers every kind with seed 1.
        assert!(kill_schedule(1, 180.0, 40.0, 2, false).is_ok());
    }

    /// Schedules that cannot kill every kind, or could spend a restart budget, are refused.
    #[test]
    fn a_schedule_that_cannot_do_its_job_is_refused() {
        let e = kill_schedule(1, 60.0, 120.0, 2, false).unwrap_err().to_string();
        assert!(e.contains("too few to kill"), "{e}");
        // Across hosts six kinds need more room than three.
        let e = kill_schedule(1, 300.0, 120.0, 2, true).unwrap_err().to_string();
        assert!(e.contains("too few to kill") && e.contains("link"), "{e}");
        let e = kill_schedule(1, 1800.0, 5.0, 1, false).unwrap_err().to_string();
        assert!(e.contains("restart budget"), "{e}");
        assert!(kill_schedule(1, 1800.0, 0.0, 2, false).is_err());
        assert!(kill_schedule(1, 1800.0, 120.0, 0, false).is_err());
    }

    fn fake_proc(root: &Path, pid: u32, ppid: u32, state: &str, args: &[&str]) {
        let d = root.join(pid.to_string());
        std::fs::create_dir_all(&d).unwrap();
        let mut cmdline = Vec::new();
        for a in args {
            cmdline.extend_from_slice(a.as_bytes());
            cmdline.push(0);
        }
        std::fs::write(d.join("cmdline"), cmdline).unwrap();
        std::fs::write(
            d.join("status"),
            format!("Name:\tx\nState:\t{state}\nTgid:\t{pid}\nPid:\t{pid}\nPPid:\t{ppid}\n"),
        )
        .unwrap();
    }

    /// Only this run's processes, children of its launcher, with its exact run
    /// directory, are victims: not another run's (a relative path to the same
    /// folder name, a longer path sharing the prefix, another launcher's child), not
    /// a zombie, not the other actor; two candidates give none.
    #[test]
    fn victims_are_found_only_in_this_run() {
        let root = std::env::temp_dir().join(format!("pednav-soak-proc-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let run = Path::new("/tmp/pednav-soak-s1-99");
        let (me, other) = (500, 600);
        let bin = "/tmp/pednav-soak-s1-99/bin/";
        fake_proc(&root, me, 1, "S (sleeping)", &["/x/pednav-run", "launch", "--run-dir", "/tmp/pednav-soak-s1-99"]);
        fake_proc(
            &root,
            501,
            me,
            "S (sleeping)",
            &[&format!("{bin}pednav-curriculum"), "serve", "--run-dir", "/tmp/pednav-soak-s1-99"],
        );
        fake_proc(
            &root,
            502,
            me,
            "R (running)",
            &[&format!("{bin}pednav-learner"), "--run-dir", "/tmp/pednav-soak-s1-99", "--device", "cpu"],
        );
        fake_proc(
            &root,
            503,
            me,
            "S (sleeping)",
            &[&format!("{bin}pednav-actor"), "--run-dir", "/tmp/pednav-soak-s1-99", "--actor", "0", "--device", "cpu"],
        );
        fake_proc(
            &root,
            504,
            me,
            "Z (zombie)",
            &[&format!("{bin}pednav-actor"), "--run-dir", "/tmp/pednav-soak-s1-99", "--actor", "1"],
        );
        // Another run on the machine: same binaries, other launcher, similar directories.
        fake_proc(
            &root,
            601,
            other,
            "R (running)",
            &["runs/bin889/pednav-learner", "--run-dir", "runs/navacl-s1", "--device", "cpu"],
        );
        fake_proc(
            &root,
            602,
            other,
            "R (running)",
            &["/w/pednav-actor", "--run-dir", "/tmp/pednav-soak-s1-99", "--actor", "1"],
        );
        fake_proc(
            &root,
            603,
            me,
            "R (running)",
            &["/w/pednav-actor", "--run-dir", "/tmp/pednav-soak-s1-999", "--actor", "1"],
        );
        fake_proc(
            &root,
            604,
            me,
            "R (running)",
            &["/w/not-pednav-actor", "--run-dir", "/tmp/pednav-soak-s1-99", "--actor", "1"],
        );
        // A bridge of this run (`pednav-run bridge`), and the launcher itself, which runs
        // the same binary with the same run directory but is no child of itself.
        fake_proc(
            &root,
            506,
            me,
            "S (sleeping)",
            &[&format!("{bin}pednav-run"), "bridge", "--run-dir", "/tmp/pednav-soak-s1-99", "--listen", "tcp/x"],
        );
        std::fs::create_dir_all(root.join("self")).unwrap();
        assert_eq!(find_victim(&root, me, run, Victim::Curriculum), Some(501));
        assert_eq!(find_victim(&root, me, run, Victim::Learner), Some(502));
        assert_eq!(find_victim(&root, me, run, Victim::Actor(0)), Some(503));
        assert_eq!(find_victim(&root, me, run, Victim::LearnerHostBridge), Some(506));
        assert!(!is_victim(&root, me, 1, run, Victim::LearnerHostBridge), "the launcher is not its bridge");
        assert_eq!(find_victim(&root, me, run, Victim::Link), None, "the link is no process");
        assert_eq!(
            find_victim(&root, me, run, Victim::Actor(1)),
            None,
            "zombie, other launcher, other dir, other binary"
        );
        assert_eq!(find_victim(&root, other, Path::new("runs/navacl-s1"), Victim::Learner), Some(601));
        assert!(!is_victim(&root, 502, me, Path::new("/tmp/pednav-soak-s1-9"), Victim::Learner));
        // Two candidates: nothing is killed on doubt.
        fake_proc(
            &root,
            505,
            me,
            "R (running)",
            &[&format!("{bin}pednav-learner"), "--run-dir", "/tmp/pednav-soak-s1-99"],
        );
        assert_eq!(find_victim(&root, me, run, Victim::Learner), None);
        std::fs::remove_dir_all(&root).unwrap();
    }

    /// The accounting of one stream, case by case.
    #[test]
    fn streams_are_accounted_as_the_end_to_end_test_does() {
        let sent = |steps, checksum, exact| Some(Sent { steps, checksum, exact });
        let rec = |first, records, checksum| Received { first: Some(first), records, checksum, jumped: Vec::new() };
        // Whole, over one learner or split over two (checksums add, wrapping).
        assert_eq!(account(sent(100, 7, true), &[rec(0, 100, 7)], None), Verdict::Whole);
        assert_eq!(account(sent(100, 7, true), &[rec(0, 60, u32::MAX), rec(60, 40, 8)], Some(30)), Verdict::Whole);
        assert_eq!(account(sent(100, 7, true), &[rec(0, 100, 8)], None), Verdict::ChecksumMismatch);
        // A restarted learner sent again what the killed one took unacknowledged: whole,
        // with the overlap counted (its checksums cannot be compared).
        assert_eq!(account(sent(100, 7, true), &[rec(0, 70, 1), rec(55, 45, 2)], Some(0)), Verdict::WholeResent(15));
        // Missing records: lost, unless the stream crossed a learner restart and no
        // more are missing than the killed learner could have taken and acknowledged.
        assert_eq!(account(sent(100, 7, true), &[rec(0, 90, 1)], None), Verdict::Lost(10));
        assert_eq!(
            account(sent(100, 7, true), &[rec(0, 50, 1), rec(70, 30, 2)], Some(20)),
            Verdict::DiedWithLearner(20)
        );
        assert_eq!(account(sent(100, 7, true), &[rec(0, 50, 1), rec(70, 30, 2)], Some(15)), Verdict::Lost(5));
        assert_eq!(account(sent(100, 7, true), &[rec(10, 90, 1)], None), Verdict::Lost(10), "a missing beginning");
        assert_eq!(account(sent(100, 7, true), &[rec(0, 101, 7)], None), Verdict::Excess(1));
        assert_eq!(
            account(
                sent(100, 7, true),
                &[Received { first: None, records: 0, checksum: 0, jumped: Vec::new() }, rec(0, 100, 7)],
                None
            ),
            Verdict::Whole,
            "a learner that took nothing of the stream adds nothing"
        );
        // A killed sender: at least what it last reported must have arrived.
        assert_eq!(account(sent(100, 7, false), &[rec(0, 130, 9)], None), Verdict::SenderKilled);
        assert_eq!(account(sent(100, 7, false), &[rec(0, 90, 9)], None), Verdict::Lost(10));
        assert_eq!(account(sent(100, 7, false), &[rec(0, 90, 9)], Some(10)), Verdict::DiedWithLearnerAtLeast(10));
        assert_eq!(account(None, &[rec(0, 5, 1)], None), Verdict::Unknown);
        // Across hosts a learner can jump over records its predecessor took (its last ack
        // arrived late): its records are not one run. The predecessor took 0 .. 50, the
        // replacement 30 .. 45 (sent again), jumped over 45 .. 50, then took 50 .. 100:
        // whole, 15 twice. Read as one run (30 .. 95) it would miss 95 .. 100.
        let jumper = Received { first: Some(30), records: 65, checksum: 2, jumped: vec![[45, 50]] };
        assert_eq!(jumper.spans(), vec![(30, 45), (50, 100)]);
        assert_eq!(account(sent(100, 7, true), &[rec(0, 50, 1), jumper.clone()], Some(0)), Verdict::WholeResent(15));
        // The predecessor's stats stopped at 40: 40 .. 45 came again, 45 .. 50 died with it.
        assert_eq!(account(sent(100, 7, true), &[rec(0, 40, 1), jumper], Some(10)), Verdict::DiedWithLearner(5));
        // A killed learner's allowance: 1.5 × its intake since its last stats write (and
        // one poll); its queue is sent again, so it is no part of it.
        assert_eq!(died_allowance(0.0, 0.5), 0);
        assert_eq!(died_allowance(200.0, 0.75), 300);
        assert!(Verdict::Lost(1).failed() && !Verdict::DiedWithLearner(5).failed() && !Verdict::SenderKilled.failed());
        assert!(!Verdict::WholeResent(3).failed());
    }
}
