//! `pednav-run` — starts and supervises the processes of one pednav run.
//!
//! `launch` validates the config (nothing starts on a bad one), prepares the run
//! directory (or resumes it), removes stale iceoryx2 resources of this run,
//! starts the curriculum service, the learner and N actors with their logs in
//! `<run>/logs/`, restarts an actor that dies, shows a live progress line from
//! the processes' heartbeats, and on Ctrl-C / SIGTERM stops the actors first,
//! then the learner (which drains the step stream and writes a final
//! checkpoint) and the curriculum service (which saves its state).
//!
//! Children run in their own process group (so a terminal's Ctrl-C reaches the
//! launcher only, which then stops them in order) and get SIGTERM if the
//! launcher itself dies.

use std::collections::VecDeque;
use std::fs::OpenOptions;
use std::io::{IsTerminal, Write};
use std::os::unix::process::CommandExt;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};

mod bench;
use clap::{Args, Parser, Subcommand};
use pednav_nets::DeviceSpec;
use pednav_runtime::messages::process_kind;
use pednav_runtime::{Ipc, RunConfig, RunDir, StopFlag, run_prefix};

#[derive(Parser)]
#[command(version, about = "Start, supervise and stop the processes of a pednav run")]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Start (or resume) a run: curriculum service, learner and N actors.
    Launch(Launch),
    /// Measure the runtime: step-stream throughput, weights latency, whole-system env steps/s.
    #[command(subcommand)]
    Bench(bench::Bench),
    /// Validate a config file and print the resolved config.
    Check {
        /// Config file (TOML).
        config: PathBuf,
        /// Override one config field, `section.field=value` (repeatable), as `launch --set`.
        #[arg(long = "set", value_name = "FIELD=VALUE")]
        overrides: Vec<String>,
    },
}

fn main() -> Result<()> {
    pednav_runtime::init_logging();
    match Cli::parse().command {
        Cmd::Bench(b) => bench::run(b),
        Cmd::Check { config, overrides } => {
            let cfg = RunConfig::load_with(&config, &overrides)?;
            check_devices(cfg.runtime.device, cfg.runtime.actor_device).with_context(|| {
                format!("{}: the config is valid, but its devices cannot be used", config.display())
            })?;
            print!("{}", cfg.to_toml());
            eprintln!("{}: valid", config.display());
            Ok(())
        }
        Cmd::Launch(args) => launch(args),
    }
}

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

fn default_bin_dir() -> Result<PathBuf> {
    let exe = std::env::current_exe().context("locating pednav-run")?;
    Ok(exe.parent().context("pednav-run has no folder")?.to_path_buf())
}

fn pid_alive(pid: i32) -> bool {
    // SAFETY: signal 0 only checks for existence.
    pid > 0 && unsafe { libc::kill(pid, 0) } == 0
}

/// Arguments of `launch`.
#[derive(Args)]
struct Launch {
    /// Number of actor processes.
    #[arg(long, default_value_t = 2)]
    actors: u32,
    /// Config file (TOML). Required for a new run; omit it to resume RUN_DIR.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Run directory (default: runs/<config name>-<unix time>). An existing one is resumed.
    #[arg(long)]
    run_dir: Option<PathBuf>,
    /// Override the config's seed (new runs only).
    #[arg(long)]
    seed: Option<u64>,
    /// Override one config field, `section.field=value` (repeatable; new runs only;
    /// the run directory's config.toml records the result), e.g.
    /// `--set dsac.twin_critics=true --set runtime.max_env_steps=500000`.
    #[arg(long = "set", value_name = "FIELD=VALUE")]
    overrides: Vec<String>,
    /// Folder holding pednav-actor, pednav-learner and pednav-curriculum (default: next to this binary).
    #[arg(long)]
    bin_dir: Option<PathBuf>,
    /// Learner compute threads (default: all cores).
    #[arg(long)]
    learner_threads: Option<usize>,
    /// Simulator instances per actor (default: the config's `runtime.envs_per_actor`).
    #[arg(long)]
    envs: Option<usize>,
    /// Where the learner trains: cpu, cuda or cuda:N (default: the config's
    /// `runtime.device`). CUDA needs the binaries of `deploy/build_cuda.sh`.
    #[arg(long)]
    device: Option<DeviceSpec>,
    /// Where the actors run policy inference (default: the config's `runtime.actor_device`).
    #[arg(long)]
    actor_device: Option<DeviceSpec>,
}

/// Open every GPU the run will use, so a missing CUDA build or GPU stops the launch
/// before any process starts (the CPU needs no check).
fn check_devices(learner: DeviceSpec, actors: DeviceSpec) -> Result<()> {
    for (whose, spec, field) in [
        ("the learner's", learner, "runtime.device / --device"),
        ("the actors'", actors, "runtime.actor_device / --actor-device"),
    ] {
        if spec.is_gpu() {
            spec.open().with_context(|| format!("{whose} device ({field})"))?;
        }
    }
    Ok(())
}

fn launch(args: Launch) -> Result<()> {
    let Launch { actors, config, run_dir, seed, overrides, bin_dir, learner_threads, envs, device, actor_device } =
        args;
    if let Some(m) = envs
        && (m == 0 || m > 4096)
    {
        bail!("--envs must be 1 … 4096, got {m}");
    }
    if actors == 0 || actors as usize > pednav_runtime::ipc::MAX_ACTORS {
        bail!("--actors must be 1 … {}, got {actors}", pednav_runtime::ipc::MAX_ACTORS);
    }
    // 1. Config and run directory: everything is checked before any process starts.
    let (cfg, run_dir) = match (config, run_dir) {
        (Some(path), run_dir) => {
            let mut cfg = RunConfig::load_with(&path, &overrides)?;
            if let Some(s) = seed {
                cfg.seed = s;
            }
            let dir = run_dir.unwrap_or_else(|| {
                let stem = path.file_stem().map(|s| s.to_string_lossy().to_string()).unwrap_or("run".into());
                let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().as_secs();
                PathBuf::from("runs").join(format!("{stem}-{secs}"))
            });
            (cfg, dir)
        }
        (None, Some(dir)) => {
            let path = dir.join("config.toml");
            if !path.exists() {
                bail!("{} has no config.toml: pass --config FILE to start a new run there", dir.display());
            }
            if seed.is_some() || !overrides.is_empty() {
                bail!("--seed and --set only apply to new runs; {} already has its config", dir.display());
            }
            (RunConfig::load(&path)?, dir)
        }
        (None, None) => bail!("pass --config FILE (a new run) or --run-dir DIR (resume)"),
    };
    let (learner_device, actor_device) =
        (device.unwrap_or(cfg.runtime.device), actor_device.unwrap_or(cfg.runtime.actor_device));
    check_devices(learner_device, actor_device)?;
    let bins = bin_dir.map_or_else(default_bin_dir, Ok)?;
    for b in ["pednav-actor", "pednav-learner", "pednav-curriculum"] {
        if !bins.join(b).exists() {
            bail!("{} not found in {} (build with `cargo build --release`)", b, bins.display());
        }
    }
    let dir = RunDir::new(&run_dir);
    let resumed = dir.prepare(&cfg)?;
    let lock = run_dir.join("launcher.pid");
    if let Some(pid) = std::fs::read_to_string(&lock).ok().and_then(|s| s.trim().parse::<i32>().ok())
        && pid_alive(pid)
        && pid != std::process::id() as i32
    {
        bail!("{} is already being run by pednav-run (pid {pid})", run_dir.display());
    }
    std::fs::write(&lock, std::process::id().to_string())?;
    let _ = std::fs::remove_file(run_dir.join("DONE"));
    let stop = StopFlag::install();
    // 2. Stale resources of this run (a previous launcher killed hard) go first.
    let ipc =
        Ipc::new(&run_prefix(&run_dir), "launcher", cfg.runtime.step_buffer, Duration::from_secs(5), stop.clone())?;
    let heartbeats = ipc.heartbeat_subscriber()?;
    eprintln!(
        "pednav: {} run {} — {} actor(s) × {} envs, variant {:?}, learner on {learner_device}, actors' inference \
         on {actor_device}, iceoryx2 prefix {}",
        if resumed { "resuming" } else { "starting" },
        run_dir.display(),
        actors,
        envs.unwrap_or(cfg.runtime.envs_per_actor),
        cfg.curriculum.variant,
        run_prefix(&run_dir)
    );
    let rd = run_dir.display().to_string();
    let mk = |name: String, bin: &str, args: Vec<String>| Proc {
        log: dir.logs().join(format!("{name}.log")),
        name,
        binary: bins.join(bin),
        args,
        child: None,
        restarts: VecDeque::new(),
        total_restarts: 0,
    };
    let mut curriculum =
        mk("curriculum".into(), "pednav-curriculum", vec!["serve".into(), "--run-dir".into(), rd.clone()]);
    let mut learner_args = vec!["--run-dir".into(), rd.clone(), "--device".into(), learner_device.to_string()];
    if let Some(t) = learner_threads {
        learner_args.extend(["--threads".into(), t.to_string()]);
    }
    let mut learner = mk("learner".into(), "pednav-learner", learner_args);
    let mut actor_procs: Vec<Proc> = (0..actors)
        .map(|k| {
            let mut args = vec![
                "--run-dir".into(),
                rd.clone(),
                "--actor".into(),
                k.to_string(),
                "--device".into(),
                actor_device.to_string(),
            ];
            if let Some(m) = envs {
                args.extend(["--envs".into(), m.to_string()]);
            }
            mk(format!("actor-{k}"), "pednav-actor", args)
        })
        .collect();
    curriculum.start()?;
    learner.start()?;
    for a in actor_procs.iter_mut() {
        a.start()?;
    }

    // 3. Supervise.
    let started = Instant::now();
    let tty = std::io::stderr().is_terminal();
    let mut last_line = Instant::now();
    let mut latest: std::collections::BTreeMap<(u32, u32), pednav_runtime::messages::Heartbeat> = Default::default();
    let mut failure: Option<String> = None;
    while !stop.is_set() {
        std::thread::sleep(Duration::from_millis(100));
        while let Ok(Some(h)) = heartbeats.receive() {
            latest.insert((h.kind, h.id), *h);
        }
        for a in actor_procs.iter_mut() {
            if let Some(status) = a.exited() {
                if stop.is_set() {
                    break;
                }
                a.restarts.push_back(Instant::now());
                while a.restarts.front().is_some_and(|t| t.elapsed() > Duration::from_secs(120)) {
                    a.restarts.pop_front();
                }
                if a.restarts.len() > 5 {
                    failure = Some(format!(
                        "{} died 6 times within 2 minutes ({status}); last log lines:\n{}",
                        a.name,
                        a.log_tail()
                    ));
                    break;
                }
                a.total_restarts += 1;
                eprintln!("\npednav: {} exited ({status}); restarting it (restart {})", a.name, a.total_restarts);
                ipc.cleanup_dead_nodes();
                a.start()?;
            }
        }
        for p in [&mut learner, &mut curriculum] {
            if let Some(status) = p.exited() {
                failure = Some(format!("{} exited ({status}); last log lines:\n{}", p.name, p.log_tail()));
            }
        }
        if let Ok(reason) = std::fs::read_to_string(run_dir.join("DONE")) {
            eprintln!("\npednav: the learner reached its budget ({reason})");
            break;
        }
        if failure.is_some() {
            break;
        }
        let every = if tty { Duration::from_secs(1) } else { Duration::from_secs(30) };
        if last_line.elapsed() >= every {
            last_line = Instant::now();
            let line = progress_line(started.elapsed(), &latest, &actor_procs);
            if tty {
                eprint!("\r\x1b[2K{line}");
            } else {
                eprintln!("{line}");
            }
            let _ = std::io::stderr().flush();
        }
    }
    // 4. Stop in order: actors, then learner (final checkpoint) and curriculum (state).
    eprintln!("\npednav: stopping — actors first, then the learner (final checkpoint) and the curriculum service");
    let mut refs: Vec<&mut Proc> = actor_procs.iter_mut().collect();
    stop_all(&mut refs, Duration::from_secs(30));
    stop_all(&mut [&mut learner, &mut curriculum], Duration::from_secs(300));
    ipc.cleanup_dead_nodes();
    let _ = std::fs::remove_file(&lock);
    let summary = std::fs::read_to_string(dir.stats().join("learner.json")).unwrap_or_default();
    eprintln!(
        "pednav: run directory {}\n{}",
        run_dir.display(),
        summary.lines().take(8).collect::<Vec<_>>().join("\n")
    );
    if let Some(f) = failure {
        bail!("the run stopped because {f}");
    }
    Ok(())
}

fn progress_line(
    elapsed: Duration,
    latest: &std::collections::BTreeMap<(u32, u32), pednav_runtime::messages::Heartbeat>,
    actors: &[Proc],
) -> String {
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
        learner.map_or(0, |h| h.steps),
        actor_rate,
        learner.map_or(0, |h| h.count),
        curriculum.map_or(0, |h| h.count),
        curriculum.map_or(f32::NAN, |h| h.recent_return),
        if curriculum.is_some_and(|h| h.phase == 1) { "ACL" } else { "first-task" },
        curriculum.map_or(0, |h| h.steps),
        alive,
        actors.len(),
        restarts
    )
}
