//! `pednav-run bench soak`: a long run (the smoke config, 30 minutes by default;
//! not in CI) whose learner, curriculum service and actors are SIGKILLed at seeded
//! random times. It reports what the launcher restarted, whether training went on
//! after every kill, and whether any step an actor sent went missing at the learner.
//!
//! - **Schedule** ([`kill_schedule`]): one ChaCha8 RNG seeded with `--seed` draws the
//!   whole schedule before the run starts — intervals uniform in [0.5, 1.5] × the mean,
//!   victims in shuffled rounds over the three kinds (learner, curriculum service, an
//!   actor drawn among `--actors`), never the same kind twice in a row — so every kind
//!   is killed at least once. The last [`recovery_secs`] of the run have no kill (time
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
//!   `stats/learner.json`: records, CRC-32 sum, sequence gaps; the final learner's
//!   exact, a killed learner's as last written). A stream that did not cross a learner
//!   restart must arrive whole — count and checksum equal, no gaps — and anything
//!   missing is **lost on the learner's side** (must be 0). A stream that crossed one
//!   may miss what died with that learner: the records it took after its last stats
//!   write (into the replay, which is not checkpointed) and those waiting in its
//!   intake queue (`runtime.step_buffer` per actor) — the loss the README documents
//!   for a learner restart (it resumes from its last checkpoint with an empty replay
//!   and refills `dsac.warmup` steps before updating again). That is allowed up to
//!   [`died_allowance`] per killed learner (the queue, plus 1.5 × the learner's intake
//!   rate over the time since its last stats write); anything beyond counts as lost.
//!   The report gives it separately, with each learner restart's rollback to its
//!   checkpoint.
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
use pednav_runtime::ipc::STEP_ROUND_PER_ACTOR;
use pednav_runtime::stats::{self, ActorStats, LearnerStats};
use pednav_runtime::{RunConfig, RunDir, StopFlag};
use rand_chacha::ChaCha8Rng;
use rand_chacha::rand_core::{RngCore, SeedableRng};
use serde_json::{Value, json};

/// The supervisor's restart budget: a process that dies more than this many times
/// within [`SUPERVISOR_RESTART_WINDOW_SECS`] ends the run.
const SUPERVISOR_MAX_RESTARTS: usize = crate::supervisor::MAX_RESTARTS;
/// The window of [`SUPERVISOR_MAX_RESTARTS`], in seconds.
const SUPERVISOR_RESTART_WINDOW_SECS: f64 = crate::supervisor::RESTART_WINDOW.as_secs_f64();
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
}

/// A process the soak kills.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Victim {
    /// The learner.
    Learner,
    /// The curriculum service.
    Curriculum,
    /// Actor K.
    Actor(u32),
}

impl Victim {
    /// Its kind: `learner`, `curriculum` or `actor`.
    pub fn kind(self) -> &'static str {
        match self {
            Victim::Learner => "learner",
            Victim::Curriculum => "curriculum",
            Victim::Actor(_) => "actor",
        }
    }

    /// The supervisor's name of the process (its log's name, its restart lines').
    pub fn process(self) -> String {
        match self {
            Victim::Actor(k) => format!("actor-{k}"),
            v => v.kind().to_string(),
        }
    }

    /// Its binary's file name.
    pub fn binary(self) -> &'static str {
        match self {
            Victim::Learner => "pednav-learner",
            Victim::Curriculum => "pednav-curriculum",
            Victim::Actor(_) => "pednav-actor",
        }
    }
}

/// One kill of the schedule.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlannedKill {
    /// Seconds after the launch.
    pub at_secs: f64,
    /// Who.
    pub victim: Victim,
}

/// The kill-free time at the end of a run with kills `mean_secs` apart on average.
pub fn recovery_secs(mean_secs: f64) -> f64 {
    (0.5 * mean_secs).max(MIN_RECOVERY_SECS)
}

/// Uniform in [0, 1).
fn unit(rng: &mut ChaCha8Rng) -> f64 {
    (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64
}

/// The kills of a `duration_secs` run with `actors` actors, drawn by one ChaCha8 RNG
/// seeded with `seed` (see the module doc); an error when the schedule cannot kill
/// every kind or could spend a process's restart budget.
pub fn kill_schedule(seed: u64, duration_secs: f64, mean_secs: f64, actors: u32) -> Result<Vec<PlannedKill>> {
    if !(mean_secs.is_finite() && mean_secs > 0.0) {
        bail!("--mean-kill-interval-secs must be a positive number of seconds, got {mean_secs}");
    }
    if !(duration_secs.is_finite() && duration_secs > 0.0) {
        bail!("--minutes must be positive, got {}", duration_secs / 60.0);
    }
    if actors == 0 || actors as usize > pednav_runtime::ipc::MAX_ACTORS {
        bail!("--actors must be 1 … {}, got {actors}", pednav_runtime::ipc::MAX_ACTORS);
    }
    let last = duration_secs - recovery_secs(mean_secs);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (mut t, mut kills, mut round) = (0.0, Vec::<PlannedKill>::new(), Vec::<u8>::new());
    loop {
        t += mean_secs * (0.5 + unit(&mut rng));
        if t > last {
            break;
        }
        if round.is_empty() {
            // A new round: the three kinds in a shuffled order (Fisher–Yates), taken from the end.
            round = vec![0, 1, 2];
            for i in (1..round.len()).rev() {
                let j = ((unit(&mut rng) * (i + 1) as f64) as usize).min(i);
                round.swap(i, j);
            }
            let previous = kills.last().map(|k| k.victim.kind());
            if previous.is_some() && previous == round.last().map(|&r| kind_name(r)) {
                let n = round.len();
                round.swap(0, n - 1);
            }
        }
        let victim = match round.pop().expect("a round is refilled when empty") {
            0 => Victim::Learner,
            1 => Victim::Curriculum,
            _ => Victim::Actor(((unit(&mut rng) * actors as f64) as u32).min(actors - 1)),
        };
        kills.push(PlannedKill { at_secs: t, victim });
    }
    if ["learner", "curriculum", "actor"].iter().any(|kind| !kills.iter().any(|k| k.victim.kind() == *kind)) {
        bail!(
            "seed {seed}: only {} kill(s) fit in {:.1} min at a mean interval of {mean_secs} s (the last {:.0} s are \
             left for recovery) — too few to kill the learner, the curriculum service and an actor each at least \
             once: raise --minutes, lower --mean-kill-interval-secs or try another --seed",
            kills.len(),
            duration_secs / 60.0,
            recovery_secs(mean_secs)
        );
    }
    for (i, a) in kills.iter().enumerate() {
        let n = kills[i..]
            .iter()
            .filter(|b| b.victim == a.victim && b.at_secs - a.at_secs < SUPERVISOR_RESTART_WINDOW_SECS)
            .count();
        if n > MAX_PLANNED_KILLS_PER_WINDOW {
            bail!(
                "seed {seed}: {n} kills of {} within {SUPERVISOR_RESTART_WINDOW_SECS} s would come close to the \
                 launcher's restart budget ({} deaths within {SUPERVISOR_RESTART_WINDOW_SECS} s end a run): raise \
                 --mean-kill-interval-secs",
                a.victim.process(),
                SUPERVISOR_MAX_RESTARTS + 1
            );
        }
    }
    Ok(kills)
}

fn kind_name(r: u8) -> &'static str {
    match r {
        0 => "learner",
        1 => "curriculum",
        _ => "actor",
    }
}

/// Whether `pid` in the /proc-like folder `proc_root` is `victim` of the run in
/// `run_dir`: a live child of `launcher` running the victim's binary with
/// `--run-dir run_dir` exactly (and `--actor K` for actor K).
pub fn is_victim(proc_root: &Path, pid: u32, launcher: u32, run_dir: &Path, victim: Victim) -> bool {
    let dir = proc_root.join(pid.to_string());
    let (Ok(cmdline), Ok(status)) = (std::fs::read(dir.join("cmdline")), std::fs::read_to_string(dir.join("status")))
    else {
        return false;
    };
    let field = |name: &str| status.lines().find_map(|l| l.strip_prefix(name)?.strip_prefix(':').map(str::trim));
    if field("PPid").and_then(|p| p.parse::<u32>().ok()) != Some(launcher)
        || field("State").is_none_or(|s| s.starts_with('Z') || s.starts_with('X'))
    {
        return false;
    }
    let args: Vec<&[u8]> = cmdline.strip_suffix(&[0]).unwrap_or(&cmdline).split(|&b| b == 0).collect();
    let after = |flag: &str| args.iter().position(|a| *a == flag.as_bytes()).and_then(|i| args.get(i + 1).copied());
    let binary = args.first().and_then(|a| Path::new(OsStr::from_bytes(a)).file_name());
    binary == Some(OsStr::new(victim.binary()))
        && after("--run-dir") == Some(run_dir.as_os_str().as_bytes())
        && match victim {
            Victim::Actor(k) => after("--actor") == Some(k.to_string().as_bytes()),
            Victim::Learner | Victim::Curriculum => true,
        }
}

/// The pid of `victim` in the run at `run_dir` supervised by `launcher`, from the
/// /proc-like folder `proc_root` ([`is_victim`]); `None` when there is none, or more
/// than one (nothing is killed on doubt).
pub fn find_victim(proc_root: &Path, launcher: u32, run_dir: &Path, victim: Victim) -> Option<u32> {
    let mut found = None;
    for entry in std::fs::read_dir(proc_root).ok()?.flatten() {
        let Some(pid) = entry.file_name().to_str().and_then(|s| s.parse::<u32>().ok()) else { continue };
        if is_victim(proc_root, pid, launcher, run_dir, victim) {
            if found.is_some() {
                return None;
            }
            found = Some(pid);
        }
    }
    found
}

/// SIGKILL `pid` through a pidfd, after `still_victim` confirmed (with the pidfd
/// open, so the pid cannot be reused in between) that it is still the victim.
fn sigkill_verified(pid: u32, still_victim: impl Fn() -> bool) -> Result<()> {
    // SAFETY: pidfd_open(2) takes a pid and flags and returns a new descriptor or -1.
    let fd = unsafe { libc::syscall(libc::SYS_pidfd_open, pid as libc::pid_t, 0 as libc::c_uint) };
    if fd < 0 {
        bail!("pidfd_open({pid}): {}", std::io::Error::last_os_error());
    }
    // SAFETY: `fd` is a descriptor we own from here on.
    let fd = unsafe { OwnedFd::from_raw_fd(fd as libc::c_int) };
    if !still_victim() {
        bail!("pid {pid} is no longer the victim");
    }
    // SAFETY: pidfd_send_signal(2) on our pidfd, no siginfo, flags 0.
    let r = unsafe {
        libc::syscall(
            libc::SYS_pidfd_send_signal,
            std::os::fd::AsRawFd::as_raw_fd(&fd),
            libc::SIGKILL,
            std::ptr::null::<libc::siginfo_t>(),
            0 as libc::c_uint,
        )
    };
    if r < 0 {
        bail!("pidfd_send_signal({pid}, SIGKILL): {}", std::io::Error::last_os_error());
    }
    Ok(())
}

/// A restart the launcher announced.
#[derive(Clone, Debug, PartialEq)]
pub struct Restart {
    /// Seconds after the launch the line arrived.
    pub at: f64,
    /// The supervisor's process name (`learner`, `curriculum`, `actor-K`).
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

/// Take the restarts the launcher recorded since the last look (`restarts.jsonl`,
/// [`pednav_runtime::RestartRecord`]) into the log, timed from the soak's start.
fn take_restarts(dir: &RunDir, started_unix: f64, log: &Mutex<LauncherLog>) {
    let records = dir.read_restarts();
    let mut l = log.lock().unwrap();
    let seen = l.restarts.len();
    for r in records.into_iter().skip(seen) {
        l.restarts.push(Restart {
            at: r.unix_time - started_unix,
            process: r.process,
            status: r.status,
            number: r.restart,
        });
    }
}

/// What the launcher's stderr told.
#[derive(Default)]
struct LauncherLog {
    restarts: Vec<Restart>,
    /// The `restarts N` of its last progress line.
    progress_restarts: Option<u32>,
    lines: Vec<String>,
}

/// One read of the learner's `metrics/learner.csv`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Sample {
    /// Seconds after the launch it was read.
    t: f64,
    env_steps: u64,
    updates: u64,
}

/// One distinct `stats/learner.json` as read.
#[derive(Clone, Copy, Debug)]
struct LearnerPoint {
    t: f64,
    pid: u64,
    updates: u64,
    env_steps: u64,
    resumed_from: Option<u64>,
    /// `received_total` the process resumed with (its checkpoint's).
    resumed_env_steps: u64,
}

/// The run's stats and metrics as polled.
struct Observer {
    dir: RunDir,
    actors: u32,
    csv_pos: u64,
    csv_pending: Vec<u8>,
    columns: Option<(usize, usize)>,
    samples: Vec<Sample>,
    points: Vec<LearnerPoint>,
    /// The last `stats/learner.json` of each learner process (by pid).
    learners: BTreeMap<u64, LearnerStats>,
    /// The last `actor-K.live.json` of each (actor, incarnation), and when it was first seen sending.
    actors_live: BTreeMap<(u64, u64), (ActorStats, Option<f64>)>,
}

/// A stats file as its writer's type; `None` while it does not exist, or (with a
/// warning) when it does not parse — the soak goes on and its report shows the gap.
fn read_stats<T: serde::de::DeserializeOwned>(dir: &RunDir, name: &str) -> Option<T> {
    dir.read_stats(name).unwrap_or_else(|e| {
        tracing::warn!("{e}");
        None
    })
}

impl Observer {
    fn new(dir: RunDir, actors: u32) -> Observer {
        Observer {
            dir,
            actors,
            csv_pos: 0,
            csv_pending: Vec::new(),
            columns: None,
            samples: Vec::new(),
            points: Vec::new(),
            learners: BTreeMap::new(),
            actors_live: BTreeMap::new(),
        }
    }

    fn poll(&mut self, t: f64) {
        self.read_csv(t);
        if let Some(v) = read_stats::<LearnerStats>(&self.dir, "learner") {
            let pid = v.pid as u64;
            let point = LearnerPoint {
                t,
                pid,
                updates: v.updates,
                env_steps: v.received_total,
                resumed_from: v.resumed_from_update,
                resumed_env_steps: v.received_total.saturating_sub(v.received_this_process),
            };
            if self
                .points
                .last()
                .is_none_or(|p| (p.pid, p.updates, p.env_steps) != (pid, point.updates, point.env_steps))
            {
                self.points.push(point);
            }
            self.learners.insert(pid, v);
        }
        for k in 0..self.actors {
            if let Some(v) = read_stats::<ActorStats>(&self.dir, &stats::actor_live(k)) {
                let key = (v.actor as u64, v.incarnation as u64);
                let sending = v.steps_sent > 0;
                let entry = self.actors_live.entry(key).or_insert((v.clone(), None));
                if sending && entry.1.is_none() {
                    entry.1 = Some(t);
                }
                entry.0 = v;
            }
        }
    }

    /// Take the complete rows appended to `metrics/learner.csv` since the last read.
    fn read_csv(&mut self, t: f64) {
        let Ok(mut f) = std::fs::File::open(self.dir.metrics_csv("learner")) else { return };
        let mut buf = Vec::new();
        if f.seek(SeekFrom::Start(self.csv_pos)).is_err() || f.read_to_end(&mut buf).is_err() {
            return;
        }
        self.csv_pos += buf.len() as u64;
        self.csv_pending.extend_from_slice(&buf);
        while let Some(i) = self.csv_pending.iter().position(|&b| b == b'\n') {
            let line: Vec<u8> = self.csv_pending.drain(..=i).collect();
            let line = String::from_utf8_lossy(&line);
            let cells: Vec<&str> = line.trim_end().split(',').collect();
            match self.columns {
                None => {
                    let col = |name: &str| cells.iter().position(|c| *c == name);
                    self.columns = col("step").zip(col("updates"));
                }
                Some((s, u)) => {
                    let value = |i: usize| cells.get(i).and_then(|c| c.parse::<f64>().ok());
                    // A row cut short by a kill, continued by the next process, does not parse: skipped.
                    if let (Some(env_steps), Some(updates)) = (value(s), value(u))
                        && cells.len() > s.max(u)
                    {
                        self.samples.push(Sample { t, env_steps: env_steps as u64, updates: updates as u64 });
                    }
                }
            }
        }
    }

    fn last_sample(&self) -> Option<Sample> {
        self.samples.last().copied()
    }
}

/// What one actor incarnation sent, from its stats.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sent {
    /// `steps_sent`.
    pub steps: u64,
    /// The CRC-32 sum of its records.
    pub checksum: u32,
    /// From its final stats (a clean stop); otherwise its last live stats (it was
    /// killed: a lower bound, with a checksum of that many records).
    pub exact: bool,
}

/// One learner process's count of one stream.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Received {
    /// Records it took.
    pub records: u64,
    /// The CRC-32 sum of those records.
    pub checksum: u32,
    /// Sequence gaps it saw.
    pub gaps: u64,
}

/// The accounting of one actor incarnation's stream.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Verdict {
    /// Everything sent arrived: count and checksum equal, no gaps.
    Whole,
    /// The sender was killed: at least everything it last reported sending arrived
    /// (what it sent after that report is not known).
    SenderKilled,
    /// The stream crossed a learner restart and this many records died with the
    /// killed learner (taken after its last stats write, or in its queue).
    DiedWithLearner(u64),
    /// As [`Verdict::DiedWithLearner`], for a killed sender: at least this many (what
    /// it sent after its last report is not known).
    DiedWithLearnerAtLeast(u64),
    /// Records missing at the learner that no learner restart explains (beyond what
    /// the killed learners could have held).
    Lost(u64),
    /// As many records arrived as were sent, with another checksum.
    ChecksumMismatch,
    /// More records counted than sent.
    Excess(u64),
    /// A learner saw sequence gaps inside the stream.
    Gaps(u64),
    /// No stats of the sender.
    Unknown,
}

impl Verdict {
    /// Records lost on the learner's side (beyond what died with a killed learner).
    pub fn lost(self) -> u64 {
        match self {
            Verdict::Lost(n) => n,
            _ => 0,
        }
    }

    /// Records that died with a killed learner (the documented loss).
    pub fn died_with_learner(self) -> u64 {
        match self {
            Verdict::DiedWithLearner(n) | Verdict::DiedWithLearnerAtLeast(n) => n,
            _ => 0,
        }
    }

    /// Whether this is a failure of the soak.
    pub fn failed(self) -> bool {
        matches!(self, Verdict::Lost(_) | Verdict::ChecksumMismatch | Verdict::Excess(_) | Verdict::Gaps(_))
    }

    fn text(self) -> String {
        match self {
            Verdict::Whole => "0 — whole (count and checksum)".into(),
            Verdict::SenderKilled => "0 — sender killed: all it last reported arrived".into(),
            Verdict::DiedWithLearner(n) => format!("{n} died with the killed learner"),
            Verdict::DiedWithLearnerAtLeast(n) => format!("≥ {n} died with the killed learner (sender killed)"),
            Verdict::Lost(n) => format!("**{n} LOST**"),
            Verdict::ChecksumMismatch => "**checksum mismatch**".into(),
            Verdict::Excess(n) => format!("**{n} more counted than sent**"),
            Verdict::Gaps(n) => format!("**{n} sequence gaps**"),
            Verdict::Unknown => "? (no sender stats)".into(),
        }
    }
}

/// What one killed learner may take with it from one actor's stream: its intake queue
/// (`step_buffer` records, plus a round's [`STEP_ROUND_PER_ACTOR`]) and what it could
/// take after its last stats write — 1.5 × its intake rate (all actors') × the time
/// since that write as polled, plus one poll interval.
pub fn died_allowance(step_buffer: u64, intake_per_s: f64, stats_age_s: f64) -> u64 {
    step_buffer + STEP_ROUND_PER_ACTOR as u64 + (1.5 * intake_per_s * (stats_age_s + POLL.as_secs_f64())).ceil() as u64
}

/// The intake rate (env steps/s) of learner `pid` over its last ≥ 3 s of stats before
/// `at`, and how long before `at` its stats last changed.
fn intake_before(points: &[LearnerPoint], pid: u64, at: f64) -> Option<(f64, f64)> {
    let mine: Vec<&LearnerPoint> = points.iter().filter(|p| p.pid == pid && p.t <= at).collect();
    let last = *mine.last()?;
    let prev = mine.iter().rev().find(|p| p.t <= last.t - 3.0).or(mine.first())?;
    (last.t - prev.t >= 0.5)
        .then(|| ((last.env_steps.saturating_sub(prev.env_steps)) as f64 / (last.t - prev.t), at - last.t))
}

/// The verdict on one stream: `sent` by the actor incarnation, `received` by each
/// learner process that counted it; `died_allowance` is `None` when the stream crossed
/// no learner restart, else how many of its records may have died with the killed
/// learners ([`died_allowance`], summed over the restarts it crossed).
pub fn account(sent: Option<Sent>, received: &[Received], died_allowance: Option<u64>) -> Verdict {
    let gaps: u64 = received.iter().map(|r| r.gaps).sum();
    if gaps > 0 {
        return Verdict::Gaps(gaps);
    }
    let records: u64 = received.iter().map(|r| r.records).sum();
    let checksum = received.iter().fold(0u32, |c, r| c.wrapping_add(r.checksum));
    let Some(sent) = sent else { return Verdict::Unknown };
    if records > sent.steps && sent.exact {
        return Verdict::Excess(records - sent.steps);
    }
    if records >= sent.steps {
        return match (sent.exact, checksum == sent.checksum) {
            (true, true) => Verdict::Whole,
            (true, false) => Verdict::ChecksumMismatch,
            (false, _) => Verdict::SenderKilled,
        };
    }
    let missing = sent.steps - records;
    match died_allowance {
        Some(a) if missing <= a && sent.exact => Verdict::DiedWithLearner(missing),
        Some(a) if missing <= a => Verdict::DiedWithLearnerAtLeast(missing),
        Some(a) => Verdict::Lost(missing - a),
        None => Verdict::Lost(missing),
    }
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
    let exe = std::env::current_exe().context("locating pednav-run")?;
    let from = exe.parent().context("pednav-run has no folder")?;
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
    let Soak { minutes, seed, actors, config, run_dir, mean_kill_interval_secs: mean } = args;
    let duration = minutes * 60.0;
    let schedule = kill_schedule(seed, duration, mean, actors)?;
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
    eprintln!(
        "soak: {minutes} min, seed {seed}, {actors} actor(s), {}, run directory {}\nsoak: schedule (s after the \
         launch; the first kill waits for the learner's first update): {}",
        config.display(),
        run_dir.display(),
        schedule.iter().map(|k| format!("{:.1} {}", k.at_secs, k.victim.process())).collect::<Vec<_>>().join(", ")
    );

    let stop = StopFlag::install();
    let start = Instant::now();
    let started_unix = unix_now();
    let now = move || start.elapsed().as_secs_f64();
    let mut cmd = Command::new(bin.join("pednav-run"));
    cmd.arg("launch")
        .args(["--actors", &actors.to_string()])
        .arg("--config")
        .arg(&config)
        .arg("--run-dir")
        .arg(&run_dir)
        .arg("--bin-dir")
        .arg(&bin)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    // SAFETY: only async-signal-safe calls between fork and exec. The launcher stops
    // its run when this soak dies.
    unsafe {
        cmd.pre_exec(|| {
            libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGINT);
            Ok(())
        });
    }
    let mut launcher = cmd.spawn().context("starting pednav-run launch")?;
    let launcher_pid = launcher.id();
    let log = Arc::new(Mutex::new(LauncherLog::default()));
    let reader = {
        let (log, stderr) = (log.clone(), launcher.stderr.take().expect("piped"));
        let mut file = std::fs::File::create(run_dir.join("soak-launcher.log"))?;
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(std::io::Result::ok) {
                let _ = writeln!(file, "{line}");
                if line.trim().is_empty() {
                    continue;
                }
                eprintln!("  launcher | {line}");
                let mut l = log.lock().unwrap();
                if line.starts_with('[')
                    && let Some(n) = line.rsplit_once("restarts ").and_then(|(_, n)| n.trim().parse().ok())
                {
                    l.progress_restarts = Some(n);
                }
                l.lines.push(line);
            }
        })
    };

    let dir = RunDir::new(&run_dir);
    let mut obs = Observer::new(dir.clone(), actors);
    let (mut kills, mut skipped) = (Vec::<KillRecord>::new(), Vec::<PlannedKill>::new());
    let (mut next, mut training_started, mut early_exit) = (0, None::<f64>, None::<ExitStatus>);
    let proc_root = Path::new("/proc");
    while now() < duration && !stop.is_set() {
        std::thread::sleep(POLL);
        let t = now();
        obs.poll(t);
        take_restarts(&dir, started_unix, &log);
        if let Some(status) = launcher.try_wait()? {
            early_exit = Some(status);
            break;
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
        let Some(pid) = find_victim(proc_root, launcher_pid, &run_dir, plan.victim) else {
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
        obs.poll(now());
        let incarnation = match plan.victim {
            Victim::Actor(k) => read_stats::<ActorStats>(&dir, &stats::actor_live(k))
                .filter(|v| v.pid as u64 == pid as u64)
                .map(|v| v.incarnation as u64),
            _ => None,
        };
        let before = obs.last_sample();
        match sigkill_verified(pid, || is_victim(proc_root, pid, launcher_pid, &run_dir, plan.victim)) {
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
    let exit = match early_exit {
        Some(s) => s,
        None => {
            eprintln!("soak: [{stopped_at:.1} s] stopping the run (SIGINT to the launcher, pid {launcher_pid})");
            // SAFETY: signalling our own child.
            unsafe { libc::kill(launcher_pid as libc::pid_t, libc::SIGINT) };
            let waited = Instant::now();
            loop {
                if let Some(s) = launcher.try_wait()? {
                    break s;
                }
                if waited.elapsed() > STOP_WAIT {
                    eprintln!("soak: the launcher did not stop within {STOP_WAIT:?}; killing it");
                    let _ = launcher.kill();
                    break launcher.wait()?;
                }
                std::thread::sleep(Duration::from_millis(100));
            }
        }
    };
    let _ = reader.join();
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
        run_dir: &run_dir,
        schedule: &schedule,
        kills: &kills,
        skipped: &skipped,
        obs: &obs,
        log: &log,
        training_started,
        stopped_at,
        end,
        exit,
        early: early_exit.is_some(),
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

/// Everything the report is made of.
struct Report<'a> {
    cfg: &'a RunConfig,
    config: &'a Path,
    seed: u64,
    actors: u32,
    minutes: f64,
    mean: f64,
    run_dir: &'a Path,
    schedule: &'a [PlannedKill],
    kills: &'a [KillRecord],
    skipped: &'a [PlannedKill],
    obs: &'a Observer,
    log: &'a LauncherLog,
    training_started: Option<f64>,
    stopped_at: f64,
    end: f64,
    exit: ExitStatus,
    early: bool,
    interrupted: bool,
}

impl Report<'_> {
    /// The Markdown report, `soak.json`'s content and the failures.
    fn build(&self) -> (String, Value, Vec<String>) {
        let mut failures = Vec::new();
        let mut md = String::new();
        let obs = self.obs;
        let restarts = &self.log.restarts;
        let warmup = self.cfg.dsac.warmup;
        md += &format!(
            "## Soak: {} min, seed {}, {} actor(s), {}\n\nRun directory `{}`; launched at 0 s, learner updating from \
             {}, stopped (SIGINT) at {:.1} s, launcher exited at {:.1} s ({}).\n\n",
            self.minutes,
            self.seed,
            self.actors,
            self.config.display(),
            self.run_dir.display(),
            secs(self.training_started),
            self.stopped_at,
            self.end,
            self.exit
        );
        if self.early {
            failures.push(format!("the launcher ended before the soak did ({})", self.exit));
        } else if !self.exit.success() {
            failures.push(format!("the launcher did not stop cleanly after SIGINT ({})", self.exit));
        }
        if self.interrupted {
            failures.push("the soak was interrupted (Ctrl-C) before its end".into());
        }

        // Kills.
        md += "| # | planned (s) | killed at (s) | victim | pid | env steps at kill | updates at kill | launcher restart | training past the kill's figures after | notes |\n|---|---|---|---|---|---|---|---|---|---|\n";
        let mut used = vec![false; restarts.len()];
        let mut kills_json = Vec::new();
        for (i, k) in self.kills.iter().enumerate() {
            let process = k.plan.victim.process();
            let restart =
                restarts.iter().enumerate().find(|(j, r)| !used[*j] && r.process == process && r.at >= k.at - 0.5).map(
                    |(j, r)| {
                        used[j] = true;
                        r.clone()
                    },
                );
            let after_restart = restart.as_ref().map_or(k.at, |r| r.at);
            let new_learner = |p: &&LearnerPoint| p.t > k.at && p.pid != k.pid as u64;
            let continued = k.before.and_then(|b| {
                obs.points
                    .iter()
                    .filter(|p| p.t >= after_restart && (k.plan.victim != Victim::Learner || new_learner(p)))
                    .find(|p| p.updates > b.updates && p.env_steps > b.env_steps)
                    .map(|p| p.t - k.at)
            });
            let mut notes = String::new();
            let mut extra = json!(null);
            match k.plan.victim {
                Victim::Learner => {
                    if let Some(first) = obs.points.iter().find(new_learner) {
                        let resumed = first.resumed_from.unwrap_or(0);
                        let updating = obs
                            .points
                            .iter()
                            .filter(|p| p.pid == first.pid && p.updates > resumed)
                            .map(|p| p.t - k.at)
                            .next();
                        let (b_steps, b_updates) = k.before.map_or((0, 0), |b| (b.env_steps, b.updates));
                        // When the killed learner's stats last changed (as polled): what it took
                        // after that is not in its last count.
                        let stats_age =
                            obs.points.iter().rev().find(|p| p.pid == k.pid as u64 && p.t <= k.at).map(|p| k.at - p.t);
                        let allowance = intake_before(&obs.points, k.pid as u64, k.at)
                            .map(|(rate, age)| died_allowance(self.cfg.runtime.step_buffer as u64, rate, age));
                        notes = format!(
                            "its stats last changed {} before (≤ {} records of each stream may die with it); resumed \
                             from update {resumed} ({} redone) and env step {} ({} rolled back: received after the \
                             last checkpoint), refill {warmup} steps, updating again after {}",
                            secs(stats_age),
                            allowance.map_or("?".into(), |a| a.to_string()),
                            b_updates.saturating_sub(resumed),
                            first.resumed_env_steps,
                            b_steps.saturating_sub(first.resumed_env_steps),
                            secs(updating)
                        );
                        extra = json!({
                            "killed_learner_stats_age_s": stats_age,
                            "died_allowance_per_stream": allowance,
                            "new_pid": first.pid,
                            "resumed_from_update": first.resumed_from,
                            "resumed_env_steps": first.resumed_env_steps,
                            "updates_redone": b_updates.saturating_sub(resumed),
                            "env_steps_rolled_back": b_steps.saturating_sub(first.resumed_env_steps),
                            "refill_steps": warmup,
                            "updating_again_after_s": updating,
                        });
                    } else {
                        notes = "no stats from a new learner process".into();
                    }
                }
                Victim::Curriculum => {
                    notes = "resumes its saved state (count below)".into();
                }
                Victim::Actor(a) => {
                    if let Some(inc) = k.incarnation {
                        let sending = obs.actors_live.get(&(a as u64, inc + 1)).and_then(|(_, t)| *t).map(|t| t - k.at);
                        notes = format!("incarnation {inc} → {}: sending after {}", inc + 1, secs(sending));
                        extra = json!({"incarnation": inc, "replacement_sending_after_s": sending});
                    }
                }
            }
            md += &format!(
                "| {} | {:.1} | {:.1} | {} | {} | {} | {} | {} | {} | {} |\n",
                i + 1,
                k.plan.at_secs,
                k.at,
                process,
                k.pid,
                k.before.map_or("—".into(), |b| b.env_steps.to_string()),
                k.before.map_or("—".into(), |b| b.updates.to_string()),
                restart.as_ref().map_or("**none**".into(), |r| format!("+{:.1} s (restart {})", r.at - k.at, r.number)),
                continued.map_or("**no**".into(), |c| format!("{c:.1} s")),
                notes
            );
            if restart.is_none() {
                failures.push(format!("kill {} ({process}): the launcher reported no restart", i + 1));
            }
            if continued.is_none() {
                failures.push(format!(
                    "kill {} ({process}): training did not get past the kill's updates and env steps",
                    i + 1
                ));
            }
            kills_json.push(json!({
                "planned_s": k.plan.at_secs,
                "at_s": k.at,
                "victim": k.plan.victim.kind(),
                "process": process,
                "pid": k.pid,
                "env_steps_at_kill": k.before.map(|b| b.env_steps),
                "updates_at_kill": k.before.map(|b| b.updates),
                "restart": restart.as_ref().map(|r| json!({"after_s": r.at - k.at, "number": r.number, "status": r.status})),
                "continued_after_s": continued,
                "details": extra,
            }));
        }
        for s in self.skipped {
            md += &format!(
                "| — | {:.1} | skipped | {} | — | | | | | no such process for {VICTIM_WAIT_SECS} s |\n",
                s.at_secs,
                s.victim.process()
            );
        }
        let mut per_kind = BTreeMap::new();
        for kind in ["learner", "curriculum", "actor"] {
            let n = self.kills.iter().filter(|k| k.plan.victim.kind() == kind).count();
            per_kind.insert(kind, n);
            if n == 0 {
                failures.push(format!("no {kind} was killed"));
            }
        }

        // Restarts.
        let mut by_process: BTreeMap<&str, u32> = BTreeMap::new();
        for r in restarts {
            *by_process.entry(&r.process).or_default() += 1;
        }
        let unplanned: Vec<&Restart> = restarts.iter().zip(&used).filter(|(_, u)| !**u).map(|(r, _)| r).collect();
        let curriculum_resumes = std::fs::read_to_string(self.run_dir.join("logs/curriculum.log"))
            .map_or(0, |l| l.matches("resumed curriculum state").count());
        let curriculum_kills = per_kind["curriculum"];
        md += &format!(
            "\nKills: learner {}, curriculum {}, actor {} (of {} planned{}). Restarts the launcher reported: {} \
             (its last progress line: {}){}. The curriculum service resumed its saved state {} time(s) for {} \
             restart(s).\n",
            per_kind["learner"],
            per_kind["curriculum"],
            per_kind["actor"],
            self.schedule.len(),
            if self.kills.len() + self.skipped.len() < self.schedule.len() {
                ", the rest fell after the end"
            } else {
                ""
            },
            if by_process.is_empty() {
                "none".to_string()
            } else {
                by_process.iter().map(|(p, n)| format!("{p} {n}")).collect::<Vec<_>>().join(", ")
            },
            self.log.progress_restarts.map_or("—".into(), |n| format!("restarts {n}")),
            if unplanned.is_empty() {
                ", all of them the soak's kills".to_string()
            } else {
                format!(
                    "; **not caused by the soak**: {}",
                    unplanned
                        .iter()
                        .map(|r| format!("{} at {:.1} s ({})", r.process, r.at, r.status))
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            },
            curriculum_resumes,
            by_process.get("curriculum").copied().unwrap_or(0),
        );
        if (curriculum_resumes as u32) < by_process.get("curriculum").copied().unwrap_or(0) {
            failures.push(format!(
                "the curriculum service resumed its state {curriculum_resumes} time(s) after {curriculum_kills} kill(s)"
            ));
        }
        for r in &unplanned {
            failures.push(format!("{} died without a kill at {:.1} s ({})", r.process, r.at, r.status));
        }

        // End figures.
        let last = obs.last_sample();
        let final_learner = read_stats::<LearnerStats>(&RunDir::new(self.run_dir), "learner");
        let final_status = final_learner.as_ref().map(|v| v.status.clone());
        md += &format!(
            "\nAt the end (metrics/learner.csv): env steps {}, updates {}; the last learner's status: {} (a final \
             checkpoint is written on `stopped`).\n",
            last.map_or("—".into(), |s| s.env_steps.to_string()),
            last.map_or("—".into(), |s| s.updates.to_string()),
            final_status.as_deref().unwrap_or("—"),
        );
        if final_status.as_deref() != Some("stopped") {
            failures.push(format!("the last learner did not stop cleanly (status {final_status:?})"));
        }

        // Step accounting.
        let final_pid = final_learner.as_ref().map(|v| v.pid as u64);
        let mut views: Vec<(u64, &LearnerStats)> = obs.learners.iter().map(|(p, v)| (*p, v)).collect();
        if let (Some(pid), Some(v)) = (final_pid, final_learner.as_ref()) {
            views.retain(|(p, _)| *p != pid);
            views.push((pid, v));
        }
        let mut received: BTreeMap<(u64, u64), Vec<Received>> = BTreeMap::new();
        for (_, v) in &views {
            for s in &v.streams {
                received.entry((s.actor as u64, s.incarnation as u64)).or_default().push(Received {
                    records: s.records,
                    checksum: s.checksum,
                    gaps: s.gaps,
                });
            }
        }
        let mut sent: BTreeMap<(u64, u64), Sent> = BTreeMap::new();
        for ((a, i), (v, _)) in &obs.actors_live {
            sent.insert((*a, *i), Sent { steps: v.steps_sent, checksum: v.checksum, exact: false });
        }
        for entry in std::fs::read_dir(RunDir::new(self.run_dir).stats()).into_iter().flatten().flatten() {
            let name = entry.file_name().to_string_lossy().to_string();
            let Some(v) = name
                .strip_prefix("actor-")
                .and_then(|n| n.strip_suffix(".json"))
                .and_then(|n| n.split_once('.'))
                .filter(|(a, i)| a.parse::<u64>().is_ok() && i.parse::<u64>().is_ok())
                .and_then(|_| read_stats::<ActorStats>(&RunDir::new(self.run_dir), name.trim_end_matches(".json")))
            else {
                continue;
            };
            sent.insert(
                (v.actor as u64, v.incarnation as u64),
                Sent { steps: v.steps_sent, checksum: v.checksum, exact: true },
            );
        }
        // Each learner restart, with what a stream crossing it may lose (unbounded for a
        // death the soak did not cause: that is a failure of its own).
        let learner_restarts: Vec<(f64, u64)> = restarts
            .iter()
            .filter(|r| r.process == "learner")
            .map(|r| {
                let kill = self.kills.iter().find(|k| {
                    k.plan.victim == Victim::Learner && r.at >= k.at - 0.5 && r.at <= k.at + LEARNER_RESTART_SLACK_SECS
                });
                let allowance = kill
                    .and_then(|k| intake_before(&obs.points, k.pid as u64, k.at))
                    .map_or(u64::MAX, |(rate, age)| died_allowance(self.cfg.runtime.step_buffer as u64, rate, age));
                (r.at, allowance)
            })
            .collect();
        let actor_restart = |a: u64, number: u64| {
            restarts.iter().find(|r| r.process == format!("actor-{a}") && r.number as u64 == number).map(|r| r.at)
        };
        md += &format!(
            "\nSteps, actor → learner, per actor incarnation (`stats/actor-K.I.json`, or the last `actor-K.live.json` of \
             a killed one, against the `streams` of every learner process's `stats/learner.json`). A stream that did \
             not cross a learner restart must arrive whole. What a crossing stream misses died with the killed learner \
             — taken after its last stats write into its replay (not checkpointed), or waiting in its intake queue \
             (runtime.step_buffer = {} records per actor) — the loss the README documents for a learner restart, after \
             which the learner refills dsac.warmup = {warmup} steps; it is allowed up to that queue plus 1.5 × the \
             killed learner's intake over the time since its last stats write, and anything beyond is lost.\n\n| \
             stream (actor.incarnation) | sent | received | learner processes | may die with killed learners | lost \
             |\n|---|---|---|---|---|---|\n",
            self.cfg.runtime.step_buffer
        );
        let keys: std::collections::BTreeSet<(u64, u64)> = sent.keys().chain(received.keys()).copied().collect();
        let (mut lost, mut died, mut streams_json) = (0u64, 0u64, Vec::new());
        for key in keys {
            let (a, i) = key;
            let begin = if i <= 1 { Some(0.0) } else { actor_restart(a, i - 1) };
            let finish = actor_restart(a, i).unwrap_or(self.end);
            let crossed: Vec<u64> = learner_restarts
                .iter()
                .filter(|(r, _)| {
                    begin.is_none_or(|b| b <= r + LEARNER_RESTART_SLACK_SECS)
                        && finish >= r - LEARNER_RESTART_SLACK_SECS
                })
                .map(|(_, a)| *a)
                .collect();
            let allowance = (!crossed.is_empty()).then(|| crossed.iter().fold(0u64, |s, a| s.saturating_add(*a)));
            let s = sent.get(&key).copied();
            let r = received.get(&key).map(Vec::as_slice).unwrap_or(&[]);
            let verdict = account(s, r, allowance);
            lost += verdict.lost();
            died += verdict.died_with_learner();
            if verdict.failed() {
                failures.push(format!("stream {a}.{i}: {}", verdict.text().replace("**", "")));
            }
            let total: u64 = r.iter().map(|x| x.records).sum();
            md += &format!(
                "| {a}.{i} | {} | {total} | {} | {} | {} |\n",
                s.map_or("?".into(), |s| format!("{}{}", s.steps, if s.exact { "" } else { " (killed; last report)" })),
                r.len(),
                match allowance {
                    None => "no (crossed no learner restart)".to_string(),
                    Some(u64::MAX) => "unbounded (an unplanned learner restart)".to_string(),
                    Some(a) => format!("≤ {a} ({} restart(s))", crossed.len()),
                },
                verdict.text()
            );
            streams_json.push(json!({
                "actor": a, "incarnation": i,
                "sent": s.map(|s| s.steps), "sent_exact": s.map(|s| s.exact),
                "received": total, "learner_processes": r.len(),
                "learner_restarts_crossed": crossed.len(),
                "died_allowance": allowance,
                "verdict": format!("{verdict:?}"),
                "lost": verdict.lost(),
                "died_with_killed_learner": verdict.died_with_learner(),
            }));
        }
        md += &format!(
            "\n**Lost on the learner's side: {lost}** (must be 0: records missing from streams that crossed no learner \
             restart or beyond what the killed learners could hold, gaps, checksum mismatches). Died with killed \
             learners (the documented loss of a learner restart): {died} records over {} learner restart(s).\n",
            learner_restarts.len()
        );
        let passed = failures.is_empty();
        md += &if passed {
            "\n**Soak passed.**".to_string()
        } else {
            format!("\n**Soak failed:**\n- {}", failures.join("\n- "))
        };
        let json = json!({
            "config": self.config.display().to_string(),
            "seed": self.seed,
            "actors": self.actors,
            "minutes": self.minutes,
            "mean_kill_interval_secs": self.mean,
            "run_dir": self.run_dir.display().to_string(),
            "training_started_s": self.training_started,
            "stopped_s": self.stopped_at,
            "duration_s": self.end,
            "launcher_exit": self.exit.to_string(),
            "schedule": self.schedule.iter().map(|k| json!({"at_s": k.at_secs, "victim": k.victim.process()})).collect::<Vec<_>>(),
            "kills": kills_json,
            "skipped": self.skipped.iter().map(|k| json!({"at_s": k.at_secs, "victim": k.victim.process()})).collect::<Vec<_>>(),
            "kills_per_kind": per_kind,
            "restarts_reported": by_process,
            "progress_line_restarts": self.log.progress_restarts,
            "unplanned_restarts": unplanned.iter().map(|r| json!({"process": r.process, "at_s": r.at, "status": r.status})).collect::<Vec<_>>(),
            "curriculum_resumes": curriculum_resumes,
            "end": {
                "env_steps": last.map(|s| s.env_steps),
                "updates": last.map(|s| s.updates),
                "learner_status": final_status,
            },
            "streams": streams_json,
            "lost_on_learner_side": lost,
            "died_with_killed_learners": died,
            "refill_steps_per_learner_restart": warmup,
            "passed": passed,
            "failures": failures,
        });
        (md, json, failures)
    }
}

#[cfg(test)]
mod tests {
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
        let a = kill_schedule(1, 1800.0, 120.0, 2).unwrap();
        assert_eq!(a, kill_schedule(1, 1800.0, 120.0, 2).unwrap());
        assert_ne!(a, kill_schedule(2, 1800.0, 120.0, 2).unwrap());
        for (duration, mean, actors) in [(1800.0, 120.0, 2), (1800.0, 120.0, 5), (180.0, 40.0, 2)] {
            let mut actors_hit = std::collections::BTreeSet::new();
            let mut refused = 0;
            for seed in 0..200 {
                let Ok(s) = kill_schedule(seed, duration, mean, actors) else {
                    refused += 1;
                    continue;
                };
                for kind in ["learner", "curriculum", "actor"] {
                    assert!(kinds(&s).contains(&kind), "seed {seed}: no {kind} in {s:?}");
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
            if duration >= 1800.0 {
                assert_eq!(refused, 0);
            } else {
                assert!(refused < 40, "{refused} of 200 short schedules refused");
            }
        }
        // The short validation soak of the README covers every kind with seed 1.
        assert!(kill_schedule(1, 180.0, 40.0, 2).is_ok());
    }

    /// Schedules that cannot kill every kind, or could spend a restart budget, are refused.
    #[test]
    fn a_schedule_that_cannot_do_its_job_is_refused() {
        let e = kill_schedule(1, 60.0, 120.0, 2).unwrap_err().to_string();
        assert!(e.contains("too few to kill"), "{e}");
        let e = kill_schedule(1, 1800.0, 5.0, 1).unwrap_err().to_string();
        assert!(e.contains("restart budget"), "{e}");
        assert!(kill_schedule(1, 1800.0, 0.0, 2).is_err());
        assert!(kill_schedule(1, 1800.0, 120.0, 0).is_err());
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
        std::fs::create_dir_all(root.join("self")).unwrap();
        assert_eq!(find_victim(&root, me, run, Victim::Curriculum), Some(501));
        assert_eq!(find_victim(&root, me, run, Victim::Learner), Some(502));
        assert_eq!(find_victim(&root, me, run, Victim::Actor(0)), Some(503));
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
        let rec = |records, checksum, gaps| Received { records, checksum, gaps };
        // Whole, over one learner or split over two (checksums add, wrapping).
        assert_eq!(account(sent(100, 7, true), &[rec(100, 7, 0)], None), Verdict::Whole);
        assert_eq!(account(sent(100, 7, true), &[rec(60, u32::MAX, 0), rec(40, 8, 0)], Some(30)), Verdict::Whole);
        assert_eq!(account(sent(100, 7, true), &[rec(100, 8, 0)], None), Verdict::ChecksumMismatch);
        // Missing records: lost, unless the stream crossed a learner restart and no
        // more are missing than the killed learner could hold.
        assert_eq!(account(sent(100, 7, true), &[rec(90, 1, 0)], None), Verdict::Lost(10));
        assert_eq!(
            account(sent(100, 7, true), &[rec(50, 1, 0), rec(30, 2, 0)], Some(20)),
            Verdict::DiedWithLearner(20)
        );
        assert_eq!(account(sent(100, 7, true), &[rec(50, 1, 0), rec(30, 2, 0)], Some(15)), Verdict::Lost(5));
        assert_eq!(account(sent(100, 7, true), &[rec(101, 7, 0)], None), Verdict::Excess(1));
        assert_eq!(account(sent(100, 7, true), &[rec(100, 7, 1)], None), Verdict::Gaps(1));
        // A killed sender: at least what it last reported must have arrived.
        assert_eq!(account(sent(100, 7, false), &[rec(130, 9, 0)], None), Verdict::SenderKilled);
        assert_eq!(account(sent(100, 7, false), &[rec(90, 9, 0)], None), Verdict::Lost(10));
        assert_eq!(account(sent(100, 7, false), &[rec(90, 9, 0)], Some(10)), Verdict::DiedWithLearnerAtLeast(10));
        assert_eq!(account(None, &[rec(5, 1, 0)], None), Verdict::Unknown);
        // A killed learner's allowance: its queue and a round, plus 1.5 × its intake
        // since its last stats write (and one poll).
        assert_eq!(died_allowance(256, 0.0, 0.5), 258);
        assert_eq!(died_allowance(256, 200.0, 0.75), 258 + 300);
        assert!(Verdict::Lost(1).failed() && !Verdict::DiedWithLearner(5).failed() && !Verdict::SenderKilled.failed());
    }
}
