//! The memory a run needs, estimated before anything starts, against the machine's.
//!
//! `pednav-run check` and every `pednav-run launch` (new or resumed), after
//! [`RunConfig::validate`], estimate the run ([`RunConfig::memory_estimate`]), print
//! one line per component and the total on stderr ([`MemoryEstimate::lines`]), and
//! refuse a config whose estimate exceeds [`USABLE_SHARE`] of the machine's memory
//! (`MemTotal` of `/proc/meminfo`) with an error naming the field that sets the
//! largest part, its value, the estimate, the other large parts and what fits
//! ([`MemoryEstimate::check`]; [`RunConfig::check_memory`] is both). Where
//! `/proc/meminfo` cannot be read the launcher warns and refuses nothing.
//!
//! # The rule for the replay pools
//!
//! Both pools grow on demand, so what counts is the most a run can ever fill:
//!
//! - the non-terminal ring holds one slot per stored step: at most
//!   `min(replay.nonterminal_capacity, runtime.max_env_steps)`;
//! - the terminal pool holds, per goal-reaching episode, one entry for each of the
//!   last min(n, L − 1) transitions of its L steps (n = `dsac.n_step`, 1 in the
//!   paper; a first step is never a stored transition), so at most n entries per
//!   n + 1 steps: `min(replay.terminal_capacity, runtime.max_env_steps · n / (n + 1))`
//!   (`max_env_steps / 2` for the paper's one-step transitions).
//!
//! (`runtime.max_env_steps` counts the steps the learner received over the whole run,
//! resumes included, and a resumed learner starts with an empty replay, so the bound
//! holds across resumes; the few records drained at the stop are not counted.)
//! `runtime.max_env_steps = 0` (no bound) leaves the capacities. How many episodes
//! reach the goal is not known in advance (≈ 0.1–0.3 % of steps on the reference
//! scene, far more with a curriculum of easy tasks), so the terminal pool is sized at
//! its bound, not at a guess: the estimate is what the run *can* need. The paper's
//! capacities (1.5e6 each) at 84×84 and N_h 16 come to ≈ 10 GiB for the ring and
//! ≈ 168 GiB for the terminal pool (each entry keeps its own 17 frames, 120 kB), so
//! the paper presets are refused on machines below ≈ 200 GiB unless
//! `replay.terminal_capacity` is lowered (the error says to what) — an unbounded run
//! with many short successful episodes would fill it.
//!
//! Per-item sizes come from [`ReplayFootprint`], the definition the learner's replay
//! is tested against (`DualReplay::stored_bytes`), so estimate and storage cannot
//! drift. Networks are built on the CPU and their parameters counted. The rest —
//! the learner's batch activations, an actor's renderer and simulator, the
//! processes' own footprint — are measured constants, named as such below.

use pednav_config::ReplayFootprint;
use pednav_nets::{DeviceSpec, DsacNets, EncoderKind};

use crate::channels::HELD_REPORTS;
use crate::config::RunConfig;
use crate::error::{Result, RuntimeError};
use crate::ipc::STEP_ROUND_PER_ACTOR;
use crate::messages::{EpisodePoint, StepHeader};

/// The share of the machine's memory a run may be estimated to need: the kernel, the
/// page cache and the rest of the machine keep the remainder.
pub const USABLE_SHARE: f64 = 0.9;

/// Measured: resident memory of an actor process besides its environments — the
/// renderer (Mesa's CPU rasteriser and its context), the scene, the runtime and the
/// binary. `pednav-sim bench --envs 1` peaks at 125 MiB, a `cpu_reduced` actor with
/// 4 envs at 131 MiB (2-core machine, llvmpipe); rounded up.
pub const ACTOR_BASE_BYTES: u64 = 160 << 20;

/// Measured: resident memory per environment of an actor — simulator state, render
/// target and readback. `pednav-sim bench` at 84×84 grows by 0.22 MB per env from 1
/// to 64 envs; rounded up (the policy's per-env inference cache is in the allowance).
pub const ACTOR_ENV_BYTES: u64 = 512 << 10;

/// Measured: resident memory of the processes besides replay, networks, batches and
/// actors — the launcher (8 MB), the curriculum service (13 MB) and the learner's
/// runtime (30 MB in a smoke-sized update); rounded up.
pub const PROCESSES_BASE_BYTES: u64 = 128 << 20;

/// Measured: the learner's peak memory per update beyond its networks (activations
/// kept for the backward pass, their gradients, the batch itself), as two terms:
///
/// - encoders: `B × side² × 4 B` per encoder network (online, twin and target
///   encoders each count one) times a factor of the encoder kind and the window w =
///   N_h + n frames a sampled transition spans (n = `dsac.n_step`) — the 3D-TCN's
///   activations grow with it (10 × w), frame stacking's mostly do not (16 + w / 2:
///   its first convolution folds the frames into channels);
///   the MLP's are in the heads' term;
/// - heads: `B × quantiles × hidden × 4 B` per quantile network (online, target,
///   twin) times [`HEAD_FACTOR`].
///
/// Fitted to `pednav-device-check --device cpu` peak RSS minus process and networks
/// (2-core machine): the paper's 3D-TCN (84², N_h 16, B 64, 6 encoders) 1.36 GB,
/// frame stacking N_h 16 / 4: 225 / 184 MB, the CPU preset (42², N_h 8, B 32, shared
/// encoder) 40 MB, the state preset 15 MB; every factor rounded up.
pub fn encoder_factor(encoder: EncoderKind, window: usize) -> f64 {
    match encoder {
        EncoderKind::Tcn => 10.0 * window as f64,
        EncoderKind::FrameStack => 16.0 + window as f64 / 2.0,
        EncoderKind::Mlp => 0.0,
    }
}

/// See [`encoder_factor`].
pub const HEAD_FACTOR: f64 = 2.0;

/// What the estimate assumes beyond the config.
#[derive(Debug, Clone, Copy)]
pub struct MemoryPlan {
    /// Actor processes (`--actors`).
    pub actors: u32,
    /// Environments per actor (`--envs`, else `runtime.envs_per_actor`).
    pub envs_per_actor: usize,
    /// Where the learner trains: on a GPU its networks and batches are in the GPU's
    /// memory, not counted against the host's.
    pub learner_device: DeviceSpec,
}

impl MemoryPlan {
    /// The plan of `cfg` as it says: its devices and envs per actor, with `actors` actors.
    pub fn of(cfg: &RunConfig, actors: u32) -> MemoryPlan {
        MemoryPlan { actors, envs_per_actor: cfg.runtime.envs_per_actor, learner_device: cfg.runtime.device }
    }
}

/// Which part of the run a [`MemoryItem`] is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MemoryPart {
    /// The replay's non-terminal ring.
    Ring,
    /// The replay's terminal pool.
    TerminalPool,
    /// The learner's networks and optimiser state.
    Networks,
    /// The learner's batch and activations.
    Batch,
    /// The actor processes.
    Actors,
    /// The step stream's shared memory.
    StepStream,
    /// The processes' own footprint.
    Processes,
}

/// One component of the estimate.
#[derive(Debug, Clone)]
pub struct MemoryItem {
    /// Which part.
    pub part: MemoryPart,
    /// What it is, for people.
    pub what: &'static str,
    /// How it is counted (e.g. `200,000 steps × 1,789 B`).
    pub how: String,
    /// The settings that size it (dotted fields with their values, or flags).
    pub fields: String,
    /// Bytes.
    pub bytes: u128,
    /// Counted against the host's memory (false: in a GPU's memory).
    pub on_host: bool,
    /// Bytes per pool item (the pools only).
    pub per_item: u128,
}

/// The estimate of a run, component by component.
#[derive(Debug, Clone)]
pub struct MemoryEstimate {
    /// The components.
    pub items: Vec<MemoryItem>,
    /// How the pools were bounded (one line, printed with the estimate).
    pub pool_rule: String,
}

impl MemoryEstimate {
    /// Bytes needed in the host's memory.
    pub fn host_total(&self) -> u128 {
        self.items.iter().filter(|i| i.on_host).map(|i| i.bytes).sum()
    }

    /// The component of `part`.
    pub fn item(&self, part: MemoryPart) -> &MemoryItem {
        self.items.iter().find(|i| i.part == part).expect("every part is estimated")
    }

    /// The estimate as lines for people: a header, one line per component, the total
    /// against `machine` (`MemTotal`, bytes; `None` when unknown).
    pub fn lines(&self, machine: Option<u64>) -> Vec<String> {
        let mut out = vec![format!("memory estimate ({}):", self.pool_rule)];
        for i in &self.items {
            let place = if i.on_host { "" } else { " [GPU memory, not counted here]" };
            out.push(format!("  {:<34} {:>10}  {} — {}{place}", i.what, human(i.bytes), i.how, i.fields));
        }
        let total = human(self.host_total());
        out.push(match machine {
            Some(m) => format!(
                "  total {total} of this machine's {} (MemTotal; a run may use {:.0} % = {})",
                human(m as u128),
                USABLE_SHARE * 100.0,
                human(usable(m))
            ),
            None => format!("  total {total} (the machine's memory is unknown: /proc/meminfo unreadable)"),
        });
        out
    }
}

/// The machine's memory in bytes: `MemTotal` of `/proc/meminfo` (`None` when unreadable).
pub fn machine_memory() -> Option<u64> {
    meminfo_field("MemTotal:")
}

/// Memory available to new processes now: `MemAvailable` of `/proc/meminfo`.
pub fn available_memory() -> Option<u64> {
    meminfo_field("MemAvailable:")
}

fn meminfo_field(name: &str) -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with(name))?;
    let kb: u64 = line[name.len()..].trim().trim_end_matches("kB").trim().parse().ok()?;
    Some(kb * 1024)
}

/// The most terminal entries `steps` env steps can create with `n_step`-step
/// transitions: n per goal-reaching episode of at least n + 1 steps (see the module
/// docs), so `steps · n / (n + 1)`.
fn terminal_fill(steps: u64, n_step: usize) -> u64 {
    (steps as u128 * n_step as u128 / (n_step as u128 + 1)) as u64
}

fn usable(machine: u64) -> u128 {
    (machine as f64 * USABLE_SHARE) as u128
}

impl RunConfig {
    /// State-target floats the learner's replay keeps per step (as the learner process
    /// builds it: `nets.state_dim` with a state head, else none).
    pub fn replay_state_target_dim(&self) -> usize {
        if self.dsac.builds_state_head() { self.nets.state_dim } else { 0 }
    }

    /// The memory this run needs under `plan`, component by component (see the
    /// module docs for the pools' rule and the measured constants).
    pub fn memory_estimate(&self, plan: &MemoryPlan) -> Result<MemoryEstimate> {
        let n = self.dsac.n_step;
        let fp = ReplayFootprint::new(self.frame_kind(), self.nets.history, n, self.replay_state_target_dim());
        let max_steps = self.runtime.max_env_steps;
        let bound = |capacity: usize, by_steps: u64| -> u128 {
            if max_steps > 0 { (capacity as u128).min(by_steps as u128) } else { capacity as u128 }
        };
        let (ring_n, term_n) = (
            bound(self.replay.nonterminal_capacity, max_steps),
            bound(self.replay.terminal_capacity, terminal_fill(max_steps, n)),
        );
        let limited = |n: u128, cap: usize, what: &str| {
            if n < cap as u128 {
                format!(" (bounded by runtime.max_env_steps = {max_steps}{what})")
            } else {
                String::new()
            }
        };
        let pool_rule = if max_steps > 0 {
            format!(
                "replay pools at the most a run can fill: min(capacity, runtime.max_env_steps = {max_steps}) steps, \
                 min(capacity, {}) terminal entries",
                terminal_fill(max_steps, n)
            )
        } else {
            "replay pools at their capacities: runtime.max_env_steps = 0 sets no bound on what a run can fill"
                .to_string()
        };
        let mut items = vec![
            MemoryItem {
                part: MemoryPart::Ring,
                what: "replay, non-terminal ring",
                how: format!("{} steps × {} B", group(ring_n), group(fp.ring_step as u128)),
                fields: format!(
                    "replay.nonterminal_capacity = {}{}",
                    self.replay.nonterminal_capacity,
                    limited(ring_n, self.replay.nonterminal_capacity, "")
                ),
                bytes: ring_n * fp.ring_step as u128,
                on_host: true,
                per_item: fp.ring_step as u128,
            },
            MemoryItem {
                part: MemoryPart::TerminalPool,
                what: "replay, terminal pool",
                how: format!(
                    "{} entries × {} B (each copies its N_h + n = {} frames)",
                    group(term_n),
                    group(fp.terminal_entry as u128),
                    self.nets.history + n
                ),
                fields: format!(
                    "replay.terminal_capacity = {}{}",
                    self.replay.terminal_capacity,
                    limited(
                        term_n,
                        self.replay.terminal_capacity,
                        &if n == 1 { " / 2".to_string() } else { format!(" · {n} / {}", n + 1) }
                    )
                ),
                bytes: term_n * fp.terminal_entry as u128,
                on_host: true,
                per_item: fp.terminal_entry as u128,
            },
        ];

        // Networks: built on the CPU and counted. Trained stores hold weights, two
        // AdamW moments and a gradient; the Polyak targets their weights only.
        let cpu = candle_core::Device::Cpu;
        let net_err = |e: pednav_nets::NetError| RuntimeError::Config {
            file: "memory estimate".into(),
            field: "nets".into(),
            value: String::new(),
            message: format!("the networks cannot be built: {e}"),
        };
        let nets = DsacNets::for_learner(&self.nets, &self.dsac, &cpu, 0).map_err(net_err)?;
        let targets: Vec<_> =
            std::iter::once(&nets.target.store).chain(nets.twin.as_ref().map(|t| &t.target.store)).collect();
        let target_params: usize = targets.iter().map(|s| s.num_scalars()).sum();
        let all_params: usize = nets.stores().iter().map(|s| s.num_scalars()).sum();
        let trained = all_params - target_params;
        let on_host = !plan.learner_device.is_gpu();
        items.push(MemoryItem {
            part: MemoryPart::Networks,
            what: "learner networks",
            how: format!(
                "{} trained parameters × 4 B × 4 (weights, 2 AdamW moments, gradient) + {} target parameters × 4 B",
                group(trained as u128),
                group(target_params as u128)
            ),
            fields: format!(
                "nets.encoder = {:?}, nets.image_size = {}, nets.history = {}, nets.hidden = {}, nets.shared_encoder = \
                 {}, dsac.twin_critics = {}",
                self.nets.encoder,
                self.nets.image_size,
                self.nets.history,
                self.nets.hidden,
                self.nets.shared_encoder,
                self.dsac.twin_critics
            ),
            bytes: (trained as u128 * 16) + target_params as u128 * 4,
            on_host,
            per_item: 0,
        });

        // Batches and activations: two measured terms (see `encoder_factor`).
        let encoders = [
            nets.policy.encoder.is_some(),
            nets.fraction.encoder.is_some(),
            nets.quantile.encoder.is_some(),
            nets.target.encoder.is_some(),
            nets.twin.as_ref().is_some_and(|t| t.quantile.encoder.is_some()),
            nets.twin.as_ref().is_some_and(|t| t.target.encoder.is_some()),
        ]
        .into_iter()
        .filter(|&e| e)
        .count();
        let critics = 2 + 2 * usize::from(nets.twin.is_some());
        let window = self.nets.history + self.dsac.n_step; // the frames a sampled transition spans
        let b = self.dsac.batch_size as f64;
        let side2 = (self.nets.image_size * self.nets.image_size) as f64;
        let enc_factor = encoder_factor(self.nets.encoder, window);
        let enc_bytes =
            if self.nets.encoder == EncoderKind::Mlp { 0.0 } else { b * side2 * 4.0 * encoders as f64 * enc_factor };
        let head_bytes = b * (self.nets.quantiles * self.nets.hidden) as f64 * 4.0 * critics as f64 * HEAD_FACTOR;
        items.push(MemoryItem {
            part: MemoryPart::Batch,
            what: "learner batch and activations",
            how: if self.nets.encoder == EncoderKind::Mlp {
                format!(
                    "B {} × {} quantiles × {} hidden × 4 B × {critics} critic nets × {HEAD_FACTOR} (measured factor)",
                    self.dsac.batch_size, self.nets.quantiles, self.nets.hidden
                )
            } else {
                format!(
                    "B {} × {}² px × 4 B × {encoders} encoder nets × {enc_factor} + heads {} (measured factors)",
                    self.dsac.batch_size,
                    self.nets.image_size,
                    human(head_bytes as u128)
                )
            },
            fields: format!("dsac.batch_size = {}, nets.history = {}", self.dsac.batch_size, self.nets.history),
            bytes: (enc_bytes + head_bytes) as u128,
            on_host,
            per_item: 0,
        });

        // Actors: measured renderer/simulator constants plus the acting networks
        // (weights and a copy being loaded) and a full window of episode reports held
        // for the curriculum service (at most HELD_REPORTS of T_max + 1 points).
        let acting: usize = nets.acting_stores().iter().map(|s| s.num_scalars()).sum();
        let reports = (HELD_REPORTS * (self.sim.t_max as usize + 1) * std::mem::size_of::<EpisodePoint>()) as u128;
        let per_actor = ACTOR_BASE_BYTES as u128
            + plan.envs_per_actor as u128 * ACTOR_ENV_BYTES as u128
            + acting as u128 * 8
            + reports;
        items.push(MemoryItem {
            part: MemoryPart::Actors,
            what: "actors",
            how: format!(
                "{} × ({} renderer and simulator + {} envs × {} + acting network {} + episode reports held {}; \
                 renderer and env sizes measured)",
                plan.actors,
                human(ACTOR_BASE_BYTES as u128),
                plan.envs_per_actor,
                human(ACTOR_ENV_BYTES as u128),
                human(acting as u128 * 8),
                human(reports)
            ),
            fields: format!(
                "--actors {}, runtime.envs_per_actor = {}, sim.t_max = {}",
                plan.actors, plan.envs_per_actor, self.sim.t_max
            ),
            bytes: plan.actors as u128 * per_actor,
            on_host: true,
            per_item: 0,
        });

        // The step stream: each actor's publisher segment holds, per subscriber (2),
        // its queue and borrowed samples, plus the loaned ones; and the actor keeps
        // the records no learner has acknowledged yet (its resend window).
        let record = (self.observation_bytes() + std::mem::size_of::<StepHeader>()) as u128;
        let samples =
            (2 * (self.runtime.step_buffer + STEP_ROUND_PER_ACTOR) + 4 + self.runtime.resend_window()) as u128;
        items.push(MemoryItem {
            part: MemoryPart::StepStream,
            what: "step stream (shared memory, resend window)",
            how: format!(
                "{} actors × ({} queued + {} held for a resend) records × {} B",
                plan.actors,
                group(2 * (self.runtime.step_buffer + STEP_ROUND_PER_ACTOR) as u128 + 4),
                group(self.runtime.resend_window() as u128),
                group(record)
            ),
            fields: format!("runtime.step_buffer = {}", self.runtime.step_buffer),
            bytes: plan.actors as u128 * samples * record,
            on_host: true,
            per_item: 0,
        });
        items.push(MemoryItem {
            part: MemoryPart::Processes,
            what: "launcher, curriculum, learner runtime",
            how: "measured constant".into(),
            fields: "(fixed)".into(),
            bytes: PROCESSES_BASE_BYTES as u128,
            on_host: true,
            per_item: 0,
        });
        Ok(MemoryEstimate { items, pool_rule })
    }

    /// [`RunConfig::memory_estimate`] checked against `machine` ([`MemoryEstimate::check`]):
    /// the validation `pednav-run check` and `launch` apply after [`RunConfig::validate`].
    pub fn check_memory(&self, file: &str, plan: &MemoryPlan, machine: Option<u64>) -> Result<MemoryEstimate> {
        let est = self.memory_estimate(plan)?;
        est.check(self, file, machine)?;
        Ok(est)
    }
}

impl MemoryEstimate {
    /// Refuse this estimate of `cfg` (read from `file`) when it exceeds
    /// [`USABLE_SHARE`] of `machine` (bytes of `MemTotal`; `None` when unknown:
    /// nothing is refused), with an error naming the file, the field that sets the
    /// largest component and its value, the estimate, the largest parts with their
    /// fields, and how to fix it (for a pool: the most entries that fit).
    pub fn check(&self, cfg: &RunConfig, file: &str, machine: Option<u64>) -> Result<()> {
        let Some(machine) = machine else { return Ok(()) };
        let (total, limit) = (self.host_total(), usable(machine));
        if total <= limit {
            return Ok(());
        }
        let mut host: Vec<&MemoryItem> = self.items.iter().filter(|i| i.on_host).collect();
        host.sort_by_key(|i| std::cmp::Reverse(i.bytes));
        let largest = host[0];
        let (field, value) = match largest.part {
            MemoryPart::Ring => ("replay.nonterminal_capacity", cfg.replay.nonterminal_capacity.to_string()),
            MemoryPart::TerminalPool => ("replay.terminal_capacity", cfg.replay.terminal_capacity.to_string()),
            MemoryPart::Networks => ("nets.image_size", cfg.nets.image_size.to_string()),
            MemoryPart::Batch => ("dsac.batch_size", cfg.dsac.batch_size.to_string()),
            MemoryPart::Actors => ("runtime.envs_per_actor", cfg.runtime.envs_per_actor.to_string()),
            MemoryPart::StepStream => ("runtime.step_buffer", cfg.runtime.step_buffer.to_string()),
            MemoryPart::Processes => ("runtime", "(the processes' fixed overhead)".to_string()),
        };
        let parts: Vec<String> =
            host.iter().take(3).map(|i| format!("{} {} ({})", i.what, human(i.bytes), i.fields)).collect();
        // How to fix it: the pools are what scales; say how many items fit.
        let (ring, term) = (self.item(MemoryPart::Ring), self.item(MemoryPart::TerminalPool));
        let min_ring = (cfg.dsac.warmup as u128).max(cfg.dsac.batch_size as u128);
        let mut fixes = Vec::new();
        for (i, name, least) in [(term, "replay.terminal_capacity", 1), (ring, "replay.nonterminal_capacity", min_ring)]
        {
            let rest = total - i.bytes;
            if i.bytes > 0 && rest < limit {
                let fits = (limit - rest) / i.per_item;
                if fits >= least {
                    fixes.push(format!("lower {name} to at most {} (--set {name}={fits})", group(fits)));
                }
            }
        }
        // Or bound the run: the largest runtime.max_env_steps whose pools fit.
        let budget = limit.saturating_sub(total - ring.bytes - term.bytes);
        let (cr, ct) = (cfg.replay.nonterminal_capacity as u128, cfg.replay.terminal_capacity as u128);
        let n = cfg.dsac.n_step;
        let fill = |m: u128| cr.min(m) * ring.per_item + ct.min(terminal_fill(m as u64, n) as u128) * term.per_item;
        let (mut lo, mut hi) = (0u128, 2 * cr.max(ct) + 2);
        while lo < hi {
            let mid = (lo + hi).div_ceil(2);
            if fill(mid) <= budget { lo = mid } else { hi = mid - 1 }
        }
        if lo >= min_ring.max(1) {
            fixes.push(format!(
                "bound the run with runtime.max_env_steps = {lo} or less (--set runtime.max_env_steps={lo})"
            ));
        }
        if fixes.is_empty() {
            fixes.push(match largest.part {
                MemoryPart::Actors => "use fewer actors (--actors) or envs per actor (runtime.envs_per_actor)".into(),
                MemoryPart::Networks | MemoryPart::Batch => {
                    "use a smaller dsac.batch_size, nets.history or nets.image_size, or train on a GPU (--device)"
                        .into()
                }
                _ => "lower the fields above, or use a machine with more memory".into(),
            });
        }
        Err(RuntimeError::Config {
            file: file.to_string(),
            field: field.to_string(),
            value,
            message: format!(
                "the run needs an estimated {} of memory, more than this machine can give it ({} = {:.0} % of its {} \
                 MemTotal). Largest parts: {}. To fit: {}. ({})",
                human(total),
                human(limit),
                USABLE_SHARE * 100.0,
                human(machine as u128),
                parts.join("; "),
                fixes.join("; or "),
                self.pool_rule
            ),
        })
    }
}

/// Bytes for people: KiB, MiB or GiB with one decimal (scientific past 1e6 GiB).
pub fn human(bytes: u128) -> String {
    let b = bytes as f64;
    const GIB: f64 = (1u64 << 30) as f64;
    if b >= 1e6 * GIB {
        format!("{:.2e} GiB", b / GIB)
    } else if b >= GIB {
        format!("{:.1} GiB", b / GIB)
    } else if b >= (1 << 20) as f64 {
        format!("{:.1} MiB", b / (1u64 << 20) as f64)
    } else {
        format!("{:.1} KiB", b / 1024.0)
    }
}

/// An integer with thousands separators (`1,500,000`).
pub fn group(n: u128) -> String {
    let s = n.to_string();
    let mut out = String::with_capacity(s.len() + s.len() / 3);
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const GIB: u64 = 1 << 30;

    fn configs() -> std::path::PathBuf {
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../deploy/configs")
    }

    fn smoke_with(sets: &[&str]) -> RunConfig {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        RunConfig::load_with(&configs().join("smoke.toml"), &sets).unwrap()
    }

    /// The config: a terminal pool of 1e15 entries passes every per-field rule
    /// but cannot fit; the check `pednav-run check` runs refuses it, naming the field,
    /// its value, the estimate and a size that fits (which then passes).
    #[test]
    fn a_config_that_cannot_fit_is_refused_naming_the_field() {
        let cfg = smoke_with(&["replay.terminal_capacity=1000000000000000"]);
        let plan = MemoryPlan::of(&cfg, 2);
        let e = cfg.check_memory("big.toml", &plan, Some(24 * GIB)).unwrap_err().to_string();
        for want in
            ["big.toml", "`replay.terminal_capacity` = 1000000000000000", "GiB", "--set replay.terminal_capacity="]
        {
            assert!(e.contains(want), "{want:?} missing: {e}");
        }
        // The suggested capacity fits.
        let fits = e.split("--set replay.terminal_capacity=").nth(1).unwrap();
        let fits: String = fits.chars().take_while(char::is_ascii_digit).collect();
        let ok = smoke_with(&[&format!("replay.terminal_capacity={fits}")]);
        ok.check_memory("ok.toml", &plan, Some(24 * GIB)).unwrap();
        // So does the suggested bound on the run's env steps.
        let steps = e.split("--set runtime.max_env_steps=").nth(1).expect("a max_env_steps fix");
        let steps: String = steps.chars().take_while(char::is_ascii_digit).collect();
        let bounded =
            smoke_with(&["replay.terminal_capacity=1000000000000000", &format!("runtime.max_env_steps={steps}")]);
        bounded.check_memory("bounded.toml", &plan, Some(24 * GIB)).unwrap();
        // Unknown machine memory: nothing is refused.
        cfg.check_memory("big.toml", &plan, None).unwrap();
        // Too many actors names them.
        let e = smoke_with(&[]).check_memory("x", &MemoryPlan::of(&cfg, 64), Some(GIB)).unwrap_err().to_string();
        assert!(e.contains("runtime.envs_per_actor") && e.contains("--actors"), "{e}");
    }

    /// The replay's part of the estimate is the footprint of the replay's storage,
    /// written out here by hand: slots × (frame + u64 link + 3 f32 action + f32
    /// reward + bool flag + state target) and entries × ((N_h + n) frames + (N_h + n − 1)
    /// × (action + reward) + state target), pools bounded by min(capacity,
    /// max_env_steps) and min(capacity, max_env_steps · n / (n + 1)).
    #[test]
    fn the_replay_estimate_is_its_per_entry_sizes_in_closed_form() {
        // smoke: 42×42 pixels, N_h 4, capacities 20,000 and 2,000, no bound, no targets.
        let cfg = smoke_with(&[]);
        let est = cfg.memory_estimate(&MemoryPlan::of(&cfg, 1)).unwrap();
        let (frame, n) = (42 * 42, 4);
        assert_eq!(est.item(MemoryPart::Ring).bytes, 20_000 * (frame + 8 + 12 + 4 + 1));
        assert_eq!(est.item(MemoryPart::TerminalPool).bytes, 2_000 * ((n + 1) * frame + n * (12 + 4)));
        // Bounded by the run's env steps (the terminal pool by half of them), with the
        // state-prediction targets (22 floats per step and per entry).
        let cfg = smoke_with(&["runtime.max_env_steps=3000", "dsac.state_aux_weight=1.0"]);
        let est = cfg.memory_estimate(&MemoryPlan::of(&cfg, 1)).unwrap();
        let target = 22 * 4;
        assert_eq!(est.item(MemoryPart::Ring).bytes, 3_000 * (frame + 25 + target));
        assert_eq!(est.item(MemoryPart::TerminalPool).bytes, 1_500 * ((n + 1) * frame + n * 16 + target));
        // 3-step transitions: each entry copies N_h + 3 frames and N_h + 2 history
        // entries, and 3 of every 4 steps can be terminal entries.
        let cfg = smoke_with(&["runtime.max_env_steps=3000", "dsac.n_step=3"]);
        let est = cfg.memory_estimate(&MemoryPlan::of(&cfg, 1)).unwrap();
        assert_eq!(est.item(MemoryPart::Ring).bytes, 3_000 * (frame + 25));
        assert_eq!(est.item(MemoryPart::TerminalPool).bytes, 2_000 * ((n + 3) * frame + (n + 2) * 16));
        let cfg = smoke_with(&["runtime.max_env_steps=2000", "dsac.n_step=3"]);
        let est = cfg.memory_estimate(&MemoryPlan::of(&cfg, 1)).unwrap();
        assert_eq!(est.item(MemoryPart::TerminalPool).bytes, 1_500 * ((n + 3) * frame + (n + 2) * 16));
        // State observations: 22 f32 per frame, history 1.
        let cfg = RunConfig::load(&configs().join("cpu_state.toml")).unwrap();
        let est = cfg.memory_estimate(&MemoryPlan::of(&cfg, 2)).unwrap();
        assert_eq!(est.item(MemoryPart::Ring).bytes, 500_000 * (22 * 4 + 25));
        assert_eq!(est.item(MemoryPart::TerminalPool).bytes, 200_000 * (2 * 22 * 4 + 16));
        // A GPU learner's networks and batches are not counted against the host.
        let gpu = MemoryPlan { learner_device: DeviceSpec::Cuda(0), ..MemoryPlan::of(&cfg, 2) };
        let on_gpu = cfg.memory_estimate(&gpu).unwrap();
        assert_eq!(
            on_gpu.host_total(),
            est.host_total() - est.item(MemoryPart::Networks).bytes - est.item(MemoryPart::Batch).bytes
        );
    }

    /// Every shipped config fits a 24 GiB machine (this one) with 2 actors, except the
    /// paper presets, whose terminal pool at its capacity (1.5e6 × 17 frames at 84²)
    /// cannot: they are refused naming `replay.terminal_capacity` and a value that fits.
    #[test]
    fn shipped_configs_on_a_24_gib_machine() {
        let mut files: Vec<_> = std::fs::read_dir(configs())
            .unwrap()
            .chain(std::fs::read_dir(configs().join("paper")).unwrap())
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "toml"))
            .collect();
        files.sort();
        assert!(files.len() >= 12, "{files:?}");
        for f in files {
            let cfg = RunConfig::load(&f).unwrap();
            // Every shipped config — the paper's included, with its terminal pool capped
            // (see deploy/configs/paper/*.toml) — fits a 24 GiB machine with 2 actors.
            cfg.check_memory(&f.display().to_string(), &MemoryPlan::of(&cfg, 2), Some(24 * GIB))
                .unwrap_or_else(|e| panic!("{}: {e}", f.display()));
        }
        // Table IV's own terminal capacity (1.5e6 windows of 17 frames) cannot fit,
        // and the refusal says what would.
        let paper = configs().join("paper/navacl_plus_s_16.toml");
        let mut cfg = RunConfig::load(&paper).unwrap();
        cfg.replay.terminal_capacity = 1_500_000;
        let e = cfg.check_memory("paper", &MemoryPlan::of(&cfg, 2), Some(24 * GIB)).unwrap_err().to_string();
        assert!(
            e.contains("`replay.terminal_capacity` = 1500000") && e.contains("--set replay.terminal_capacity="),
            "{e}"
        );
    }

    #[test]
    fn bytes_and_counts_read_well() {
        assert_eq!(group(1_500_000), "1,500,000");
        assert_eq!(group(999), "999");
        assert_eq!(human(3 << 29), "1.5 GiB");
        assert_eq!(human(5 << 20), "5.0 MiB");
        assert_eq!(human(u128::MAX), "3.17e29 GiB");
    }
}
