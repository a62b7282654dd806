//! The run directory: one folder per run holding everything it produced.
//!
//! ```text
//! <run>/config.toml                resolved config (what every process reads)
//! <run>/checkpoints/learner/       DSAC checkpoint (safetensors + state.json)
//! <run>/checkpoints/curriculum.json curriculum state (gate, t_c, task net, RNG)
//! <run>/checkpoints/curriculum-snapshots/  curriculum states every 500 episodes (Fig. 4)
//! <run>/metrics/<process>.csv      metrics rows
//! <run>/tb/<process>/events.out.tfevents.*   TensorBoard event files
//! <run>/logs/<process>.log         each process's log (written by the launcher)
//! <run>/stats/<process>.json       end-of-process counters (steps, checksums)
//! <run>/launcher.pid               the supervising launcher's pid while it runs
//! <run>/DONE                       why the run ended, once its budget is spent
//! ```
//!
//! Every process finds these paths through [`RunDir`]; no binary spells them.
//!
//! Invariant: a run directory with a `config.toml` is resumed, never overwritten;
//! starting it with a different config is refused.

use std::path::{Path, PathBuf};

use crate::config::RunConfig;
use crate::error::{Result, RuntimeError};
use crate::generations::write_atomic;
use crate::ipc::{Ipc, run_prefix};
use crate::signal::StopFlag;

/// Paths of one run.
#[derive(Debug, Clone)]
pub struct RunDir {
    root: PathBuf,
}

impl RunDir {
    /// The run at `root` (not created).
    pub fn new(root: impl Into<PathBuf>) -> RunDir {
        RunDir { root: root.into() }
    }

    /// Create the run directory for `config`, or check that an existing one has
    /// the same config (a resume). Returns true when resuming.
    pub fn prepare(&self, config: &RunConfig) -> Result<bool> {
        for d in [self.root.clone(), self.checkpoints(), self.logs(), self.metrics(), self.tb(), self.stats()] {
            std::fs::create_dir_all(&d).map_err(|e| RuntimeError::file(&d, format!("cannot create: {e}")))?;
        }
        let path = self.config_path();
        if path.exists() {
            let existing = RunConfig::load(&path)?;
            if &existing != config {
                return Err(RuntimeError::file(
                    &path,
                    "this run directory already holds a different config; resume it without --config, \
                     or start a new run with another --run-dir",
                ));
            }
            Ok(true)
        } else {
            write_atomic(&path, config.to_toml().as_bytes())
                .map_err(|source| RuntimeError::Write { path: path.clone(), source })?;
            Ok(false)
        }
    }

    /// Join this run's services as the process `name` — how every process of a run
    /// (actor, learner, curriculum service) opens its [`Ipc`]: the run's prefix, its
    /// `runtime.step_buffer` and `runtime.give_up_secs`.
    pub fn join_ipc(&self, cfg: &RunConfig, name: &str, stop: StopFlag) -> Result<Ipc> {
        let give_up = std::time::Duration::from_secs_f64(cfg.runtime.give_up_secs);
        Ipc::new(&run_prefix(&self.root), name, cfg.runtime.step_buffer, give_up, stop)
    }

    /// The run's resolved config.
    pub fn load_config(&self) -> Result<RunConfig> {
        RunConfig::load(&self.config_path())
    }

    /// The root folder.
    pub fn root(&self) -> &Path {
        &self.root
    }
    /// `config.toml`.
    pub fn config_path(&self) -> PathBuf {
        self.root.join("config.toml")
    }
    /// `checkpoints/`.
    pub fn checkpoints(&self) -> PathBuf {
        self.root.join("checkpoints")
    }
    /// The learner's checkpoint folder.
    pub fn learner_checkpoint(&self) -> PathBuf {
        self.checkpoints().join("learner")
    }
    /// The curriculum state file.
    pub fn curriculum_state(&self) -> PathBuf {
        self.checkpoints().join("curriculum.json")
    }
    /// Where the curriculum service keeps a copy of its state every 500 episodes.
    pub fn curriculum_snapshots(&self) -> PathBuf {
        self.checkpoints().join("curriculum-snapshots")
    }
    /// The launcher's lock file (its pid), so a run is supervised once.
    pub fn launcher_lock(&self) -> PathBuf {
        self.root.join("launcher.pid")
    }
    /// The marker the learner writes when the run's budget is spent (its content says
    /// which budget); the launcher stops the run on it and clears it on a new start.
    pub fn done_marker(&self) -> PathBuf {
        self.root.join("DONE")
    }
    /// `metrics/<process>.csv`.
    pub fn metrics_csv(&self, process: &str) -> PathBuf {
        self.metrics().join(format!("{process}.csv"))
    }
    /// `logs/`.
    pub fn logs(&self) -> PathBuf {
        self.root.join("logs")
    }
    /// `metrics/`.
    pub fn metrics(&self) -> PathBuf {
        self.root.join("metrics")
    }
    /// `tb/`.
    pub fn tb(&self) -> PathBuf {
        self.root.join("tb")
    }
    /// `stats/`.
    pub fn stats(&self) -> PathBuf {
        self.root.join("stats")
    }
    /// `restarts.jsonl`: one [`RestartRecord`] per restart the launcher made.
    pub fn restarts_log(&self) -> PathBuf {
        self.root.join("restarts.jsonl")
    }

    /// Append a restart to [`RunDir::restarts_log`] (one JSON object per line).
    pub fn append_restart(&self, record: &RestartRecord) -> Result<()> {
        let path = self.restarts_log();
        let line = serde_json::to_string(record).expect("a restart record serialises") + "\n";
        // Whole lines only: a write the disk refuses is cut off again (AppendFile).
        let mut file = crate::AppendFile::open(&path)?;
        file.append(line.into_bytes());
        match file.failure() {
            None => Ok(()),
            Some(f) => {
                Err(RuntimeError::Write { path, source: std::io::Error::new(f.error.kind(), f.error.to_string()) })
            }
        }
    }

    /// Every restart recorded so far, in order (an unreadable line is skipped with a warning).
    pub fn read_restarts(&self) -> Vec<RestartRecord> {
        let text = std::fs::read_to_string(self.restarts_log()).unwrap_or_default();
        text.lines()
            .filter(|l| !l.trim().is_empty())
            .filter_map(|l| {
                serde_json::from_str(l)
                    .map_err(|e| tracing::warn!("{}: unreadable restart record: {e}", self.restarts_log().display()))
                    .ok()
            })
            .collect()
    }

    /// Write a stats file atomically (`stats/<name>.json`; the types are [`crate::stats`]).
    pub fn write_stats(&self, name: &str, value: &impl serde::Serialize) -> Result<()> {
        let path = self.stats().join(format!("{name}.json"));
        let text = serde_json::to_string_pretty(value).expect("stats serialise");
        write_atomic(&path, text.as_bytes()).map_err(|source| RuntimeError::Write { path, source })
    }

    /// Read a stats file (`stats/<name>.json`): `None` when it does not exist (yet); an
    /// error naming the file when it does not hold a `T` (another writer's field names).
    pub fn read_stats<T: serde::de::DeserializeOwned>(&self, name: &str) -> Result<Option<T>> {
        let path = self.stats().join(format!("{name}.json"));
        let Ok(text) = std::fs::read_to_string(&path) else { return Ok(None) };
        serde_json::from_str(&text)
            .map(Some)
            .map_err(|e| RuntimeError::file(&path, format!("not the stats expected: {e}")))
    }

    /// Next incarnation number of process `name` (counts starts; kept in `stats/`).
    pub fn next_incarnation(&self, name: &str) -> Result<u32> {
        let path = self.stats().join(format!("{name}.starts"));
        let n = std::fs::read_to_string(&path).ok().and_then(|s| s.trim().parse::<u32>().ok()).unwrap_or(0) + 1;
        write_atomic(&path, n.to_string().as_bytes()).map_err(|source| RuntimeError::Write { path, source })?;
        Ok(n)
    }
}

/// The launcher's restart budget: a process that dies more than this many times within
/// [`RESTART_WINDOW`] ends the run (`pednav-run`'s supervisor keeps it; the soak plans
/// its kills inside it).
pub const MAX_RESTARTS: usize = 5;
/// The window of [`MAX_RESTARTS`].
pub const RESTART_WINDOW: std::time::Duration = std::time::Duration::from_secs(120);

/// One restart the launcher made, as `restarts.jsonl` records it (written by the
/// supervisor, read by the soak and by people): the contract between them is this type.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RestartRecord {
    /// When the death was seen, seconds since the Unix epoch.
    pub unix_time: f64,
    /// The supervisor's process name (`learner`, `curriculum`, `actor-K`).
    pub process: String,
    /// How it ended (`exit status: 1`, `signal: 9 (SIGKILL)`, `hung: …`).
    pub status: String,
    /// The error it died of, one line (its message and root cause), from its log.
    pub cause: String,
    /// The process's restart count after this one.
    pub restart: u32,
    /// Seconds waited before starting it again (back-off on a repeated error).
    pub delay_secs: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The supervisor writes restarts and the soak reads them through one type: a
    /// field renamed on one side cannot go unnoticed.
    #[test]
    fn restart_records_read_back_as_written() {
        let root = std::env::temp_dir().join(format!("pednav-restarts-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        std::fs::create_dir_all(&root).unwrap();
        let dir = RunDir::new(&root);
        assert!(dir.read_restarts().is_empty());
        let a = RestartRecord {
            unix_time: 1.5,
            process: "learner".into(),
            status: "exit status: 1".into(),
            cause: "the final checkpoint could not be written — No space left on device (os error 28)".into(),
            restart: 1,
            delay_secs: 0.0,
        };
        let b = RestartRecord { process: "actor-1".into(), restart: 2, delay_secs: 4.0, ..a.clone() };
        dir.append_restart(&a).unwrap();
        dir.append_restart(&b).unwrap();
        assert_eq!(dir.read_restarts(), vec![a, b]);
        let _ = std::fs::remove_dir_all(&root);
    }
}
