//! One DSAC update on two devices from the same weights and the same batch, compared:
//! the check that a GPU learner computes what the CPU learner computes
//! (`pednav-device-check`, run by `deploy/gpu_check.sh`).
//!
//! Both sides build their networks from the same seed (the initial weights are drawn
//! on the host, then placed on the device), fill a replay with the same synthetic
//! transitions ([`fill_replay`]) and draw the same batch with identically seeded
//! generators; the update's own noise is drawn on the host too. So the two updates
//! differ only by floating-point order, and the comparison's tolerances
//! ([`DeviceComparison::passes`]) bound exactly that.

use candle_core::Device;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use pednav_nets::{NetsConfig, ParamStore};

use crate::dsac::{Dsac, UpdateStats};
use crate::error::Result;
use crate::replay::{DualReplay, Frame, FrameKind, ReplayConfig, Step};
use pednav_config::DsacConfig;

/// Fill `replay` with `steps` synthetic transitions from `rng`: random frames (or
/// state vectors), actions and rewards, episodes of 100 steps of which every third
/// ends at the goal. Benchmarks and device checks use it; it trains nothing.
pub fn fill_replay(replay: &mut DualReplay, kind: FrameKind, steps: usize, rng: &mut ChaCha8Rng) -> Result<()> {
    let (pixels, values) = match kind {
        FrameKind::Pixels { size } => (size * size, 0),
        FrameKind::State { dim } => (0, dim),
    };
    let (mut frame, mut state) = (vec![0u8; pixels], vec![0f32; values]);
    let mut target = vec![0f32; replay.state_target_dim()];
    for i in 0..steps {
        rng.fill(&mut frame[..]);
        for v in state.iter_mut().chain(target.iter_mut()) {
            *v = rng.random_range(-1.0..1.0);
        }
        let t = i % 100;
        let action: [f32; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
        let frame = match kind {
            FrameKind::Pixels { .. } => Frame::Pixels(&frame),
            FrameKind::State { .. } => Frame::State(&state),
        };
        replay.push(&Step {
            stream: 0,
            first: t == 0,
            frame,
            action,
            reward: -0.1,
            terminal: t == 99 && i % 300 == 99,
            state_target: (!target.is_empty()).then_some(&target[..]),
        })?;
    }
    Ok(())
}

/// How far one update on device B is from the same update on device A.
#[derive(Debug, Clone)]
pub struct DeviceComparison {
    /// The update's statistics on device A.
    pub a: UpdateStats,
    /// The same on device B.
    pub b: UpdateStats,
    /// Largest relative difference of the four losses: |a − b| / max(1, |a|).
    pub loss_rel_diff: f64,
    /// Largest absolute difference of any weight after the update.
    pub weight_max_diff: f64,
    /// 99.9th percentile of the absolute weight differences.
    pub weight_p999_diff: f64,
    /// Weights compared.
    pub weights: usize,
    /// The largest learning rate of the update: one Adam step moves a weight by at
    /// most about this much, so two devices whose gradient for a weight is ≈ 0 with
    /// opposite signs may disagree by up to twice it.
    pub max_lr: f64,
}

impl DeviceComparison {
    /// Losses within 1e-3 (relative), 99.9 % of the weights within 1e-5, and every
    /// weight within two Adam steps (2·lr + 1e-5) of the other device's.
    pub fn passes(&self) -> bool {
        self.loss_rel_diff <= 1e-3 && self.weight_p999_diff <= 1e-5 && self.weight_max_diff <= 2.0 * self.max_lr + 1e-5
    }
}

/// Run one update of `cfg` / `nets` on `a` and on `b` from the same seed and batch
/// (`batch` transitions drawn from a replay of 3 × batch synthetic steps), and compare.
pub fn compare_update(
    cfg: &DsacConfig,
    nets: &NetsConfig,
    kind: FrameKind,
    a: &Device,
    b: &Device,
    seed: u64,
) -> Result<DeviceComparison> {
    let run = |device: &Device| -> Result<(UpdateStats, Vec<Vec<f32>>)> {
        let mut dsac = Dsac::new(cfg, nets, device, seed)?;
        let rc = ReplayConfig { nonterminal_capacity: 4 * cfg.batch_size, terminal_capacity: cfg.batch_size };
        let mut replay = DualReplay::new(&rc, kind, nets.history, device)?;
        if cfg.builds_state_head() {
            replay = replay.with_state_targets(nets.state_dim)?;
        }
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        fill_replay(&mut replay, kind, 3 * cfg.batch_size, &mut rng)?;
        let batch = replay.sample(cfg.batch_size, &mut rng)?;
        let stats = dsac.update(&batch)?;
        Ok((stats, weights(&dsac.nets.stores())?))
    };
    let (sa, wa) = run(a)?;
    let (sb, wb) = run(b)?;
    let losses = |s: &UpdateStats| [s.critic_loss, s.policy_loss, s.fraction_loss, s.alpha_loss];
    let loss_rel_diff =
        losses(&sa).iter().zip(losses(&sb)).map(|(x, y)| (x - y).abs() / x.abs().max(1.0)).fold(0.0, f64::max);
    let mut diffs: Vec<f64> =
        wa.iter().flatten().zip(wb.iter().flatten()).map(|(x, y)| (*x as f64 - *y as f64).abs()).collect();
    diffs.sort_by(f64::total_cmp);
    let weights = diffs.len();
    let weight_max_diff = diffs.last().copied().unwrap_or(0.0);
    let weight_p999_diff = diffs.get(weights.saturating_sub(1).min(weights * 999 / 1000)).copied().unwrap_or(0.0);
    let max_lr = [cfg.lr_policy, cfg.lr_quantile, cfg.lr_fraction, cfg.lr_alpha].into_iter().fold(0.0, f64::max);
    Ok(DeviceComparison { a: sa, b: sb, loss_rel_diff, weight_max_diff, weight_p999_diff, weights, max_lr })
}

/// Every weight of the stores, on the host, in a fixed order (store, then name).
fn weights(stores: &[&ParamStore]) -> Result<Vec<Vec<f32>>> {
    let mut out = Vec::new();
    for store in stores {
        let mut named: Vec<_> = store.tensors().into_iter().collect();
        named.sort_by(|x, y| x.0.cmp(&y.0));
        for (_, t) in named {
            let host = t.flatten_all().and_then(|t| t.to_device(&Device::Cpu)).and_then(|t| t.to_vec1::<f32>());
            out.push(host.map_err(pednav_nets::NetError::from)?);
        }
    }
    Ok(out)
}
