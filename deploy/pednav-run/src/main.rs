//! `pednav-run` — starts and supervises the processes of one pednav run.
//!
//! `launch` validates the config (nothing starts on a bad one, nor on one whose
//! estimated memory exceeds the machine's — `check` applies the same), prepares the run
//! directory (or resumes it), removes stale iceoryx2 resources of this run,
//! starts the curriculum service, the learner and N actors with their logs in
//! `<run>/logs/`, restarts an actor that dies, shows a live progress line from
//! the processes' heartbeats, and on Ctrl-C / SIGTERM stops the actors first,
//! then the learner (which drains the step stream and writes a final
//! checkpoint) and the curriculum service (which saves its state).
//!
//! `join` starts an actor host of a run whose learner host was launched with
//! `--listen`; each host then runs a bridge (`multihost.rs`, `pednav_bridge`).
//!
//! Children run in their own process group (so a terminal's Ctrl-C reaches the
//! launcher only, which then stops them in order) and get SIGTERM if the
//! launcher itself dies. `launch.rs` turns the flags into a prepared run,
//! `supervisor.rs` keeps the processes alive.

mod bench;
mod bench_bridge;
mod child;
mod exit_cause;
mod launch;
mod multihost;
mod relay;
mod soak;
mod supervisor;
mod tls;

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use pednav_runtime::{MemoryPlan, RunConfig};

#[derive(Parser)]
#[command(version, about = "Start, supervise and stop the processes of a pednav run")]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Start (or resume) a run: curriculum service, learner and N actors; with
    /// `--listen`, actor hosts can join it.
    Launch(launch::Launch),
    /// Join a run on another host (its `launch --listen`) with N actors on this one.
    Join(multihost::Join),
    /// The bridge between this host's processes of a run and the other hosts'
    /// (started by `launch --listen` and `join`; not for direct use).
    #[command(hide = true)]
    Bridge(multihost::Bridge),
    /// Measure the runtime: step-stream throughput, weights latency, whole-system env steps/s.
    #[command(subcommand)]
    Bench(bench::Bench),
    /// Validate a config file, estimate the memory the run needs against this
    /// machine's (on stderr; refused when it cannot fit), and print the resolved config.
    Check {
        /// Config file (TOML).
        config: PathBuf,
        /// Actor processes the memory estimate assumes (as `launch --actors`).
        #[arg(long, default_value_t = 2)]
        actors: u32,
        /// Override one config field, `section.field=value` (repeatable), as `launch --set`.
        #[arg(long = "set", value_name = "FIELD=VALUE")]
        overrides: Vec<String>,
    },
}

/// Exit with the error's report on failure: its message and `Caused by:` chain, and
/// never a backtrace — `RUST_BACKTRACE` or `RUST_LIB_BACKTRACE` in a user's
/// environment would otherwise bury the cause under frames of the launcher itself.
fn main() -> std::process::ExitCode {
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("{}", exit_cause::report_of(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

impl Cmd {
    /// Whether this command links hosts over mutual TLS (its process, or a bridge it starts).
    fn uses_tls(&self) -> bool {
        match self {
            Cmd::Launch(a) => a.uses_tls(),
            Cmd::Join(a) => a.uses_tls(),
            Cmd::Bridge(a) => a.uses_tls(),
            Cmd::Bench(b) => b.uses_tls(),
            Cmd::Check { .. } => false,
        }
    }
}

fn run() -> Result<()> {
    let command = Cli::parse().command;
    // Before anything starts a thread (zenoh reads it once, at its first use).
    let runtime_set = tls::prepare_zenoh_runtime(command.uses_tls());
    pednav_runtime::init_logging();
    if runtime_set {
        tracing::info!(
            "TLS link: {}='{}' (zenoh 1.10's TLS link needs its reads and writes on one thread; docs/multi-host.md, TLS)",
            pednav_bridge::link::ZENOH_RUNTIME_ENV,
            pednav_bridge::link::TLS_SAFE_RUNTIME
        );
    }
    match command {
        Cmd::Bench(b) => bench::run(b),
        Cmd::Check { config, actors, overrides } => {
            let cfg = RunConfig::load_with(&config, &overrides)?;
            launch::check_devices(cfg.runtime.device, cfg.runtime.actor_device).with_context(|| {
                format!("{}: the config is valid, but its devices cannot be used", config.display())
            })?;
            launch::check_memory(&cfg, &config.display().to_string(), &MemoryPlan::of(&cfg, actors))?;
            print!("{}", cfg.to_toml());
            eprintln!("{}: valid", config.display());
            Ok(())
        }
        Cmd::Launch(args) => launch::launch(args),
        Cmd::Join(args) => multihost::join(args),
        Cmd::Bridge(args) => multihost::bridge(args),
    }
}
