//! Replay settings (the `[replay]` section) and what one stored frame is.

use serde::{Deserialize, Serialize};

use crate::error::{ConfigError, Result};

/// Replay settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReplayConfig {
    /// |B_N| capacity: steps in the non-terminal ring (Table IV: 1.5e6). Each step
    /// holds its frame plus 25 B ([`ReplayFootprint::ring_step`]: 7,081 B at 84×84).
    /// Range: ≥ max(N_h + n + 1, `dsac.batch_size`, `dsac.warmup`); the upper bound is
    /// the machine's memory (see `terminal_capacity`).
    pub nonterminal_capacity: usize,
    /// |B_T| capacity: terminal transitions kept (Table IV: 1.5e6). Each entry holds
    /// its own copy of N_h + n frames (n = `dsac.n_step`, 1 in the paper) ([`ReplayFootprint::terminal_entry`]: 120,208 B
    /// at 84×84, N_h 16), so the paper's capacity is ≈ 168 GiB if filled. The launcher
    /// sizes both pools at the most a run can fill — min(capacity,
    /// `runtime.max_env_steps`) ring steps, min(capacity, `runtime.max_env_steps` / 2)
    /// terminal entries, the capacities when the run is unbounded — and refuses a
    /// config that cannot fit the machine (`pednav-run check` prints the estimate).
    /// Range: ≥ 1, up to what fits the machine's memory.
    pub terminal_capacity: usize,
}

impl Default for ReplayConfig {
    fn default() -> Self {
        ReplayConfig { nonterminal_capacity: 1_500_000, terminal_capacity: 1_500_000 }
    }
}

impl ReplayConfig {
    /// The rules the learner's replay (`pednav_learner::DualReplay`) applies, for
    /// frames of `kind`, observation windows of `history` frames and `n_step`-step
    /// transitions (the run config's check calls this too, so a config the learner
    /// would refuse never starts a run).
    pub fn validate(&self, kind: FrameKind, history: usize, n_step: usize) -> Result<()> {
        if history == 0 || (matches!(kind, FrameKind::State { .. }) && history != 1) {
            return Err(ConfigError::learner("history", history, "must be ≥ 1 (exactly 1 for state observations)"));
        }
        if n_step == 0 {
            return Err(ConfigError::learner("n_step", n_step, "must be at least 1"));
        }
        if self.nonterminal_capacity < history + n_step + 1 {
            return Err(ConfigError::learner(
                "nonterminal_capacity",
                self.nonterminal_capacity,
                format!("must hold at least N_h + n + 1 = {} steps", history + n_step + 1),
            ));
        }
        if self.terminal_capacity == 0 {
            return Err(ConfigError::learner("terminal_capacity", self.terminal_capacity, "must be at least 1"));
        }
        Ok(())
    }
}

/// What one stored observation frame is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameKind {
    /// Greyscale `size × size` pixels (u8).
    Pixels {
        /// Side length.
        size: usize,
    },
    /// A state vector of `dim` floats (the MLP encoder; history must be 1).
    State {
        /// Length.
        dim: usize,
    },
}

impl FrameKind {
    /// Values (bytes of pixels, or floats) in one frame.
    pub fn values_per_frame(&self) -> usize {
        match *self {
            FrameKind::Pixels { size } => size * size,
            FrameKind::State { dim } => dim,
        }
    }

    /// Bytes of one stored frame: a `u8` per pixel, an `f32` per state value.
    pub fn bytes_per_frame(&self) -> usize {
        match *self {
            FrameKind::Pixels { size } => size * size,
            FrameKind::State { dim } => dim * 4,
        }
    }
}

/// Values of one stored action (speed, turn rate, head yaw); the learner's replay
/// asserts at compile time that this is `pednav_nets::ACTION_DIM`.
pub const ACTION_VALUES: usize = 3;

/// Bytes the learner's replay (`pednav_learner::DualReplay`) holds per stored item —
/// the one definition both the replay's own accounting (`DualReplay::stored_bytes`,
/// tested equal to these sizes times its counts) and the run's memory estimate
/// (`pednav-run check`) use, so the two cannot drift.
///
/// - A **ring step** (non-terminal pool; every step the learner stores occupies one
///   slot, first and terminal steps included): its frame, the link to the previous
///   step of its episode (`u64`), the action that led to it (`ACTION_VALUES` × `f32`),
///   the reward (`f32`), the terminal flag (`bool`), and its state target
///   (`state_target_dim` × `f32`, 0 without the state-prediction loss).
/// - A **terminal entry**: its own copy of the N_h + n frames of the transition's
///   window (so it outlives the ring; n = `dsac.n_step`), the N_h + n − 1 actions and
///   rewards of its history, and o_t's state target.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReplayFootprint {
    /// Bytes of one slot of the non-terminal ring.
    pub ring_step: usize,
    /// Bytes of one entry of the terminal pool.
    pub terminal_entry: usize,
}

impl ReplayFootprint {
    /// Bytes of a ring slot besides its frame and state target: the previous-step link
    /// (`u64`), the action (`ACTION_VALUES` × `f32`), the reward (`f32`) and the
    /// terminal flag (`bool`).
    pub const RING_STEP_EXTRA: usize = 8 + ACTION_VALUES * 4 + 4 + 1;
    /// Bytes of one history entry of a terminal entry: an action and a reward.
    pub const HISTORY_ENTRY: usize = ACTION_VALUES * 4 + 4;

    /// The footprint of a replay of frames of `kind`, windows of `history` frames,
    /// `n_step`-step transitions and state targets of `state_target_dim` floats (0:
    /// none kept).
    pub fn new(kind: FrameKind, history: usize, n_step: usize, state_target_dim: usize) -> ReplayFootprint {
        let frame = kind.bytes_per_frame();
        let target = state_target_dim * 4;
        let span = history + n_step;
        ReplayFootprint {
            ring_step: frame + Self::RING_STEP_EXTRA + target,
            terminal_entry: span * frame + (span - 1) * Self::HISTORY_ENTRY + target,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Capacities below their lower bounds are refused naming the field; the bounds
    /// themselves are accepted (the upper bound is the machine's memory, checked by
    /// the launcher).
    #[test]
    fn capacities_below_their_ranges_are_refused_naming_the_field() {
        let pixels = FrameKind::Pixels { size: 42 };
        let cases = [
            (ReplayConfig { nonterminal_capacity: 8 + 3, ..Default::default() }, 3, Some("nonterminal_capacity")),
            (ReplayConfig { nonterminal_capacity: 8 + 3 + 1, ..Default::default() }, 3, None),
            (ReplayConfig { terminal_capacity: 0, ..Default::default() }, 1, Some("terminal_capacity")),
            (ReplayConfig { terminal_capacity: 1, ..Default::default() }, 1, None),
        ];
        for (cfg, n_step, refused) in cases {
            match (cfg.validate(pixels, 8, n_step), refused) {
                (Ok(()), None) => {}
                (Err(e), Some(field)) => assert_eq!(e.field, field, "{e}"),
                (got, want) => panic!("{cfg:?}: got {got:?}, want {want:?}"),
            }
        }
    }
}
