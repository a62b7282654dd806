//! Test support shared by the learner's integration tests.

use pednav_learner::{Dsac, DsacConfig};
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

/// Every parameter of the agent (networks and log α), store by store, as flat vectors:
/// two agents hold the same weights exactly when these are equal.
pub fn all_values(d: &Dsac) -> Vec<Vec<f32>> {
    let mut out = Vec::new();
    for store in d.nets.stores().into_iter().chain([&d.log_alpha]) {
        for (_, v) in store.vars() {
            out.push(v.flatten_all().unwrap().to_vec1().unwrap());
        }
    }
    out
}
