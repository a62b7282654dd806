//! Test support shared by the learner's integration tests.

use candle_core::Device;
use pednav_learner::{Batch, DsacConfig, DualReplay, Frame, FrameKind, ReplayConfig, Step};
use pednav_nets::{EncoderKind, NetsConfig};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

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

/// A batch of random 4-float states, with 4-float state targets (s₀ − s₁, 2·s₃, s₂,
/// 0.5) for the state-prediction loss (sampling them draws nothing from `rng`).
#[allow(dead_code)] // the loss and checkpoint tests use it, the agent tests do not
pub fn state_batch(b: usize, rng: &mut ChaCha8Rng) -> Batch {
    let cfg = ReplayConfig { nonterminal_capacity: 1000, terminal_capacity: 100 };
    let mut replay =
        DualReplay::new(&cfg, FrameKind::State { dim: 4 }, 1, &Device::Cpu).unwrap().with_state_targets(4).unwrap();
    for ep in 0..20 {
        for t in 0..10 {
            let s: [f32; 4] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            let target = [s[0] - s[1], 2.0 * s[3], s[2], 0.5];
            let a: [f32; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            replay
                .push(&Step {
                    stream: 0,
                    first: t == 0,
                    frame: Frame::State(&s),
                    action: a,
                    reward: rng.random_range(-1.0..1.0),
                    terminal: t == 9 && ep % 2 == 0,
                    state_target: Some(&target),
                })
                .unwrap();
        }
    }
    replay.sample(b, rng).unwrap()
}
