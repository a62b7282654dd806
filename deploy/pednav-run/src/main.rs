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

mod child;
mod exit_cause;
mod launch;
mod multihost;
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
    /// Measure the runtime and soak it with faults: runs `pednav-bench ARGS`, built
    /// beside this binary (`pednav-run bench --help` lists its commands).
    #[command(disable_help_flag = true)]
    Bench {
        /// The arguments of `pednav-bench`.
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<std::ffi::OsString>,
    },
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
            Cmd::Bench { .. } => false, // pednav-bench prepares its own
            Cmd::Check { .. } => false,
        }
    }
}

fn run() -> Result<()> {
    let command = Cli::parse().command;
    pednav_bridge::link::start_process(command.uses_tls());
    match command {
        Cmd::Bench { args } => run_bench(&args),
        Cmd::Check { config, actors, overrides } => {
            let cfg = RunConfig::load_with(&config, &overrides)?;
            launch::check_init_from(&cfg)?;
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

/// `pednav-run bench ARGS`: replace this process with `pednav-bench ARGS` from this
/// binary's folder (the measurements and soaks live there, not in the launcher).
fn run_bench(args: &[std::ffi::OsString]) -> Result<()> {
    use std::os::unix::process::CommandExt;
    let exe = std::env::current_exe().context("locating pednav-run")?;
    let bench = exe.parent().context("pednav-run has no folder")?.join("pednav-bench");
    if !bench.exists() {
        anyhow::bail!("{} not found (build it: cargo build --release -p pednav-bench)", bench.display());
    }
    let err = std::process::Command::new(&bench).args(args).exec();
    Err(err).with_context(|| format!("starting {}", bench.display()))
}
