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
            let tmp = path.with_extension("toml.tmp");
            std::fs::write(&tmp, config.to_toml()).map_err(|e| RuntimeError::file(&tmp, e))?;
            std::fs::rename(&tmp, &path).map_err(|e| RuntimeError::file(&path, e))?;
            Ok(false)
        }
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

    /// Write a JSON stats file atomically (`stats/<name>.json`).
    pub fn write_stats(&self, name: &str, value: &serde_json::Value) -> Result<()> {
        let path = self.stats().join(format!("{name}.json"));
        let tmp = path.with_extension("json.tmp");
        let text = serde_json::to_string_pretty(value).expect("JSON values serialise");
        std::fs::write(&tmp, text).map_err(|e| RuntimeError::file(&tmp, e))?;
        std::fs::rename(&tmp, &path).map_err(|e| RuntimeError::file(&path, e))
    }

    /// Next incarnation number of process `name` (counts starts; kept in `stats/`).
    pub fn next_incarnation(&self, name: &str) -> Result<u32> {
        let path = self.stats().join(format!("{name}.starts"));
        let n = std::fs::read_to_string(&path).ok().and_then(|s| s.trim().parse::<u32>().ok()).unwrap_or(0) + 1;
        std::fs::write(&path, n.to_string()).map_err(|e| RuntimeError::file(&path, e))?;
        Ok(n)
    }
}
