//! Network settings (a section of every run's config file).

use serde::{Deserialize, Serialize};

use crate::error::{Result, config_error};

/// Dimension of the pedestrian's action (speed, turn rate, head yaw).
pub const ACTION_DIM: usize = 3;

/// How observations are encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EncoderKind {
    /// 3D temporal convolutions over the last N_h frames plus dilated 1-D
    /// convolutions over the past actions and rewards (the paper's 3D-TCN).
    Tcn,
    /// The N_h frames stacked as channels of 2D convolutions (the paper's baseline).
    FrameStack,
    /// A two-layer MLP over the simulator's state-debug observation.
    Mlp,
}

/// Architecture of the policy, fraction-proposal and quantile networks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NetsConfig {
    /// Observation encoder: `tcn` (paper), `frame_stack` (baseline) or `mlp` (state observations).
    pub encoder: EncoderKind,
    /// Side of the square greyscale frames in pixels (84 in the paper; 42 in the CPU preset).
    pub image_size: usize,
    /// N_h: frames per observation (16 in the paper, 8 in the CPU preset, 4 for Non-ACL-FR-4).
    pub history: usize,
    /// Length of the state-debug observation (used by the `mlp` encoder only).
    pub state_dim: usize,
    /// Width of the fully connected layer after the encoder (256 in the paper).
    pub hidden: usize,
    /// Output width of each history branch (actions, rewards): 8 in the paper.
    pub history_features: usize,
    /// N: quantile fractions proposed per state-action (Table IV: 32).
    pub quantiles: usize,
    /// Intervals of the NDQFN fixed fraction grid on which monotone quantile values are
    /// produced (then linearly interpolated at the proposed fractions). Not in the
    /// paper; 32 matches N so every proposed fraction sees a distinct grid interval on average.
    pub quantile_grid: usize,
    /// `false` (paper): policy, fraction-proposal and quantile networks each have their
    /// own encoder. `true`: one encoder, trained by the critic loss; the policy and
    /// fraction heads use its features detached (≈ 3× less encoder compute).
    pub shared_encoder: bool,
}

impl Default for NetsConfig {
    fn default() -> Self {
        NetsConfig {
            encoder: EncoderKind::Tcn,
            image_size: 84,
            history: 16,
            state_dim: 22,
            hidden: 256,
            history_features: 8,
            quantiles: 32,
            quantile_grid: 32,
            shared_encoder: false,
        }
    }
}

impl NetsConfig {
    /// Reject settings no network can be built from, naming the field.
    pub fn validate(&self) -> Result<()> {
        if self.encoder != EncoderKind::Mlp {
            if self.image_size < 21 {
                return Err(config_error(
                    "image_size",
                    self.image_size,
                    "must be at least 21 pixels (three strided stages)",
                ));
            }
            let min_history = if self.encoder == EncoderKind::Tcn { 2 } else { 1 };
            if self.history < min_history || self.history > 64 {
                return Err(config_error("history", self.history, format!("must be in {min_history}..=64")));
            }
        } else if self.state_dim == 0 {
            return Err(config_error("state_dim", self.state_dim, "must be positive"));
        }
        // Upper bounds far above any published setting (256 / 8 / 32 / 32): a larger
        // value is a typo, and `pednav-run check` builds the networks to estimate memory.
        for (field, value, min, max) in [
            ("image_size", self.image_size, 1, 1024),
            ("state_dim", self.state_dim, 1, 4096),
            ("hidden", self.hidden, 1, 8192),
            ("history_features", self.history_features, 1, 1024),
            ("quantiles", self.quantiles, 2, 1024),
            ("quantile_grid", self.quantile_grid, 1, 1024),
        ] {
            if !(min..=max).contains(&value) {
                return Err(config_error(field, value, format!("must be in {min}..={max}")));
            }
        }
        Ok(())
    }
}
