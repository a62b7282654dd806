//! `pednav-actor` — one actor process of a pednav run.
//!
//! Owns `runtime.envs_per_actor` simulator instances (`VecEnv`: one renderer, all
//! views in one submission and one readback) and a local copy of the policy.
//! Each iteration ([`process::ActorProcess::step`]):
//! 1. at an episode's start, ask the curriculum service for a task;
//! 2. pick up the newest weights, if the learner published any (never blocks);
//! 3. choose actions for all envs — through the `PolicyStream` cache, so a step
//!    costs one new frame of spatial convolution plus the temporal layers, not a
//!    recompute of all N_h frames;
//! 4. step all envs, render all views once;
//! 5. per env, loan a step record from shared memory, copy the frame straight
//!    from the renderer's mapped readback into it (the only copy between the
//!    rasteriser and the learner's replay), push the same bytes into the policy
//!    cache, send;
//! 6. at an episode's end, publish its report.
//!
//! This file parses the flags and wires the process together.

mod process;

use std::path::PathBuf;

use anyhow::Result;
use clap::Parser;
use pednav_runtime::{RunDir, StopFlag};

#[derive(Parser)]
#[command(version, about = "pednav actor: steps simulators, streams steps to the learner, acts with its newest policy")]
struct Cli {
    /// The run directory (created by `pednav-run`).
    #[arg(long)]
    run_dir: PathBuf,
    /// This actor's id (0-based; seeds and stream ids derive from it).
    #[arg(long)]
    actor: u32,
    /// Simulator instances in this actor (default: the config's `runtime.envs_per_actor`).
    #[arg(long)]
    envs: Option<usize>,
    /// Where to run policy inference: cpu, cuda or cuda:N (default: the config's
    /// `runtime.actor_device`).
    #[arg(long)]
    device: Option<pednav_nets::DeviceSpec>,
}

fn main() -> Result<()> {
    pednav_sim::prepare_headless_env();
    pednav_runtime::init_logging();
    let cli = Cli::parse();
    pednav_nets::init_cpu_runtime(Some(1));
    let stop = StopFlag::install();
    let dir = RunDir::new(&cli.run_dir);
    let cfg = dir.load_config()?;
    let device = cli.device.unwrap_or(cfg.runtime.actor_device).open()?;
    if device.is_cpu() {
        tracing::info!(conv_precision = cfg.nets.conv_precision.resolved().name(), "actor convolutions");
    }
    let opts = process::ActorOptions { actor: cli.actor, envs: cli.envs, device };
    process::ActorProcess::open(dir, cfg, opts, stop)?.run()
}
