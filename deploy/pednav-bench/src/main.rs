//! `pednav-bench` — the runtime's test tooling, beside the launcher: measurements
//! (`stream`, `weights`, `system` within one host; `bridge` across two hosts on
//! loopback) and fault-injection soaks (`soak`: a run whose processes are SIGKILLed at
//! seeded random times, across hosts with `--across-hosts`). Figures go in
//! `docs/`; none of it is in CI but the bridge's smoke test (`tests/tests/multihost.rs`).
//!
//! `pednav-run bench ARGS` runs `pednav-bench ARGS` (the command users knew first);
//! the launcher itself carries none of this code.

mod bridge;
mod relay;
mod runtime;
mod soak;

use anyhow::Result;
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(version, about = "Measure pednav's runtime and soak it with faults (also `pednav-run bench`)")]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Step-record throughput between two processes.
    Stream {
        /// Records to send.
        #[arg(long, default_value_t = 200_000)]
        records: u64,
        /// Frame side in pixels (record payload = side² bytes).
        #[arg(long, default_value_t = 84)]
        frame: usize,
    },
    /// Weights broadcast latency to N subscriber processes.
    Weights {
        /// Subscriber processes.
        #[arg(long, default_value_t = 1)]
        subscribers: usize,
        /// Broadcasts to time.
        #[arg(long, default_value_t = 200)]
        repeats: usize,
        /// Image size of the networks whose policy is broadcast (84: the paper's).
        #[arg(long, default_value_t = 84)]
        image_size: usize,
    },
    /// Whole-system env steps/s with 1 and 2 actors.
    System {
        /// Actor counts to measure.
        #[arg(long, value_delimiter = ',', default_value = "1,2")]
        actors: Vec<u32>,
        /// Envs per actor.
        #[arg(long, default_value_t = 16)]
        envs: usize,
        /// Env steps per measurement (the learner's budget).
        #[arg(long, default_value_t = 40_000)]
        steps: u64,
        /// Also measure with policy inference (TCN, N_h 16, 84×84, streaming cache).
        #[arg(long, default_value_t = true)]
        inference: bool,
    },
    /// Soak: a smoke-config run (30 min by default; not in CI) whose learner, curriculum
    /// service and actors are SIGKILLed at seeded random times (--across-hosts: a
    /// learner host and an actor host on this machine, whose bridges are killed and
    /// whose link is cut too); reports the launchers' restarts, whether training
    /// continued after each kill, and steps lost between the actors and the learner
    /// (Markdown on stdout, soak.json in the run directory).
    Soak(soak::Soak),
    /// The bridges of a run across hosts, on loopback: step records/s, weights and
    /// task latency, and records lost or duplicated across a cut link and a stalled
    /// learner (about 2½ minutes with the defaults).
    Bridge(bridge::BenchBridge),
    /// (internal) publisher side of `stream`.
    #[command(hide = true)]
    StreamPublisher { prefix: String, records: u64, frame: usize },
    /// (internal) subscriber side of `weights`.
    #[command(hide = true)]
    WeightsSubscriber { prefix: String, repeats: usize, ready: std::path::PathBuf },
}

impl Cmd {
    /// Whether the command runs a link over mutual TLS.
    fn uses_tls(&self) -> bool {
        matches!(self, Cmd::Bridge(b) if b.uses_tls())
    }
}

/// Exit with the error's message and causes on one line on failure (no backtrace).
fn main() -> std::process::ExitCode {
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run() -> Result<()> {
    let command = Cli::parse().command;
    pednav_bridge::link::start_process(command.uses_tls());
    match command {
        Cmd::Stream { records, frame } => runtime::stream(records, frame),
        Cmd::StreamPublisher { prefix, records, frame } => runtime::stream_publisher(&prefix, records, frame),
        Cmd::Weights { subscribers, repeats, image_size } => runtime::weights_latency(subscribers, repeats, image_size),
        Cmd::WeightsSubscriber { prefix, repeats, ready } => runtime::weights_subscriber(&prefix, repeats, &ready),
        Cmd::System { actors, envs, steps, inference } => runtime::system(&actors, envs, steps, inference),
        Cmd::Soak(args) => soak::run(args),
        Cmd::Bridge(args) => bridge::run(args),
    }
}
