//! # pednav-runtime — what every pednav process shares at run time
//!
//! - [`messages`]: the `#[repr(C)]`, zero-copy message types;
//! - [`channels`]: an actor's typed channel ends (step writer, episode reporter,
//!   task requester);
//! - [`ipc`]: the run's iceoryx2 services, opened identically everywhere, under a
//!   per-run prefix;
//! - [`config`]: the run configuration and its single validation gate;
//! - [`memory`]: the memory a run needs, estimated and checked against the machine's
//!   before anything starts;
//! - [`rundir`]: the run directory layout (resume, never overwrite);
//! - [`generations`]: two-generation atomic saves (checkpoints, curriculum state)
//!   that survive a kill or a full disk at any step;
//! - [`metrics`]: CSV + TensorBoard scalars, whose columns [`columns`] names once;
//! - [`weights`]: the flat weights message;
//! - [`reliable`]: sequence numbers, acknowledgements and resends that make a step
//!   stream lossless across a restarted learner and a cut link;
//! - [`reports`]: episode reports held by their actor until the curriculum service
//!   acknowledges them, taken once however often they arrive;
//! - [`signal`]: Ctrl-C / SIGTERM as a flag;
//! - [`stats`]: the stats files each process writes and the soak and tests read;
//! - [`write_health`]: writes that failed (a full disk), logged once per interval and
//!   reported in the heartbeat while the process goes on;
//! - [`log_health`]: the process's own log lines, counted when the log refuses them.

#![warn(missing_docs)]

pub mod channels;
pub mod columns;
pub mod config;
pub mod error;
pub mod generations;
pub mod ipc;
pub mod log_health;
pub mod memory;
pub mod messages;
pub mod metrics;
pub mod reliable;
pub mod reports;
pub mod rundir;
pub mod signal;
pub mod stats;
pub mod weights;
pub mod write_health;

pub use config::{ActorPolicy, RunConfig, RuntimeConfig};
pub use error::{Result, RuntimeError};
pub use ipc::{Ipc, run_prefix};
pub use memory::{MemoryEstimate, MemoryPlan};
pub use metrics::{AppendFile, Metrics, MetricsFailure, TbWriter};
pub use rundir::{MAX_RESTARTS, RESTART_WINDOW, RestartRecord, RunDir};
pub use signal::StopFlag;

/// Set up `tracing` for a process: human-readable lines on stderr (the launcher
/// sends them to `logs/<process>.log`; lines the log refuses are counted and shown in
/// the heartbeat, [`log_health`]), level from `RUST_LOG` (default info).
pub fn init_logging() {
    // zenoh's peer routing warns at every start that gossip is off, which pednav's
    // links choose on purpose (no traffic to hosts nobody named): not shown by default.
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info,zenoh::net::routing::hat::peer=error"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_target(false)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_writer(|| log_health::LoggedWriter)
        .try_init();
}

/// Nanoseconds since the Unix epoch.
pub fn now_ns() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos() as u64).unwrap_or(0)
}
