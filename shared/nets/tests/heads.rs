//! Heads, networks, streaming cache and optimiser against independent values.

use candle_core::{Device, IndexOp, Tensor, Var};
use pednav_nets::heads::standard_normal;
use pednav_nets::{
    AdamW, AdamWConfig, CholeskyGaussian, DsacNets, EncoderKind, NetsConfig, Obs, OptimStep, ParamStore, PolicyStream,
    Transitions,
};
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

mod common;

/// Every test of this file (heads, encoders, the streaming cache, AdamW) also passes
/// on the other instruction-set paths of the kernels.
#[test]
fn every_test_here_passes_on_every_instruction_set() {
    common::rerun_on_every_other_isa("every_test_here_passes_on_every_instruction_set");
}

fn random(rng: &mut ChaCha8Rng, shape: &[usize], scale: f32) -> Tensor {
    let n: usize = shape.iter().product();
    let data: Vec<f32> = (0..n).map(|_| rng.random_range(-scale..scale)).collect();
    Tensor::from_vec(data, shape, &Device::Cpu).unwrap()
}

fn rows(t: &Tensor) -> Vec<Vec<f32>> {
    t.to_vec2().unwrap()
}

/// log N(u; μ, Σ) in f64 from Σ = LLᵀ, its determinant and adjugate inverse.
fn mvn_log_density(u: [f64; 3], mu: [f64; 3], l: [[f64; 3]; 3]) -> f64 {
    let mut s = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            s[i][j] = (0..3).map(|k| l[i][k] * l[j][k]).sum();
        }
    }
    let det = s[0][0] * (s[1][1] * s[2][2] - s[1][2] * s[2][1]) - s[0][1] * (s[1][0] * s[2][2] - s[1][2] * s[2][0])
        + s[0][2] * (s[1][0] * s[2][1] - s[1][1] * s[2][0]);
    let cof = |r: usize, c: usize| {
        let (r0, r1) = ((r + 1) % 3, (r + 2) % 3);
        let (c0, c1) = ((c + 1) % 3, (c + 2) % 3);
        s[r0][c0] * s[r1][c1] - s[r0][c1] * s[r1][c0]
    };
    let d: Vec<f64> = (0..3).map(|i| u[i] - mu[i]).collect();
    let mut quad = 0.0;
    for i in 0..3 {
        for j in 0..3 {
            quad += d[i] * cof(j, i) / det * d[j];
        }
    }
    -0.5 * quad - 0.5 * det.ln() - 1.5 * (2.0 * std::f64::consts::PI).ln()
}

fn gaussian(rng: &mut ChaCha8Rng, b: usize) -> CholeskyGaussian {
    CholeskyGaussian::from_raw(random(rng, &[b, 3], 1.0), &random(rng, &[b, 6], 1.5)).unwrap()
}

#[test]
fn cholesky_log_density_matches_the_closed_form() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let g = gaussian(&mut rng, 16);
    let u = random(&mut rng, &[16, 3], 2.0);
    let ours: Vec<f32> = g.log_density(&u).unwrap().to_vec1().unwrap();
    let (mu, us) = (rows(&g.mean), rows(&u));
    let ls: Vec<Vec<Vec<f32>>> = g.scale_tril.to_vec3().unwrap();
    for i in 0..16 {
        let l = [0, 1, 2].map(|r| [0, 1, 2].map(|c| ls[i][r][c] as f64));
        assert_eq!([l[0][1], l[0][2], l[1][2]], [0.0; 3], "factor is lower triangular");
        assert!(l[0][0] > 0.0 && l[1][1] > 0.0 && l[2][2] > 0.0);
        let expect = mvn_log_density(
            us[i].iter().map(|&v| v as f64).collect::<Vec<_>>().try_into().unwrap(),
            [0, 1, 2].map(|k| mu[i][k] as f64),
            l,
        );
        assert!((ours[i] as f64 - expect).abs() < 1e-4 * (1.0 + expect.abs()), "row {i}: {} vs {expect}", ours[i]);
    }
}

#[test]
fn squashed_sample_log_prob_includes_the_tanh_jacobian() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let g = gaussian(&mut rng, 8);
    let eps = standard_normal(&mut rng, 8, &Device::Cpu).unwrap();
    let s = g.sample(&eps).unwrap();
    let u = g.pre_squash(&eps).unwrap();
    let lp: Vec<f32> = s.log_prob.to_vec1().unwrap();
    let dens: Vec<f32> = g.log_density(&u).unwrap().to_vec1().unwrap();
    let (us, acts) = (rows(&u), rows(&s.action));
    for i in 0..8 {
        let jac: f64 = us[i].iter().map(|&v| (1.0 - (v as f64).tanh().powi(2)).ln()).sum();
        assert!((lp[i] as f64 - (dens[i] as f64 - jac)).abs() < 1e-3, "row {i}");
        for k in 0..3 {
            assert!((acts[i][k] as f64 - (us[i][k] as f64).tanh()).abs() < 1e-6);
        }
    }
    let mode = rows(&g.mode().unwrap());
    assert!((mode[0][0] - rows(&g.mean)[0][0].tanh()).abs() < 1e-6);
}

fn tiny(encoder: EncoderKind, shared: bool) -> NetsConfig {
    NetsConfig {
        encoder,
        image_size: 21,
        history: 4,
        state_dim: 5,
        hidden: 16,
        quantiles: 8,
        quantile_grid: 6,
        shared_encoder: shared,
        ..Default::default()
    }
}

fn pixel_obs(rng: &mut ChaCha8Rng, cfg: &NetsConfig, b: usize) -> Obs {
    let s = cfg.image_size;
    Obs::Pixels {
        frames: random(rng, &[b, cfg.history, s, s], 1.0).abs().unwrap(),
        actions: random(rng, &[b, cfg.history - 1, 3], 1.0),
        rewards: random(rng, &[b, cfg.history - 1], 1.0),
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]
    #[test]
    fn quantiles_never_decrease_in_tau(seed in 0u64..1000, b in 1usize..5) {
        let cfg = tiny(EncoderKind::Mlp, false);
        let nets = DsacNets::new(&cfg, &Device::Cpu, seed).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let obs = Obs::State(random(&mut rng, &[b, 5], 3.0));
        let f = nets.online_features(&obs).unwrap();
        let a = random(&mut rng, &[b, 3], 1.0);
        let grid = nets.quantile.grid(&f.quantile, &a).unwrap();
        let mut taus: Vec<f32> = (0..b * 50).map(|_| rng.random_range(0.0..1.0)).collect();
        for row in taus.chunks_mut(50) { row.sort_by(|x, y| x.partial_cmp(y).unwrap()); }
        let q = rows(&grid.at(&Tensor::from_vec(taus, (b, 50), &Device::Cpu).unwrap()).unwrap());
        for row in q { for w in row.windows(2) { prop_assert!(w[1] >= w[0] - 1e-6, "{} > {}", w[0], w[1]); } }
        let fr = nets.fraction.fractions(&f.fraction, &a).unwrap();
        for row in rows(&fr.taus) {
            prop_assert_eq!(row[0], 0.0);
            prop_assert_eq!(*row.last().unwrap(), 1.0);
            for w in row.windows(2) { prop_assert!(w[1] > w[0]); }
        }
    }
}

#[test]
fn quantile_interpolation_hits_the_grid_and_midpoints() {
    let values = Tensor::new(&[[0f32, 1.0, 3.0, 6.0]], &Device::Cpu).unwrap();
    let grid = pednav_nets::QuantileGrid { values, intervals: 3 };
    let taus = Tensor::new(&[[0f32, 1.0 / 6.0, 1.0 / 3.0, 0.5, 1.0]], &Device::Cpu).unwrap();
    let q = rows(&grid.at(&taus).unwrap())[0].clone();
    for (got, want) in q.iter().zip([0.0, 0.5, 1.0, 2.0, 6.0]) {
        assert!((got - want).abs() < 1e-5, "{q:?}");
    }
}

#[test]
fn networks_are_reproducible_from_the_seed_and_the_target_starts_equal() {
    let cfg = tiny(EncoderKind::Tcn, false);
    let a = DsacNets::new(&cfg, &Device::Cpu, 5).unwrap();
    let b = DsacNets::new(&cfg, &Device::Cpu, 5).unwrap();
    let c = DsacNets::new(&cfg, &Device::Cpu, 6).unwrap();
    let first = |n: &DsacNets| n.policy.store.vars()[0].1.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    assert_eq!(first(&a), first(&b));
    assert_ne!(first(&a), first(&c));
    for ((_, q), (_, t)) in a.quantile.store.vars().iter().zip(a.target.store.vars()) {
        assert_eq!(
            q.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
            t.flatten_all().unwrap().to_vec1::<f32>().unwrap()
        );
    }
}

/// `DsacNets::prepare` (frame stacking: frames transposed once for every encoder)
/// changes no feature, for any encoder kind.
#[test]
fn prepared_observations_give_the_same_features() {
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    for kind in [EncoderKind::FrameStack, EncoderKind::Tcn] {
        let cfg = tiny(kind, false);
        let nets = DsacNets::new(&cfg, &Device::Cpu, 2).unwrap();
        let obs = pixel_obs(&mut rng, &cfg, 3);
        let prepared = nets.prepare(&obs).unwrap();
        assert_eq!(matches!(prepared, Obs::Stacked(_)), kind == EncoderKind::FrameStack);
        let (a, b) = (nets.online_features(&obs).unwrap(), nets.online_features(&prepared).unwrap());
        for (x, y) in [(&a.policy, &b.policy), (&a.fraction, &b.fraction), (&a.quantile, &b.quantile)] {
            assert_eq!(rows(x), rows(y), "{kind:?}");
        }
        assert_eq!(rows(&nets.target_features(&obs).unwrap()), rows(&nets.target_features(&prepared).unwrap()));
    }
}

#[test]
fn every_encoder_kind_runs_forward_and_backward() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for (kind, shared) in [
        (EncoderKind::Tcn, false),
        (EncoderKind::Tcn, true),
        (EncoderKind::FrameStack, false),
        (EncoderKind::Mlp, false),
    ] {
        let cfg = tiny(kind, shared);
        let nets = DsacNets::new(&cfg, &Device::Cpu, 1).unwrap();
        let obs = if kind == EncoderKind::Mlp {
            Obs::State(random(&mut rng, &[3, 5], 1.0))
        } else {
            pixel_obs(&mut rng, &cfg, 3)
        };
        let f = nets.online_features(&obs).unwrap();
        let a = random(&mut rng, &[3, 3], 1.0);
        let q = nets.quantile.grid(&f.quantile, &a).unwrap().values.sum_all().unwrap();
        let grads = q.backward().unwrap();
        let enc_grad = nets
            .quantile
            .store
            .vars()
            .iter()
            .filter(|(n, _)| n.starts_with("enc."))
            .filter(|(_, v)| grads.get(v).is_some())
            .count();
        assert!(enc_grad > 0, "{kind:?}: the critic loss must reach its encoder");
        if shared {
            // Policy features are detached: the policy loss does not reach the shared encoder.
            let p = nets.policy.head(&f.policy).unwrap().mean.sum_all().unwrap().backward().unwrap();
            assert!(nets.quantile.store.vars().iter().all(|(_, v)| p.get(v).is_none()));
        }
    }
}

/// Build the expected window at step t of an episode independently: frames
/// f_{t−N+1..t} padded with f_0, actions/rewards a_{t−N+1..t−1} padded with zeros.
fn expected_window(frames: &[Vec<u8>], actions: &[[f32; 3]], rewards: &[f32], n: usize, s: usize) -> Obs {
    let t = frames.len() - 1;
    let mut fr = Vec::new();
    let mut ac = Vec::new();
    let mut rw = Vec::new();
    for k in 0..n {
        let idx = (t + k + 1).saturating_sub(n);
        fr.extend(frames[idx].iter().map(|&p| p as f32 / 255.0));
    }
    for k in 0..n - 1 {
        let j = (t + k + 1) as isize - n as isize;
        if j < 0 {
            ac.extend([0.0; 3]);
            rw.push(0.0);
        } else {
            ac.extend(actions[j as usize]);
            rw.push(rewards[j as usize]);
        }
    }
    Obs::Pixels {
        frames: Tensor::from_vec(fr, (1, n, s, s), &Device::Cpu).unwrap(),
        actions: Tensor::from_vec(ac, (1, n - 1, 3), &Device::Cpu).unwrap(),
        rewards: Tensor::from_vec(rw, (1, n - 1), &Device::Cpu).unwrap(),
    }
}

/// Frames, actions and rewards of one scripted episode so far.
type Episode = (Vec<Vec<u8>>, Vec<[f32; 3]>, Vec<f32>);

fn max_abs(t: &Tensor) -> f32 {
    t.abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar().unwrap()
}

#[test]
fn streaming_cache_equals_full_recompute_over_an_episode_with_a_reset() {
    for (kind, history, size) in
        [(EncoderKind::Tcn, 16, 42), (EncoderKind::Tcn, 8, 42), (EncoderKind::FrameStack, 4, 42)]
    {
        let cfg = NetsConfig { encoder: kind, history, image_size: size, ..Default::default() };
        let nets = DsacNets::new(&cfg, &Device::Cpu, 9).unwrap();
        let enc = nets.acting_encoder();
        let mut rng = ChaCha8Rng::seed_from_u64(10);
        let envs = 2;
        let mut stream = PolicyStream::new(&cfg, envs, &Device::Cpu);
        let frame = |rng: &mut ChaCha8Rng| (0..size * size).map(|_| rng.random::<u8>()).collect::<Vec<u8>>();
        let mut eps: Vec<Episode> = vec![Default::default(); envs];
        for step in 0..40 {
            for (e, ep) in eps.iter_mut().enumerate() {
                let f = frame(&mut rng);
                // Env 0 resets at step 23 (mid-episode); env 1 runs one 40-step episode.
                if step == 0 || (e == 0 && step == 23) {
                    stream.reset(e, &f).unwrap();
                    *ep = (vec![f], vec![], vec![]);
                } else {
                    let a = [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)];
                    let r = rng.random_range(-3.0..1.0);
                    stream.push(e, a, r, &f).unwrap();
                    ep.0.push(f);
                    ep.1.push(a);
                    ep.2.push(r);
                }
            }
            if step == 30 {
                stream.invalidate();
            }
            let cached = stream.features(enc, &[0, 1]).unwrap();
            for (e, ep) in eps.iter().enumerate() {
                let want = enc.encode(&expected_window(&ep.0, &ep.1, &ep.2, history, size)).unwrap();
                let got = cached.i(e..e + 1).unwrap();
                let diff = max_abs(&(got - &want).unwrap());
                let scale = max_abs(&want);
                assert!(
                    diff <= 1e-5 * (1.0 + scale),
                    "{kind:?} N_h {history}: step {step} env {e}: max |Δ| {diff} (scale {scale})"
                );
            }
        }
    }
}

#[test]
fn adamw_first_step_is_lr_times_sign_and_nonfinite_gradients_change_nothing() {
    let mut store = ParamStore::new("p", &Device::Cpu);
    let v = store.insert("x", Tensor::new(&[1f32, -2.0, 3.0], &Device::Cpu).unwrap()).unwrap();
    let mut opt = AdamW::new(&store, AdamWConfig::with_lr(0.1)).unwrap();
    // loss = Σ c·x with c = (2, −0.5, 0): first bias-corrected step is −lr·g/(|g| + ε).
    let c = Tensor::new(&[2f32, -0.5, 0.0], &Device::Cpu).unwrap();
    let grads = (v.as_tensor() * &c).unwrap().sum_all().unwrap().backward().unwrap();
    assert!(
        matches!(opt.step(&grads).unwrap(), OptimStep::Applied { grad_norm } if (grad_norm - 4.25f64.sqrt()).abs() < 1e-6)
    );
    let x: Vec<f32> = v.to_vec1().unwrap();
    assert!((x[0] - 0.9).abs() < 1e-6 && (x[1] + 1.9).abs() < 1e-6 && (x[2] - 3.0).abs() < 1e-6, "{x:?}");
    let bad = (v.as_tensor() * Tensor::new(&[f32::NAN, 1.0, 1.0], &Device::Cpu).unwrap())
        .unwrap()
        .sum_all()
        .unwrap()
        .backward()
        .unwrap();
    assert_eq!(opt.step(&bad).unwrap(), OptimStep::SkippedNonFinite);
    assert_eq!(v.to_vec1::<f32>().unwrap(), x);
    assert_eq!(opt.steps(), 1);
}

#[test]
fn gradient_clipping_scales_the_global_norm() {
    let mut store = ParamStore::new("p", &Device::Cpu);
    let v: Var = store.insert("x", Tensor::new(&[0f32, 0.0], &Device::Cpu).unwrap()).unwrap();
    let cfg = AdamWConfig { max_grad_norm: Some(1.0), beta1: 0.0, beta2: 0.0, eps: 0.0, ..AdamWConfig::with_lr(1.0) };
    let mut opt = AdamW::new(&store, cfg).unwrap();
    // With β₁ = β₂ = 0 and ε = 0 the step is g/|g| elementwise, so clipping must not
    // change it; the reported norm is the unclipped one.
    let grads = (v.as_tensor() * Tensor::new(&[30f32, 40.0], &Device::Cpu).unwrap())
        .unwrap()
        .sum_all()
        .unwrap()
        .backward()
        .unwrap();
    assert_eq!(opt.step(&grads).unwrap(), OptimStep::Applied { grad_norm: 50.0 });
    assert_eq!(v.to_vec1::<f32>().unwrap(), vec![-1.0, -1.0]);
    let clipped = grads.get(&v).unwrap();
    assert_eq!(clipped.to_vec1::<f32>().unwrap(), vec![30.0, 40.0], "the caller's gradients are not modified");
}

#[test]
fn adamw_moments_hold_values_not_the_update_graph() {
    // For a loss non-linear in the parameters, the gradients `backward` returns are
    // themselves built from tracked tensors. Moments computed from them without
    // detaching would keep every previous step's graph alive (the learner's memory
    // grew by one update's graph — ≈15 MB on the CPU preset — per update).
    let mut store = ParamStore::new("p", &Device::Cpu);
    let v = store.insert("x", Tensor::new(&[1f32, -2.0, 3.0], &Device::Cpu).unwrap()).unwrap();
    let mut opt = AdamW::new(&store, AdamWConfig::with_lr(0.1)).unwrap();
    for _ in 0..3 {
        let grads = v.as_tensor().sqr().unwrap().sum_all().unwrap().backward().unwrap();
        assert!(grads.get(&v).unwrap().track_op(), "the premise: a gradient of Σx² carries a graph");
        opt.step(&grads).unwrap();
        for (name, t) in opt.state_tensors() {
            assert!(!t.track_op(), "moment {name} still tracks the update's graph");
        }
    }
}

/// One pass over a transition's N_h + 1 frames gives the same features as encoding
/// o_t and o_{t+1} separately (separate and shared encoders, several N_h).
#[test]
fn transition_features_equal_separate_encoding() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for (history, shared) in [(4, false), (8, true), (16, false), (7, true)] {
        let cfg = NetsConfig { history, ..tiny(EncoderKind::Tcn, shared) };
        let nets = DsacNets::new(&cfg, &Device::Cpu, 2).unwrap();
        let (b, s) = (3, cfg.image_size);
        let window = random(&mut rng, &[b, history + 1, s, s], 1.0).abs().unwrap();
        let (actions, rewards) = (random(&mut rng, &[b, history, 3], 1.0), random(&mut rng, &[b, history], 1.0));
        let t = Transitions::Pixels { frames: window.clone(), actions: actions.clone(), rewards: rewards.clone() };
        // o_t and o_{t+1} are the stored tensors' overlapping views, made contiguous
        // here so the reference encodes plain tensors.
        let part = |x: &Tensor, start: usize, len: usize| x.narrow(1, start, len).unwrap().contiguous().unwrap();
        let obs = Obs::Pixels {
            frames: part(&window, 0, history),
            actions: part(&actions, 0, history - 1),
            rewards: part(&rewards, 0, history - 1),
        };
        let next = Obs::Pixels {
            frames: part(&window, 1, history),
            actions: part(&actions, 1, history - 1),
            rewards: part(&rewards, 1, history - 1),
        };
        let (Obs::Pixels { frames: f0, actions: a0, .. }, Obs::Pixels { frames: f1, rewards: r1, .. }) =
            (t.obs().unwrap(), t.next_obs().unwrap())
        else {
            panic!("pixel transitions give pixel observations")
        };
        let (Obs::Pixels { frames: g0, actions: b0, .. }, Obs::Pixels { frames: g1, rewards: s1, .. }) = (&obs, &next)
        else {
            unreachable!()
        };
        for (view, plain) in [(&f0, g0), (&a0, b0), (&f1, g1), (&r1, s1)] {
            assert_eq!(
                view.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
                plain.flatten_all().unwrap().to_vec1::<f32>().unwrap()
            );
        }
        let together = nets.transition_features(&t).unwrap();
        let online = nets.online_features(&obs).unwrap();
        let (next_policy, next_fraction) = nets.policy_and_fraction_features(&next).unwrap();
        let close = |a: &Tensor, b: &Tensor, what: &str| {
            assert_eq!(a.dims(), b.dims(), "N_h {history} {what}");
            for (u, v) in rows(a).concat().iter().zip(rows(b).concat()) {
                assert!((u - v).abs() <= 1e-5 * (1.0 + v.abs()), "N_h {history} shared {shared} {what}: {u} vs {v}");
            }
        };
        close(&together.online.policy, &online.policy, "policy");
        close(&together.online.fraction, &online.fraction, "fraction");
        close(&together.online.quantile, &online.quantile, "quantile");
        close(&together.next_policy, &next_policy, "next policy");
        close(&together.next_fraction, &next_fraction, "next fraction");
    }
}

/// The fast frames → channel-last transpose equals candle's permute.
#[test]
fn frames_to_channels_last_equals_the_permute() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    // Frames smaller than one transpose block, and several blocks with a partial last one.
    for (b, t, h, w) in [(3, 5, 7, 6), (2, 16, 13, 11)] {
        let frames = random(&mut rng, &[b, t, h, w], 1.0);
        let fast = pednav_nets::ops::frames_to_channels_last(&frames).unwrap();
        let reference = frames.permute((0, 2, 3, 1)).unwrap().reshape((b, 1, h, w, t)).unwrap();
        assert_eq!(fast.dims(), reference.dims());
        assert_eq!(rows(&fast.flatten_from(1).unwrap()), rows(&reference.flatten_from(1).unwrap()));
    }
}
