//! Replay settings (the `[replay]` section) and what one stored frame is.

use serde::{Deserialize, Serialize};

use crate::error::{ConfigError, Result};

/// Replay settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReplayConfig {
    /// |B_N| capacity: steps in the non-terminal ring (Table IV: 1.5e6).
    pub nonterminal_capacity: usize,
    /// |B_T| capacity: terminal transitions kept (Table IV: 1.5e6).
    pub terminal_capacity: usize,
}

impl Default for ReplayConfig {
    fn default() -> Self {
        ReplayConfig { nonterminal_capacity: 1_500_000, terminal_capacity: 1_500_000 }
    }
}

impl ReplayConfig {
    /// The rules the learner's replay (`pednav_learner::DualReplay::new`) applies,
    /// for frames of `kind` and observation windows of `history` frames (the run config's check calls this too, so a
    /// config the learner would refuse never starts a run).
    pub fn validate(&self, kind: FrameKind, history: usize) -> Result<()> {
        if history == 0 || (matches!(kind, FrameKind::State { .. }) && history != 1) {
            return Err(ConfigError::learner("history", history, "must be ≥ 1 (exactly 1 for state observations)"));
        }
        if self.nonterminal_capacity < history + 2 {
            return Err(ConfigError::learner(
                "nonterminal_capacity",
                self.nonterminal_capacity,
                format!("must hold at least N_h + 2 = {} steps", history + 2),
            ));
        }
        if self.terminal_capacity == 0 {
            return Err(ConfigError::learner("terminal_capacity", self.terminal_capacity, "must be positive"));
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
}
