//! Losses, the temperature update and checkpoints against hand-computed values.

use candle_core::{Device, Tensor};
use pednav_learner::{
    Batch, Dsac, DsacConfig, DualReplay, Frame, FrameKind, ReplayConfig, Step, fraction_gradient, load_checkpoint,
    quantile_huber_loss, save_checkpoint,
};
use pednav_nets::{EncoderKind, NetsConfig, Obs};
use rand::{Rng, SeedableRng};
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

fn state_batch(b: usize, rng: &mut ChaCha8Rng) -> Batch {
    let cfg = ReplayConfig { nonterminal_capacity: 1000, terminal_capacity: 100 };
    let mut replay = DualReplay::new(&cfg, FrameKind::State { dim: 4 }, 1, &Device::Cpu).unwrap();
    for ep in 0..20 {
        for t in 0..10 {
            let s: [f32; 4] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            let a: [f32; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            replay
                .push(&Step {
                    stream: 0,
                    first: t == 0,
                    frame: Frame::State(&s),
                    action: a,
                    reward: rng.random_range(-1.0..1.0),
                    terminal: t == 9 && ep % 2 == 0,
                })
                .unwrap();
        }
    }
    replay.sample(b, rng).unwrap()
}

fn small() -> (DsacConfig, NetsConfig) {
    (
        DsacConfig { batch_size: 16, warmup: 16, ..Default::default() },
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

/// The device check's comparison: the same device twice gives identical losses and
/// weights and passes; each tolerance fails just beyond its bound (lr 3e-4 → two Adam
/// steps 6e-4 + 1e-5).
#[test]
fn one_update_on_two_devices_is_compared_weight_by_weight() {
    let (mut cfg, nets) = small();
    (cfg.lr_policy, cfg.lr_quantile, cfg.lr_fraction, cfg.lr_alpha) = (3e-4, 3e-4, 1e-4, 3e-4);
    let same = pednav_learner::compare_update(&cfg, &nets, FrameKind::State { dim: 4 }, &Device::Cpu, &Device::Cpu, 3)
        .unwrap();
    assert!(same.passes() && same.weights > 1000, "{same:?}");
    assert_eq!((same.loss_rel_diff, same.weight_max_diff, same.weight_p999_diff), (0.0, 0.0, 0.0));
    assert_eq!(same.a.critic_loss, same.b.critic_loss);
    assert_eq!(same.max_lr, 3e-4);
    for (field, ok, bad) in [("losses", 0.9e-3, 1.1e-3), ("p999", 0.9e-5, 1.1e-5), ("max", 6.09e-4, 6.11e-4)] {
        for (value, passes) in [(ok, true), (bad, false)] {
            let mut c = same.clone();
            match field {
                "losses" => c.loss_rel_diff = value,
                "p999" => c.weight_p999_diff = value,
                _ => c.weight_max_diff = value,
            }
            assert_eq!(c.passes(), passes, "{field} = {value}");
        }
    }
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

fn all_values(d: &Dsac) -> Vec<Vec<f32>> {
    let mut out = Vec::new();
    for store in d.nets.stores().into_iter().chain([&d.log_alpha]) {
        for (_, v) in store.vars() {
            out.push(v.flatten_all().unwrap().to_vec1().unwrap());
        }
    }
    out
}

#[test]
fn checkpoints_round_trip_bit_exactly_and_bad_ones_change_nothing() {
    let dir = std::env::temp_dir().join(format!("pednav-ckpt-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let (cfg, nets) = small();
    let mut a = Dsac::new(&cfg, &nets, &Device::Cpu, 1).unwrap();
    for _ in 0..3 {
        a.update(&state_batch(16, &mut rng)).unwrap();
    }
    let ck = dir.join("ckpt");
    save_checkpoint(&ck, &mut a, None, serde_json::json!({"env_steps": 123})).unwrap();
    let mut b = Dsac::new(&cfg, &nets, &Device::Cpu, 2).unwrap();
    let meta = load_checkpoint(&ck, &mut b).unwrap();
    assert_eq!(meta.extra["env_steps"], 123);
    assert_eq!(all_values(&a), all_values(&b));
    assert_eq!((a.updates, a.rng.clone()), (b.updates, b.rng.clone()));
    // Continuing both gives identical results: moments, counters and RNG were restored.
    let batch = state_batch(16, &mut rng);
    let (sa, sb) = (a.update(&batch).unwrap(), b.update(&batch).unwrap());
    assert_eq!(sa, sb);
    assert_eq!(all_values(&a), all_values(&b));

    // Corrupt one byte of a weight file: checksum error naming the file, nothing changed.
    let mut c = Dsac::new(&cfg, &nets, &Device::Cpu, 3).unwrap();
    let untouched = all_values(&c);
    let file = ck.join("quantile.safetensors");
    let mut bytes = std::fs::read(&file).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 0xff;
    std::fs::write(&file, &bytes).unwrap();
    let err = load_checkpoint(&ck, &mut c).unwrap_err().to_string();
    assert!(err.contains("quantile.safetensors") && err.contains("checksum"), "{err}");
    assert_eq!(untouched, all_values(&c));

    // A checkpoint of another architecture: a clear error, nothing changed.
    save_checkpoint(&ck, &mut a, None, serde_json::Value::Null).unwrap();
    let other = NetsConfig { hidden: 16, ..nets.clone() };
    let mut d = Dsac::new(&cfg, &other, &Device::Cpu, 3).unwrap();
    let untouched = all_values(&d);
    let err = load_checkpoint(&ck, &mut d).unwrap_err().to_string();
    assert!(err.contains("written for networks"), "{err}");
    assert_eq!(untouched, all_values(&d));
    let err = load_checkpoint(&dir.join("missing"), &mut d).unwrap_err().to_string();
    assert!(err.contains("is this a checkpoint directory"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn acting_is_seeded_and_deterministic_mode_is_tanh_of_the_mean() {
    let (cfg, nets) = small();
    let obs = Obs::State(Tensor::new(&[[0.1f32, -0.2, 0.3, 0.0]], &Device::Cpu).unwrap());
    let mut a = Dsac::new(&cfg, &nets, &Device::Cpu, 1).unwrap();
    let mut b = Dsac::new(&cfg, &nets, &Device::Cpu, 1).unwrap();
    let (x, _) = a.act(&obs, false).unwrap();
    let (y, _) = b.act(&obs, false).unwrap();
    assert_eq!(x.to_vec2::<f32>().unwrap(), y.to_vec2::<f32>().unwrap());
    let (m1, _) = a.act(&obs, true).unwrap();
    let (m2, _) = a.act(&obs, true).unwrap();
    assert_eq!(m1.to_vec2::<f32>().unwrap(), m2.to_vec2::<f32>().unwrap());
}
