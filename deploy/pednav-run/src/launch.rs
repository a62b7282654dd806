//! `pednav-run launch`: from the flags to a prepared run — config resolved and
//! checked, devices opened, run directory created or resumed, the run locked —
//! then handed to the [`Supervisor`].
//!
//! Invariant: everything that can refuse a run — the config's rules, its devices, the
//! memory it needs against the machine's — is checked before any process starts.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;
use pednav_nets::DeviceSpec;
use pednav_runtime::{MemoryPlan, RunConfig, RunDir, StopFlag, memory, run_prefix};

use crate::supervisor::{HostRole, ProcessPlan, Supervisor};

/// Arguments of `launch`.
#[derive(Args)]
pub struct Launch {
    /// Number of actor processes on this host (0 only with --listen: every actor on
    /// other hosts).
    #[arg(long, default_value_t = 2)]
    actors: u32,
    /// Let actor hosts join the run (`pednav-run join --connect …`): listen on this
    /// endpoint, `tcp/HOST:PORT`, e.g. `tcp/0.0.0.0:7447`, or `tls/HOST:PORT` with the
    /// --tls-* files (repeatable). Explicit endpoints only: nothing is discovered,
    /// nothing multicast.
    #[arg(long, value_name = "ENDPOINT")]
    listen: Vec<String>,
    #[command(flatten)]
    tls: crate::tls::TlsArgs,
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
pub fn check_devices(learner: DeviceSpec, actors: DeviceSpec) -> Result<()> {
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

/// Estimate the memory the run of `cfg` (read from `file`) needs under `plan`, print
/// the estimate (stderr, one line per component and the total against the machine),
/// and refuse it when it exceeds what the machine can give ([`pednav_runtime::memory`]:
/// the error names the fields and what fits). When `/proc/meminfo` cannot be read it
/// warns and refuses nothing.
pub fn check_memory(cfg: &RunConfig, file: &str, plan: &MemoryPlan) -> Result<()> {
    let machine = memory::machine_memory();
    let estimate = cfg.memory_estimate(plan)?;
    for line in estimate.lines(machine) {
        eprintln!("pednav: {line}");
    }
    if machine.is_none() {
        eprintln!("pednav: warning: cannot read MemTotal from /proc/meminfo; the estimate is not checked");
    }
    estimate.check(cfg, file, machine)?;
    if let Some(available) = memory::available_memory()
        && estimate.host_total() > available as u128
    {
        eprintln!(
            "pednav: warning: the estimate exceeds the memory available now ({}, MemAvailable): other processes \
             hold the rest",
            memory::human(available as u128)
        );
    }
    Ok(())
}

/// `--actors` and `--envs` within what a run can have (no actors only when actor hosts
/// join: `listening`).
fn check_counts(actors: u32, envs: Option<usize>, listening: bool) -> Result<()> {
    if let Some(m) = envs
        && (m == 0 || m > 4096)
    {
        bail!("--envs must be 1 … 4096, got {m}");
    }
    if actors as usize > pednav_runtime::ipc::MAX_ACTORS || (actors == 0 && !listening) {
        bail!(
            "--actors must be 1 … {} (0 only with --listen, when actor hosts bring every actor), got {actors}",
            pednav_runtime::ipc::MAX_ACTORS
        );
    }
    Ok(())
}

/// A new run's `dsac.init_from`: a checkpoint folder whose networks are this run's —
/// what the learner loads at its start, checked here so that a wrong folder stops the
/// launch before any process starts (the learner verifies every file's checksum, name
/// and shape as it loads them).
pub fn check_init_from(cfg: &RunConfig) -> Result<()> {
    /// The part of a checkpoint's state file that says which networks it holds.
    #[derive(serde::Deserialize)]
    struct Architecture {
        nets: pednav_nets::NetsConfig,
        #[serde(default)]
        twin_critics: bool,
    }
    let Some(from) = &cfg.dsac.init_from else { return Ok(()) };
    let state = from.join("state.json");
    let text = std::fs::read_to_string(&state).with_context(|| {
        format!(
            "dsac.init_from = \"{}\": cannot read {} (give a run's checkpoints/learner folder, or a results \
             folder's copy of it)",
            from.display(),
            state.display()
        )
    })?;
    let found: Architecture = serde_json::from_str(&text)
        .with_context(|| format!("dsac.init_from: {} is not a checkpoint's state file", state.display()))?;
    if !found.nets.same_architecture(&cfg.nets) {
        bail!(
            "dsac.init_from = \"{}\": its networks {:?} are not this run's {:?} ([nets])",
            from.display(),
            found.nets,
            cfg.nets
        );
    }
    if found.twin_critics != cfg.dsac.twin_critics {
        bail!(
            "dsac.init_from = \"{}\": its twin_critics is {}, this run's {} (dsac.twin_critics)",
            from.display(),
            found.twin_critics,
            cfg.dsac.twin_critics
        );
    }
    Ok(())
}

impl Launch {
    /// Whether the link to actor hosts is mutual TLS.
    pub fn uses_tls(&self) -> bool {
        self.tls.given()
    }
}

/// Prepare the run of `args` and supervise it to the end.
pub fn launch(args: Launch) -> Result<()> {
    let Launch {
        actors,
        listen,
        tls,
        config,
        run_dir,
        seed,
        overrides,
        bin_dir,
        learner_threads,
        envs,
        device,
        actor_device,
    } = args;
    check_counts(actors, envs, !listen.is_empty())?;
    let tls = tls.files()?;
    if !listen.is_empty() {
        pednav_bridge::LinkConfig::listening(&listen).with_tls(tls.clone()).check()?;
        check_listen_free(&listen)?;
    } else if tls.is_some() {
        bail!("--tls-ca, --tls-cert and --tls-key secure the link to actor hosts: give --listen tls/HOST:PORT too");
    }
    // 1. Config and run directory: everything is checked before any process starts.
    let (cfg, run_dir, file) = match (config, run_dir) {
        (Some(path), run_dir) => {
            let mut cfg = RunConfig::load_with(&path, &overrides)?;
            if let Some(s) = seed {
                cfg.seed = s;
            }
            check_init_from(&cfg)?;
            let dir = run_dir.unwrap_or_else(|| {
                let stem = path.file_stem().map(|s| s.to_string_lossy().to_string()).unwrap_or("run".into());
                let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().as_secs();
                PathBuf::from("runs").join(format!("{stem}-{secs}"))
            });
            (cfg, dir, path)
        }
        (None, Some(dir)) => {
            let path = dir.join("config.toml");
            if !path.exists() {
                bail!("{} has no config.toml: pass --config FILE to start a new run there", dir.display());
            }
            if seed.is_some() || !overrides.is_empty() {
                bail!("--seed and --set only apply to new runs; {} already has its config", dir.display());
            }
            (RunConfig::load(&path)?, dir, path)
        }
        (None, None) => bail!("pass --config FILE (a new run) or --run-dir DIR (resume)"),
    };
    let (learner_device, actor_device) =
        (device.unwrap_or(cfg.runtime.device), actor_device.unwrap_or(cfg.runtime.actor_device));
    check_devices(learner_device, actor_device)?;
    let envs_per_actor = envs.unwrap_or(cfg.runtime.envs_per_actor);
    check_memory(&cfg, &file.display().to_string(), &MemoryPlan { actors, envs_per_actor, learner_device })?;
    let bins = bin_dir.map_or_else(default_bin_dir, Ok)?;
    for b in ["pednav-actor", "pednav-learner", "pednav-curriculum"] {
        if !bins.join(b).exists() {
            bail!("{} not found in {} (build with `cargo build --release`)", b, bins.display());
        }
    }
    let dir = RunDir::new(&run_dir);
    let resumed =
        dir.prepare(&cfg).with_context(|| format!("the run directory {} cannot be used", run_dir.display()))?;
    let lock = lock_run_dir(&dir)?;
    let stop = StopFlag::install();
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
    if !listen.is_empty() {
        eprintln!(
            "pednav: actor hosts join with `pednav-run join --connect {}/THIS_HOST:PORT{} --run-dir DIR` (listening on \
             {}; run {:?})",
            if tls.is_some() { "tls" } else { "tcp" },
            if tls.is_some() { " --tls-ca CA --tls-cert CERT --tls-key KEY" } else { "" },
            listen.join(", "),
            pednav_bridge::run_name(&run_dir)
        );
    }
    let plan = ProcessPlan {
        bins,
        actors,
        first_actor: 0,
        envs,
        learner_threads,
        learner_device,
        actor_device,
        role: HostRole::Learner { listen, tls },
    };
    let result = Supervisor::start(&dir, &cfg, &plan, stop).and_then(Supervisor::run);
    let _ = std::fs::remove_file(&lock);
    let summary = std::fs::read_to_string(dir.stats().join("learner.json")).unwrap_or_default();
    eprintln!(
        "pednav: run directory {}\n{}",
        run_dir.display(),
        summary.lines().take(8).collect::<Vec<_>>().join("\n")
    );
    result
}

/// Take the run directory for this launcher (refused while another launcher runs it)
/// and clear the previous run's done marker; returns the lock file to remove at the end.
pub fn lock_run_dir(dir: &RunDir) -> Result<PathBuf> {
    let lock = dir.launcher_lock();
    if let Some(pid) = std::fs::read_to_string(&lock).ok().and_then(|s| s.trim().parse::<i32>().ok())
        && pid_alive(pid)
        && pid != std::process::id() as i32
    {
        bail!("{} is already being run by pednav-run (pid {pid})", dir.root().display());
    }
    std::fs::write(&lock, std::process::id().to_string()).with_context(|| {
        format!(
            "{}: cannot write the launcher's lock file (is the run directory writable, the disk full?)",
            lock.display()
        )
    })?;
    let _ = std::fs::remove_file(dir.done_marker());
    Ok(lock)
}

/// The folder of this binary (where the other pednav binaries are built).
pub fn default_bin_dir() -> Result<PathBuf> {
    let exe = std::env::current_exe().context("locating pednav-run")?;
    Ok(exe.parent().context("pednav-run has no folder")?.to_path_buf())
}

fn pid_alive(pid: i32) -> bool {
    // SAFETY: signal 0 only checks for existence.
    pid > 0 && unsafe { libc::kill(pid, 0) } == 0
}

/// Every `--listen` endpoint can be bound now (a probe, released at once), so a port
/// that a second learner host or another program holds stops the launch before any
/// process starts, instead of a bridge that fails and restarts.
fn check_listen_free(listen: &[String]) -> Result<()> {
    for endpoint in listen {
        // Checked as tcp/ or tls/ just before (`LinkConfig::check`).
        let address = pednav_bridge::link::endpoint_address(endpoint).unwrap_or(endpoint);
        if let Err(e) = std::net::TcpListener::bind(address) {
            bail!(
                "--listen {endpoint}: cannot listen there ({e}) — is another learner host, or another program, on \
                 this port? Stop it or choose another port"
            );
        }
    }
    Ok(())
}
