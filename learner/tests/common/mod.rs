//! Test support shared by the learner's integration tests.

use pednav_learner::DsacConfig;
use pednav_nets::{EncoderKind, NetsConfig};

/// A DSAC agent small enough to update in microseconds: one critic, a 4-float state
/// through a 32-unit MLP, 8 quantiles.
pub fn small() -> (DsacConfig, NetsConfig) {
    (
        DsacConfig { batch_size: 16, warmup: 16, twin_critics: false, ..Default::default() },
        NetsConfig {
            encoder: EncoderKind::Mlp,
            state_dim: 4,
            history: 1,
            hidden: 32,
            quantiles: 8,
            quantile_grid: 8,
            ..Default::default()
        },
    )
}
