//! `pednav-learner` — the learner process of a pednav run.
//!
//! Receives every step record (the stream is lossless), rebuilds N_h-frame
//! observations per (actor, env, incarnation) inside the `DualReplay` (frames
//! stored once), runs DSAC updates at the configured replay ratio — the
//! `RateLimiter` holds back updates until there is data and holds back inserts (so
//! the actors wait on their full send buffers) when updates lag — publishes the
//! acting weights every `runtime.weights_every` updates, writes checkpoints and
//! metrics, and on Ctrl-C/SIGTERM drains what was sent, writes a final checkpoint
//! and exits.
//!
//! Resume: a checkpoint in the run directory restores networks, optimisers, α,
//! RNGs and the limiter's counters. The replay itself is not checkpointed (up to
//! 3e6 frames); a resumed learner refills `dsac.warmup` steps — not counted
//! towards the replay ratio — before it updates again.
//!
//! This file parses the flags and wires the process together; the loop is
//! [`process::LearnerProcess`].

mod intake;
mod process;

use std::path::PathBuf;

use anyhow::Result;
use clap::Parser;
use pednav_runtime::{RunDir, StopFlag};

#[derive(Parser)]
#[command(
    version,
    about = "pednav learner: dual replay + DSAC updates at a fixed replay ratio, weight broadcasts, checkpoints"
)]
struct Cli {
    /// The run directory (created by `pednav-run`).
    #[arg(long)]
    run_dir: PathBuf,
    /// Compute threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Where to train: cpu, cuda or cuda:N (default: the config's `runtime.device`).
    #[arg(long)]
    device: Option<pednav_nets::DeviceSpec>,
}

fn main() -> Result<()> {
    pednav_runtime::init_logging();
    let cli = Cli::parse();
    let threads = pednav_nets::init_cpu_runtime(cli.threads);
    let stop = StopFlag::install();
    let dir = RunDir::new(&cli.run_dir);
    let cfg = dir.load_config()?;
    let device_spec = cli.device.unwrap_or(cfg.runtime.device);
    let device = device_spec.open()?;
    // The CPU kernels' arithmetic (`auto` resolved for this CPU); CUDA runs candle's own.
    let conv_precision = if device.is_cpu() { cfg.nets.conv_precision.resolved().name() } else { "cuda" };
    tracing::info!(device = %device_spec, threads, conv_precision, "learner device");
    process::LearnerProcess::open(dir, cfg, &device, stop)?.run()
}
