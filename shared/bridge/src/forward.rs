//! What both bridges share: the newest-wins slot a zenoh callback fills, the tally of
//! what a bridge moved (written to the run's `stats/bridge.json`), and how the local
//! run's services are opened.
//!
//! Invariant: a zenoh callback never blocks — it only stores into a [`Latest`] slot
//! or a channel — because a blocked receive path stalls the sending host's queue
//! until zenoh closes the transport (`wait_before_close`).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

pub(crate) use pednav_runtime::stats::BridgeStats;
use pednav_runtime::{Ipc, RunConfig, RunDir, StopFlag, run_prefix};

use crate::error::{BridgeError, Result};

/// The name the learner host goes by on the link (its liveliness token and heartbeat key).
pub const LEARNER_HOST: &str = "learner-host";

/// How often a bridge writes its tally to `stats/bridge.json`.
pub(crate) const STATS_EVERY: Duration = Duration::from_secs(10);

/// How long a bridge's loop sleeps when a pass found nothing to move.
pub(crate) const IDLE: Duration = Duration::from_micros(250);

/// A zenoh error as a [`BridgeError::Link`] naming what was being done.
pub(crate) fn link_err(what: &'static str) -> impl Fn(zenoh::Error) -> BridgeError {
    move |e| BridgeError::Link(format!("{what}: {e}"))
}

/// Count and log (at debug level: a flood would fill the log) a refused message.
pub(crate) fn refuse(tally: &Tally, e: &BridgeError) {
    let first = tally.refused.fetch_add(1, Ordering::Relaxed) == 0;
    if first {
        tracing::warn!("a message from the link was refused (further ones are counted in stats/bridge.json): {e}");
    } else {
        tracing::debug!("refused: {e}");
    }
}

/// The newest value a callback stored, taken by the bridge's loop; an older one not
/// yet taken is replaced (acknowledgement tables and weights: newest wins).
pub(crate) struct Latest<T>(Arc<Mutex<Option<T>>>);

impl<T> Clone for Latest<T> {
    fn clone(&self) -> Self {
        Latest(self.0.clone())
    }
}

impl<T> Latest<T> {
    pub(crate) fn new() -> Latest<T> {
        Latest(Arc::new(Mutex::new(None)))
    }

    pub(crate) fn put(&self, value: T) {
        *self.0.lock().unwrap_or_else(|p| p.into_inner()) = Some(value);
    }

    pub(crate) fn take(&self) -> Option<T> {
        self.0.lock().unwrap_or_else(|p| p.into_inner()).take()
    }
}

impl<T: Clone> Latest<T> {
    /// The value, left in place (for a queryable that answers with the newest).
    pub(crate) fn peek(&self) -> Option<T> {
        self.0.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }
}

/// Counters a bridge and its callbacks and workers add to.
#[derive(Default)]
pub struct Tally {
    /// Step records moved (put on the link, or published locally).
    pub step_records: AtomicU64,
    /// Their observation bytes.
    pub step_bytes: AtomicU64,
    /// Episode reports moved (reports sent again by their actor included).
    pub episode_reports: AtomicU64,
    /// Acknowledgement tables (of step records) moved.
    pub ack_tables: AtomicU64,
    /// Acknowledgement tables of episode reports moved.
    pub report_acks: AtomicU64,
    /// Weights versions moved.
    pub weights: AtomicU64,
    /// Task requests answered across the link.
    pub tasks: AtomicU64,
    /// Heartbeats moved.
    pub heartbeats: AtomicU64,
    /// Messages refused (malformed, another version, an actor id that is not the
    /// sender's, an observation of another size).
    pub refused: AtomicU64,
    /// Records or reports not delivered: ones a learner or curriculum service did not
    /// take (gone or stalled past `runtime.give_up_secs`), ones a learner-host worker
    /// dropped beyond its backlog, and reports an actor host did not put on the link
    /// while the learner host was away. The actor still holds each step record and
    /// sends it again when asked, and each episode report until the curriculum service
    /// acknowledges it.
    pub not_delivered: AtomicU64,
    /// Times a host's liveliness token was withdrawn.
    pub hosts_gone: AtomicU64,
}

impl Tally {
    /// Add `n` to `counter`.
    pub(crate) fn add(counter: &AtomicU64, n: u64) {
        counter.fetch_add(n, Ordering::Relaxed);
    }

    /// The counters now, as written to `stats/bridge.json`.
    pub fn snapshot(&self, role: &str, host: &str, run: &str) -> BridgeStats {
        let get = |c: &AtomicU64| c.load(Ordering::Relaxed);
        BridgeStats {
            role: role.to_string(),
            host: host.to_string(),
            run: run.to_string(),
            step_records: get(&self.step_records),
            step_bytes: get(&self.step_bytes),
            episode_reports: get(&self.episode_reports),
            ack_tables: get(&self.ack_tables),
            report_acks: get(&self.report_acks),
            weights: get(&self.weights),
            tasks: get(&self.tasks),
            heartbeats: get(&self.heartbeats),
            refused: get(&self.refused),
            not_delivered: get(&self.not_delivered),
            hosts_gone: get(&self.hosts_gone),
        }
    }
}

/// The run a bridge serves: its directory, resolved config and local services.
pub(crate) struct LocalRun {
    pub dir: RunDir,
    pub cfg: RunConfig,
    pub prefix: String,
    pub give_up: Duration,
}

impl LocalRun {
    /// The run in `run_dir` (its `config.toml` must be there).
    pub(crate) fn open(run_dir: &std::path::Path) -> Result<LocalRun> {
        let dir = RunDir::new(run_dir);
        let cfg = dir.load_config()?;
        let prefix = run_prefix(dir.root());
        let give_up = Duration::from_secs_f64(cfg.runtime.give_up_secs);
        Ok(LocalRun { dir, cfg, prefix, give_up })
    }

    /// A connection to the run's services as the node `name`.
    pub(crate) fn ipc(&self, name: &str, stop: &StopFlag) -> Result<Ipc> {
        Ok(Ipc::new(&self.prefix, name, self.cfg.runtime.step_buffer, self.give_up, stop.clone())?)
    }

    /// Write the tally (a failed write is logged, never fatal: the bridge goes on).
    pub(crate) fn write_stats(&self, stats: &BridgeStats) {
        if let Err(e) = self.dir.write_stats("bridge", stats) {
            tracing::warn!("stats/bridge.json not written: {e}");
        }
    }
}
