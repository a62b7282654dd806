//! `pednav-run join` (an actor host joins a run) and `pednav-run bridge` (the bridge
//! process the launcher starts on each host of a run that spans several).
//!
//! Invariant: an actor host starts nothing before the learner host granted its join —
//! the grant brings the run's config (recorded in the local run directory, which must
//! not hold another) and the host's global actor ids, which its actors use as theirs.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::Args;
use pednav_bridge::{ActorHostOptions, JoinRequest, LearnerHostOptions, LinkConfig, request_join};
use pednav_nets::DeviceSpec;
use pednav_runtime::{RunConfig, RunDir, StopFlag, run_prefix};

use crate::launch::{check_devices, default_bin_dir, lock_run_dir};
use crate::supervisor::{HostRole, ProcessPlan, Supervisor};
use crate::tls::TlsArgs;

/// How long `join` tries to reach the learner host and be answered.
const JOIN_TIMEOUT: Duration = Duration::from_secs(30);

/// Arguments of `join`.
#[derive(Args)]
pub struct Join {
    /// The learner host's endpoint, `tcp/HOST:PORT`, or `tls/HOST:PORT` with the
    /// --tls-* files (its `launch --listen`).
    #[arg(long, required = true)]
    connect: Vec<String>,
    /// Actor processes on this host.
    #[arg(long, default_value_t = 2)]
    actors: u32,
    /// This host's run directory (created, or resumed when it holds the same run).
    #[arg(long)]
    run_dir: PathBuf,
    /// This host's name on the link (default: the machine's name); a host that joins
    /// again under its name with as many actors gets the same actor ids.
    #[arg(long)]
    host: Option<String>,
    /// Folder holding pednav-actor (default: next to this binary).
    #[arg(long)]
    bin_dir: Option<PathBuf>,
    /// Simulator instances per actor (default: the run config's `runtime.envs_per_actor`).
    #[arg(long)]
    envs: Option<usize>,
    /// Where the actors run policy inference (default: the run config's `runtime.actor_device`).
    #[arg(long)]
    actor_device: Option<DeviceSpec>,
    #[command(flatten)]
    tls: TlsArgs,
}

/// Arguments of `bridge` (started by the launcher; see `pednav_bridge`).
#[derive(Args)]
pub struct Bridge {
    /// The local run directory.
    #[arg(long)]
    run_dir: PathBuf,
    /// Learner host: endpoints to listen on for actor hosts.
    #[arg(long, conflicts_with = "connect")]
    listen: Vec<String>,
    /// Learner host: its own actors (ids 0 .. N).
    #[arg(long, default_value_t = 0)]
    local_actors: u32,
    /// Actor host: the learner host's endpoint.
    #[arg(long)]
    connect: Vec<String>,
    /// Actor host: the run's name on the link (from the join).
    #[arg(long, requires = "connect")]
    run: Option<String>,
    /// Actor host: this host's name on the link.
    #[arg(long, requires = "connect")]
    host: Option<String>,
    #[command(flatten)]
    tls: TlsArgs,
}

impl Join {
    /// Whether the link to the learner host is mutual TLS.
    pub fn uses_tls(&self) -> bool {
        self.tls.given()
    }
}

impl Bridge {
    /// Whether the link between the hosts is mutual TLS.
    pub fn uses_tls(&self) -> bool {
        self.tls.given()
    }
}

/// This machine's name, made key-safe.
fn machine_name() -> String {
    let raw = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
    pednav_bridge::join::key_safe_name(&raw)
}

/// Join the run of the learner host at `--connect` and supervise this host's actors
/// and bridge until the run ends or Ctrl-C.
pub fn join(args: Join) -> Result<()> {
    let Join { connect, actors, run_dir, host, bin_dir, envs, actor_device, tls } = args;
    if actors == 0 || actors as usize > pednav_runtime::ipc::MAX_ACTORS {
        bail!("--actors must be 1 … {}, got {actors}", pednav_runtime::ipc::MAX_ACTORS);
    }
    if let Some(m) = envs
        && (m == 0 || m > 4096)
    {
        bail!("--envs must be 1 … 4096, got {m}");
    }
    let host = host.unwrap_or_else(machine_name);
    let tls = tls.files()?;
    let link = LinkConfig::connecting(&connect).with_tls(tls.clone());
    link.check()?;
    let bins = bin_dir.map_or_else(default_bin_dir, Ok)?;
    if !bins.join("pednav-actor").exists() {
        bail!("pednav-actor not found in {} (build with `cargo build --release`)", bins.display());
    }
    eprintln!("pednav: joining the run at {} as host {host:?} with {actors} actor(s)", connect.join(", "));
    let grant = {
        let session = link.open()?;
        let grant = request_join(&session, &JoinRequest::new(&host, actors), JOIN_TIMEOUT);
        pednav_bridge::link::close(session);
        grant?
    };
    std::fs::create_dir_all(&run_dir).with_context(|| format!("creating {}", run_dir.display()))?;
    let offered = run_dir.join("config.learner-host.toml");
    pednav_runtime::generations::write_atomic(&offered, grant.config_toml.as_bytes())
        .with_context(|| format!("writing {}", offered.display()))?;
    let cfg = RunConfig::load(&offered).context("the learner host's config is not valid for this pednav build")?;
    cfg.scene().with_context(
        || "the run's scene cannot be loaded on this host (a scene file must be at the same path on every host)",
    )?;
    let actor_device = actor_device.unwrap_or(cfg.runtime.actor_device);
    check_devices(DeviceSpec::Cpu, actor_device)?;
    let dir = RunDir::new(&run_dir);
    let resumed = dir.prepare(&cfg).with_context(|| {
        format!(
            "{} holds another run's config than the learner host's ({}): join with another --run-dir",
            run_dir.display(),
            offered.display()
        )
    })?;
    let lock = lock_run_dir(&dir)?;
    let stop = StopFlag::install();
    eprintln!(
        "pednav: {} run {:?} in {} — actors {} .. {} × {} envs, inference on {actor_device}, iceoryx2 prefix {}",
        if resumed { "rejoined" } else { "joined" },
        grant.run,
        run_dir.display(),
        grant.first_actor,
        grant.first_actor + grant.actors,
        envs.unwrap_or(cfg.runtime.envs_per_actor),
        run_prefix(&run_dir)
    );
    let plan = ProcessPlan {
        bins,
        actors,
        first_actor: grant.first_actor,
        envs,
        learner_threads: None,
        learner_device: DeviceSpec::Cpu,
        actor_device,
        role: HostRole::Actors { connect, run: grant.run, host, tls },
    };
    let result = Supervisor::start(&dir, &cfg, &plan, stop).and_then(Supervisor::run);
    let _ = std::fs::remove_file(&lock);
    eprintln!("pednav: run directory {}", run_dir.display());
    result
}

/// Run one host's bridge until SIGTERM / Ctrl-C.
pub fn bridge(args: Bridge) -> Result<()> {
    let stop = StopFlag::install();
    let tls = args.tls.files()?;
    let stats = if !args.listen.is_empty() {
        let opts = LearnerHostOptions {
            run_dir: args.run_dir,
            link: LinkConfig::listening(&args.listen).with_tls(tls),
            local_actors: args.local_actors,
        };
        pednav_bridge::run_learner_host(&opts, &stop)?
    } else if !args.connect.is_empty() {
        let opts = ActorHostOptions {
            run_dir: args.run_dir,
            link: LinkConfig::connecting(&args.connect).with_tls(tls).keep_trying(),
            run: args.run.context("--run is required with --connect")?,
            host: args.host.context("--host is required with --connect")?,
        };
        pednav_bridge::run_actor_host(&opts, &stop)?
    } else {
        bail!("pass --listen ENDPOINT (the learner host) or --connect ENDPOINT (an actor host)");
    };
    tracing::info!(?stats, "bridge stopped");
    Ok(())
}
