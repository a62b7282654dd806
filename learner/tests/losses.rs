//! Losses (quantile Huber, FQF fractions, twin critics, state prediction), the
//! temperature update and the non-finite guard against hand-computed values.

mod common;
use common::{small, state_batch};

use candle_core::{Device, Tensor};
use pednav_learner::{Dsac, DsacConfig, fraction_gradient, quantile_huber_loss, smaller_mean};
use pednav_nets::NetsConfig;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn t2(rows: &[&[f32]]) -> Tensor {
    let n = rows[0].len();
    Tensor::from_vec(rows.iter().flat_map(|r| r.iter().copied()).collect::<Vec<_>>(), (rows.len(), n), &Device::Cpu)
        .unwrap()
}

#[test]
fn quantile_huber_loss_by_hand() {
    // One sample, N = 2 predictions z = (0, 1), N′ = 2 targets y = (0.5, 3) with widths (0.25, 0.75), τ̂ = (0.25, 0.75), κ = 1.
    // δ = y − z: (0.5, 3; −0.5, 2). Huber: 0.125, 2.5; 0.125, 1.5.
    // |τ̂ − 1{δ<0}|: row 0: 0.25, 0.25; row 1: |0.75 − 1| = 0.25, 0.75.
    // Row 0: 0.25·0.125·0.25 + 0.25·2.5·0.75 = 0.0078125 + 0.46875 = 0.4765625
    // Row 1: 0.25·0.125·0.25 + 0.75·1.5·0.75 = 0.0078125 + 0.84375 = 0.8515625
    // Mean over i: 0.6640625.
    let loss = quantile_huber_loss(
        &t2(&[&[0.0, 1.0]]),
        &t2(&[&[0.5, 3.0]]),
        &t2(&[&[0.25, 0.75]]),
        &t2(&[&[0.25, 0.75]]),
        1.0,
    )
    .unwrap();
    let v: Vec<f32> = loss.to_vec1().unwrap();
    assert!((v[0] - 0.6640625).abs() < 1e-6, "{v:?}");
    // κ = 2 keeps |δ| = 3 → 2·(3 − 1) = 4 and |δ| ≤ 2 quadratic, then divides by κ:
    // row 0: 0.25·0.125·0.25 + 0.25·4·0.75 = 0.7578125; row 1: 0.0078125 + 0.75·2·0.75 = 1.1328125 → mean 0.9453125 / 2.
    let loss = quantile_huber_loss(
        &t2(&[&[0.0, 1.0]]),
        &t2(&[&[0.5, 3.0]]),
        &t2(&[&[0.25, 0.75]]),
        &t2(&[&[0.25, 0.75]]),
        2.0,
    )
    .unwrap();
    assert!((loss.to_vec1::<f32>().unwrap()[0] - 0.47265625).abs() < 1e-6);
}

#[test]
fn fraction_gradient_by_hand() {
    // Z(τ₁) = 1, Z(τ₂) = 2 at the inner fractions; Z(τ̂) = (0, 1.5, 4):
    // ∂W/∂τ₁ = 2·1 − 0 − 1.5 = 0.5; ∂W/∂τ₂ = 2·2 − 1.5 − 4 = −1.5.
    let g = fraction_gradient(&t2(&[&[1.0, 2.0]]), &t2(&[&[0.0, 1.5, 4.0]])).unwrap();
    assert_eq!(g.to_vec2::<f32>().unwrap(), vec![vec![0.5, -1.5]]);
}

#[test]
fn twin_target_takes_the_distribution_with_the_smaller_mean_per_sample() {
    // Row 0: means 0.5·0 + 0.5·2 = 1 and 0.5·1 + 0.5·1 = 1 — a tie keeps the first.
    // Row 1: means 5 and 0.9·0 + 0.1·10 = 1 — the second, though its top quantile is larger.
    let a = t2(&[&[0.0, 2.0], &[5.0, 5.0]]);
    let b = t2(&[&[1.0, 1.0], &[0.0, 10.0]]);
    let widths = t2(&[&[0.5, 0.5], &[0.9, 0.1]]);
    let picked = smaller_mean(&a, &b, &widths).unwrap();
    assert_eq!(picked.to_vec2::<f32>().unwrap(), vec![vec![0.0, 2.0], vec![0.0, 10.0]]);
}

/// With the second critic a copy of the first, twin critics change nothing: the same
/// losses, the same first critic after the update (own encoders: its gradient comes
/// from its own loss only), and the second critic updated exactly like the first.
#[test]
fn twin_critics_with_equal_critics_reduce_to_one_critic() {
    let (cfg, nets) = small();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let batch = state_batch(16, &mut rng);
    let mut single = Dsac::new(&cfg, &nets, &Device::Cpu, 1).unwrap();
    let mut twin = Dsac::new(&DsacConfig { twin_critics: true, ..cfg.clone() }, &nets, &Device::Cpu, 1).unwrap();
    {
        let t = twin.nets.twin.as_ref().unwrap();
        t.quantile.store.copy_from(&twin.nets.quantile.store).unwrap();
        t.target.store.copy_from(&twin.nets.target.store).unwrap();
    }
    for _ in 0..2 {
        let (s, t) = (single.update(&batch).unwrap(), twin.update(&batch).unwrap());
        for (name, x, y) in [
            ("critic", s.critic_loss, t.critic_loss),
            ("policy", s.policy_loss, t.policy_loss),
            ("fraction", s.fraction_loss, t.fraction_loss),
            ("q_mean", s.q_mean, t.q_mean),
        ] {
            assert!((x - y).abs() <= 1e-5 * x.abs().max(1.0), "{name}: single {x}, twin {y}");
        }
    }
    let close = |a: &pednav_nets::ParamStore, b: &pednav_nets::ParamStore, what: &str| {
        for ((n, x), (_, y)) in a.vars().iter().zip(b.vars()) {
            let d =
                (x.as_tensor() - y.as_tensor()).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
            assert!(d <= 1e-5, "{what} `{n}` differs by {d}");
        }
    };
    let pair = twin.nets.twin.as_ref().unwrap();
    close(&single.nets.quantile.store, &twin.nets.quantile.store, "first critic (single vs twin)");
    close(&twin.nets.quantile.store, &pair.quantile.store, "second critic vs first");
    close(&twin.nets.target.store, &pair.target.store, "second target vs first");
    close(&single.nets.policy.store, &twin.nets.policy.store, "policy (single vs twin)");
}

/// With a shared encoder the second critic's loss trains the encoder too: after one
/// update its weights differ from a single critic's update on the same batch (Adam's
/// first step is lr·sign(g), so they differ exactly where the twin's gradient flips a
/// sign), while the fraction net, which reads the encoder detached and Z₁ only, moves
/// identically.
#[test]
fn the_twin_critic_trains_a_shared_encoder() {
    let (cfg, nets) = small();
    let nets = NetsConfig { shared_encoder: true, ..nets };
    let batch = state_batch(16, &mut ChaCha8Rng::seed_from_u64(12));
    let mut single = Dsac::new(&cfg, &nets, &Device::Cpu, 1).unwrap();
    let mut twin = Dsac::new(&DsacConfig { twin_critics: true, ..cfg.clone() }, &nets, &Device::Cpu, 1).unwrap();
    assert!(twin.nets.twin.as_ref().unwrap().quantile.encoder.is_none(), "the twin reads the shared encoder");
    single.update(&batch).unwrap();
    twin.update(&batch).unwrap();
    let encoder = |d: &Dsac| -> Vec<f32> {
        let vars = d.nets.quantile.store.vars();
        let (_, first) = vars.iter().find(|(n, _)| n.starts_with("enc.")).expect("an encoder parameter");
        first.flatten_all().unwrap().to_vec1().unwrap()
    };
    let (a, b) = (encoder(&single), encoder(&twin));
    assert!(a.iter().zip(&b).any(|(x, y)| x != y), "the twin's loss did not reach the shared encoder");
    let fraction = |d: &Dsac| d.nets.fraction.store.vars()[0].1.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    assert_eq!(fraction(&single), fraction(&twin));
}

#[test]
fn temperature_moves_toward_the_target_entropy_by_one_adam_step() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let batch = state_batch(16, &mut rng);
    for (target, direction) in [(-100.0, -1.0), (100.0, 1.0)] {
        let (mut cfg, nets) = small();
        cfg.target_entropy = target;
        cfg.lr_alpha = 1e-2;
        let mut dsac = Dsac::new(&cfg, &nets, &Device::Cpu, 1).unwrap();
        let before = dsac.alpha().unwrap().ln();
        let stats = dsac.update(&batch).unwrap();
        let after = dsac.alpha().unwrap().ln();
        // L = −mean(η·log α·(log π + H̄)); with H̄ = ∓100 the sign of ∂L/∂log α is fixed,
        // and Adam's first step moves log α by exactly lr against it.
        assert!(!stats.skipped);
        assert!(((after - before) - direction * 1e-2).abs() < 1e-5, "target {target}: Δ log α = {}", after - before);
    }
}

#[test]
fn a_non_finite_batch_skips_the_update_and_keeps_the_weights() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut batch = state_batch(16, &mut rng);
    let (cfg, nets) = small();
    let mut dsac = Dsac::new(&cfg, &nets, &Device::Cpu, 1).unwrap();
    let before: Vec<f32> = dsac.nets.quantile.store.vars()[0].1.flatten_all().unwrap().to_vec1().unwrap();
    let mut r: Vec<f32> = batch.reward.to_vec1().unwrap();
    r[3] = f32::NAN;
    batch.reward = Tensor::from_vec(r, 16, &Device::Cpu).unwrap();
    let stats = dsac.update(&batch).unwrap();
    assert!(stats.skipped);
    assert_eq!(dsac.skipped, 1);
    assert_eq!(dsac.updates, 0);
    assert_eq!(before, dsac.nets.quantile.store.vars()[0].1.flatten_all().unwrap().to_vec1::<f32>().unwrap());
}

/// ℓ_s by hand from the head's parameters and the encoder's features: the mean over
/// the batch of ‖W·f + b − s‖²; the loss trains the critic's encoder (and not the
/// policy's own one), and on a fixed batch it falls.
#[test]
fn state_prediction_loss_by_hand_and_it_shapes_the_critic_encoder() {
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    let batch = state_batch(16, &mut rng);
    let (cfg, nets) = small();
    let aux_cfg = DsacConfig { state_aux_weight: 0.5, lr_quantile: 1e-3, ..cfg.clone() };
    let plain_cfg = DsacConfig { lr_quantile: 1e-3, ..cfg.clone() };
    let mut aux = Dsac::new(&aux_cfg, &nets, &Device::Cpu, 1).unwrap();
    let mut plain = Dsac::new(&plain_cfg, &nets, &Device::Cpu, 1).unwrap();
    let head = aux.nets.state_head.as_ref().expect("a state head with state_aux_weight > 0");
    assert!(plain.nets.state_head.is_none());
    let obs = aux.nets.prepare(&batch.transitions.obs().unwrap()).unwrap();
    let f: Vec<Vec<f32>> = aux.nets.online_features(&obs).unwrap().quantile.to_vec2().unwrap();
    let param = |name: &str| head.store.vars().iter().find(|(n, _)| n == name).unwrap().1.as_tensor().clone();
    let (w, b): (Vec<Vec<f32>>, Vec<f32>) =
        (param("linear.w").to_vec2().unwrap(), param("linear.b").to_vec1().unwrap());
    let s: Vec<Vec<f32>> = batch.state_target.as_ref().unwrap().to_vec2().unwrap();
    let mut by_hand = 0.0f64;
    for (fi, si) in f.iter().zip(&s) {
        for (d, target) in si.iter().enumerate() {
            let pred: f32 = b[d] + fi.iter().zip(&w).map(|(x, row)| x * row[d]).sum::<f32>();
            by_hand += ((pred - target) as f64).powi(2);
        }
    }
    by_hand /= f.len() as f64;
    let first = aux.update(&batch).unwrap();
    let plain_stats = plain.update(&batch).unwrap();
    assert!((first.state_loss - by_hand).abs() < 1e-5 * by_hand.max(1.0), "{} vs {by_hand}", first.state_loss);
    assert_eq!(plain_stats.state_loss, 0.0);
    // Same seeds: only the critic's encoder (and head) differ after the update.
    assert_eq!(first.critic_loss, plain_stats.critic_loss, "ℓ_s is reported apart from the critic loss");
    let store_values = |s: &pednav_nets::ParamStore| -> Vec<Vec<f32>> {
        s.vars().iter().map(|(_, v)| v.flatten_all().unwrap().to_vec1().unwrap()).collect()
    };
    assert_ne!(store_values(&aux.nets.quantile.store), store_values(&plain.nets.quantile.store));
    assert_eq!(store_values(&aux.nets.policy.store), store_values(&plain.nets.policy.store));
    let mut last = first.state_loss;
    for _ in 0..60 {
        last = aux.update(&batch).unwrap().state_loss;
    }
    assert!(last < 0.5 * first.state_loss, "ℓ_s {} → {last}", first.state_loss);
    // A batch without targets is refused rather than trained without ℓ_s.
    let mut bare = batch.clone();
    bare.state_target = None;
    let err = aux.update(&bare).unwrap_err().to_string();
    assert!(err.contains("state targets"), "{err}");
}

/// An n-step batch bootstraps with γⁿ: the same batch marked 2-step under γ = 0.9
/// gives the update a 1-step batch gives under γ = 0.81 (same seed, same weights),
/// and not the one under γ = 0.9.
#[test]
fn an_n_step_batch_discounts_its_bootstrap_by_gamma_to_the_n() {
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    let one_step = state_batch(16, &mut rng);
    assert_eq!(one_step.n_step, 1);
    let two_step = pednav_learner::Batch { n_step: 2, ..one_step.clone() };
    let (cfg, nets) = small();
    let update = |gamma: f64, batch: &pednav_learner::Batch| {
        let mut dsac = Dsac::new(&DsacConfig { gamma, ..cfg.clone() }, &nets, &Device::Cpu, 1).unwrap();
        dsac.update(batch).unwrap().critic_loss
    };
    let (two, squared, plain) = (update(0.9, &two_step), update(0.81, &one_step), update(0.9, &one_step));
    assert!((two - squared).abs() <= 1e-6 * squared.abs(), "γ = 0.9, n = 2: {two}; γ = 0.81, n = 1: {squared}");
    assert!((two - plain).abs() > 1e-4 * plain.abs(), "γ² must differ from γ here: {two} vs {plain}");
}

/// ℓ_c by hand from the head's parameters and the features: the mean over rows of
/// log Σ_j exp(s_ij) − s_ii with s_ij = cos(W a_i + b, p_j) / 0.1, a the online
/// critic features of o_t and p the target encoder's of o_{t+n}. The loss trains the
/// critic's encoder (not the policy), is reported apart from the critic loss, and on
/// a fixed batch it falls.
#[test]
fn temporal_contrast_loss_by_hand_and_it_shapes_the_critic_encoder() {
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let batch = state_batch(16, &mut rng);
    let (cfg, nets) = small();
    let with_cfg = DsacConfig { contrast_weight: 1.0, lr_quantile: 1e-3, ..cfg.clone() };
    let plain_cfg = DsacConfig { lr_quantile: 1e-3, ..cfg.clone() };
    let mut with = Dsac::new(&with_cfg, &nets, &Device::Cpu, 1).unwrap();
    let mut plain = Dsac::new(&plain_cfg, &nets, &Device::Cpu, 1).unwrap();
    assert!(plain.nets.contrast_head.is_none());
    let head = with.nets.contrast_head.as_ref().expect("a contrastive head with contrast_weight > 0");
    let obs = with.nets.prepare(&batch.transitions.obs().unwrap()).unwrap();
    let next = with.nets.prepare(&batch.transitions.next_obs().unwrap()).unwrap();
    let anchors: Vec<Vec<f32>> = with.nets.online_features(&obs).unwrap().quantile.to_vec2().unwrap();
    let positives: Vec<Vec<f32>> = with.nets.target_features(&next).unwrap().to_vec2().unwrap();
    let param = |name: &str| head.store.vars().iter().find(|(n, _)| n == name).unwrap().1.as_tensor().clone();
    let (w, b): (Vec<Vec<f32>>, Vec<f32>) =
        (param("linear.w").to_vec2().unwrap(), param("linear.b").to_vec1().unwrap());
    let unit = |v: Vec<f64>| -> Vec<f64> {
        let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        v.into_iter().map(|x| x / n).collect()
    };
    let q: Vec<Vec<f64>> = anchors
        .iter()
        .map(|a| {
            unit(
                (0..b.len())
                    .map(|d| b[d] as f64 + a.iter().zip(&w).map(|(x, row)| (x * row[d]) as f64).sum::<f64>())
                    .collect(),
            )
        })
        .collect();
    let k: Vec<Vec<f64>> = positives.iter().map(|p| unit(p.iter().map(|&x| x as f64).collect())).collect();
    let mut by_hand = 0.0;
    for (i, qi) in q.iter().enumerate() {
        let s: Vec<f64> = k.iter().map(|kj| qi.iter().zip(kj).map(|(x, y)| x * y).sum::<f64>() / 0.1).collect();
        by_hand += s.iter().map(|v| v.exp()).sum::<f64>().ln() - s[i];
    }
    by_hand /= q.len() as f64;
    let first = with.update(&batch).unwrap();
    let plain_stats = plain.update(&batch).unwrap();
    assert!((first.contrast_loss - by_hand).abs() < 1e-4 * by_hand.max(1.0), "{} vs {by_hand}", first.contrast_loss);
    assert_eq!(plain_stats.contrast_loss, 0.0);
    assert_eq!(first.critic_loss, plain_stats.critic_loss, "ℓ_c is reported apart from the critic loss");
    let store_values = |s: &pednav_nets::ParamStore| -> Vec<Vec<f32>> {
        s.vars().iter().map(|(_, v)| v.flatten_all().unwrap().to_vec1().unwrap()).collect()
    };
    assert_ne!(store_values(&with.nets.quantile.store), store_values(&plain.nets.quantile.store));
    assert_eq!(store_values(&with.nets.policy.store), store_values(&plain.nets.policy.store));
    let mut last = first.contrast_loss;
    for _ in 0..60 {
        last = with.update(&batch).unwrap().contrast_loss;
    }
    assert!(last < 0.8 * first.contrast_loss, "ℓ_c {} → {last}", first.contrast_loss);
}
