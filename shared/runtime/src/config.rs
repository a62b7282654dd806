//! The run configuration: one TOML file holds everything every process needs,
//! and the resolved copy in the run directory is what all processes read.
//!
//! Invariant: [`RunConfig::validate`] is the single gate — a config that passes
//! can be built by every process (same image size, history, observation kind and
//! network sizes everywhere); one that fails names the file, the dotted field and
//! the value, before any process starts. Whether the run fits the machine's memory
//! depends on the machine and the number of actors, so it is a second check that the
//! launcher applies after this one (`check` and `launch`): [`crate::memory`].

use std::path::{Path, PathBuf};

use pednav_config::{CurriculumConfig, DsacConfig, FrameKind, ReplayConfig};
use pednav_nets::{DeviceSpec, EncoderKind, NetsConfig};
use pednav_sim::{ObsMode, STATE_OBS_DIM, Scene, SimConfig, state_obs_dim};
use serde::{Deserialize, Serialize};

use crate::channels::HELD_REPORTS;
use crate::error::{Result, RuntimeError};

/// How actors choose actions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ActorPolicy {
    /// Sample from the newest policy the learner published (training).
    #[default]
    Learned,
    /// Uniform random actions in [−1, 1]³ (the random-walk baseline, throughput benchmarks).
    Random,
}

/// Longest duration any `runtime.*_secs` setting may give (≈ 116 days): longer ones
/// are typos, and `std::time::Duration` cannot hold every finite `f64`.
pub const MAX_SECS: f64 = 1e7;

/// Largest `runtime.max_updates` and `runtime.max_env_steps` (0 is no bound): larger
/// ones are typos (10¹² env steps is decades of any machine's run).
pub const MAX_COUNT: u64 = 1_000_000_000_000;

/// Settings of the distributed runtime (processes, IPC, cadence of outputs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RuntimeConfig {
    /// Simulator instances per actor process (stepped and rendered as one batch).
    /// Range: 1 ..= 4096.
    pub envs_per_actor: usize,
    /// How actors choose actions.
    pub policy: ActorPolicy,
    /// Publish the policy weights every this many updates (K). Range: 1 ..= 1000000.
    pub weights_every: u64,
    /// Write a learner checkpoint every this many updates (and on stop). Range: 1 ..= 1e9.
    pub checkpoint_every_updates: u64,
    /// Also write a learner checkpoint when this many seconds passed since the last.
    /// Range: (0, 1e7].
    pub checkpoint_every_secs: f64,
    /// Save the curriculum state every this many episode reports (and on stop); at
    /// most 1,024: each actor holds its reports until a save holds them, 1,024 at most.
    /// Range: 1 ..= 1024.
    pub curriculum_save_every_episodes: u64,
    /// Write a metrics row (CSV + TensorBoard) every this many seconds, and a last one at stop.
    /// Range: (0, 1e7].
    pub metrics_every_secs: f64,
    /// Step records the learner's subscriber buffers before actors wait. Each actor
    /// also holds twice this many records until the learner acknowledges them, to send
    /// them again to a learner that restarts ([`RuntimeConfig::resend_window`]).
    /// Range: 16 ..= 1048576.
    pub step_buffer: usize,
    /// Seconds a lossless publisher (steps, episode reports) keeps retrying a full
    /// receiver before it gives up and the process exits with an error. Range: (0, 1e7].
    pub give_up_secs: f64,
    /// Seconds an actor waits for the curriculum service to answer a task request.
    /// Range: (0, 1e7].
    pub task_timeout_secs: f64,
    /// Stop the run after this many learner updates (0: run until stopped). Range: 0 ..= 1e12.
    pub max_updates: u64,
    /// Stop the run after this many env steps received by the learner (0: until stopped).
    /// Range: 0 ..= 1e12.
    pub max_env_steps: u64,
    /// Where the learner trains: "cpu", "cuda" or "cuda:N". CUDA needs the binaries
    /// built by `deploy/build_cuda.sh`; `--device` on `pednav-run launch` overrides it.
    pub device: DeviceSpec,
    /// Where the actors run policy inference ("cpu", "cuda", "cuda:N"; the simulator
    /// renders on the CPU either way); `--actor-device` on launch overrides it.
    pub actor_device: DeviceSpec,
    /// A learner or curriculum service that sent no heartbeat for this many seconds
    /// (after its first; they send one every `metrics_every_secs`) is treated as dead:
    /// the launcher kills it and restarts it from its checkpoint or state. Range:
    /// [3 × `metrics_every_secs`, 1e7].
    pub hang_secs: f64,
}

impl RuntimeConfig {
    /// Step records an actor holds until the learner acknowledges them: twice what
    /// the learner's queue holds, so the queue (not this window) is what makes an
    /// actor wait in normal running.
    pub fn resend_window(&self) -> usize {
        2 * self.step_buffer
    }
}

impl Default for RuntimeConfig {
    fn default() -> Self {
        RuntimeConfig {
            envs_per_actor: 4,
            policy: ActorPolicy::Learned,
            weights_every: 10,
            checkpoint_every_updates: 5000,
            checkpoint_every_secs: 900.0,
            curriculum_save_every_episodes: 100,
            metrics_every_secs: 10.0,
            step_buffer: 2048,
            give_up_secs: 600.0,
            task_timeout_secs: 120.0,
            max_updates: 0,
            max_env_steps: 0,
            device: DeviceSpec::Cpu,
            actor_device: DeviceSpec::Cpu,
            hang_secs: 600.0,
        }
    }
}

/// Everything a run needs; `config.toml` in the run directory.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RunConfig {
    /// Seed of the run: every process derives its own seed from it (actor k: seed ⊕ k).
    /// Range: any u64.
    pub seed: u64,
    /// Scene file (TOML), or a scene compiled in: `built-in:corner` (the reference,
    /// also what an absent value means) or `built-in:corner_plain` (the reference
    /// scene's first version, whose corners look alike).
    pub scene: Option<PathBuf>,
    /// Simulator.
    pub sim: SimConfig,
    /// Networks.
    pub nets: NetsConfig,
    /// DSAC hyper-parameters (Table IV).
    pub dsac: DsacConfig,
    /// Dual replay capacities.
    pub replay: ReplayConfig,
    /// Curriculum variant and constants.
    pub curriculum: CurriculumConfig,
    /// Processes and IPC.
    pub runtime: RuntimeConfig,
}

impl RunConfig {
    /// Read and validate a config file; relative scene paths resolve against the file's folder.
    pub fn load(path: &Path) -> Result<RunConfig> {
        RunConfig::load_with(path, &[])
    }

    /// [`RunConfig::load`] with `overrides` applied to the file before it is read:
    /// each is `section.field=value` with a TOML value (`dsac.twin_critics=true`,
    /// `runtime.max_env_steps=500000`, `curriculum.variant=navacl`; a bare word is a
    /// string). The result is validated like a file that says the same.
    pub fn load_with(path: &Path, overrides: &[String]) -> Result<RunConfig> {
        let text = std::fs::read_to_string(path).map_err(|e| RuntimeError::file(path, format!("cannot read: {e}")))?;
        let invalid = |e: &dyn std::fmt::Display| RuntimeError::file(path, format!("not a valid run config: {e}"));
        let mut cfg: RunConfig = if overrides.is_empty() {
            toml::from_str(&text).map_err(|e| invalid(&e))?
        } else {
            let mut table: toml::Table = toml::from_str(&text).map_err(|e| invalid(&e))?;
            for o in overrides {
                apply_override(&mut table, o).map_err(|m| RuntimeError::file(path, format!("--set {o}: {m}")))?;
            }
            let described = format!("with --set {}", overrides.join(" "));
            RunConfig::deserialize(table).map_err(|e| invalid(&format!("{described}: {e}")))?
        };
        if let Some(scene) = cfg.scene.as_mut().filter(|s| s.is_relative() && !pednav_sim::scene::is_built_in(s)) {
            let base = path.parent().unwrap_or(Path::new("."));
            let candidate = base.join(&*scene);
            if candidate.exists() || !scene.exists() {
                *scene = candidate;
            }
        }
        cfg.validate(&path.display().to_string())?;
        Ok(cfg)
    }

    /// The config as TOML (what the run directory keeps).
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).expect("a run config always serialises")
    }

    /// The scene of the run, as its processes see it: with the traffic fixtures
    /// (extra signal poles, head housings) when `sim.traffic` is on, so the
    /// curriculum's start checks know every collider the actors' worlds have.
    pub fn scene(&self) -> Result<Scene> {
        Scene::load_or_reference(self.scene.as_deref())
            .and_then(|s| s.with_traffic(self.sim.traffic))
            .map_err(|e| RuntimeError::file(self.scene.clone().unwrap_or_else(|| "reference scene".into()), e))
    }

    /// Check every section and their consistency; `file` names the source in errors.
    pub fn validate(&self, file: &str) -> Result<()> {
        let bad = |field: &str, value: String, message: &str| {
            Err(RuntimeError::Config {
                file: file.to_string(),
                field: field.to_string(),
                value,
                message: message.to_string(),
            })
        };
        let section = |name: &str, e: String| RuntimeError::Section {
            file: file.to_string(),
            section: name.to_string(),
            message: e,
        };
        self.sim.validate().map_err(|e| section("sim", e.to_string()))?;
        self.nets.validate().map_err(|e| section("nets", e.to_string()))?;
        self.dsac.validate().map_err(|e| section("dsac", e.to_string()))?;
        self.curriculum.validate().map_err(|e| section("curriculum", e.to_string()))?;
        let scene = self.scene()?;
        self.curriculum
            .validate_for_scene(&scene.origin, !scene.enlarged_curriculum_region.is_empty())
            .and_then(|()| self.curriculum.validate_for_traffic(self.sim.traffic.is_on()))
            .map_err(|e| RuntimeError::Config {
                file: file.to_string(),
                field: format!("curriculum.{}", e.field),
                value: e.value,
                message: e.message,
            })?;
        let dim = state_obs_dim(&self.sim); // the simulator's state vector: 22, or 50 with traffic
        match self.sim.obs_mode {
            ObsMode::Pixels => {
                if self.nets.encoder == EncoderKind::Mlp {
                    return bad("nets.encoder", "\"mlp\"".into(), "pixel observations need \"tcn\" or \"frame_stack\"");
                }
                if self.nets.image_size != self.sim.image_size as usize {
                    return bad(
                        "nets.image_size",
                        self.nets.image_size.to_string(),
                        &format!("must equal sim.image_size = {}", self.sim.image_size),
                    );
                }
                // As `random_shift > image_size / 4`: `4 × random_shift` could overflow.
                if self.dsac.random_shift > self.nets.image_size / 4 {
                    return bad(
                        "dsac.random_shift",
                        self.dsac.random_shift.to_string(),
                        &format!("must be at most a quarter of the image side ({})", self.nets.image_size / 4),
                    );
                }
            }
            ObsMode::State => {
                if self.dsac.random_shift != 0 {
                    return bad(
                        "dsac.random_shift",
                        self.dsac.random_shift.to_string(),
                        "shifts pixel frames: must be 0 for state observations",
                    );
                }
                if self.nets.encoder != EncoderKind::Mlp {
                    return bad("nets.encoder", format!("{:?}", self.nets.encoder), "state observations need \"mlp\"");
                }
                if self.nets.state_dim != dim {
                    return bad(
                        "nets.state_dim",
                        self.nets.state_dim.to_string(),
                        &format!(
                            "the simulator's state observation has {dim} values with sim.traffic = {:?} \
                             ({STATE_OBS_DIM} of the scene, {} more with traffic): set nets.state_dim = {dim}",
                            self.sim.traffic,
                            pednav_sim::TRAFFIC_STATE_DIM
                        ),
                    );
                }
            }
        }
        self.dsac.validate_with_encoder(self.nets.shared_encoder).map_err(|e| section("dsac", e.to_string()))?;
        if self.dsac.builds_state_head() && self.nets.state_dim != dim {
            return bad(
                "nets.state_dim",
                self.nets.state_dim.to_string(),
                &format!(
                    "dsac.state_aux_weight > 0 predicts the simulator's state vector of {dim} values \
                     (sim.traffic = {:?}): set nets.state_dim = {dim}",
                    self.sim.traffic
                ),
            );
        }
        // The replay's own rules (history vs observation kind, capacities), exactly as
        // the learner applies them when it builds the replay.
        self.replay
            .validate(self.frame_kind(), self.nets.history, self.dsac.n_step)
            .map_err(|e| section("replay (with nets.history and dsac.n_step)", e.to_string()))?;
        let r = &self.runtime;
        if r.envs_per_actor == 0 || r.envs_per_actor > 4096 {
            return bad("runtime.envs_per_actor", r.envs_per_actor.to_string(), "must be 1 … 4096");
        }
        for (field, v, min, max) in [
            ("runtime.weights_every", r.weights_every, 1, 1_000_000),
            ("runtime.checkpoint_every_updates", r.checkpoint_every_updates, 1, 1_000_000_000),
            ("runtime.max_updates", r.max_updates, 0, MAX_COUNT),
            ("runtime.max_env_steps", r.max_env_steps, 0, MAX_COUNT),
        ] {
            if !(min..=max).contains(&v) {
                return bad(field, v.to_string(), &format!("must be in {min}..={max}"));
            }
        }
        if r.curriculum_save_every_episodes == 0 || r.curriculum_save_every_episodes > HELD_REPORTS as u64 {
            return bad(
                "runtime.curriculum_save_every_episodes",
                r.curriculum_save_every_episodes.to_string(),
                &format!(
                    "must be 1 … {HELD_REPORTS}: each actor holds its episode reports until a saved curriculum state \
                     holds them, {HELD_REPORTS} at most"
                ),
            );
        }
        for (field, v) in [
            ("runtime.checkpoint_every_secs", r.checkpoint_every_secs),
            ("runtime.metrics_every_secs", r.metrics_every_secs),
            ("runtime.give_up_secs", r.give_up_secs),
            ("runtime.task_timeout_secs", r.task_timeout_secs),
        ] {
            if !(v > 0.0 && v <= MAX_SECS) {
                return bad(
                    field,
                    v.to_string(),
                    &format!("must be a positive number of seconds, at most {MAX_SECS:e}"),
                );
            }
        }
        if !(r.hang_secs <= MAX_SECS && r.hang_secs >= 3.0 * r.metrics_every_secs) {
            return bad(
                "runtime.hang_secs",
                r.hang_secs.to_string(),
                &format!(
                    "must be at least 3 × runtime.metrics_every_secs = {} (heartbeats come that often) \
                     and at most {MAX_SECS:e}",
                    3.0 * r.metrics_every_secs
                ),
            );
        }
        if !(16..=1 << 20).contains(&r.step_buffer) {
            return bad("runtime.step_buffer", r.step_buffer.to_string(), "must be 16 … 1048576 records");
        }
        let (nt, t) = (self.replay.nonterminal_capacity, self.replay.terminal_capacity);
        if nt < self.dsac.batch_size || t == 0 {
            return bad(
                "replay.nonterminal_capacity",
                nt.to_string(),
                &format!("must hold at least one batch ({}), and terminal_capacity ≥ 1", self.dsac.batch_size),
            );
        }
        if (self.dsac.warmup as usize) < self.dsac.batch_size {
            return bad(
                "dsac.warmup",
                self.dsac.warmup.to_string(),
                &format!("must be at least dsac.batch_size = {}", self.dsac.batch_size),
            );
        }
        if self.dsac.warmup as usize > nt {
            return bad(
                "dsac.warmup",
                self.dsac.warmup.to_string(),
                &format!("cannot exceed replay.nonterminal_capacity = {nt} (the learner would never start)"),
            );
        }
        if (self.dsac.gamma as f32 - self.curriculum.gamma).abs() > 1e-6 {
            return bad(
                "curriculum.gamma",
                self.curriculum.gamma.to_string(),
                &format!("must equal dsac.gamma = {} (the curriculum predicts the agent's returns)", self.dsac.gamma),
            );
        }
        Ok(())
    }

    /// Seed of the curriculum service's randomness (task sampling, the task-value
    /// net), derived from the run's one `seed` so that it differs from the learner's
    /// and the actors' streams; the Fig. 4 drawing restores a curriculum with it.
    pub fn curriculum_seed(&self) -> u64 {
        pednav_config::rng::curriculum_seed(self.seed)
    }

    /// What the learner's replay stores per step: frames of `sim.image_size`² pixels,
    /// or state vectors of `nets.state_dim` values.
    pub fn frame_kind(&self) -> FrameKind {
        match self.sim.obs_mode {
            ObsMode::Pixels => FrameKind::Pixels { size: self.sim.image_size as usize },
            ObsMode::State => FrameKind::State { dim: self.nets.state_dim },
        }
    }

    /// Bytes of one observation record (frame or state vector).
    pub fn observation_bytes(&self) -> usize {
        match self.sim.obs_mode {
            ObsMode::Pixels => (self.sim.image_size * self.sim.image_size) as usize,
            ObsMode::State => crate::messages::state_payload::bytes(state_obs_dim(&self.sim)),
        }
    }
}

/// Set `key.path=value` in `table` (see [`RunConfig::load_with`]).
fn apply_override(table: &mut toml::Table, assignment: &str) -> std::result::Result<(), String> {
    let (key, raw) = assignment.split_once('=').ok_or("expected section.field=value")?;
    let path: Vec<&str> = key.split('.').map(str::trim).collect();
    if path.iter().any(|p| p.is_empty()) {
        return Err(format!("`{key}` is not a dotted field name such as dsac.batch_size"));
    }
    let raw = raw.trim();
    let value = toml::from_str::<toml::Table>(&format!("v = {raw}"))
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(raw.to_string()));
    let (last, sections) = path.split_last().expect("split gives at least one part");
    let mut at = table;
    for section in sections {
        let entry = at.entry(section.to_string()).or_insert_with(|| toml::Value::Table(Default::default()));
        at = entry.as_table_mut().ok_or_else(|| format!("`{section}` is a value, not a section"))?;
    }
    at.insert(last.to_string(), value);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn with_traffic_the_runs_scene_carries_the_signal_poles_every_process_checks_starts_against() {
        let mut cfg = RunConfig::default();
        let off = cfg.scene().unwrap();
        cfg.sim.traffic = pednav_sim::TrafficLevel::Medium;
        let on = cfg.scene().unwrap();
        let extra = on.traffic.as_ref().unwrap().extra_poles.len();
        assert!(extra > 0 && on.traffic_fixtures && !off.traffic_fixtures);
        assert_eq!(on.obstacles.len(), off.obstacles.len() + extra);
        // A start touching an extra pole is refused by the scene the curriculum samples from.
        let p = on.traffic.as_ref().unwrap().extra_poles[0];
        let pose = pednav_sim::Pose { x: p[0] + 0.2, y: p[1], yaw: 0.0 };
        assert!(on.check_task(pose).is_err() && off.check_task(pose).is_ok());
    }

    #[test]
    fn defaults_are_valid_and_round_trip_through_toml() {
        let cfg = RunConfig::default();
        cfg.validate("defaults").unwrap();
        let back: RunConfig = toml::from_str(&cfg.to_toml()).unwrap();
        assert_eq!(back, cfg);
    }

    /// `conv_precision = "auto"` is written as it was given (each process resolves it
    /// for its own CPU) and is valid on every machine.
    #[test]
    fn auto_precision_round_trips_and_is_valid_everywhere() {
        let mut cfg = RunConfig::default();
        cfg.nets.conv_precision = pednav_nets::ConvPrecision::Auto;
        cfg.validate("auto.toml").unwrap();
        let text = cfg.to_toml();
        assert!(text.contains("conv_precision = \"auto\""), "{text}");
        let back: RunConfig = toml::from_str(&text).unwrap();
        assert_eq!(back.nets.conv_precision, pednav_nets::ConvPrecision::Auto);
    }

    #[test]
    fn errors_name_the_field_and_value() {
        let mut cfg = RunConfig::default();
        cfg.nets.image_size = 42;
        let e = cfg.validate("x.toml").unwrap_err().to_string();
        assert!(e.contains("x.toml") && e.contains("nets.image_size") && e.contains("42"), "{e}");
        let mut cfg = RunConfig::default();
        cfg.runtime.envs_per_actor = 0;
        let e = cfg.validate("x.toml").unwrap_err().to_string();
        assert!(e.contains("runtime.envs_per_actor"), "{e}");
        // More reports between two saves than an actor can hold.
        let mut cfg = RunConfig::default();
        cfg.runtime.curriculum_save_every_episodes = 5_000;
        let e = cfg.validate("x.toml").unwrap_err().to_string();
        assert!(
            e.contains("runtime.curriculum_save_every_episodes") && e.contains("5000") && e.contains("1024"),
            "{e}"
        );
        let mut cfg = RunConfig::default();
        cfg.dsac.warmup = 10;
        let e = cfg.validate("x").unwrap_err().to_string();
        assert!(e.contains("[dsac]") && e.contains("warmup") && e.contains("10"), "{e}");
        let mut cfg = RunConfig::default();
        cfg.dsac.batch_size = 16;
        cfg.dsac.warmup = 2_000_000;
        let e = cfg.validate("x").unwrap_err().to_string();
        assert!(e.contains("dsac.warmup") && e.contains("replay.nonterminal_capacity"), "{e}");
        let cfg = RunConfig { scene: Some("/nonexistent/scene.toml".into()), ..RunConfig::default() };
        assert!(cfg.validate("x").unwrap_err().to_string().contains("/nonexistent/scene.toml"));
        // A rule only the learner's replay knew: state observations have no history.
        let mut cfg = RunConfig::default();
        cfg.sim.obs_mode = ObsMode::State;
        cfg.nets.encoder = EncoderKind::Mlp;
        cfg.nets.state_dim = STATE_OBS_DIM;
        cfg.nets.history = 1;
        cfg.validate("x").unwrap();
        cfg.dsac.random_shift = 2;
        let e = cfg.validate("x").unwrap_err().to_string();
        assert!(e.contains("dsac.random_shift") && e.contains("state"), "{e}");
        cfg.dsac.random_shift = 0;
        cfg.nets.history = 8;
        let e = cfg.validate("x").unwrap_err().to_string();
        assert!(e.contains("nets.history") && e.contains("history") && e.contains("8") && e.contains("state"), "{e}");
        // With traffic the state observation is longer (the traffic part).
        cfg.nets.history = 1;
        cfg.sim.traffic = pednav_sim::TrafficLevel::Medium;
        let e = cfg.validate("x").unwrap_err().to_string();
        assert!(e.contains("nets.state_dim") && e.contains("50") && e.contains("Medium"), "{e}");
        cfg.nets.state_dim = 50;
        cfg.validate("x").unwrap();
        assert_eq!(cfg.observation_bytes(), crate::messages::state_payload::bytes(50));
        let mut cfg = RunConfig::default();
        cfg.dsac.state_aux_weight = 1.0;
        cfg.validate("x").unwrap();
        cfg.nets.state_dim = 5;
        let e = cfg.validate("x").unwrap_err().to_string();
        assert!(e.contains("nets.state_dim") && e.contains("state_aux_weight"), "{e}");
        cfg.dsac.state_aux_weight = -1.0;
        let e = cfg.validate("x").unwrap_err().to_string();
        assert!(e.contains("state_aux_weight") && e.contains("-1"), "{e}");
        let mut cfg = RunConfig::default();
        cfg.runtime.hang_secs = 20.0;
        let e = cfg.validate("x").unwrap_err().to_string();
        assert!(e.contains("runtime.hang_secs") && e.contains("metrics_every_secs = 30"), "{e}");
        let mut cfg = RunConfig::default();
        cfg.dsac.random_shift = 22;
        let e = cfg.validate("x").unwrap_err().to_string();
        assert!(e.contains("dsac.random_shift") && e.contains("21"), "{e}");
        // The online encoder's target features exist only with a shared encoder.
        let mut cfg = RunConfig::default();
        cfg.dsac.target_encoder = pednav_config::dsac::TargetEncoder::Online;
        let e = cfg.validate("x").unwrap_err().to_string();
        assert!(e.contains("[dsac]") && e.contains("target_encoder") && e.contains("nets.shared_encoder"), "{e}");
        cfg.nets.shared_encoder = true;
        cfg.validate("x").unwrap();
    }

    /// Values that once passed `check` and then panicked a process or were taken
    /// silently: each `--set` alone must be refused, naming the field, without a panic.
    #[test]
    fn malformed_values_are_refused_naming_the_field() {
        let dir = std::env::temp_dir().join(format!("pednav-config-malformed-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("base.toml");
        std::fs::write(&path, "").unwrap();
        let cases = [
            ("runtime.give_up_secs=1e20", "runtime.give_up_secs"),
            ("runtime.task_timeout_secs=1e300", "runtime.task_timeout_secs"),
            ("runtime.hang_secs=1e20", "runtime.hang_secs"),
            ("runtime.metrics_every_secs=inf", "runtime.metrics_every_secs"),
            ("runtime.step_buffer=9223372036854775807", "runtime.step_buffer"),
            ("dsac.random_shift=4611686018427387904", "dsac.random_shift"),
            ("dsac.target_entropy=nan", "target_entropy"),
            ("dsac.fraction_entropy=nan", "fraction_entropy"),
            ("dsac.initial_alpha=inf", "initial_alpha"),
            ("dsac.huber_kappa=inf", "huber_kappa"),
            ("dsac.max_grad_norm=inf", "max_grad_norm"),
            ("dsac.train_interval=0", "train_interval"),
            ("dsac.rate_slack=0", "rate_slack"),
            ("dsac.n_step=0", "n_step"),
            ("dsac.n_step=1000", "n_step"),
            ("dsac.contrast_weight=nan", "contrast_weight"),
            // The absurd learner settings, once "valid".
            ("dsac.lr_quantile=0.0", "lr_quantile"),
            ("dsac.lr_policy=1e15", "lr_policy"),
            ("dsac.lr_fraction=0.0", "lr_fraction"),
            ("dsac.contrast_weight=1e15", "contrast_weight"),
            ("runtime.weights_every=10000000", "runtime.weights_every"),
            ("runtime.max_env_steps=1000000000000000", "runtime.max_env_steps"),
            ("curriculum.net.lr=1e15", "net.lr"),
            ("sim.t_max=4000000000", "t_max"),
            ("nets.hidden=1000000", "hidden"),
            ("nets.quantiles=100000", "quantiles"),
            ("nets.quantile_grid=100000", "quantile_grid"),
            ("nets.history_features=100000", "history_features"),
            ("curriculum.net.hidden=[0]", "net.hidden"),
            ("curriculum.net.hidden=[64, 100000]", "net.hidden"),
            ("curriculum.net.lr=inf", "net.lr"),
            ("curriculum.net.batch=0", "net.batch"),
            ("curriculum.candidates=1000000000000000000", "candidates"),
            ("curriculum.pass_window=1000000000000000000", "pass_window"),
            ("curriculum.pass_threshold=nan", "pass_threshold"),
            ("sim.agent_height=inf", "agent_height"),
        ];
        for (set, field) in cases {
            let e = RunConfig::load_with(&path, &[set.to_string()]).expect_err(set).to_string();
            assert!(e.contains(field) && e.contains("base.toml"), "--set {set}: the error must name `{field}`: {e}");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_enlarged_region_needs_a_scene_that_has_one() {
        let mut cfg = RunConfig::default();
        cfg.curriculum.enlarged_region = true;
        cfg.validate("x").unwrap();
        let dir = std::env::temp_dir().join(format!("pednav-config-enlarged-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let plain = dir.join("plain.toml");
        let cut = pednav_sim::scene::REFERENCE_SCENE_TOML.split("# Enlarged ACL-proposed region").next().unwrap();
        std::fs::write(&plain, cut).unwrap();
        cfg.scene = Some(plain.clone());
        let e = cfg.validate("x").unwrap_err().to_string();
        assert!(e.contains("curriculum.enlarged_region") && e.contains("plain.toml"), "{e}");
        cfg.curriculum.enlarged_region = false;
        cfg.validate("x").unwrap();
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_signal_phase_in_the_task_needs_traffic() {
        let mut cfg: RunConfig = toml::from_str("[curriculum]\nsignal_phase = \"task\"\n").unwrap();
        let e = cfg.validate("run.toml").unwrap_err().to_string();
        assert!(e.contains("curriculum.signal_phase") && e.contains("sim.traffic"), "{e}");
        cfg.sim.traffic = pednav_sim::TrafficLevel::Medium;
        cfg.validate("run.toml").unwrap();
    }

    #[test]
    fn unknown_fields_and_variants_are_rejected() {
        assert!(toml::from_str::<RunConfig>("[runtime]\nenvs = 3\n").is_err());
        let e = toml::from_str::<RunConfig>("[curriculum]\nvariant = \"navacl_plus_sideways\"\n").unwrap_err();
        assert!(e.to_string().contains("variant"), "{e}");
    }

    #[test]
    fn overrides_set_typed_values_and_name_what_is_wrong() {
        let dir = std::env::temp_dir().join(format!("pednav-config-set-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("base.toml");
        std::fs::write(&path, "seed = 4\n[dsac]\nbatch_size = 32\nwarmup = 100\n").unwrap();
        let set = |o: &[&str]| RunConfig::load_with(&path, &o.iter().map(|s| s.to_string()).collect::<Vec<_>>());
        let cfg =
            set(&["dsac.twin_critics=true", "runtime.max_env_steps = 5000", "curriculum.variant=navacl"]).unwrap();
        assert!(cfg.dsac.twin_critics);
        assert_eq!((cfg.runtime.max_env_steps, cfg.dsac.batch_size, cfg.seed), (5000, 32, 4));
        assert_eq!(cfg.curriculum.variant, pednav_config::Variant::NavAcl);
        let e = set(&["dsac.batch_sise=3"]).unwrap_err().to_string();
        assert!(e.contains("batch_sise") && e.contains("base.toml"), "{e}");
        let e = set(&["dsac.warmup=10"]).unwrap_err().to_string();
        assert!(e.contains("warmup") && e.contains("10"), "{e}");
        let e = set(&["dsac"]).unwrap_err().to_string();
        assert!(e.contains("--set dsac") && e.contains("section.field=value"), "{e}");
        let e = set(&["seed.x=1"]).unwrap_err().to_string();
        assert!(e.contains("`seed` is a value"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
